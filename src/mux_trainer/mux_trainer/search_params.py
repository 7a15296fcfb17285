"""The settings a pattern search or baseline is built from, grouped by what they configure.

Each group is a small frozen dataclass given to the estimator as one parameter (like
scikit-learn's `estimator=` parameters): `scoring` (how a pattern matrix is scored: repeated
inner splits, by physical sample or by pose, and the split classifier), `refinement` (the greedy search's SVM race),
`rendering` (how a ModelSet becomes training images and features), `final_classifier` (the
kept classifiers) and `execution` (how the work is spread; never what is searched for).
What defines a method's own search (mode, column counts, beam, count rule) and the seed stay
flat. The estimators store the groups as given and check them in `fit` (`check_group`);
`get_params(deep=True)` lists their fields as `group__field`, and `set_params(group__field=v)`
replaces the group by a copy with that field changed (the groups are frozen, so a default
shared by every estimator is never changed in place).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from lightstage_physics.rig import DEFAULT_DIMMER
from mux_classifier.features import DEFAULT_EXTRACTOR

from .splits import check_inner_groups

__all__ = ['ParamGroup', 'SplitScoring', 'Refinement', 'Rendering', 'FinalClassifier',
           'Execution', 'GroupedParamsMixin', 'check_group']


class ParamGroup:
    """Base of the setting groups: scikit-learn's nested-parameter protocol for a frozen
    dataclass (`get_params`; `set_params` is the estimator's, which replaces the group)."""

    def get_params(self, deep: bool = True) -> dict:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def replace(self, **changes) -> 'ParamGroup':
        """A copy with `changes`; ValueError naming a field the group does not have."""
        unknown = set(changes) - {f.name for f in dataclasses.fields(self)}
        if unknown:
            raise ValueError(f'{type(self).__name__} has no field(s) {sorted(unknown)}; its '
                             f'fields: {sorted(self.get_params())}')
        return dataclasses.replace(self, **changes)

    def check(self) -> None:
        """ValueError for a setting out of range (called by the estimator's fit)."""


@dataclass(frozen=True)
class SplitScoring(ParamGroup):
    """How columns are scored: the mean accuracy over `n_repeats` random pose splits holding
    out `test_fraction` of the pose indices (the paper: 400, 0.25), by the split classifier
    `classifier`: 'ridge' (fast, one kernel for all splits), 'squared_hinge' (the exact
    linear SVM) or 'linear_svm' (one LinearSVC per split); None: the method's own (the
    greedy search: the ridge screen, refined by the exact SVM; the baselines, which score
    one matrix per image count: the exact SVM). `alpha` is the ridge penalty (0.5 =
    1 / (2 C): the SVM's first Newton step), `C` the linear SVM's.

    `inner_groups`: what a split holds out (`splits.inner_splits`): 'instances' whole
    physical samples, `test_fraction` of every class's with all their poses, every sample
    in turn (the inner estimate is then one for objects never seen in training, the
    product's use: pose splits overstate it where a classifier can recognise the sample
    rather than the class); 'poses' pose indices (the paper's rule); 'auto' (default)
    'instances' where the data says each sample's physical sample (`SearchData.instance`)
    and every class has two or more, else 'poses'."""

    n_repeats: int = 400
    test_fraction: float = 0.25
    classifier: str | None = None
    alpha: float = 0.5
    C: float = 1.0
    inner_groups: str = 'auto'

    def check(self) -> None:
        check_inner_groups(self.inner_groups)
        if int(self.n_repeats) < 1:
            raise ValueError(f'scoring.n_repeats must be >= 1, got {self.n_repeats}')
        if not 0 < float(self.test_fraction) < 1:
            raise ValueError(f'scoring.test_fraction must be in (0, 1), got {self.test_fraction}')


# refinement defaults (see `greedy.could_still_win`; benchmarks/rank_agreement.py measures them)
REFINE_TOP = 16     # candidates the exact SVM scores first, in the screen's order
REFINE_MAX = 64     # then more (greedy.REFINE_BATCH at a time), never more than this per column
REFINE_SLACK = 1.0


@dataclass(frozen=True)
class Refinement(ParamGroup):
    """The greedy search's race (with the 'ridge' screen only): the exact linear SVM
    re-scores the screen's best `top` candidates per column, then more (in the screen's
    order, greedy.REFINE_BATCH at a time, up to `max`) while `greedy.could_still_win` with `slack`
    says one of the rest could still beat the SVM's best. `top` 0: the screen picks."""

    top: int = REFINE_TOP
    max: int = REFINE_MAX
    slack: float = REFINE_SLACK

    def check(self) -> None:
        if int(self.top) < 0:
            raise ValueError(f'refine_top must be >= 0, got {self.top}')


@dataclass(frozen=True)
class Rendering(ParamGroup):
    """How `fit` renders a ModelSet (a SearchData carries its own): the camera `noise`
    setting (anything `data.resolve_noise` takes), the LED `dimmer`, the `hog_config`
    (None: the default HogConfig) and the feature extractor `features` the search scores
    and the kept classifiers use (`mux_classifier.features`; "hog_grid" is the paper's)."""

    noise: object = 'sigma3'
    dimmer: float = DEFAULT_DIMMER
    hog_config: object = None
    features: str = DEFAULT_EXTRACTOR


@dataclass(frozen=True)
class FinalClassifier(ParamGroup):
    """The kept classifiers (one per column count, `mux_classifier.MuxClassifier`):
    `estimator` 'linear_svm' (the paper's) or 'ridge', with its `C` / `alpha`."""

    estimator: str = 'linear_svm'
    C: float = 1.0
    alpha: float = 0.1


@dataclass(frozen=True)
class Execution(ParamGroup):
    """How the work runs: `n_jobs` joblib workers (never changes a result), `chunk_size`
    candidates per task (fixed rather than derived from n_jobs: candidates within a chunk
    are rendered incrementally, so it can change float32 rounding), `progress` a tqdm bar
    on stderr. The baselines use only n_jobs (for their classifiers' fits)."""

    n_jobs: int = 1
    chunk_size: int = 32
    progress: bool = False

    def check(self) -> None:
        if int(self.chunk_size) < 1:
            raise ValueError(f'execution.chunk_size must be >= 1, got {self.chunk_size}')


def check_group(owner, name: str, kind: type) -> None:
    """TypeError unless `owner.<name>` is a `kind`; then the group's own range checks."""
    value = getattr(owner, name)
    if not isinstance(value, kind):
        raise TypeError(f'{type(owner).__name__}({name}=...) must be a {kind.__name__} '
                        f'(mux_trainer.search_params), got {type(value).__name__} {value!r}')
    value.check()


class GroupedParamsMixin:
    """`set_params` that also takes `group__field=value` for a ParamGroup parameter: the
    group is replaced by a copy with that field changed (groups are frozen). Put it before
    BaseEstimator in the bases."""

    def set_params(self, **params):
        nested: dict = {}
        flat = {}
        for key, value in params.items():
            group, sep, field = key.partition('__')
            if sep and isinstance(getattr(self, group, None), ParamGroup):
                nested.setdefault(group, {})[field] = value
            else:
                flat[key] = value
        super().set_params(**flat)  # a whole group given too is set first
        for group, changes in nested.items():
            setattr(self, group, getattr(self, group).replace(**changes))
        return self
