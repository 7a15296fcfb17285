"""Errors of the camera package's procedures (model capture, noise calibration)."""
from lightstage_graph.errors import StageError


class AcquisitionError(StageError):
    """Images could not be acquired on the stage, or do not make a usable capture; the message
    says why and what to do. A StageError: the stage failing to deliver is one cause."""
