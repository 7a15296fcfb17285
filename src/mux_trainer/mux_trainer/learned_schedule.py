"""How long learned illumination trains: the step counts the CLI, the trainer node, the
estimator and `lightstage eval` share (no JAX here, so the node and the CLI read them for
free)."""
from __future__ import annotations

# gradient steps on the light from each start descended (`learned`'s fine_tune: the random
# start, greedy's columns and the best raking split; every `eval_every` steps a snapshot is
# scored by the inner splits, the best kept). 0: the starts are scored and the best
# kept, no descent. Why 0 by default (docs/LEARNED.md, "Gradient steps on the levels"): with the cross-image
# statistics no snapshot of 200 steps from any of the three was kept on the 16-class mix, at
# 17 min per descent; the starts alone score at least as well as descents on every capture
# measured but the weakest cue strength, where the inner score still rose at 200 steps from
# the random start (strength 0.2; docs/research/LEARNED_PATH.md).
DEFAULT_STEPS = 0
MAX_STEPS = 100_000
# exposure counts `lightstage eval` trains a learned model for (one model each: a learned
# k-image model's patterns are not the first k of a larger one's)
EVAL_EXPOSURES = (4, 8)


def check_steps(steps: int) -> None:
    if not 0 <= int(steps) <= MAX_STEPS:
        raise ValueError(f'steps (training steps of the learned patterns; 0: the starts only) '
                         f'must be 0 .. {MAX_STEPS}, got {steps}')
