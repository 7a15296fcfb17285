"""Old name of `candidate_patterns`, kept for greedy.py (the search-speed line's file)."""
# SHIM(issue 13): remove at merge
from lightstage_camera.rig import N_LEDS  # noqa: F401

from .candidate_patterns import site_pattern_candidates  # noqa: F401
