"""The demo's closing table counts every answer a person gets: right, not sure, unknown."""
from lightstage_bringup.demo import _report


def _call(true, label, decision, images=8):
    return {'true': true, 'label': label, 'decision': decision, 'images_used': images,
            'images_budget': 8, 'acquisition_ms': 100.0, 'compute_ms': 5.0}


def test_the_table_counts_unsure_and_unknown_answers_apart(capsys):
    rows = [_call('a', 'a', 'accepted', 4), _call('b', 'a', 'unsure'),
            _call('b', 'b', 'unknown'), _call('a', 'b', 'unknown')]
    report = _report({'greedy': rows}, {'greedy': {'train_seconds': 1.0}})
    assert report['greedy']['unsure'] == 1
    assert report['greedy']['unknown'] == 2
    assert report['greedy']['accuracy'] == 0.5
    assert report['greedy']['images_used_mean'] == 7.0
    header, row = [line.split() for line in capsys.readouterr().out.splitlines()
                   if line.strip().startswith(('method', 'greedy'))]
    assert header[-2:] == ['unsure', 'unknown']
    assert row[-2:] == ['1', '2']
