"""Learned illumination where the other methods are -- `lightstage train
--method learned`, `lightstage eval --methods ...,learned`, the trainer node's parameters --
on the tiny capture (24 px) with a few steps."""
import json

import numpy as np
import pytest
from mux_classifier.artifact import TrainedArtifact

from mux_trainer.cli import eval_main, train_main

from helpers.trainer import TINY


def test_train_learned_writes_a_learned_artifact(capture, tmp_path, capsys):
    out = tmp_path / 'learned.npz'
    rc = train_main([str(capture), '--out', str(out), '--method', 'learned', '--max-images', '2',
                     '--steps', '3', '--repeats', '30', '--json', *TINY])
    assert rc == 0
    captured = capsys.readouterr()
    doc = json.loads(captured.out)  # stdout is exactly one JSON document, progress on stderr
    # progress: the starts' inner accuracy
    assert '[learned, 2 exposures, graded] inner accuracy of the starts: random ' in captured.err
    assert doc['method'] == 'learned' and doc['mode'] == 'learned' and not doc['binary']
    assert doc['features'] == 'intensity_stats' and doc['best_n_images'] == 2
    # what the model classifies with beyond the per-image statistics, and its head
    assert doc['cross_image_stats'] is True and doc['head'] == 'by_type'
    assert set(doc['accuracy_by_images']) == {'2'}
    art = TrainedArtifact.load(out)
    assert art.mode == 'learned' and art.n_images == [2] and art.hog_config.image_size == 24
    assert art.class_names == doc['class_names'] and art.noise['name'] == 'sigma3'
    np.testing.assert_allclose(art.led_patterns, np.array(doc['patterns']), atol=5e-4)
    assert art.provenance['method'] == 'learned' and art.provenance['max_steps'] == 3
    assert art.provenance['chosen'] == doc['chosen'] and art.provenance['head'] == 'by_type'
    assert art.provenance['n_repeats'] == 30   # --repeats: its inner splits, as the search's
    # one physical sample per class: pose splits, and the artifact says so
    assert art.provenance['inner_estimate']['held_out'] == 'poses'
    assert art.provenance['inner_estimate'] == doc['inner_estimate']
    assert art.provenance['levels'] == doc['levels'] in ('graded', 'on/off')
    assert art.learned.class_groups is not None
    # graded: levels in [0, 1], and a fine-tuned snapshot (not a 0/1 start) has levels between
    assert ((art.led_patterns >= 0) & (art.led_patterns <= 1)).all()
    if '+' in art.provenance['chosen']:  # e.g. 'per_colour+3': a start and 3 steps
        assert ((art.led_patterns > 0) & (art.led_patterns < 1)).any()
    images = np.full((1, 2, 24, 24), 100.0, np.float32)
    assert art.predict(images)[0] in art.class_names
    # unknown objects: a novelty model for its two images, saved and loaded with it; a
    # uniform grey card is unlike every trained fruit
    assert list(art.novelty) == [2] and doc['novelty']['2']['false_alarm_rate'] == 0.05
    decision = art.decide(images[0])
    assert decision.novelty >= 1.0 and decision.decision == 'unknown'
    # calibrated on held-out inner answers: probabilities, accepted at 90 % (one image count)
    assert art.calibrated and art.confidence.counts == [2]
    assert art.confidence.stop_probability == doc['confidence']['stop_probability'] == 0.9
    assert decision.probabilities.shape == (len(art.class_names),)
    assert decision.probabilities.sum() == pytest.approx(1.0)
    assert decision.probabilities.argmax() == decision.index


def test_train_learned_binary_gives_on_off_levels(capture, tmp_path, capsys):
    out = tmp_path / 'binary.npz'
    rc = train_main([str(capture), '--out', str(out), '--method', 'learned', '--binary',
                     '--max-images', '2', '--steps', '2', '--repeats', '10', *TINY])
    assert rc == 0
    art = TrainedArtifact.load(out)
    assert set(np.unique(art.led_patterns)) == {0.0, 1.0}  # exactly: pwm_bits 0 boards
    assert art.provenance['binary'] is True and 'learned on/off patterns' in art.describe()
    # what it kept, in words: exposures, its own features, on/off, the kept candidate, the
    # inner estimate and that pose splits speak only for the objects trained on
    text = capsys.readouterr().out
    assert "{'" not in text and 'image count' not in text
    assert 'learned: 2 exposures, one learned pattern each; features intensity_stats + ' \
           'cross-image statistics; head gated by object type' in text
    assert 'LED levels: on/off (every LED fully on or off)' in text
    assert f'kept {art.provenance["chosen"]}' in text
    assert 'inner accuracy by exposures: 2 exposures ' in text
    assert 'holding out 2 of 8 pose indices (every class has one physical sample): it holds ' \
           'only for the objects trained on' in text


