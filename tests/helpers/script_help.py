"""Run a script's `--help` without importing what it imports: `python script_help.py SCRIPT`.

A benchmark's top-level imports (numpy, JAX, the project's packages, rclpy) cost 1-20 s per
script; its `--help` needs none of them, only its own argparse code. Here every module outside
the standard library and the script's own folder (its sibling modules, e.g. benchmarks/_common.py,
are imported for real) is a stand-in whose attributes, calls, items and subclasses are
stand-ins too, so the script runs as `__main__` with `--help` in about 0.1 s: its parser is
built, the help is printed, and it exits as argparse makes it. Whether the real imports
resolve is what `make bench` shows (it runs every script to the end).
"""
import importlib.abc
import importlib.machinery
import runpy
import sys
from pathlib import Path


class _StandInType(type):
    """The stand-ins' metaclass: anything asked of a stand-in is a stand-in."""

    def __getattr__(cls, name):
        if name.startswith('__') and name.endswith('__'):
            raise AttributeError(name)
        return StandIn

    def __call__(cls, *args, **kwargs):
        return StandIn

    def __getitem__(cls, key):
        return StandIn

    def __setitem__(cls, key, value):
        pass

    def __iter__(cls):
        return iter(())

    def __len__(cls):
        return 0

    def __or__(cls, other):
        return StandIn

    __ror__ = __add__ = __radd__ = __sub__ = __mul__ = __rmul__ = __truediv__ = __or__


class StandIn(metaclass=_StandInType):
    """A value of a module that was not imported (a class too: scripts subclass them)."""


class _StandInLoader(importlib.abc.Loader):
    def create_module(self, spec):
        return None

    def exec_module(self, module):
        module.__getattr__ = lambda name: StandIn
        module.__path__ = []  # a package: its submodules are stand-ins too


class _StandInFinder(importlib.abc.MetaPathFinder):
    def __init__(self, own_folder: Path):
        self.own = {p.stem for p in own_folder.glob('*.py')}

    def find_spec(self, name, path=None, target=None):
        top = name.partition('.')[0]
        if top in sys.stdlib_module_names or top in self.own or top in sys.builtin_module_names:
            return None
        return importlib.machinery.ModuleSpec(name, _StandInLoader(), is_package=True)


def main() -> None:
    script = Path(sys.argv[1]).resolve()
    sys.path[0] = str(script.parent)  # as when the script itself is run
    sys.meta_path.insert(0, _StandInFinder(script.parent))
    sys.argv = [str(script), '--help']
    runpy.run_path(str(script), run_name='__main__')


if __name__ == '__main__':
    main()
