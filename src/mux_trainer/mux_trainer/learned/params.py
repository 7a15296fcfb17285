"""The learned method's own settings, grouped as the search's are (`search_params`): the
starts (which candidate lights are made), the descent (gradient steps on the levels) and
the head (the final classifier). Each is a frozen dataclass given to the estimator as one
parameter; `get_params(deep=True)` lists its fields as `group__field` and
`set_params(group__field=v)` replaces the group by a changed copy. The inner splits, the
rendering and the execution are the search's own groups (`SplitScoring`, `Rendering`,
`Execution`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..learned_schedule import DEFAULT_STEPS, check_steps
from ..search_params import ParamGroup

__all__ = ['BUILTIN_STARTS', 'HEADS', 'DEFAULT_FINE_TUNE', 'Starts', 'Descent', 'Head']

BUILTIN_STARTS = ('random', 'per_colour', 'snr_optimal', 'greedy', 'raking_sides')
HEADS = ('by_type', 'flat')
# the starts a descent runs from (docs/LEARNED.md, "Gradient steps on the levels")
DEFAULT_FINE_TUNE = ('random', 'greedy', 'raking_sides')
# what `Descent.fine_tune` may name besides starts
FINE_TUNE_WORDS = ('best', 'all', 'none')


@dataclass(frozen=True)
class Starts(ParamGroup):
    """The candidate lights made before any gradient step, each scored by the inner splits
    and kept as it is if it scores best (docs/LEARNED.md, "Candidate lights and how one is
    kept").

    `names`: built-in starts, among 'random' (`starts.random_start`), 'per_colour'
    (`starts.per_colour_start`), 'snr_optimal' (the SNR-optimal baseline's first k / 4 site
    columns), 'greedy' (the greedy search's k / 4 per-colour columns on the same training
    data and inner splits), both expanded to LEDs by `rig.site_to_led_patterns`, and
    'raking_sides' (`starts.raking_sides_start` on the rig's site positions, one start per
    split of the low sites, `starts.low_side_splits`: 'raking_sides', 'raking_sides/1', ...);
    the last three are skipped unless 4 divides k. `patterns`: more starts, {name: (32, k)
    LED levels in [0, 1]}. `site_positions_mm`: (n_sites, 3) for the raking-sides start;
    None: the rig of the ModelSet fitted, or the paper's stage for a SearchData."""

    names: tuple = BUILTIN_STARTS
    patterns: dict | None = None
    site_positions_mm: object = None

    def all_names(self) -> set:
        """The names a descent may start from: the built-in ones asked for and the given."""
        return set(self.names) | set(self.patterns or {})

    def check(self) -> None:
        unknown = set(self.names) - set(BUILTIN_STARTS)
        if unknown:
            raise ValueError(f"unknown starts {sorted(unknown)}; use {', '.join(BUILTIN_STARTS)}")
        if self.site_positions_mm is not None:
            positions = np.asarray(self.site_positions_mm, np.float64)
            if positions.ndim != 2 or positions.shape[1] != 3:
                raise ValueError(f'starts.site_positions_mm must be (n_sites, 3), got shape '
                                 f'{positions.shape}')


@dataclass(frozen=True)
class Descent(ParamGroup):
    """Gradient steps on the LED logits (docs/LEARNED.md, "Gradient steps on the levels").

    `max_steps` steps (0, the default `learned_schedule.DEFAULT_STEPS`: no descent, the
    starts alone) from each start `fine_tune` names: names of starts (default 'random',
    'greedy', 'raking_sides'; 'raking_sides' means the best scored of its splits), or
    'best' (the start the inner splits score best), 'all', 'none'. Each step renders
    `batch_size` training samples (all of them when it is at least their number) with a
    fresh noise draw, and Adam at learning rate `lr` follows the gradient of
    `descent.cv_ridge_loss` over `n_folds` folds (`descent.inner_folds`) with ridge `ridge`;
    every `eval_every` steps a snapshot of the levels is scored by the inner splits."""

    max_steps: int = DEFAULT_STEPS
    fine_tune: tuple | str = DEFAULT_FINE_TUNE
    eval_every: int = 50
    batch_size: int = 256
    lr: float = 0.2
    n_folds: int = 5
    ridge: float = 0.01

    def tuned_names(self) -> tuple:
        """fine_tune as a tuple of names (one name may be given as a string)."""
        tune = self.fine_tune
        return (tune,) if isinstance(tune, str) else tuple(str(n) for n in tune)

    def check(self) -> None:
        check_steps(self.max_steps)
        for name in ('batch_size', 'eval_every', 'n_folds'):
            if int(getattr(self, name)) < 1:
                raise ValueError(f'descent.{name} must be >= 1, got {getattr(self, name)}')
        for name in ('ridge', 'lr'):
            value = float(getattr(self, name))
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f'descent.{name} must be a positive number, got {value}')
        if not self.tuned_names():
            raise ValueError("descent.fine_tune must name starts or be 'best', 'all' or "
                             "'none', got nothing")


@dataclass(frozen=True)
class Head(ParamGroup):
    """The final classifier (docs/LEARNED.md, "The head: gated by object type"): linear SVMs
    with `C` on the training samples rendered under the kept light with `renders` noise
    draws (the inner splits' draw and `renders` - 1 more: a head fitted on one draw may
    learn its noise). `kind` 'by_type' (default): gated by object type
    (`mux_classifier.gated_head`, types from the class names' prefix,
    `data.class_type_groups`): one SVM tells the types apart, within a type a class scores
    by its type's own SVM plus the flat SVM; the flat head where gating changes nothing
    (one type, or one class per type). 'flat': one one-vs-rest SVM over every class."""

    kind: str = 'by_type'
    renders: int = 6
    C: float = 1.0

    def check(self) -> None:
        if self.kind not in HEADS:
            raise ValueError(f"head.kind must be one of {', '.join(HEADS)}, got {self.kind!r}")
        if int(self.renders) < 1:
            raise ValueError(f'head.renders must be >= 1, got {self.renders}')
        if not (np.isfinite(float(self.C)) and float(self.C) > 0):
            raise ValueError(f'head.C must be a positive number, got {self.C}')
