"""Each package's manifest names what its code imports, so that `rosdep install` + `colcon
build` on a ROS 2 install gives nodes that start: every third-party import of a package's
modules and launch files is an exec_depend of its package.xml (a ROS package, or the rosdep
key of a Python library), or, where rosdep has no key, a line of the package's
requirements.txt (docs/NODES.md, "On a ROS 2 install"), pinned as in constraints.txt; the
optional camera and cluster libraries are named in the workspace's extras."""
import ast
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / 'src'
PYTHON_PACKAGES = sorted(p.name for p in SRC.iterdir() if (p / 'setup.py').is_file())

# import name -> rosdep key (ros/rosdistro rosdep/python.yaml)
ROSDEP_KEYS = {
    'numpy': 'python3-numpy', 'scipy': 'python3-scipy', 'sklearn': 'python3-sklearn',
    'skimage': 'python3-skimage', 'yaml': 'python3-yaml', 'serial': 'python3-serial',
    'aiohttp': 'python3-aiohttp', 'matplotlib': 'python3-matplotlib', 'PIL': 'python3-pil',
    'joblib': 'python3-joblib', 'numba': 'python3-numba', 'tqdm': 'python3-tqdm',
    'lz4': 'python3-lz4', 'zstandard': 'python3-zstandard',
}
# import name -> pip distribution, for the libraries rosdep has no key for
PIP_ONLY = {'jax': 'jax', 'optax': 'optax', 'mcap': 'mcap', 'threadpoolctl': 'threadpoolctl'}
# imported only where an optional feature is used: import name -> the workspace's extra
OPTIONAL = {'pypylon': 'requirements-camera.txt', 'gi': 'requirements-camera.txt',
            'distributed': 'requirements-cluster.txt'}


def _imports(package: str) -> set[str]:
    files = [*(SRC / package / package).rglob('*.py'), *(SRC / package / 'launch').glob('*.py')]
    roots = set()
    for path in files:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                roots |= {alias.name.split('.')[0] for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and not node.level:
                roots.add(node.module.split('.')[0])
    return {r for r in roots if r not in sys.stdlib_module_names and r != package}


def _exec_depends(package: str) -> set[str]:
    tree = ET.parse(SRC / package / 'package.xml')
    return {e.text.strip() for tag in ('exec_depend', 'depend') for e in tree.iter(tag)}


def _requirements(path: Path) -> dict[str, str]:
    """name -> the whole requirement line, of a requirements file (no -r includes)."""
    if not path.is_file():
        return {}
    lines = [line.split('#')[0].strip() for line in path.read_text().splitlines()]
    return {re.split(r'[\[=<>~ ]', line)[0].lower(): line for line in lines if line and not line.startswith('-')}


@pytest.mark.parametrize('package', PYTHON_PACKAGES)
def test_every_import_is_declared_with_its_rosdep_key_or_a_pip_requirement(package):
    depends = _exec_depends(package)
    requirements = _requirements(SRC / package / 'requirements.txt')
    undeclared = []
    for name in sorted(_imports(package)):
        if name in ROSDEP_KEYS:
            ok = ROSDEP_KEYS[name] in depends
        elif name in PIP_ONLY:
            ok = PIP_ONLY[name] in requirements
        elif name in OPTIONAL:
            ok = name in (SRC / package / 'package.xml').read_text()  # named in its comment
        else:  # a ROS package: its import name is its package name
            ok = name in depends
        if not ok:
            undeclared.append(name)
    assert not undeclared, (f'{package} imports {undeclared} but its package.xml (rosdep keys: '
                            f'{ {n: ROSDEP_KEYS.get(n) for n in undeclared} }) or requirements.txt '
                            'does not declare them')


@pytest.mark.parametrize('package', PYTHON_PACKAGES)
def test_a_packages_pip_requirements_are_pinned_as_the_workspace_pins_them(package):
    constraints = _requirements(ROOT / 'constraints.txt')
    for name, line in _requirements(SRC / package / 'requirements.txt').items():
        pin = line.split('==')[-1]
        assert constraints.get(name, '').endswith(f'=={pin}'), (
            f'src/{package}/requirements.txt pins {line!r}; constraints.txt: {constraints.get(name)!r}')


def test_the_optional_libraries_are_in_the_workspace_extras():
    for name, extra in OPTIONAL.items():
        dist = {'gi': 'pygobject'}.get(name, name)
        assert dist in _requirements(ROOT / extra), f'{extra} lacks {dist} (imported as {name})'
