"""Every script in benchmarks/ (what a maintainer reruns; `make bench` runs each with --quick)
has a `--help` that exits 0 and names its quick mode, and runs as a file as it is: no
sys.path edits, no import of the test suite's helpers. A new script is covered by being there
(benchmarks/_*.py are the scripts' shared modules, not scripts)."""
import ast
import subprocess
import sys
from pathlib import Path

import pytest

from helpers.suite import REPO

pytestmark = pytest.mark.process

BENCHMARKS = REPO / 'benchmarks'
SCRIPTS = sorted(p for p in BENCHMARKS.glob('*.py') if not p.name.startswith('_'))
SCRIPT_HELP = Path(__file__).resolve().parent / 'helpers' / 'script_help.py'


def test_there_are_benchmarks_to_check():
    assert len(SCRIPTS) >= 10 and (BENCHMARKS / '_common.py').is_file()


@pytest.mark.parametrize('script', SCRIPTS, ids=[p.stem for p in SCRIPTS])
def test_a_benchmark_prints_its_usage_and_quick_mode(script):
    # its imports are stand-ins (helpers/script_help.py): about 0.1 s instead of 1-20 s each
    p = subprocess.run([sys.executable, str(SCRIPT_HELP), str(script)], capture_output=True,
                       text=True, timeout=60, cwd=REPO)
    assert p.returncode == 0, p.stdout + p.stderr
    assert p.stdout.startswith(f'usage: {script.name}'), p.stdout + p.stderr
    assert '--quick' in p.stdout, f'{script.name} has no --quick (make bench runs it so)'


@pytest.mark.parametrize('script', SCRIPTS, ids=[p.stem for p in SCRIPTS])
def test_a_benchmark_edits_no_sys_path_and_imports_no_test_helper(script):
    tree = ast.parse(script.read_text(), str(script))
    edits = [n.lineno for n in ast.walk(tree) if isinstance(n, ast.Attribute)
             and n.attr == 'path' and isinstance(n.value, ast.Name) and n.value.id == 'sys']
    assert not edits, f'{script.name} uses sys.path (lines {edits}): a script run as a file ' \
                      'already has its own folder on sys.path'
    imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    helpers = sorted(m for m in imported if m.split('.')[0] in ('helpers', 'tests', 'conftest'))
    assert not helpers, f'{script.name} imports the test suite\'s {helpers}: shared code goes ' \
                        'in benchmarks/_common.py or the product'
