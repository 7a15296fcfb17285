"""SHIM(issue 13): remove at merge. Frame matching and decoding moved to
`lightstage_graph.frames`, stamps to `lightstage_graph.stamps`, AcquisitionError to
`lightstage_camera.errors`; camera_node.py and the acquisition cores (acquisition.py,
calibration.py) still import them from here."""
from lightstage_graph.frames import mono16_to_gray  # noqa: F401  SHIM(issue 13): remove at merge
from lightstage_graph.stamps import stamp_to_ns  # noqa: F401  SHIM(issue 13): remove at merge

from .errors import AcquisitionError  # noqa: F401  SHIM(issue 13): remove at merge
