"""Every command through a real pty, against each firmware backend (python simulator, AVR in simavr).

What the firmware put on its pins (latched LED words, trigger pulses) is compared with
what was asked.
"""
import time

import numpy as np
import pytest

from lightstage_driver import protocol as p
from lightstage_driver.errors import DisconnectedError, LightStageError, NakError, PatternError
from lightstage_driver.stage import LightStage

from helpers.driver import distinct_words, wait_until

pytestmark = pytest.mark.process


def one_hot(*leds):
    pattern = np.zeros(32)
    pattern[list(leds)] = 1.0
    return pattern


def test_identify_reports_the_rig(stage):
    ident = stage.identity
    assert (ident.protocol_version, ident.led_count, ident.sites, ident.channels) == (1, 32, 8, 4)
    assert ident.pwm_bits in (0, 8, 12)
    assert 1 <= ident.min_exposure_us <= ident.max_exposure_us
    assert ident.max_sequence >= 1 and ident.max_payload == p.MAX_PAYLOAD
    assert ident.name.startswith('lightstage')


def test_heartbeat_reports_status_and_syncs_the_clock(stage):
    host_start = time.monotonic()
    first = stage.heartbeat()
    assert not first.leds_lit and not first.sequence_running
    later = []

    def firmware_clock_advanced() -> bool:
        later.append(stage.heartbeat())
        return (later[-1].t_us - first.t_us) % 2**32 >= 40_000
    assert wait_until(firmware_clock_advanced, 10.0)
    host_us = (time.monotonic() - host_start) * 1e6
    elapsed_us = (later[-1].t_us - first.t_us) % 2**32
    assert elapsed_us <= 10 * host_us        # microseconds (simavr may run faster than real time)
    assert stage.clock.synced and stage.clock.uncertainty_s < 0.05


def test_set_pattern_shows_the_word_and_all_off_clears_it(stage, backend):
    word = stage.set_pattern(one_hot(0, 9, 31), show_now=True)
    assert word == (1 << 0) | (1 << 9) | (1 << 31)
    assert wait_until(lambda: backend.current_word() == word, 2.0)
    assert stage.heartbeat().leds_lit
    stage.all_off()
    assert wait_until(lambda: backend.current_word() == 0, 2.0)
    assert distinct_words(backend) == [word, 0]


def observed_up_to_now(stage, backend) -> int:
    """A barrier on what the backend reports: the firmware handles commands in order, so once
    the word latched by a command sent now is observed, everything before it is too."""
    word = stage.set_pattern(one_hot(30), show_now=True)
    assert wait_until(lambda: backend.current_word() == word, 5.0)
    return word


def test_set_pattern_without_show_now_only_arms(stage, backend):
    stage.set_pattern(one_hot(4), show_now=False)
    assert not stage.heartbeat().leds_lit
    word = observed_up_to_now(stage, backend)
    assert distinct_words(backend) in ([word], [0, word])     # one_hot(4) was never latched


def test_fire_lights_the_pattern_for_the_exposure(stage, backend):
    stage.set_pattern(one_hot(1, 2), show_now=False)
    stage.heartbeat()
    before = time.monotonic()
    trigger = stage.fire(3000)
    after = time.monotonic()
    assert trigger.exposure_us == 3000
    # the trigger happened during the call, on the host clock (within the mapping's error)
    slack = trigger.uncertainty_s + 0.002
    assert before - slack <= trigger.host_time_s <= after - 0.003 + slack
    assert wait_until(lambda: len(backend.trigger_pulses()) == 1, 2.0)
    pulse, = backend.trigger_pulses()
    assert pulse.width_us == pytest.approx(3000, abs=backend.pulse_tolerance_us)
    assert distinct_words(backend) == [0b110, 0]


def test_apply_runs_a_sequence_with_one_trigger_each(stage, backend):
    patterns = np.array([one_hot(k * 4 + (k % 4)) for k in range(8)])
    exposures = [500 + 250 * k for k in range(8)]
    seen = []
    triggers = stage.apply(patterns, exposures, trigger=True, gap_us=200, on_trigger=seen.append)
    assert seen == triggers                  # reported one by one as the events came in
    assert [t.index for t in triggers] == list(range(8))
    assert [t.word for t in triggers] == [1 << (k * 4 + k % 4) for k in range(8)]
    starts = [t.firmware_us for t in triggers]
    for k in range(7):       # exposure + gap apart (the firmware may stretch the gap <= 2 ms)
        assert exposures[k] + 200 <= starts[k + 1] - starts[k] <= exposures[k] + 200 + 2000 + 10
    assert all(a.host_time_s < b.host_time_s for a, b in zip(triggers, triggers[1:]))
    assert wait_until(lambda: len(backend.trigger_pulses()) == 8, 2.0)
    widths = [pulse.width_us for pulse in backend.trigger_pulses()]
    assert widths == pytest.approx(exposures, abs=backend.pulse_tolerance_us)
    lit = [w for w in distinct_words(backend) if w]
    assert lit == [t.word for t in triggers]
    assert backend.current_word() == 0


def test_apply_longer_than_one_firmware_sequence_is_chunked(stage, backend):
    n = stage.identity.max_sequence + 3
    patterns = np.array([one_hot(k % 32) for k in range(n)])
    triggers = stage.apply(patterns, 100)
    assert len(triggers) == n and [t.index for t in triggers] == list(range(n))
    assert wait_until(lambda: len(backend.trigger_pulses()) == n, 2.0)


