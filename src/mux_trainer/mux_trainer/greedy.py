"""Greedy joint selection of illumination patterns and classifier (the paper's method).

The illumination matrix grows one column at a time; for each new column every candidate is
scored with the earlier columns fixed (`evaluation.CandidateEvaluator`) and the best one is
kept. The search stops when the best candidate no longer improves the accuracy (or, with
`n_patterns` set, continues to that many columns as the paper does for its figures, marking
the columns that did not improve). A classifier is trained for every column count.

Screen, then refine (a race): every candidate is scored with a fast inner classifier (ridge
with one kernel for all splits); then the paper's classifier, the linear SVM solved exactly
(`split_scoring.SquaredHingeSplitScorer`), re-scores the screen's best candidates on the same
noise draw and splits (each re-rendered on its own rather than incrementally, which changes
only float32 rounding): first `refine_top`, then more in the screen's order while one of the
rest could still win (`could_still_win`), and the column is the SVM's best.
benchmarks/rank_agreement.py scores all candidates with the SVM to check, column by column,
that the race keeps the SVM's winner on our data (docs/SEARCH.md).

Two modes:
- 'per_colour' (the paper's): each column is one of the 254 site patterns (1..7 of 8 sites
  lit), applied to each colour in turn, so it gives 4 images (R, G, B, NIR). Exhaustive.
- 'joint' (the paper's future work): each column is a 32-LED pattern giving one image.
  2^32 candidates cannot be enumerated, so a column is built by a beam search over LED
  additions: start from no LED lit, try adding each unlit LED to each pattern of the beam,
  keep the `beam_width` best, and stop when adding an LED no longer improves the column's
  best score (or `max_lit_leds` is reached). Cost per column: about 32 * lit * beam_width
  candidate evaluations of one image each, instead of 254 of four images.
"""
from __future__ import annotations

import sys
import time

import numpy as np
from joblib import Parallel
from lightstage_physics.rig import N_LEDS
from sklearn.base import BaseEstimator

from .evaluation import images_per_column
from .candidate_patterns import site_pattern_candidates
from .pattern_model import PatternModelMixin
from .search_params import (REFINE_MAX, REFINE_SLACK, REFINE_TOP, Execution, FinalClassifier,
                            Refinement, Rendering, SplitScoring, check_group)
from .selection_bias import selection_optimism
from .split_scoring import SquaredHingeSplitScorer

__all__ = ['GreedyPatternSelector', 'could_still_win', 'REFINE_TOP', 'REFINE_BATCH',
           'REFINE_MAX', 'REFINE_SLACK']

REFINE_BATCH = 8    # refinement: candidates the exact SVM scores at a time after the first


def could_still_win(screen_refined, svm_refined, screen_next, slack=REFINE_SLACK) -> bool:
    """Could the best candidate not yet refined (screen score `screen_next`) beat the best
    SVM score so far?

    The refined candidates tell how far the SVM's score rises above the screen's: a
    candidate is still in the race while `screen_next + max(rise) + slack * std(rise)`
    reaches the best SVM score. Candidates are refined in the screen's order, so when the
    next one is out, all the rest are too.
    """
    rise = np.asarray(svm_refined) - np.asarray(screen_refined)
    return bool(screen_next + rise.max() + slack * rise.std() >= np.max(svm_refined))


def _progress(total, desc, enabled):
    if not enabled:
        return None
    from tqdm.auto import tqdm
    return tqdm(total=total, desc=desc, file=sys.stderr, leave=False)


