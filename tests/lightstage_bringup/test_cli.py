"""The `lightstage` dispatcher: help, unknown verbs, and that every verb resolves."""
import importlib
import re

import pytest

from lightstage_bringup import cli

from helpers.suite import REPO


def test_help_lists_every_verb(capsys):
    assert cli.main(['--help']) == 0
    out = capsys.readouterr().out
    for verb in cli.VERBS:
        assert verb in out


def test_no_arguments_prints_help_and_fails(capsys):
    assert cli.main([]) == 2
    assert 'verbs:' in capsys.readouterr().out


def test_unknown_verb_is_a_clear_error(capsys):
    with pytest.raises(SystemExit) as excinfo:
        cli.main(['frobnicate'])
    assert excinfo.value.code == 2
    err = capsys.readouterr().err
    assert "unknown verb 'frobnicate'" in err
    assert 'synth' in err


@pytest.mark.parametrize('verb', sorted(cli.VERBS))
def test_every_verb_points_at_a_callable(verb):
    module, function, _ = cli.VERBS[verb]
    assert callable(getattr(importlib.import_module(module), function))


def _ros_run_wrappers():
    root = REPO / 'src'
    return sorted(root.glob('*/scripts/*'))


@pytest.mark.parametrize('wrapper', _ros_run_wrappers(), ids=lambda p: f'{p.parts[-3]}/{p.name}')
def test_every_ros_run_executable_has_its_main(wrapper):
    """Each lib/<pkg>/<exe> wrapper (what `ros2 run` starts) imports an existing main()."""
    match = re.search(r'^from ([\w.]+) import main$', wrapper.read_text(), re.M)
    assert match, f'{wrapper}: no `from MODULE import main` line'
    assert callable(importlib.import_module(match.group(1)).main)
    assert wrapper.stat().st_mode & 0o111, f'{wrapper} is not executable'
