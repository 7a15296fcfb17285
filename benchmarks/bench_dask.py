"""The default search locally and on a Dask cluster: wall time and bytes sent to the workers.

Prints, from one run on the same data (default: the synthetic dataset of `make demo`, 10
classes x 20 poses, Sigma3, 400 splits, seed 0), the wall time of the default per-colour
search (ridge screen + exact-SVM race) over --columns columns:
1. with 1 local process (--jobs 1),
2. with 2 local processes (--jobs 2),
3. on a 2-worker Dask cluster started here as separate processes on 127.0.0.1 (`dask
   scheduler`, two `dask worker --nthreads 1 --no-nanny`; stopped at the end), through
   `--dask-scheduler`'s code path (`mux_trainer.cluster.dask_cluster`),
whether the three selected the same columns with the same split accuracies, and the bytes
broadcast to the workers: the search data once per search and the column's context once per
column, per worker (pickled sizes, checked against the scheduler's own size of what its
workers hold), against what sending both with every task would cost; then the same figures
for 800 px models.

Usage (docs/SEARCH.md, "Searching on a Dask cluster"; the full 8 columns take ~3 x 7-15 min):
    .venv/bin/python benchmarks/bench_dask.py --columns 2 [--capture DIR]
    .venv/bin/python benchmarks/bench_dask.py --quick   # 1 column, 10 splits, a small capture
The machine may be shared: the load average is printed beside the figures.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from lightstage_physics.capture_format import load_capture
from mux_trainer.cluster import dask_cluster, shared_bytes
from mux_trainer.data import search_data
from mux_trainer.greedy import GreedyPatternSelector
from mux_trainer.search_params import Execution, SplitScoring

from _common import capture_or_default, parse_args

DASK = [sys.executable, '-m', 'dask']
MB = 1e6


def load() -> str:
    return ' '.join(f'{v:.1f}' for v in os.getloadavg())


def start_cluster(folder: Path, n_workers: int = 2):
    """`dask scheduler` + workers on loopback; returns (address, processes)."""
    file = folder / 'scheduler.json'
    procs = [subprocess.Popen([*DASK, 'scheduler', '--host', '127.0.0.1', '--port', '0',
                               '--no-dashboard', '--scheduler-file', str(file)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    deadline = time.monotonic() + 120
    while True:
        try:
            address = json.loads(file.read_text())['address']
            break
        except (OSError, ValueError, KeyError):
            if time.monotonic() > deadline or procs[0].poll() is not None:
                raise SystemExit('bench_dask: the dask scheduler did not start') from None
            time.sleep(0.1)
    for k in range(n_workers):
        procs.append(subprocess.Popen([*DASK, 'worker', address, '--host', '127.0.0.1',
                                       '--nthreads', '1', '--no-dashboard', '--no-nanny',
                                       '--name', f'w{k}'],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
    return address, procs


def search(data, args, n_jobs):
    t0 = time.perf_counter()
    sel = GreedyPatternSelector(n_patterns=args.columns,
                                scoring=SplitScoring(n_repeats=args.repeats), seed=args.seed,
                                execution=Execution(n_jobs=n_jobs, progress=True)).fit(data)
    return time.perf_counter() - t0, sel


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--capture', help='capture folder (default: the synthetic dataset in .cache)')
    p.add_argument('--columns', type=int, default=8, help='pattern columns to search (default 8)')
    p.add_argument('--repeats', type=int, default=400)
    p.add_argument('--noise', default='sigma3')
    p.add_argument('--seed', type=int, default=0)
    args = parse_args(p, argv, columns=1, repeats=10)
    capture = capture_or_default(args.capture, args.quick)
    data = search_data(load_capture(capture, downscale_to=120), args.noise)
    n, px = data.basis.shape[2], data.basis.shape[3]
    print(f'data: {capture}, {len(data.class_names)} classes, {n} samples, '
          f'{data.image_shape[0]} px; {args.columns} column(s) x 254 candidates x '
          f'{args.repeats} splits; load average {load()}', flush=True)

    runs = {}
    for label, n_jobs in (('1 local process', 1), ('2 local processes', 2)):
        wall, sel = search(data, args, n_jobs)
        runs[label] = sel
        print(f'  {label:<26}: {wall:8.1f} s; load average {load()}', flush=True)

    with tempfile.TemporaryDirectory() as folder:
        address, procs = start_cluster(Path(folder))
        try:
            with dask_cluster(address) as cluster:
                cluster.client.wait_for_workers(2, timeout=120)
                wall, sel = search(data, args, 1)
                runs['2-worker Dask cluster'] = sel
                print(f'  {"2-worker Dask cluster":<26}: {wall:8.1f} s; load average {load()}; '
                      f'{address}', flush=True)
                # what the scheduler says its workers hold now: the data, the last context
                held = {}
                for slot, (obj, future) in cluster._shared.items():
                    holders = len(cluster.client.who_has([future])[future.key])
                    size = cluster.client.nbytes([future.key], summary=False)[future.key]
                    held[slot] = (shared_bytes(obj), size, holders)
                sent, tasks = cluster.bytes_broadcast, cluster.tasks_submitted
        finally:
            for proc in procs:
                proc.kill()
                proc.wait()

    first = runs['1 local process']
    same = all(np.array_equal(sel.patterns_, first.patterns_)
               and sel.accuracy_by_images_ == first.accuracy_by_images_ for sel in runs.values())
    columns = ' | '.join(''.join(str(int(v)) for v in col) for col in first.patterns_.T)
    print(f'  same columns and split accuracies in the three runs: {same} ({columns})')

    data_bytes, ctx_bytes = held['search data'][0], held['column context'][0]
    print(f'\nbytes broadcast to the 2 workers: {sent / MB:.1f} MB in all for {args.columns} '
          f'column(s) and {tasks} tasks = search data {data_bytes / MB:.1f} MB per worker once '
          f'per search + column context {ctx_bytes / MB:.1f} MB per worker per column, i.e. '
          f'{sent / args.columns / MB:.1f} MB per column on average, '
          f'{2 * ctx_bytes / MB:.1f} MB per column after the first')
    for slot, (pickled, size, holders) in held.items():
        print(f'  scheduler: {slot} {size / MB:.1f} MB (its size estimate) on {holders} '
              f'worker(s); pickled {pickled / MB:.1f} MB')
    print(f'  sending both with every task instead: {tasks * (data_bytes + ctx_bytes) / MB:.0f} MB')
    # 800 px: the basis and the candidate noise scale with the pixels, the rest does not
    ctx = first.evaluator_.prepare_column(None)
    pixel_data = data.basis.nbytes
    pixel_ctx = 0 if ctx.z is None else ctx.z.nbytes
    scale = (800 * 800) / px
    print(f'800 px models: at the default feature size (--image-size 120) the client downscales '
          f'them before anything is sent: the same {data_bytes / MB:.1f} + '
          f'{ctx_bytes / MB:.1f} MB per worker; with --image-size 800 (features at full '
          f'resolution): search data {(data_bytes + pixel_data * (scale - 1)) / 1e9:.1f} GB per '
          f'worker once, column context {(ctx_bytes + pixel_ctx * (scale - 1)) / 1e9:.2f} GB per '
          f'worker per column (x{scale:.1f} the pixels)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