def test_apply_without_trigger_leaves_the_last_pattern_lit(stage, backend):
    assert stage.apply(np.array([one_hot(3), one_hot(5)]), 1000, trigger=False) == []
    assert wait_until(lambda: backend.current_word() == 1 << 5, 2.0)
    assert backend.trigger_pulses() == []


@pytest.mark.parametrize('patterns, exposure, match', [
    (np.zeros(30), 1000, 'exactly 32'),
    (np.full(32, np.nan), 1000, 'NaN'),
    (np.full(32, -1.0), 1000, 'negative'),
    (np.full(32, 2.0), 1000, 'above 1'),
    (np.zeros(32), 1, 'outside the firmware range'),
    (np.zeros(32), 10**9, 'outside the firmware range'),
])
def test_bad_input_is_refused_before_anything_is_sent(stage, backend, patterns, exposure, match):
    sent = stage.link.stats.commands
    with pytest.raises(PatternError, match=match):
        stage.apply(patterns, exposure)
    assert stage.link.stats.commands == sent
    word = observed_up_to_now(stage, backend)
    assert distinct_words(backend) in ([word], [0, word])
    assert backend.trigger_pulses() == []


def test_firmware_refuses_out_of_range_exposure_with_its_reason(stage, backend):
    # bypass the host's own check to see the firmware's
    with pytest.raises(NakError, match='EXPOSURE_RANGE') as info:
        stage.link.transact(p.Command.FIRE, p.pack_u32(stage.identity.max_exposure_us + 1))
    assert info.value.reason == p.NakReason.EXPOSURE_RANGE
    assert info.value.value == stage.identity.max_exposure_us + 1
    assert backend.trigger_pulses() == []


def test_firmware_nak_for_an_unknown_command(stage):
    with pytest.raises(NakError, match='UNKNOWN_COMMAND'):
        stage.link.transact(0x3C)


def test_watchdog_darkens_the_leds_after_host_silence(stage, backend):
    trips = []
    stage.on_watchdog = trips.append
    stage.set_watchdog(150)
    word = stage.set_pattern(one_hot(7, 8), show_now=True)
    assert wait_until(lambda: backend.current_word() == word, 2.0)
    assert wait_until(lambda: backend.current_word() == 0, 10.0)
    words = backend.led_words()
    assert words[-1].time_s - next(w for w in words if w.word == word).time_s == \
        pytest.approx(0.150, abs=0.01)    # on the firmware clock
    status = stage.heartbeat()           # host is back: the trip is reported
    assert status.watchdog_tripped and not status.leds_lit
    assert len(trips) == 1


def test_link_recovers_after_the_firmware_is_killed_and_restarted(stage, backend):
    stage.set_pattern(one_hot(0), show_now=True)
    backend.kill()
    with pytest.raises(LightStageError) as info:
        stage.heartbeat()
    assert isinstance(info.value, (DisconnectedError,)) or 'does not exist' in str(info.value) \
        or 'no IDENTIFY' in str(info.value)
    backend.restart()
    backend.reset_observations()
    status = stage.heartbeat()          # reopens the port and re-identifies
    assert not status.leds_lit           # a reset firmware comes up dark
    assert stage.link.stats.reconnects >= 1
    trigger = stage.apply(one_hot(2), 500)[0]
    assert trigger.word == 1 << 2
    assert wait_until(lambda: len(backend.trigger_pulses()) == 1, 2.0)


def test_clock_wraps_without_breaking_stamps():
    from lightstage_driver.sim_backend import PythonSimBackend
    with PythonSimBackend(clock_offset_us=2**32 - 20_000) as backend:
        with LightStage(backend.port) as stage:
            triggers = []
            # at least 4 triggers, until the firmware clock has crossed the wrap
            while len(triggers) < 4 or triggers[-1].firmware_us <= 2**32:
                assert len(triggers) < 100, 'the firmware clock did not wrap'
                triggers += stage.apply(one_hot(0), 5000)
            us = [t.firmware_us for t in triggers]
            assert all(b - a >= 5000 for a, b in zip(us, us[1:]))
            hosts = [t.host_time_s for t in triggers]
            assert all(b > a for a, b in zip(hosts, hosts[1:]))
            assert hosts[-1] - hosts[0] == pytest.approx((us[-1] - us[0]) * 1e-6, abs=2e-3)


def test_pwm_firmware_gets_levels_and_dims():
    from lightstage_driver.sim_backend import PythonSimBackend
    with PythonSimBackend(pwm_bits=8) as backend, LightStage(backend.port) as stage:
        assert stage.identity.pwm_bits == 8
        dim = np.zeros(32)
        dim[[0, 1]] = [0.2, 1.0]            # 0.2 is off on an on/off rig, dimmed here
        triggers = stage.apply(np.array([dim, one_hot(4)]), 500)
        assert [t.word for t in triggers] == [0b11, 1 << 4]
        assert wait_until(lambda: len(backend.trigger_pulses()) == 2, 2.0)
        stage.apply(dim, 500, trigger=False)
        assert wait_until(lambda: backend.current_word() == 0b11, 2.0)
