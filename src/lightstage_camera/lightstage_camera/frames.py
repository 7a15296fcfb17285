"""SHIM(issue 13): remove at merge. Frame matching moved to `lightstage_graph.frames`,
AcquisitionError to `lightstage_camera.errors`; the camera node and the acquisition cores
(acquisition.py, calibration.py) still import them from here."""
from lightstage_graph.errors import MissingImagesError  # noqa: F401  SHIM(issue 13): remove at merge
from lightstage_graph.frames import (MONO16_ENCODINGS, ImageMatcher,  # noqa: F401  SHIM(issue 13): remove at merge
                                     image_from_buffer, mono16_to_gray)
from lightstage_graph.stamps import format_stamp, stamp_to_ns  # noqa: F401  SHIM(issue 13): remove at merge

from .errors import AcquisitionError  # noqa: F401  SHIM(issue 13): remove at merge
