"""SHIM(issue 13): remove at merge. Moved to `lightstage_graph.spin`; camera_node.py still
imports it from here."""
from lightstage_graph.spin import init_node, spin_until_stopped  # noqa: F401  SHIM(issue 13): remove at merge
