"""Worker counts of the parallel verbs (`--jobs` of train, eval, synth, demo; the trainer
node's `n_jobs`): one default and one rule, so that every verb says the same thing."""
from __future__ import annotations

import argparse


def usable_cores() -> int:
    """The CPUs this process may run on: its affinity mask and any cgroup CPU quota, as
    joblib counts them (os.cpu_count() would also count CPUs it may not use)."""
    from joblib import cpu_count
    return max(1, int(cpu_count()))


def jobs_problem(n_jobs) -> str:
    """'' for a usable worker count (>= 1, or -1 = all usable cores), else what is wrong."""
    if isinstance(n_jobs, int) and not isinstance(n_jobs, bool) and (n_jobs >= 1 or n_jobs == -1):
        return ''
    return (f'must be a number of worker processes >= 1, or -1 for all {usable_cores()} usable '
            f'cores; got {n_jobs!r}')


def check_jobs(n_jobs, name: str = 'n_jobs') -> int:
    """`n_jobs` if usable, else ValueError naming `name` (a flag or parameter)."""
    problem = jobs_problem(n_jobs)
    if problem:
        raise ValueError(f'{name} {problem}')
    return n_jobs


def jobs_type(text: str) -> int:
    """argparse `type=` of a --jobs flag: argparse then names the flag in its error."""
    try:
        n_jobs = int(text)
    except ValueError:
        n_jobs = text
    problem = jobs_problem(n_jobs)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return n_jobs
