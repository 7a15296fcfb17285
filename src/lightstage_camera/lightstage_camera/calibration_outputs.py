"""The files of a noise calibration: the noise file and the noise-characteristic plot.

Checked before anything is lit (`check_calibration_outputs`) and written after the fit
(`write_calibration_outputs`); a file that cannot be written raises DestinationError with
the fit in its message, so the measurement is kept.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from lightstage_physics.errors import DestinationError
from lightstage_physics.noise import save_noise_file
from lightstage_physics.output_files import NOISE_FILE, PLOT_FILE, check_output_file

if TYPE_CHECKING:
    from .calibration import CalibrationResult

__all__ = ["check_calibration_outputs", "write_calibration_outputs", "PLOT_SUFFIXES",
           "NOISE_FILE_SUFFIXES"]

# what plot_noise_characteristic can draw into (matplotlib's Agg, PDF, SVG, PS backends)
PLOT_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg", ".tif", ".tiff", ".eps", ".ps")
NOISE_FILE_SUFFIXES = (".yaml", ".yml")


def check_calibration_outputs(noise_path: str = "", plot_path: str = "",
                              overwrite: bool = False) -> tuple[Path | None, Path | None]:
    """The noise file and plot a calibration will write, checked before anything is lit:
    known suffixes (which also keeps the two apart), nothing replaced unless `overwrite` and
    then only a noise file by a noise file and a plot by a plot (never a capture's rig.yaml),
    folders that take new files. None for an empty path. Raises DestinationError."""
    targets = []
    for path, suffixes, what, kind in ((noise_path, NOISE_FILE_SUFFIXES, "noise file", NOISE_FILE),
                                       (plot_path, PLOT_SUFFIXES, "plot", PLOT_FILE)):
        if not str(path).strip():
            targets.append(None)
            continue
        target = check_output_file(path, overwrite, kind)
        if target.suffix.lower() not in suffixes:
            raise DestinationError(f"the {what} {target} should end in one of "
                                   f"{', '.join(suffixes)} (the {what} format follows it)")
        targets.append(target)
    return targets[0], targets[1]


def write_calibration_outputs(result: "CalibrationResult", noise_path: str = "",
                              plot_path: str = "", overwrite: bool = False,
                              measured_at: str = "") -> tuple[str, str]:
    """The noise file (`noise.save_noise_file`) and the noise-characteristic plot (with the
    fit generalized to Sigma1..3) of a calibration; empty paths are skipped. Returns the
    paths written ('' for skipped ones). A file that cannot be written raises
    DestinationError with the fit in its message, so the measurement is kept."""
    written = ["", ""]
    try:
        targets = check_calibration_outputs(noise_path, plot_path, overwrite)
        for target in targets:
            if target is not None:
                target.parent.mkdir(parents=True, exist_ok=True)
        _write_calibration_files(result, targets, measured_at, written)
    except (DestinationError, OSError) as exc:
        fit = result.model
        raise DestinationError(
            f"{exc}; the fit, not written: sigma_p2 = {fit.sigma_p2:.6g} (+-{result.stderr[0]:.2g}), "
            f"sigma_r2 = {fit.sigma_r2:.6g} (+-{result.stderr[1]:.2g}) at {fit.gain_db:g} dB, "
            f"{fit.exposure_ms:g} ms" + (f" (written: {', '.join(w for w in written if w)})"
                                          if any(written) else "")) from None
    return written[0], written[1]


def _write_calibration_files(result: "CalibrationResult", targets, measured_at: str,
                             written: list) -> None:
    s = result.settings
    if targets[0] is not None:
        measured = {"levels": int(s.levels), "frames_per_level": int(s.frames_per_level),
                    "leds_lit": [int(n) for n in result.leds_lit],
                    "image_size": [int(v) for v in result.image_shape],
                    "pixels_used": result.pixels_used,
                    "mean_range": [round(float(result.characteristic.pixel_mean.min()), 2),
                                   round(float(result.characteristic.pixel_mean.max()), 2)]}
        if measured_at:
            measured["at"] = measured_at
        save_noise_file(targets[0], result.model, result.stderr, measured)
        written[0] = str(targets[0])
    if targets[1] is not None:
        from lightstage_physics.camera_plots import plot_noise_characteristic  # matplotlib: only when asked
        plot_noise_characteristic(targets[1], result.characteristic, result.model,
                                  result.generalized())
        written[1] = str(targets[1])
