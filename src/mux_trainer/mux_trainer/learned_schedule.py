"""How long learned illumination trains: the step counts the CLI, the trainer node, the
estimator and `lightstage eval` share (no JAX here, so the node and the CLI read them for
free)."""
from __future__ import annotations

# gradient steps on the light from each start descended (`learned`'s default: the random
# start and greedy's columns; every `eval_every` steps a snapshot is scored by the inner pose
# splits, the best kept). On the strength-0.2 capture the inner score still rose at 200 steps
# from the random start (docs/LEARNED.md, round 3).
DEFAULT_STEPS = 200
MAX_STEPS = 100_000
# exposure counts `lightstage eval` trains a learned model for (one model each: a learned
# k-image model's patterns are not the first k of a larger one's)
EVAL_EXPOSURES = (4, 8)


def check_steps(steps: int) -> None:
    if not 1 <= int(steps) <= MAX_STEPS:
        raise ValueError(f'steps (training steps of the learned patterns) must be 1 .. '
                         f'{MAX_STEPS}, got {steps}')
