"""The greedy search reports its progress per column through `callback`."""
from mux_trainer.greedy import GreedyPatternSelector
from mux_trainer.search_params import SplitScoring


def test_callback_sees_every_column_start_and_result(tiny4_data):
    events = []
    sel = GreedyPatternSelector(n_patterns=2, seed=3, callback=events.append,
                                scoring=SplitScoring(n_repeats=10)).fit(tiny4_data)
    assert [(e['event'], e['column']) for e in events] == [
        ('column_start', 1), ('column_done', 1), ('column_start', 2), ('column_done', 2)]
    done = [e for e in events if e['event'] == 'column_done']
    assert [e['accuracy'] for e in done] == [sel.accuracy_by_images_[k] for k in (1, 2)]
    assert [e['candidates'] for e in done] == [len(h['scores']) for h in sel.history_]
    assert all(e['of'] == 2 for e in done)
    assert done[1]['best_accuracy'] == max(e['accuracy'] for e in done)


def test_callback_is_a_plain_parameter():
    sel = GreedyPatternSelector(callback=print)
    assert sel.get_params()['callback'] is print
