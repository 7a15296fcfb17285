"""The errors of lightstage_camera's cores, in one place; each message says what to do.

`frames.AcquisitionError` (images could not be acquired on the stage) is the base of the
capture errors; it stays in `frames` for now.
"""
from __future__ import annotations

from .frames import AcquisitionError

__all__ = ["CaptureCancelled", "DestinationError", "ExposureError", "CaptureFormatError",
           "NoiseFileError", "SampleError"]


class CaptureCancelled(AcquisitionError):
    """A capture or calibration was cancelled between stage requests; nothing was written."""


class DestinationError(AcquisitionError):
    """A capture folder, pose or output file cannot take what is to be written; the message
    says what to do."""


class ExposureError(AcquisitionError):
    """The preview found clipped LED images; the message names them and suggests an exposure."""


class CaptureFormatError(ValueError):
    """A capture folder that does not follow the format; the message names the file."""


class NoiseFileError(ValueError):
    """A noise file that does not load; the message names the file and the problem."""


class SampleError(ValueError):
    """A sample name or index that is not in the capture; the message lists what is."""
