"""The method lives in plain modules: every module of the packages except the nodes (and the
rclpy glue of the recorder) imports without rclpy, so it runs in a notebook, a CLI or a
Dask worker that has no ROS."""
import subprocess
import sys
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / 'src'
# modules that are ROS by design besides the nodes: the recorder's rclpy glue, the nodes' main
ROS_MODULES = {'bag_ros', 'spinning'}


def pure_modules() -> list[str]:
    names = []
    for package in sorted(p.parent for p in SRC.glob('*/*/__init__.py')):
        for module in sorted(package.glob('*.py')):
            if module.stem == '__init__' or module.stem.endswith('_node') \
                    or module.stem in ROS_MODULES:
                continue
            names.append(f'{package.name}.{module.stem}')
    return names


def test_every_core_module_imports_without_rclpy():
    modules = pure_modules()
    assert {'lightstage_camera.acquisition', 'lightstage_camera.calibration',
            'mux_trainer.greedy', 'mux_classifier.observe',
            'lightstage_recording.recording', 'lightstage_recording.writer', 'lightstage_driver.protocol'} <= set(modules)
    code = ('import importlib, sys\n'
            f'for name in {modules!r}:\n'
            '    importlib.import_module(name)\n'
            '    assert "rclpy" not in sys.modules, f"importing {name} imported rclpy"\n')
    p = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