class GreedyPatternSelector(PatternModelMixin, BaseEstimator):
    """Greedy illumination-pattern search with a classifier per column count.

    Parameters
    ----------
    mode : 'per_colour' | 'joint'
    n_patterns : None for early termination (stop at the first column that does not improve
        the accuracy by more than `tol`), or a fixed number of columns to select.
    max_patterns : upper bound on the columns in early-termination mode.
    tol : minimum improvement of the mean accuracy that counts as an improvement.
    scoring : `search_params.SplitScoring`, how candidates are scored: random inner splits
        by physical sample or by pose (`inner_groups`; the paper: 400 pose splits, 0.25)
        and the screening classifier (None or 'ridge': the fast
        screen; the SVMs 'squared_hinge' or 'linear_svm' score every candidate exactly,
        without refinement); its C also serves the refinement.
    refinement : `search_params.Refinement`, with the 'ridge' screen: the exact linear SVM
        re-scores the screen's best `top` candidates per column, then more (in the screen's
        order, REFINE_BATCH at a time, up to `max`) while `could_still_win` with `slack` says
        one of the rest could still beat the SVM's best; the SVM's best is the column (top 0:
        the screen picks).
    rendering : `search_params.Rendering` (noise, dimmer, hog_config, features), used when
        `fit` is given a ModelSet (a SearchData carries its own).
    final_classifier : `search_params.FinalClassifier`, the kept classifiers ('linear_svm',
        the paper's, or 'ridge', with C / alpha).
    beam_width, max_lit_leds : joint mode only (see module docstring).
    count_rule : how many columns the fitted model keeps (`best_n_patterns_`) from the
        search's split accuracies: 'max' (the highest mean, the paper's) or 'one_se' (the
        fewest columns within one standard error of it; `column_count`).
    seed : seeds the splits, the noise and the kept classifiers.
    execution : `search_params.Execution` (n_jobs, chunk_size, progress).
    callback : None, or a callable given one dict per event of the search, for progress
        reports (the trainer node's action feedback): {'event': 'column_start', 'column'
        (1-based), 'of'} before a column is searched, {'event': 'candidates', 'column',
        'done', 'of'} (candidates scored so far of this screen's) before each round of
        scoring tasks, and {'event': 'column_done', 'column', 'of', 'candidates'
        (evaluated), 'accuracy', 'improved', 'best_accuracy'} after. An exception it raises
        stops the search there (the node's cancel: within one round, not one column).

    Fitted attributes
    -----------------
    patterns_ : (8, m) site patterns or (32, m) LED patterns, the selected columns.
    accuracy_by_images_ : {column count: mean split accuracy of the search}.
    split_accuracy_by_images_ : {column count: the chosen column's split accuracies}.
    optimism_by_images_ : {column count: how far choosing that column on the inner splits
        raises its split accuracy above a choice made without the held-out group it is
        scored on (`selection_bias.selection_optimism` over the refined candidates, or all
        with an SVM split classifier)}; `estimate_by_images_`, the accuracy less it, is the
        inner estimate reported.
    improved_ : bool (m,), whether each column improved on the best accuracy before it.
    best_n_patterns_ : the column count kept by `count_rule`.
    classifiers_ : {column count: fitted MuxClassifier on that many columns' images}.
    history_ : one dict per column: 'candidates' (rows, c), 'scores' (c,) and 'score_std' (c,)
        of the inner classifier, 'refined' (indices of the re-scored candidates, best screen
        score first) with 'refined_scores' and 'refined_std' of the linear SVM, 'best' (index
        of the chosen candidate), 'accuracy' (its score by the classifier that chose it),
        'improved', 'kept', 'screen_seconds' and 'refine_seconds' (wall time of each stage).
    """

    def __init__(self, mode='per_colour', n_patterns=None, max_patterns=8, tol=0.0,
                 scoring=SplitScoring(), refinement=Refinement(), rendering=Rendering(),
                 final_classifier=FinalClassifier(), beam_width=1, max_lit_leds=N_LEDS,
                 count_rule='max', seed=0, execution=Execution(), callback=None):
        self.mode = mode
        self.n_patterns = n_patterns
        self.max_patterns = max_patterns
        self.tol = tol
        self.scoring = scoring
        self.refinement = refinement
        self.rendering = rendering
        self.final_classifier = final_classifier
        self.beam_width = beam_width
        self.max_lit_leds = max_lit_leds
        self.count_rule = count_rule
        self.seed = seed
        self.execution = execution
        self.callback = callback

    # ------------------------------------------------------------------ fit
    def fit(self, X, y=None):
        """Search patterns on a ModelSet (or a prepared SearchData); returns self."""
        images_per_column(self.mode)
        self._check_groups()
        check_group(self, 'refinement', Refinement)
        target = self.n_patterns if self.n_patterns is not None else self.max_patterns
        if target is None or int(target) < 1:
            raise ValueError(f'need at least one pattern column, got n_patterns={self.n_patterns}, '
                             f'max_patterns={self.max_patterns}')
        data = self._data(X)
        self.data_ = data
        self.class_names_ = list(data.class_names)
        run = self.execution
        ev = self._evaluator(data, run.n_jobs, run.chunk_size)
        self.evaluator_ = ev
        rows = data.n_sites if self.mode == 'per_colour' else data.n_sites * data.n_channels
        columns = np.zeros((rows, 0), dtype=np.float32)
        self.history_ = []
        self.accuracy_by_images_ = {}
        self.split_accuracy_by_images_ = {}
        self.optimism_by_images_ = {}
        improved = []
        best_so_far = -np.inf
        bar = _progress(int(target), f'greedy {self.mode}', run.progress)
        with Parallel(n_jobs=run.n_jobs) as parallel:
            for col in range(int(target)):
                self._notify(event='column_start', column=col + 1, of=int(target))
                ctx = ev.prepare_column(columns if col else None)
                if self.mode == 'per_colour':
                    record = self._search_site_column(ev, ctx, parallel, data.n_sites)
                else:
                    record = self._search_led_column(ev, ctx, parallel)
                acc = record['accuracy']
                did_improve = bool(acc > best_so_far + self.tol)
                record['improved'] = did_improve
                self._notify(event='column_done', column=col + 1, of=int(target),
                             candidates=int(len(record['scores'])), accuracy=float(acc),
                             improved=did_improve, best_accuracy=float(max(best_so_far, acc)))
                if not did_improve and self.n_patterns is None:
                    record['kept'] = False
                    self.history_.append(record)
                    break
                record['kept'] = True
                self.history_.append(record)
                improved.append(did_improve)
                best_so_far = max(best_so_far, acc)
                columns = np.hstack([columns, record['pattern'][:, None]])
                self.accuracy_by_images_[columns.shape[1]] = float(acc)
                self.optimism_by_images_[columns.shape[1]] = float(record['optimism'])
                self.split_accuracy_by_images_[columns.shape[1]] = record['split_accuracy']
                if bar is not None:
                    bar.update(1)
                    bar.set_postfix(accuracy=f'{acc:.3f}')
        if bar is not None:
            bar.close()
        self.patterns_ = columns
        self.improved_ = np.array(improved, dtype=bool)
        self.best_n_patterns_ = self._best_count()
        self.classifiers_ = self._fit_classifiers(ev, columns)
        return self

    method_name = 'greedy'
    default_split_classifier = 'ridge'

    def _notify(self, **event) -> None:
        if self.callback is not None:
            self.callback(event)

    def _search_site_column(self, ev, ctx, parallel, n_sites):
        t0 = time.perf_counter()
        cands = site_pattern_candidates(n_sites)
        acc = ev.score(ctx, cands, parallel, on_progress=self._progress_of(ctx, cands.shape[1]))
        return self._choose(ev, ctx, parallel, cands, acc, time.perf_counter() - t0)

    def _progress_of(self, ctx, total: int):
        """`CandidateEvaluator.score`'s on_progress as 'candidates' events for `callback`
        (None without one: the scoring then runs in one round)."""
        if self.callback is None:
            return None
        return lambda done: self._notify(event='candidates', column=ctx.column + 1,
                                         done=int(done), of=int(total))

    def _choose(self, ev, ctx, parallel, cands, acc, screen_seconds):
        """The column's record: the screen's best, or the linear SVM's best after refining."""
        scores = acc.mean(axis=1)
        record = {'candidates': cands, 'scores': scores, 'score_std': acc.std(axis=1),
                  'screen_seconds': screen_seconds, 'refine_seconds': 0.0}
        t0 = time.perf_counter()
        race = self.refinement
        if self.split_classifier != 'ridge' or int(race.top) == 0:
            best = int(np.argmax(scores))
            record.update(best=best, accuracy=float(scores[best]), split_accuracy=acc[best].copy(),
                          optimism=selection_optimism(acc, best, ev.split_groups))
        else:
            scorer = SquaredHingeSplitScorer(C=self.scoring.C)
            order = np.argsort(-scores, kind='stable')
            parts = []

            def svm_mean():
                return np.vstack(parts).mean(axis=1)

            k = 0
            while k == 0 or (k < min(int(race.max), order.size) and could_still_win(
                    scores[order[:k]], svm_mean(), scores[order[k]], race.slack)):
                step = int(race.top) if k == 0 else REFINE_BATCH
                parts.append(ev.score(ctx, cands[:, order[k:k + step]], parallel, scorer=scorer,
                                      chunk_size=1))
                k = min(k + step, order.size)
            svm = np.vstack(parts)
            svm_scores = svm.mean(axis=1)
            pick = int(np.argmax(svm_scores))
            best = int(order[pick])
            record.update(refined=order[:k], refined_scores=svm_scores,
                          refined_std=svm.std(axis=1), best=best,
                          accuracy=float(svm_scores[pick]), split_accuracy=svm[pick].copy(),
                          optimism=selection_optimism(svm, pick, ev.split_groups),
                          refine_seconds=time.perf_counter() - t0)
        record['pattern'] = cands[:, best].copy()
        return record

    def _search_led_column(self, ev, ctx, parallel):
        t0 = time.perf_counter()
        n_leds = ev.data.n_sites * ev.data.n_channels
        beam = [np.zeros(n_leds, dtype=np.float32)]
        seen = set()
        all_cands, all_acc = [], []
        best_score = -np.inf
        for _ in range(min(int(self.max_lit_leds), n_leds)):
            cands = []
            for parent in beam:
                for led in np.flatnonzero(parent == 0):
                    child = parent.copy()
                    child[led] = 1
                    key = child.tobytes()
                    if key not in seen:
                        seen.add(key)
                        cands.append(child)
            if not cands:
                break
            cands = np.stack(cands, axis=1)
            acc = ev.score(ctx, cands, parallel, on_progress=self._progress_of(ctx, cands.shape[1]))
            scores = acc.mean(axis=1)
            all_cands.append(cands)
            all_acc.append(acc)
            order = np.argsort(-scores, kind='stable')
            if scores[order[0]] <= best_score + self.tol:
                break  # lighting one more LED does not help this column
            best_score = float(scores[order[0]])
            beam = [cands[:, i] for i in order[:int(self.beam_width)]]
        # the beam's steps ranked by the screen; the column is then chosen among every
        # pattern it evaluated
        return self._choose(ev, ctx, parallel, np.hstack(all_cands), np.vstack(all_acc),
                            time.perf_counter() - t0)
