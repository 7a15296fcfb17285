"""The method lives in plain modules: every module of the packages except the nodes and the
ROS glue listed below imports without rclpy, so it runs in a notebook, a CLI or a Dask
worker that has no ROS. And the packages depend on each other as docs/ARCHITECTURE.md says."""
import ast
import graphlib
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.process

SRC = Path(__file__).resolve().parents[1] / 'src'
# modules that are ROS by design besides the nodes: the graph contract's rclpy parts (QoS
# profiles, the node main, a worker thread's result awaited in the executor, the stage
# client) and the recorder's rclpy glue
ROS_MODULES = {'lightstage_graph.qos', 'lightstage_graph.spin', 'lightstage_graph.awaitable',
               'lightstage_graph.stage_client', 'lightstage_recording.bag_ros'}

# package -> the project packages it may import (lightstage_interfaces aside): a tree, no cycles.
# The learning packages take the stage's physics from lightstage_physics and never import
# lightstage_camera (camera SDKs, backends); the driver takes the LED layout from lightstage_graph.
ALLOWED_IMPORTS = {
    'lightstage_graph': set(),
    'lightstage_physics': {'lightstage_graph'},
    'lightstage_driver': {'lightstage_graph'},
    'lightstage_camera': {'lightstage_graph', 'lightstage_physics'},
    'mux_classifier': {'lightstage_graph', 'lightstage_physics'},
    'mux_trainer': {'lightstage_graph', 'lightstage_physics', 'mux_classifier'},
    'lightstage_recording': {'lightstage_graph'},
    'lightstage_bringup': {'lightstage_graph', 'lightstage_physics', 'lightstage_camera',
                           'lightstage_driver', 'mux_classifier', 'mux_trainer',
                           'lightstage_recording'},
}
# the learning code and the physics it needs import no camera SDK (pypylon; Aravis through gi)
NO_CAMERA_PACKAGES = ('lightstage_physics', 'mux_classifier', 'mux_trainer')
CAMERA_MODULES = ('lightstage_camera', 'pypylon', 'gi')


def package_modules(package: str) -> dict[str, Path]:
    """{dotted name: file} of every module of `package`, its subpackages' too (no __init__)."""
    root = SRC / package / package
    return {'.'.join((package, *m.relative_to(root).with_suffix('').parts)): m
            for m in sorted(root.rglob('*.py')) if m.stem != '__init__'}


def pure_modules() -> list[str]:
    names = []
    for package in sorted(p.parent.name for p in SRC.glob('*/*/__init__.py')):
        for name in package_modules(package):
            if name.endswith('_node') or name in ROS_MODULES:
                continue
            names.append(name)
    return names


def assert_imports_load_no(modules: list[str], forbidden: str) -> None:
    """Importing each of `modules`, in order, in a fresh interpreter never loads `forbidden`."""
    code = ('import importlib, sys\n'
            f'for name in {modules!r}:\n'
            '    importlib.import_module(name)\n'
            f'    assert {forbidden!r} not in sys.modules, f"importing {{name}} imported {forbidden}"\n')
    p = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]


def test_every_core_module_imports_without_rclpy():
    modules = pure_modules()
    assert {'lightstage_camera.acquisition', 'lightstage_camera.calibration',
            'lightstage_physics.synth', 'lightstage_physics.render_jax', 'lightstage_graph.leds',
            'mux_trainer.greedy', 'mux_classifier.observe',
            'lightstage_recording.recording', 'lightstage_recording.writer', 'lightstage_driver.protocol',
            'lightstage_graph.frames', 'lightstage_graph.params', 'lightstage_graph.names',
            'lightstage_graph.stamps', 'lightstage_graph.diagnostics', 'lightstage_graph.ros_env',
            'lightstage_graph.graph_client'} <= set(modules)
    assert_imports_load_no(modules, 'rclpy')


