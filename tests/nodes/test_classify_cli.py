"""`lightstage classify` without a graph: argument checks and the printed answer."""
from lightstage_bringup import classify_cli


def test_answer_lists_the_label_then_scores_best_first():
    text = classify_cli.format_answer({
        'success': True, 'message': '', 'label': 'pear-real', 'class_names': ['pear-fake', 'pear-real', 'fig-real'],
        'scores': [-0.5, 0.75, 0.1], 'images_used': 4, 'acquisition_ms': 101.26, 'compute_ms': 5.04})
    lines = text.splitlines()
    assert lines[0] == 'label: pear-real  (4 images, acquisition 101.3 ms, compute 5.0 ms)'
    assert [ln.split()[0] for ln in lines[1:]] == ['pear-real', 'fig-real', 'pear-fake']
    assert lines[1].endswith('+0.750') and lines[3].endswith('-0.500')
    failed = classify_cli.format_answer({'success': False, 'message': 'no classifier loaded: x'})
    assert failed == 'classification failed: no classifier loaded: x'


def test_bad_arguments_exit_2_with_the_reason(capsys):
    assert classify_cli.main(['--max-images', '-1']) == classify_cli.EXIT_USAGE
    assert '--max-images must be >= 0' in capsys.readouterr().err
    assert classify_cli.main(['--timeout-s', '-2']) == classify_cli.EXIT_USAGE
    assert classify_cli.main(['--domain-id', '400']) == classify_cli.EXIT_USAGE
    assert 'out of range' in capsys.readouterr().err
