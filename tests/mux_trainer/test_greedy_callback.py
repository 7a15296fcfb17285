"""The greedy search reports its progress per column, and per round of candidates within
one, through `callback`; an exception from it stops the search there."""
from mux_trainer.greedy import GreedyPatternSelector
from mux_trainer.search_params import Execution, SplitScoring


def test_callback_sees_every_column_start_and_result(tiny4_data):
    events = []
    sel = GreedyPatternSelector(n_patterns=2, seed=3, callback=events.append,
                                scoring=SplitScoring(n_repeats=10),
                                execution=Execution(chunk_size=4)).fit(tiny4_data)
    assert [(e['event'], e['column']) for e in events if e['event'] != 'candidates'] == [
        ('column_start', 1), ('column_done', 1), ('column_start', 2), ('column_done', 2)]
    # before each round of scoring tasks (one per worker; n_jobs 1: one chunk of 4 of the
    # 4 sites' 14 candidates)
    rounds = [(e['column'], e['done'], e['of']) for e in events if e['event'] == 'candidates']
    assert rounds == [(c, d, 14) for c in (1, 2) for d in (0, 4, 8, 12)], rounds
    done = [e for e in events if e['event'] == 'column_done']
    assert [e['accuracy'] for e in done] == [sel.accuracy_by_images_[k] for k in (1, 2)]
    assert [e['candidates'] for e in done] == [len(h['scores']) for h in sel.history_]
    assert all(e['of'] == 2 for e in done)
    assert done[1]['best_accuracy'] == max(e['accuracy'] for e in done)


def test_callback_is_a_plain_parameter():
    sel = GreedyPatternSelector(callback=print)
    assert sel.get_params()['callback'] is print


def test_an_exception_from_the_callback_stops_the_search_within_a_column(tiny4_data, monkeypatch):
    """The node's cancel: the candidates after the round where the callback raised are not
    scored, and the scores do not depend on whether a callback was given."""
    import pytest
    import mux_trainer.evaluation as evaluation
    scored = []
    original = evaluation.score_chunk_with

    def counting(data, ctx, chunk, scorer=None):
        scored.append(chunk.shape[1])
        return original(data, ctx, chunk, scorer)

    monkeypatch.setattr(evaluation, 'score_chunk_with', counting)

    class Stop(Exception):
        pass

    def stop_after_two_rounds(event):
        if event['event'] == 'candidates' and event['done'] >= 8:
            raise Stop
    small_tasks = Execution(chunk_size=4)
    with pytest.raises(Stop):
        GreedyPatternSelector(n_patterns=1, seed=3, callback=stop_after_two_rounds,
                              scoring=SplitScoring(n_repeats=10),
                              execution=small_tasks).fit(tiny4_data)
    assert scored == [4, 4]
    quiet = GreedyPatternSelector(n_patterns=2, seed=3, scoring=SplitScoring(n_repeats=10),
                                  execution=small_tasks).fit(tiny4_data)
    heard = GreedyPatternSelector(n_patterns=2, seed=3, callback=lambda e: None,
                                  scoring=SplitScoring(n_repeats=10),
                                  execution=small_tasks).fit(tiny4_data)
    for a, b in zip(quiet.history_, heard.history_):
        assert (a['scores'] == b['scores']).all()
