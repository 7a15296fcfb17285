"""The errors of lightstage_camera's cores, in one place; each message says what to do.

`AcquisitionError` (images could not be acquired on the stage, or do not make a usable
capture) is the base of the capture errors; it is a `lightstage_graph.errors.StageError`, so
a node's one `except StageError` also catches the stage failing to deliver.
"""
from __future__ import annotations

from lightstage_graph.errors import StageError

__all__ = ["AcquisitionError", "CaptureCancelled", "DestinationError", "ExposureError",
           "CaptureFormatError", "NoiseFileError", "SampleError"]


class AcquisitionError(StageError):
    """Images could not be acquired on the stage, or do not make a usable capture."""


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
