"""A trigger's values must never stop the camera. A gain or exposure out of range,
NaN LED values ... are refused naming the field and reported as a lost frame; the camera
goes on with the next trigger."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from lightstage_camera.camera_backend import Trigger, check_trigger, hand_trigger
from lightstage_camera.sim_camera import SimCamera, SimCameraBackend
from lightstage_graph.limits import (EXPOSURE_US_MAX, GAIN_DB_MAX, GAIN_DB_MIN, LimitError,
                                     check_exposure_us, check_gain_db)

from helpers.camera import make_modelset

LEDS = np.full(32, 0.5, np.float32)


@pytest.fixture(scope='module')
def backend():
    frames = []
    backend = SimCameraBackend(frames.append, SimCamera(make_modelset(), noise='auto', seed=0))
    backend.delivered = frames
    return backend


@pytest.mark.parametrize('gain_db', [1e6, math.inf, -math.inf, -1e6, -0.5, 48.5, 1e300])
def test_a_gain_no_camera_has_is_refused_naming_gain_db(backend, gain_db):
    before = len(backend.delivered)
    reason = hand_trigger(backend, Trigger(1, 7, LEDS, 22500, gain_db))
    assert reason.startswith('bad trigger values: gain_db = ') and '0 .. 48 dB' in reason
    assert len(backend.delivered) == before
    # the camera goes on: the next, good trigger is imaged
    assert hand_trigger(backend, Trigger(2, 8, LEDS, 22500, 17.5)) == ''
    assert len(backend.delivered) == before + 1


@pytest.mark.parametrize('exposure_us', [EXPOSURE_US_MAX + 1, 2**32 - 1])
def test_an_exposure_out_of_range_is_refused_naming_exposure_us(backend, exposure_us):
    reason = hand_trigger(backend, Trigger(1, 7, LEDS, exposure_us, 15.0))
    assert 'exposure_us = ' in reason and 'out of range' in reason


def test_nan_means_the_default_gain_and_edges_of_the_range_are_taken(backend):
    for gain in (math.nan, GAIN_DB_MIN, GAIN_DB_MAX):
        assert hand_trigger(backend, Trigger(1, 7, LEDS, 22500, gain)) == ''


@pytest.mark.parametrize('leds, what', [(np.full(32, np.nan, np.float32), 'intensities'),
                                        (np.full(32, 2.0, np.float32), 'intensities'),
                                        (np.full(31, 0.5, np.float32), '32 LED values')])
def test_bad_led_values_are_refused(backend, leds, what):
    assert what in hand_trigger(backend, Trigger(1, 7, leds, 22500, 15.0))


def test_whatever_the_backend_trips_over_is_the_reason_not_an_exception():
    class Broken(SimCameraBackend):
        def trigger(self, trigger):
            raise OverflowError('(34, Numerical result out of range)')
    broken = Broken(lambda frame: None, SimCamera(make_modelset(), noise='none'))
    assert hand_trigger(broken, Trigger(1, 7, LEDS, 22500, 15.0)).startswith('OverflowError: ')


finite_or_not = st.floats(allow_nan=True, allow_infinity=True, width=32)


@settings(max_examples=200, deadline=None)
@given(gain_db=finite_or_not, exposure_us=st.integers(0, 2**32 - 1),
       led=st.floats(allow_nan=True, allow_infinity=True, width=32))
def test_fuzz_trigger_values_never_escape_and_name_the_field(gain_db, exposure_us, led):
    """Any gain, exposure and LED value an IlluminationState can carry: the trigger is
    imaged, or refused with a reason naming the field at fault; nothing is raised."""
    frames = []
    backend = SimCameraBackend(frames.append, SimCamera(make_modelset(size=8), noise='auto', seed=0))
    leds = np.full(32, led, np.float32)
    reason = hand_trigger(backend, Trigger(1, 3, leds, exposure_us, gain_db))
    gain_ok = math.isnan(gain_db) or GAIN_DB_MIN <= gain_db <= GAIN_DB_MAX
    exposure_ok = 1 <= exposure_us <= EXPOSURE_US_MAX  # the sim camera needs an exposure
    leds_ok = math.isfinite(led) and 0 <= led <= 1
    if gain_ok and exposure_ok and leds_ok:
        assert reason == '' and len(frames) == 1
        return
    assert reason and not frames
    named = [name for name, ok in (('gain_db', gain_ok), ('exposure_us', exposure_ok),
                                   ('intensities', leds_ok)) if not ok]
    assert any(name in reason for name in named), (reason, named)


def test_the_shared_checks_name_the_field_they_are_given():
    with pytest.raises(LimitError, match=r"pattern 3: gain_db = inf dB is out of range"):
        check_gain_db(math.inf, 'pattern 3: gain_db')
    with pytest.raises(LimitError, match=r"exposure_us = -5 us is out of range: give 1 \.\. 10000000 us"):
        check_exposure_us(-5)
    with pytest.raises(LimitError, match="must be a number, got 'loud'"):
        check_gain_db('loud')
    assert check_exposure_us(0, zero_is_default=True) == 0.0
    with pytest.raises(LimitError):
        check_trigger(Trigger(1, 1, LEDS, 0, True))


@pytest.mark.ros
def test_the_camera_node_survives_a_gain_of_1e6_and_reports_the_trigger_lost(stage_capture):
    """`gain_db` = 1e6 killed the camera node (OverflowError in noise.gain_ratio)
    and the launcher then stopped the graph."""
    from test_camera_node import CameraHarness
    h = CameraHarness(capture_dir=str(stage_capture), noise='auto', diagnostics_period_s=0.2)
    try:
        h.trigger(5, 1_000, LEDS, gain_db=1e6)
        h.trigger(6, 2_000, LEDS, gain_db=math.inf)
        h.trigger(7, 3_000, LEDS, gain_db=17.5)
        assert h.spin_until(lambda: len(h.lost) == 2 and len(h.images) == 1)
        assert [m.sequence for m in h.lost] == [5, 6]
        assert all('gain_db = ' in m.reason and 'out of range' in m.reason for m in h.lost)
        values = {kv.key: kv.value for kv in h.last_status().values}
        assert values['triggers_dropped'] == '2' and 'gain_db' in values['last_error']
    finally:
        h.close()
