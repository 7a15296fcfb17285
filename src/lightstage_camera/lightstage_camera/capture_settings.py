"""What one model capture asks of the stage: camera setting, frames per LED image, request size.

Its own module because the acquisition (`acquisition`), the capture folder (`capture_destination`,
which records the setting in rig.yaml) and the noise calibration (`calibration`, the request
size) all need it, and `acquisition` imports `capture_destination`.
"""
from __future__ import annotations

from dataclasses import dataclass

from lightstage_graph.limits import check_camera_setting
from lightstage_physics.rig import N_CHANNELS, N_SITES

__all__ = ["CaptureSettings", "MAX_FRAMES_PER_REQUEST"]

# one stage request's frames must fit the camera's image queue (reliable, keep-last 32)
MAX_FRAMES_PER_REQUEST = 32


@dataclass(frozen=True)
class CaptureSettings:
    """One model capture: camera setting, frames averaged per LED image, request size.

    exposure_us           exposure (and LED on-time) per frame [us]
    gain_db               camera gain [dB] (recorded in rig.yaml with the exposure)
    frames                frames averaged per single-LED image
    bit_depth             significant bits of the camera's mono16 images
    n_sites               illumination sites (4 LEDs each)
    frames_per_request    frames per stage request (one trigger sequence)
    max_saturated_fraction  preview: largest fraction of an LED image's pixels allowed at the
                          camera's maximum before the capture is refused
    """
    exposure_us: int = 30000
    gain_db: float = 15.0
    frames: int = 16
    bit_depth: int = 10
    n_sites: int = N_SITES
    frames_per_request: int = 16
    max_saturated_fraction: float = 0.0

    def __post_init__(self) -> None:
        check_camera_setting(self.exposure_us, self.gain_db)  # LimitError (a ValueError)
        if int(self.frames) != self.frames or self.frames < 1:
            raise ValueError(f"frames must be >= 1, got {self.frames}")
        if not 8 <= int(self.bit_depth) <= 16:
            raise ValueError(f"bit_depth must be 8..16, got {self.bit_depth}")
        if int(self.n_sites) < 1:
            raise ValueError(f"n_sites must be >= 1, got {self.n_sites}")
        if not 1 <= int(self.frames_per_request) <= MAX_FRAMES_PER_REQUEST:
            raise ValueError(f"frames_per_request must be 1..{MAX_FRAMES_PER_REQUEST}, got "
                             f"{self.frames_per_request}")
        if not 0.0 <= self.max_saturated_fraction <= 1.0:
            raise ValueError(f"max_saturated_fraction must be in [0, 1], got "
                             f"{self.max_saturated_fraction}")

    @property
    def n_leds(self) -> int:
        return int(self.n_sites) * N_CHANNELS

    @property
    def max_level(self) -> int:
        return (1 << int(self.bit_depth)) - 1

    @property
    def total_frames(self) -> int:
        return self.n_leds * int(self.frames)
