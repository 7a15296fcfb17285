"""The learned-illumination estimator: candidate lights scored by the greedy search's own
inner splits, the best kept, a linear head on it (docs/LEARNED.md, "Candidate lights and
how one is kept").

Candidate lights are scored with the exact linear SVM on the inner splits
(`evaluation.CandidateEvaluator` in the joint mode) and the best is kept (a tie keeps the
earlier): the starts (`starts`, `params.Starts`) and, with `Descent.max_steps` > 0 (0 by
default), snapshots of gradient steps from some of them (`descent.descend`). The final
classifier is `head.fit_head` on the kept light's rendered training statistics.
"""
from __future__ import annotations

import time

import numpy as np
from joblib import Parallel
from lightstage_physics.rig import Rig, site_to_led_patterns
from mux_classifier.intensity_stats import N_STATS
from sklearn.base import BaseEstimator

from ..baselines import SnrOptimalClassifier
from ..evaluation import CandidateEvaluator
from ..greedy import GreedyPatternSelector
from ..pattern_model import PatternModelMixin
from ..rendering import SearchData
from ..search_params import Execution, Rendering, SplitScoring, check_group
from ..selection_bias import selection_optimism, split_groups
from ..splits import resolve_inner_groups
from .descent import descend
from .head import FEATURES, fit_head, head_features, learned_data, ratio_offset, stack_features
from .params import FINE_TUNE_WORDS, Descent, Head, Starts
from .starts import (low_side_splits, per_colour_start, random_start, raking_name,
                     raking_sides_start)
from .streams import descent_rng, fit_rng, inner_seeds, raking_rng

__all__ = ['LearnedIlluminationClassifier']


