"""A cache whose bytes changed with its size kept is
rebuilt; `synth --strength` and `--size` out of range are refused before any work."""
import numpy as np
import pytest

from lightstage_physics import synth, synth_cli
from lightstage_physics.capture_format import load_capture, write_capture

from helpers.camera import make_modelset


def test_a_zeroed_cache_of_the_same_size_is_not_trusted(tmp_path):
    root = write_capture(tmp_path / "cap", make_modelset(n_per_class=2, size=16), compress_level=1)
    first = load_capture(root)
    data = root / ".cache" / "models_u16.npy"
    size, stat = data.stat().st_size, data.stat()
    raw = np.load(data, mmap_mode="r+")
    raw[...] = 0  # the data zeroed in place: same size, same header
    raw.flush()
    del raw
    assert data.stat().st_size == size
    again = load_capture(root)
    np.testing.assert_array_equal(again.models, first.models)
    assert np.load(data).any()  # rebuilt from the PNGs
    assert stat.st_size == data.stat().st_size


@pytest.mark.parametrize("strength, message", [
    (-3.0, "strength must be 0 .. 10 (0 = identical real and fake materials, 1 = as tabled), got -3.0"),
    (float("nan"), "strength must be 0 .. 10"),
    (9.0, "strength 9 makes the fake banana's"),
])
def test_a_strength_that_makes_no_material_is_refused(tmp_path, strength, message):
    with pytest.raises(ValueError, match=None) as exc:
        synth.generate(tmp_path / "cap", 16, 1, 1, object_types=("banana",), strength=strength)
    assert message in str(exc.value)
    assert not (tmp_path / "cap").exists()


def test_the_cli_refuses_a_negative_strength(tmp_path, capsys):
    assert synth_cli.main([str(tmp_path / "cap"), "--size", "16", "--strength", "-3",
                       "--types", "banana"]) == 2
    assert "lightstage synth: strength must be 0 .. 10" in capsys.readouterr().err


def test_a_size_that_cannot_be_rendered_in_memory_is_refused_with_the_estimate(tmp_path, capsys):
    assert synth_cli.main([str(tmp_path / "cap"), "--size", "100000", "--types", "banana"]) == 2
    err = capsys.readouterr().err
    assert "lightstage synth: size 100000 px needs about" in err and "use a size up to" in err
    assert not (tmp_path / "cap").exists()


def test_the_memory_estimate_names_the_largest_size_that_fits():
    with pytest.raises(ValueError, match=r"needs about 0\.0205 GiB .* use a size up to 95 px"):
        synth.check_render_memory(100, 2, available=20_000_000)
    synth.check_render_memory(90, 2, available=20_000_000)


@pytest.mark.parametrize("settings, message", [
    (dict(gain_db=1e6), "gain_db = 1000000.0 dB is out of range: give 0 .. 48 dB"),
    (dict(gain_db=float("nan")), "gain_db = nan dB is out of range"),
    (dict(exposure_us=10**12), "exposure_us = 1000000000000 us is out of range"),
    (dict(exposure_us=2.5), "exposure_us must be a whole number of microseconds, got 2.5"),
])
def test_capture_and_calibration_settings_are_those_a_rig_yaml_can_record(settings, message):
    """A capture records its setting in rig.yaml: one rig.yaml would refuse is refused first."""
    from lightstage_camera.capture_settings import CaptureSettings
    from lightstage_camera.calibration import CalibrationSettings
    for kind in (CaptureSettings, CalibrationSettings):
        with pytest.raises(ValueError) as exc:
            kind(**settings)
        assert message in str(exc.value)
