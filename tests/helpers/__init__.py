"""The test suite's helper modules, imported explicitly (`from helpers.suite import ...`):
pytest.ini's `pythonpath = tests` puts tests/ on sys.path, so no helper depends on which
test folder pytest happened to prepend.

Shared by several packages' tests:
  suite               domain ids, params files, project nodes as processes, the suite artifact's patterns
  workers             which pytest-xdist worker this is (disjoint domain ids per worker)
  ros                 node processes checked through the graph (`running_nodes`), their environment
  dask_cluster        a real Dask scheduler and workers as processes
  proc_sockets        which sockets a process holds (nothing listens beyond loopback)
  artifact_mutations  Hypothesis strategies for malformed artifact files
  markers             the `process` marker a module declares, the guard that keeps fast tests from starting processes
  script_help         a script's --help with its imports stood in (tests/test_benchmarks.py)
One package's tests (tests/<package>/...):
  bringup, web, browser              lightstage_bringup (launcher, `lightstage web`/`view`, Chromium)
  camera, acquisition, emulated_cameras  lightstage_camera (models, frame sources, pylon/Aravis emulation)
  driver, firmware_wire, graded_pins lightstage_driver (processes, the raw protocol, pin on-times)
  recording, write_faults            lightstage_recording (serialized messages, a disk that fills up)
  trainer                            mux_trainer (small structured search data)
nodes/ holds stand-in node scripts that tests start as processes by module name
(`ros_fake_driver_node`, `bringup_fake_node`, `bringup_no_graph_node`; `ros.NODE_SCRIPTS` is
put on the children's PYTHONPATH, and pytest.ini's `pythonpath` on the run's, where `lightstage
up` checks in-process that a node's module exists); the tests do not import them.
"""
