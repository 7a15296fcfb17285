"""The method lives in plain modules: every module of the packages except the nodes and the
ROS glue listed below imports without rclpy, so it runs in a notebook, a CLI or a Dask
worker that has no ROS. And the packages depend on each other as docs/ARCHITECTURE.md says."""
import ast
import subprocess
import sys
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / 'src'
# modules that are ROS by design besides the nodes: the graph contract's rclpy parts (QoS
# profiles, the node main, the stage client) and the recorder's rclpy glue
ROS_MODULES = {'lightstage_graph.qos', 'lightstage_graph.spin', 'lightstage_graph.stage_client',
               'lightstage_recording.bag_ros'}

# package -> the project packages it may import (lightstage_interfaces aside): a tree, no cycles
ALLOWED_IMPORTS = {
    'lightstage_graph': set(),
    'lightstage_driver': {'lightstage_graph'},
    'lightstage_camera': {'lightstage_graph'},
    'mux_classifier': {'lightstage_graph', 'lightstage_camera'},
    'mux_trainer': {'lightstage_graph', 'lightstage_camera', 'mux_classifier'},
    'lightstage_recording': {'lightstage_graph'},
    'lightstage_bringup': {'lightstage_graph', 'lightstage_camera', 'lightstage_driver',
                           'mux_classifier', 'mux_trainer', 'lightstage_recording'},
}


def pure_modules() -> list[str]:
    names = []
    for package in sorted(p.parent for p in SRC.glob('*/*/__init__.py')):
        for module in sorted(package.glob('*.py')):
            name = f'{package.name}.{module.stem}'
            if module.stem == '__init__' or module.stem.endswith('_node') or name in ROS_MODULES:
                continue
            names.append(name)
    return names


def test_every_core_module_imports_without_rclpy():
    modules = pure_modules()
    assert {'lightstage_camera.acquisition', 'lightstage_camera.calibration',
            'mux_trainer.greedy', 'mux_classifier.observe',
            'lightstage_recording.recording', 'lightstage_recording.writer', 'lightstage_driver.protocol',
            'lightstage_graph.frames', 'lightstage_graph.params', 'lightstage_graph.names',
            'lightstage_graph.stamps', 'lightstage_graph.diagnostics', 'lightstage_graph.ros_env',
            'lightstage_graph.graph_client'} <= set(modules)
    code = ('import importlib, sys\n'
            f'for name in {modules!r}:\n'
            '    importlib.import_module(name)\n'
            '    assert "rclpy" not in sys.modules, f"importing {name} imported rclpy"\n')
    p = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]


def imported_project_packages(package: str) -> dict[str, set[str]]:
    """{other project package: the modules of `package` that import it}."""
    found: dict[str, set[str]] = {}
    for module in (SRC / package / package).glob('*.py'):
        for node in ast.walk(ast.parse(module.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module] if isinstance(node, ast.ImportFrom) and node.module and not node.level else []
            for name in names:
                top = name.split('.')[0]
                if top in ALLOWED_IMPORTS and top != package:
                    found.setdefault(top, set()).add(module.name)
    return found


def test_packages_import_each_other_only_down_the_documented_tree():
    assert set(ALLOWED_IMPORTS) == {p.parent.name for p in SRC.glob('*/*/__init__.py')}
    for package, allowed in ALLOWED_IMPORTS.items():
        extra = {p: m for p, m in imported_project_packages(package).items() if p not in allowed}
        assert not extra, f'{package} imports {extra}; docs/ARCHITECTURE.md allows only {allowed or "none"}'