@pytest.mark.parametrize('argv, message', [
    (['--method', 'greedy', '--steps', '3'], '--binary and --steps apply to --method learned only'),
    (['--binary'], '--binary and --steps apply to --method learned only'),
    (['--method', 'learned', '--steps', '-1'], 'steps (training steps of the learned patterns; 0: the '
     'starts only) must be 0 .. 100000, got -1'),
])
def test_learned_options_are_checked_before_the_capture_is_loaded(capture, tmp_path, no_work,
                                                                  argv, message):
    with pytest.raises(SystemExit) as exc:
        train_main([str(capture), '--out', str(tmp_path / 'x.npz'), *argv, *TINY])
    assert message in str(exc.value)
    assert not (tmp_path / 'x.npz').exists()


def test_eval_has_a_learned_row(capture, tmp_path, capsys):
    out_dir = tmp_path / 'eval'
    rc = eval_main([str(capture), '--methods', 'naive,learned', '--repeats', '4',
                    '--renders', '2', '--learned-exposures', '1,2', '--learned-steps', '3',
                    '--json', '--out', str(out_dir), *TINY])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    m = doc['methods']['learned']
    assert set(m['accuracy_by_images']) == {'1', '2'} == set(m['search_accuracy_by_images'])
    assert m['n_images'] in (1, 2) and m['n_exposures'] == m['n_images']
    assert m['accuracy'] == m['accuracy_by_images'][str(m['n_images'])]
    assert set(m['accuracy_by_type']) == {'fruit0', 'fruit1'}
    assert np.array(m['patterns']).shape == (32, m['n_images']) and m['mode'] == 'learned'
    assert m['head'] == 'by_type'   # fruit0- and fruit1- classes: gated by type
    assert m['train_seconds'] > 0 and m['infer_ms_per_sample'] > 0
    table = (out_dir / 'table1.csv').read_text()
    assert '\nsigma3,learned,' in table
    curve = (out_dir / 'accuracy_vs_images.csv').read_text()
    assert 'sigma3,learned,1,' in curve and 'sigma3,learned,2,' in curve
    assert (out_dir / 'patterns.png').stat().st_size > 0


def test_eval_refuses_bad_learned_options_before_the_load(capture, no_work):
    with pytest.raises(SystemExit, match='--learned-exposures must list counts >= 1'):
        eval_main([str(capture), '--methods', 'learned', '--learned-exposures', '0', *TINY])
    with pytest.raises(SystemExit, match='steps .* must be 0 .. 100000, got -1'):
        eval_main([str(capture), '--methods', 'learned', '--learned-steps', '-1', *TINY])


def test_trainer_node_parameters_choose_the_method(capture):
    """The trainer node's method parameter (a goal with an empty method) and the learned
    options, with their ranges; a goal's own method wins."""
    from types import SimpleNamespace

    from lightstage_graph.params import check_value
    from mux_trainer.trainer_node import PARAMETERS, TrainerNode
    default, descriptor = PARAMETERS['method']
    assert default == 'greedy' and 'learned' in descriptor.additional_constraints
    default, descriptor = PARAMETERS['learned_steps']
    assert default == 0 and check_value('learned_steps', 40, descriptor) == 40
    assert check_value('learned_steps', 0, descriptor) == 0   # the starts alone
    with pytest.raises(ValueError, match='out of range'):
        check_value('learned_steps', -1, descriptor)
    params = {'method': 'learned', 'learned_steps': 7, 'learned_binary': True}
    node = SimpleNamespace(p=params.get)
    options = TrainerNode._method_options(node, SimpleNamespace(method=''))
    assert options == {'method': 'learned', 'steps': 7, 'binary': True}
    assert TrainerNode._method_options(node, SimpleNamespace(method='naive')) == {'method': 'naive'}


def test_the_kept_candidate_is_described_as_what_it_is():
    from mux_trainer.learned_method import describe_choice
    assert describe_choice('random+200') == 'random+200: 200 gradient steps from the random start'
    assert describe_choice('per_colour', 200).startswith('per_colour: a start kept as it is, no snapshot')
    assert describe_choice('per_colour') == ('per_colour: the start the inner splits score best, '
                                             'kept as it is (no gradient steps)')