class LearnedIlluminationClassifier(PatternModelMixin, BaseEstimator):
    """LED levels and a linear classifier over the k images (docs/LEARNED.md).

    Parameters
    ----------
    n_images : k exposures = k images, one learned pattern each.
    binary : on/off levels: the starts binarised at 0.5, a descent straight-through
        (`descent.levels`); runs on ``pwm_bits = 0`` boards.
    starts : `params.Starts`, the candidate lights made before any gradient step (the
        built-in ones, lights of your own, the site positions of the raking-sides start).
    descent : `params.Descent`, gradient steps on the levels from some starts (max_steps
        0 by default: the starts alone), each from a random stream of its own. A perfect
        inner score ends the fit early (nothing after it could be kept: a tie keeps the
        earlier).
    head : `params.Head`, the final classifier: gated by object type or flat, its noise
        draws and C.
    ratio_stats : after the images' own statistics, the cross-image relief statistics of
        every pair of images (`mux_classifier.ratio_stats`: the log ratio's spread and mean
        gradient over the object; albedo and print cancel in a ratio, relief's shading does
        not) in the descent's criterion, the inner splits and the head (the model stores
        their offset). Default True; False: the 9 statistics per image alone.
    inner_draws : independent sets of inner splits, each with its own noise draw
        (`streams.inner_seeds`; the first is the one seed gives), whose mean accuracy scores
        a candidate (1, the default: one set).
    scoring : `search_params.SplitScoring`, the inner splits that score every start and
        snapshot (greedy's split scoring and noise streams): n_repeats, test_fraction,
        inner_groups (what the splits and the descent's folds hold out; the greedy start is
        searched on the same splits), and the split classifier (None: 'squared_hinge', the
        exact linear SVM, the head's kind: it ranks lights more nearly as their held-out
        accuracy does, docs/research/LEARNED_PATH.md; 'ridge': the search's fast screen).
    rendering : `search_params.Rendering` (noise, dimmer, hog_config: the image size) when
        fitting a ModelSet; its features must be 'intensity_stats', the statistics the
        model classifies with.
    execution : `search_params.Execution`: n_jobs for the inner splits, progress (a line
        per scored candidate on stdout).
    seed : seeds the splits, the noise, the starts' and descents' draws and the head.
    callback : called with a dict per step of the fit (as greedy's `callback`): a start
        begun and scored, greedy's columns while its start is made, a descent's snapshot
        (`learned_method.progress_text` words one). An exception it raises ends the fit
        there: the trainer node's cancel.

    After fit: patterns_ (32, k) site-major levels, model_ (a numpy `LearnedModel`: the
    head as one linear layer), classifiers_ {k: model_}, best_n_patterns_ = k,
    accuracy_by_images_ {k: the chosen candidate's inner split accuracy},
    optimism_by_images_ {k: the optimism of having chosen it among the scored candidates on
    these splits, `selection_bias.selection_optimism`; the inner estimate is the accuracy
    less it},
    candidate_scores_ {name: inner split accuracy}, candidate_split_scores_ {name: its
    accuracy on every inner split, the inner draws' one after the other}, candidates_ {name:
    (32, k) LED levels of every scored candidate}, chosen_ (its name), best_step_ (0: a
    start was kept), inner_estimate_ (the chosen candidate's inner accuracy and how the
    splits were made, `splits.inner_splits`), evaluator_ (the first inner draw's
    evaluator), noise_, history_, train_seconds_.
    """

    method_name = 'learned'
    mode = 'joint'

    def __init__(self, n_images=4, binary=False, starts=Starts(), descent=Descent(),
                 head=Head(), ratio_stats=True, inner_draws=1, scoring=SplitScoring(),
                 rendering=Rendering(features=FEATURES), execution=Execution(), seed=0,
                 callback=None):
        self.n_images = n_images
        self.binary = binary
        self.starts = starts
        self.descent = descent
        self.head = head
        self.ratio_stats = ratio_stats
        self.inner_draws = inner_draws
        self.scoring = scoring
        self.rendering = rendering
        self.execution = execution
        self.seed = seed
        self.callback = callback

    def _check_groups(self) -> None:
        """TypeError / ValueError for a setting out of range, before any work."""
        for name, kind in (('scoring', SplitScoring), ('rendering', Rendering),
                           ('execution', Execution), ('starts', Starts), ('descent', Descent),
                           ('head', Head)):
            check_group(self, name, kind)
        if int(self.n_images) < 1:
            raise ValueError(f'n_images must be >= 1, got {self.n_images}')
        if int(self.inner_draws) < 1:
            raise ValueError(f'inner_draws must be >= 1, got {self.inner_draws}')
        if self.rendering.features != FEATURES:
            raise ValueError(f"rendering.features must be {FEATURES!r} (the statistics a learned "
                             f"model classifies with), got {self.rendering.features!r}")
        names = self.starts.all_names()
        tuned = self.descent.tuned_names()
        unknown = [n for n in tuned if n not in FINE_TUNE_WORDS and n not in names]
        if unknown:
            raise ValueError(f"descent.fine_tune must be 'best', 'all', 'none' or names of starts "
                             f"({', '.join(sorted(names)) or 'none given'}), got "
                             f"{self.descent.fine_tune!r}")

    def _data(self, X) -> SearchData:
        # the inner splits and the head score what the model classifies with
        return learned_data(super()._data(X))

    def _site_positions(self, X) -> np.ndarray:
        """(n_sites, 3) mm: starts.site_positions_mm, else the fitted capture's rig (a
        ModelSet's), else the paper's stage (a SearchData carries no rig)."""
        if self.starts.site_positions_mm is not None:
            return np.asarray(self.starts.site_positions_mm, np.float64)
        rig = getattr(X, 'rig', None)
        return (rig if rig is not None else Rig.paper_default()).site_positions_mm()

    def _start_makers(self, data: SearchData, k: int, rng) -> list:
        """[(name, () -> (32, k) levels)]: each start made only when it is scored
        (greedy's search is the costly one; none is made after a perfect score)."""
        L = data.n_sites * data.n_channels
        per_colour = k % data.n_channels == 0
        names = self.starts.names
        makers = []
        # the two drawn starts are drawn now, in this order (the stream's first draws)
        if 'random' in names:
            P_random = random_start(data, k, rng)
            makers.append(('random', lambda: P_random))
        if 'per_colour' in names:
            P_colour = per_colour_start(data.n_sites, data.n_channels, k, rng)
            makers.append(('per_colour', lambda: P_colour))
        if 'snr_optimal' in names and per_colour:
            snr = SnrOptimalClassifier(n_images=k // data.n_channels, seed=int(self.seed))
            makers.append(('snr_optimal', lambda: site_to_led_patterns(
                snr._patterns_for(data), data.n_channels)))
        if 'greedy' in names and per_colour:
            run = self.execution
            greedy = GreedyPatternSelector(
                mode='per_colour', n_patterns=k // data.n_channels, seed=int(self.seed),
                scoring=self.scoring.replace(classifier=None),   # greedy's own screen
                execution=Execution(n_jobs=run.n_jobs, chunk_size=run.chunk_size),
                callback=None if self.callback is None else self._greedy_progress)
            makers.append(('greedy', lambda: site_to_led_patterns(
                greedy.fit(data).patterns_, data.n_channels)))
        positions = self._site_positions_
        if 'raking_sides' in names and per_colour and len(positions) == data.n_sites:
            # one start per split of the low sites ('raking_sides' the most nearly opposite,
            # then 'raking_sides/1', ...), each with a stream of its own (its later images'
            # random halves): the others' draws stay
            for split in range(len(low_side_splits(positions))):
                makers.append((raking_name(split), lambda rng=raking_rng(self.seed, split),
                               split=split: (
                    raking_sides_start(positions, data.n_channels, k, rng, split))))
        for name, P in dict(self.starts.patterns or {}).items():
            P = np.asarray(P, np.float32)
            if P.shape != (L, k) or P.min() < 0 or P.max() > 1:
                raise ValueError(f'start pattern {name!r} must be ({L}, {k}) LED levels in '
                                 f'[0, 1], got shape {P.shape}')
            makers.append((str(name), lambda P=P: P))
        if not makers:
            raise ValueError('no start pattern: give starts.names or starts.patterns')
        return makers

    def _evaluators(self, data: SearchData) -> list[CandidateEvaluator]:
        """One evaluator per inner draw (`streams.inner_seeds`), scoring as `scoring` says."""
        s, run = self.scoring, self.execution
        return [CandidateEvaluator(data, mode='joint', n_repeats=int(s.n_repeats),
                                   test_fraction=float(s.test_fraction), seed=seed,
                                   inner_classifier=self.split_classifier, alpha=s.alpha,
                                   C=s.C, n_jobs=run.n_jobs, chunk_size=run.chunk_size,
                                   inner_groups=s.inner_groups)
                for seed in inner_seeds(self.seed, self.inner_draws)]

    def fit(self, X, y=None):
        """Fit on a SearchData or a ModelSet (its labels; y is ignored)."""
        self._check_groups()
        t_start = time.perf_counter()
        data = self._data(X)
        self._site_positions_ = self._site_positions(X)
        by = resolve_inner_groups(self.scoring.inner_groups, data.labels, data.instance)
        if by == 'poses' and np.unique(data.pose_index).size < 2:
            raise ValueError('learned illumination needs at least 2 training poses per class '
                             '(the inner splits hold poses out); capture more poses')
        k = int(self.n_images)
        offset = ratio_offset(data, self.ratio_stats)
        rng = fit_rng(self.seed)
        evaluators = self._evaluators(data)
        ev = evaluators[0]   # the head's first draw is the first inner draw's
        history = []
        with Parallel(n_jobs=self.execution.n_jobs) as parallel:
            split_scores = {}

            def inner(P, name):
                # the mean split accuracy over the inner draws (each its splits and noise);
                # every split's accuracy is kept for the optimism of the choice
                if offset:   # cross-image statistics: the whole stack's features
                    per_draw = [e.score_features(stack_features(data, e.images(P), offset))
                                for e in evaluators]
                else:
                    per_draw = [e.score(e.prepare_column(P[:, :k - 1] if k > 1 else None),
                                        P[:, k - 1:], parallel)[0] for e in evaluators]
                split_scores[name] = np.concatenate([np.ravel(a) for a in per_draw])
                return float(np.mean([np.mean(a) for a in per_draw]))

            # a perfect inner score cannot be beaten (a tie keeps the earlier candidate),
            # so nothing is made or descended after one
            candidates, scores = {}, {}

            def perfect():
                return bool(scores) and max(scores.values()) >= 1.0

            makers = self._start_makers(data, k, rng)
            for i, (name, make) in enumerate(makers):
                if perfect():
                    break
                self._notify(event='start', start=name, index=i + 1, of=len(makers))
                P = np.asarray(make(), np.float32)
                if self.binary:
                    P = (P >= 0.5).astype(np.float32)
                if P.any():   # an all-dark start (e.g. greedy found nothing) is no start
                    candidates[name], scores[name] = P, inner(P, name)
                    self._notify(event='start_scored', start=name, index=i + 1, of=len(makers),
                                 accuracy=scores[name], best_accuracy=max(scores.values()))
            if not candidates:
                raise ValueError('no start pattern lights anything: give starts.names or '
                                 'starts.patterns')
            steps = dict.fromkeys(candidates, 0)
            self._say(k, 'starts', scores)
            max_steps = int(self.descent.max_steps)
            for name in self._tuned_starts(scores) if max_steps > 0 else []:
                # the random start's descent continues the stream that drew it; any other
                # start's has a stream of its own (seed, name)
                chain_rng = rng if name == 'random' else descent_rng(self.seed, name)
                for step, P, loss in ([] if perfect() else descend(
                        data, candidates[name], chain_rng, self.descent, binary=bool(self.binary),
                        ratio_offset=offset, inner_groups=self.scoring.inner_groups)):
                    tag = f'{name}+{step}'
                    candidates[tag], steps[tag], scores[tag] = P, step, inner(P, tag)
                    history.append({'start': name, 'step': step, 'loss': loss,
                                    'inner_accuracy': scores[tag]})
                    self._say(k, tag, {tag: scores[tag]}, loss)
                    self._notify(event='step', start=name, step=step, of=max_steps,
                                 accuracy=scores[tag], best_accuracy=max(scores.values()))
                    if perfect():
                        break
            # the best inner score; a tie keeps the earlier candidate (a start before its tuning)
            chosen = max(scores, key=scores.get)
            patterns = candidates[chosen]
            draws = head_features(data, ev.images(patterns), patterns, self.head, offset,
                                  self.seed)
            self.model_ = fit_head(np.vstack(draws), np.tile(data.labels, len(draws)),
                                   data.class_names, patterns, self.head, offset, self.seed)
        self.patterns_ = patterns
        self.class_names_ = list(data.class_names)
        self.classifiers_ = {k: self.model_}
        self.best_n_patterns_ = k
        self.accuracy_by_images_ = {k: scores[chosen]}
        names = list(scores)
        groups = split_groups([m for e in evaluators for m in e.test_masks])
        self.optimism_by_images_ = {k: selection_optimism(
            np.vstack([split_scores[n] for n in names]), names.index(chosen), groups)}
        self.candidate_scores_ = scores
        self.candidates_ = candidates
        self.candidate_split_scores_ = split_scores
        self.evaluator_ = ev
        self.chosen_ = chosen
        self.best_step_ = int(steps[chosen])
        self.history_ = history
        self.train_seconds_ = time.perf_counter() - t_start
        return self

    def _tuned_starts(self, scores: dict) -> list:
        """The scored starts `descent.fine_tune` names, in its order."""
        tune = self.descent.tuned_names()
        if 'none' in tune:
            return []
        if 'all' in tune:
            return list(scores)
        if 'best' in tune:
            return [max(scores, key=scores.get)]
        return [n for n in (self._family_best(t, scores) for t in tune) if n is not None]

    @staticmethod
    def _family_best(name: str, scores: dict) -> str | None:
        """The start a fine_tune name means: itself, or for 'raking_sides' the best scored of
        its splits (a tie keeps the earlier); None if no such start was made."""
        family = [n for n in scores if n == name or (name == 'raking_sides'
                                                      and n.startswith('raking_sides/'))]
        return max(family, key=scores.get) if family else None

    @property
    def inner_estimate_(self) -> dict:
        """The kept candidate's inner accuracy and how the splits were made
        (`splits.inner_splits`); n_repeats counts the splits of every inner draw."""
        return {**super().inner_estimate_,
                'n_repeats': int(self.scoring.n_repeats) * int(self.inner_draws)}

    def _greedy_progress(self, event: dict) -> None:
        """Greedy's events while its start is made: 'start_column' (a column begun or chosen)
        and 'start_candidates' (candidates scored so far of the column's)."""
        if event['event'] == 'candidates':
            self._notify(event='start_candidates', start='greedy', column=event['column'],
                         done=event['done'], of=event['of'])
        else:
            self._notify(event='start_column', start='greedy', column=event['column'],
                         of=event['of'], done=event['event'] == 'column_done')

    def _notify(self, **event) -> None:
        """Progress for `callback` (a dict with 'event': 'start' / 'start_scored' / 'step' /
        'start_column' / 'start_candidates', greedy's progress while its start is made;
        `learned_method.progress_text` words it).
        An exception the callback raises ends the fit there: how a cancel stops it."""
        if self.callback is not None:
            self.callback(event)

    def _say(self, k, what, scores, loss=None):
        if self.execution.progress:
            text = ', '.join(f'{n} {s:.3f}' for n, s in scores.items())
            extra = '' if loss is None else f' (loss {loss:.3f})'
            levels = 'on/off' if self.binary else 'graded'
            what = 'the starts' if what == 'starts' else what
            print(f'[learned, {k} exposures, {levels}] inner accuracy of {what}: {text}{extra}',
                  flush=True)

    # --- prediction and the artifact ------------------------------------------------------
    def predict_images(self, images: np.ndarray) -> np.ndarray:
        """Class indices of images (k, n, pixels) rendered under patterns_ (the numpy model)."""
        k, n, P = images.shape
        side = int(round(np.sqrt(P)))
        stacks = np.asarray(images).transpose(1, 0, 2).reshape(n, k, side, P // side)
        return self.model_.predict(stacks)

    def predict_features(self, X: np.ndarray, n_patterns: int) -> np.ndarray:
        """Class indices from the model's raw features (n, `LearnedModel.n_features`) of the
        k images (the PatternModelMixin interface; only n_patterns = n_images exists)."""
        if int(n_patterns) not in self.classifiers_:
            raise ValueError(f'this learned model has {self.n_images} images; n_patterns '
                             f'{n_patterns} is not available')
        X = np.asarray(X)
        if self.model_.ratio_offset:
            if X.shape[1] != self.model_.n_features:
                raise ValueError(f'features must be the model\'s {self.model_.n_features} '
                                 f'statistics (intensity and cross-image); got {X.shape[1]}')
            return self.model_.predict_features(X)
        if X.shape[1] != self.model_.n_images * N_STATS:
            raise ValueError(f'features must be the {N_STATS} intensity statistics of each of '
                             f'{self.model_.n_images} images ({self.model_.n_images * N_STATS} '
                             f'values); got {X.shape[1]} (use --features intensity_stats)')
        return self.model_.predict_features(X)

    def predict(self, stacks) -> np.ndarray:
        """Class indices of stacks (n, k, H, W) taken under patterns_."""
        return self.model_.predict(stacks)

    def to_artifact(self, n_patterns: int | None = None, provenance: dict | None = None):
        """The trained artifact (`learned_method.learned_artifact`); a learned model has one
        image count, so `n_patterns` must be None or n_images."""
        from ..learned_method import learned_artifact
        if n_patterns is not None and int(n_patterns) not in self.classifiers_:
            raise ValueError(f'this learned model has {self.n_images} images; n_patterns '
                             f'{n_patterns} is not available')
        return learned_artifact(self, provenance)
