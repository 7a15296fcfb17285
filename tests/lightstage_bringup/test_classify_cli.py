"""`lightstage classify` without a graph: argument checks and the printed answer."""
import subprocess

import pytest
from lightstage_bringup import classify_cli

from helpers.suite import lightstage_command

pytestmark = pytest.mark.process


def test_answer_lists_the_label_then_scores_best_first():
    text = classify_cli.format_answer({
        'success': True, 'message': '', 'label': 'pear-real', 'class_names': ['pear-fake', 'pear-real', 'fig-real'],
        'scores': [-0.5, 0.75, 0.1], 'images_used': 4, 'acquisition_ms': 101.26, 'compute_ms': 5.04})
    lines = text.splitlines()
    assert lines[0] == ('label: pear-real  (uncalibrated classifier: scores only; 4 of 4 '
                        'exposures, acquisition 101.3 ms, compute 5.0 ms)')
    assert [ln.split()[0] for ln in lines[1:]] == ['pear-real', 'fig-real', 'pear-fake']
    assert lines[1].endswith('+0.750') and lines[3].endswith('-0.500')
    failed = classify_cli.format_answer({'success': False, 'message': 'no classifier loaded: x'})
    assert failed == 'classification failed: no classifier loaded: x'


CALIBRATED = {'success': True, 'message': '', 'label': 'pear-real',
              'class_names': ['pear-fake', 'pear-real', 'fig-real'], 'scores': [-0.5, 0.75, 0.1],
              'images_used': 4, 'images_budget': 8, 'acquisition_ms': 96.0, 'compute_ms': 2.0,
              'calibrated': True, 'novelty': None}


def test_a_sure_answer_says_its_probability_and_the_exposures_it_took():
    text = classify_cli.format_answer({**CALIBRATED, 'probabilities': [0.02, 0.97, 0.01],
                                       'decision': 'accepted'})
    lines = text.splitlines()
    assert lines[0] == ('label: pear-real, 97.0 % (accepted; 4 of 8 exposures, acquisition '
                        '96.0 ms, compute 2.0 ms)')
    assert lines[1].split()[:3] == ['pear-real', '97.0', '%'] and lines[1].endswith('(score +0.750)')


def test_an_unsure_answer_says_so_and_what_to_do():
    text = classify_cli.format_answer({**CALIBRATED, 'probabilities': [0.39, 0.58, 0.03],
                                       'decision': 'unsure', 'images_used': 8})
    assert text.splitlines()[0] == ('not sure: pear-real 58.0 %, pear-fake 39.0 %: look again or '
                                    'ask a person (8 of 8 exposures, acquisition 96.0 ms, '
                                    'compute 2.0 ms)')


def test_an_unknown_object_is_called_unknown_not_the_nearest_class():
    text = classify_cli.format_answer({**CALIBRATED, 'probabilities': [0.3, 0.6, 0.1],
                                       'decision': 'unknown', 'novelty': 2.3})
    assert text.splitlines()[0].startswith('unknown: unlike every trained class (novelty 2.30); '
                                           'nearest pear-real 60.0 %')


def test_a_target_probability_outside_zero_to_one_is_a_usage_error(capsys):
    for bad in ['-0.1', '1.5', 'nan', 'inf']:
        assert classify_cli.main([f'--target-probability={bad}']) == classify_cli.EXIT_USAGE, bad
        assert '--target-probability must be a number from 0' in capsys.readouterr().err


def test_bad_arguments_exit_2_with_the_reason(capsys):
    assert classify_cli.main(['--max-images', '-1']) == classify_cli.EXIT_USAGE
    assert '--max-images must be an integer from 0' in capsys.readouterr().err
    assert classify_cli.main(['--max-images', str(2**32)]) == classify_cli.EXIT_USAGE
    assert 'to 4294967295; got 4294967296' in capsys.readouterr().err
    for bad in ['-2', 'nan', 'inf', '-inf', '1e-6', '0.05', '601', '1e10']:
        assert classify_cli.main([f'--timeout-s={bad}']) == classify_cli.EXIT_USAGE, bad
        err = capsys.readouterr().err
        assert '--timeout-s must be 0 (the classifier node\'s default) or between 0.1 and 600 s' in err, bad
    for bad in ['-1', 'nan', 'inf', '-inf']:
        assert classify_cli.main([f'--wait-s={bad}']) == classify_cli.EXIT_USAGE, bad
        assert '--wait-s must be a finite number of seconds >= 0' in capsys.readouterr().err
    assert classify_cli.main(['--domain-id', '400']) == classify_cli.EXIT_USAGE
    assert 'out of range' in capsys.readouterr().err


def test_timeout_beyond_any_timer_is_a_usage_error():
    """`lightstage classify --timeout-s 1e10` failed building an rclpy timer
    (TypeError); it is a usage error naming the option and its range, before any ROS set-up."""
    p = subprocess.run(lightstage_command('classify', '--timeout-s', '1e10'),
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == classify_cli.EXIT_USAGE, p.stderr
    assert p.stderr.strip() == ('lightstage classify: --timeout-s must be 0 (the classifier '
                                'node\'s default) or between 0.1 and 600 s; got 10000000000.0')