def imported_modules(module: Path, package: str) -> set[str]:
    """The absolute names of the modules `module` (a file of `package`, dotted: a subpackage
    too) imports anywhere in it (function-level and TYPE_CHECKING imports too): `from a.b
    import c` gives a.b and a.b.c."""
    names = set()
    for node in ast.walk(ast.parse(module.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ''
            if node.level:
                parts = package.split('.')
                parent = '.'.join(parts[:len(parts) - node.level + 1])
                base = f'{parent}.{base}' if base else parent
            names |= {base} | {f'{base}.{a.name}' for a in node.names}
    return names


def imported_project_packages(package: str) -> dict[str, set[str]]:
    """{other project package: the modules of `package` that import it}."""
    found: dict[str, set[str]] = {}
    for dotted, module in package_modules(package).items():
        for name in imported_modules(module, dotted.rpartition('.')[0]):
            top = name.split('.')[0]
            if top in ALLOWED_IMPORTS and top != package:
                found.setdefault(top, set()).add(module.name)
    return found


def test_packages_import_each_other_only_down_the_documented_tree():
    assert set(ALLOWED_IMPORTS) == {p.parent.name for p in SRC.glob('*/*/__init__.py')}
    for package, allowed in ALLOWED_IMPORTS.items():
        extra = {p: m for p, m in imported_project_packages(package).items() if p not in allowed}
        assert not extra, f'{package} imports {extra}; docs/ARCHITECTURE.md allows only {allowed or "none"}'


def test_no_import_cycles_between_packages_or_modules():
    """The documented tree has no cycle, and no two modules import each other round a circle
    (counting imports inside functions and under TYPE_CHECKING: a circle there is one a
    refactoring has to untangle too)."""
    packages = {p: set(imported_project_packages(p)) for p in ALLOWED_IMPORTS}
    graphlib.TopologicalSorter(packages).prepare()  # CycleError names the circle
    modules = {name: path for package in ALLOWED_IMPORTS
               for name, path in package_modules(package).items()}
    graph = {name: {d for d in imported_modules(path, name.rpartition('.')[0])
                    if d in modules and d != name}
             for name, path in modules.items()}
    graphlib.TopologicalSorter(graph).prepare()


def test_learning_code_and_physics_import_no_camera():
    """Every module of the trainer, the classifier and the physics package, nodes included,
    imports without lightstage_camera and without a camera SDK (pypylon, gi for Aravis)."""
    modules = sorted(name for package in NO_CAMERA_PACKAGES for name in package_modules(package))
    assert {'lightstage_physics.render_jax', 'lightstage_physics.synth', 'mux_trainer.trainer_node',
            'mux_trainer.learned.estimator', 'mux_classifier.hog_kernel'} <= set(modules)
    code = ('import importlib, sys\n'
            f'for name in {modules!r}:\n'
            '    importlib.import_module(name)\n'
            f'    found = [m for m in {CAMERA_MODULES!r} if m in sys.modules]\n'
            '    assert not found, f"importing {name} imported {found}"\n')
    p = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]


def test_the_classifier_package_never_imports_jax():
    """Learned models classify in numpy (`mux_classifier.learned_model`); JAX is the
    trainer's. No module of mux_classifier names jax in any import (function-level too), and
    importing every one of them, the classifier node included, loads no jax."""
    naming = sorted(m.name for m in (SRC / 'mux_classifier' / 'mux_classifier').glob('*.py')
                    if any(n.split('.')[0] in ('jax', 'jaxlib')
                           for n in imported_modules(m, 'mux_classifier')))
    assert not naming, f'{naming} import jax'
    modules = sorted(f'mux_classifier.{m.stem}' for m in
                     (SRC / 'mux_classifier' / 'mux_classifier').glob('*.py') if m.stem != '__init__')
    assert {'mux_classifier.classifier_node', 'mux_classifier.learned_model',
            'mux_classifier.artifact'} <= set(modules)
    assert_imports_load_no(modules, 'jax')
