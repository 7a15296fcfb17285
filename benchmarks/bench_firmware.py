#!/usr/bin/env python3
"""Pattern-apply round trips per second: the compiled AVR firmware in simavr beside the
Python firmware simulator, measured side by side in one run.

Each backend is driven through the driver's `LightStage` over a pty, with the same
patterns: `SET_PATTERN` (show now) alone, and a pattern apply (`SET_PATTERN` + `FIRE`
of 20 us, what one classify image costs the stage). Backends:

- python: the Python simulator, replying as fast as the pty allows;
- python@115200: the same, waiting the wire time of each frame at 115200 baud;
- avr: the compiled firmware in simavr, simulated time throttled to wall time (the
  UART's baud timing is simulated, so this is what a real Uno would do, plus pty and
  harness overhead);
- avr-unthrottled: simulated time allowed to run ahead of wall time.

The last column is the limit set by the bytes alone on a real 115200 8N1 line.

    .venv/bin/python benchmarks/bench_firmware.py [-n 300]
    .venv/bin/python benchmarks/bench_firmware.py --quick   # -n 20
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from lightstage_driver import protocol as p
from lightstage_driver.sim_backend import PythonSimBackend
from lightstage_driver.simavr_backend import SimavrBackend, missing_tools
from lightstage_driver.stage import LightStage

from _common import parse_args
from bench_driver import timed

BAUD = 115200
EXPOSURE_US = 20


def backends():
    yield 'python', lambda: PythonSimBackend()
    yield 'python@115200', lambda: PythonSimBackend(emulate_baud=BAUD)
    if missing_tools():
        print(f'(avr backends skipped: missing {", ".join(missing_tools())})')
        return
    yield 'avr', lambda: SimavrBackend()
    yield 'avr-unthrottled', lambda: SimavrBackend(throttle=False)


def line_per_s(*frames: tuple[int, int], exposure_us: float = 0.0) -> float:
    """Round trips per second the wire allows for these (command, reply) payload sizes."""
    seconds = sum(p.line_seconds(p.frame_bytes(c) + p.frame_bytes(r), BAUD) for c, r in frames)
    return 1.0 / (seconds + exposure_us * 1e-6)


def measure(make, patterns: np.ndarray) -> dict:
    backend = make()
    backend.start()
    try:
        with LightStage(backend.port, timeout_s=0.5) as stage:
            for _ in range(20):
                stage.heartbeat()          # warm up
            show = timed(lambda i: stage.set_pattern(patterns[i]), len(patterns))
            apply = timed(lambda i: stage.apply(patterns[i], EXPOSURE_US), len(patterns))
            t0_host, t0_fw = time.perf_counter(), stage.heartbeat().t_us
            time.sleep(0.5)
            t1_fw, t1_host = stage.heartbeat().t_us, time.perf_counter()
            stats = stage.link.stats
            # firmware-clock speed against the host's while the firmware idles
            speed = ((t1_fw - t0_fw) % 2**32) / 1e6 / (t1_host - t0_host)
            words = backend.led_words()
        return {'show': show, 'apply': apply, 'retries': stats.retries, 'speed': speed,
                'words_ok': [w.word for w in words if w.word][:len(patterns)] ==
                            [int(sum(1 << k for k in range(32) if row[k])) for row in patterns]}
    finally:
        backend.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('-n', type=int, default=300, help='round trips per command and backend')
    args = parse_args(parser, argv, n=20)
    rng = np.random.default_rng(0)
    patterns = (rng.random((args.n, 32)) > 0.5).astype(float)
    patterns[:, 0] = 1.0       # never all-off, so every shown word is visible on the pins

    results = {name: measure(make, patterns) for name, make in backends()}

    limit_show = line_per_s((5, 4))
    limit_apply = line_per_s((5, 4), (4, 8), exposure_us=EXPOSURE_US)
    header = (f'{"backend":16s} {"SET_PATTERN/s":>13s} {"p50 ms":>7s} {"apply/s":>8s} {"p50 ms":>7s} '
              f'{"p99 ms":>7s} {"retries":>7s} {"fw clock/host":>13s} {"words ok":>8s}')
    print(f'pattern-apply round trips through LightStage over a pty, n={args.n} each, '
          f'exposure {EXPOSURE_US} us')
    print(header)
    print('-' * len(header))
    for name, r in results.items():
        show_p50 = np.median(r['show']) * 1e3
        apply_p50, apply_p99 = np.percentile(r['apply'] * 1e3, [50, 99])
        print(f'{name:16s} {1 / r["show"].mean():13.0f} {show_p50:7.2f} {1 / r["apply"].mean():8.0f} '
              f'{apply_p50:7.2f} {apply_p99:7.2f} {r["retries"]:7d} {r["speed"]:12.2f}x '
              f'{"yes" if r["words_ok"] else "NO":>8s}')
    print(f'{"115200 line":16s} {limit_show:13.0f} {1e3 / limit_show:7.2f} {limit_apply:8.0f} '
          f'{1e3 / limit_apply:7.2f}')
    for reference in ('python', 'python@115200'):
        if 'avr' in results and reference in results:
            print(f'avr / {reference} pattern-apply rate: '
                  f'{results[reference]["apply"].mean() / results["avr"]["apply"].mean():.2f}')
    print('fw clock/host = firmware microseconds per host microsecond while idle (simavr throttled '
          'to wall time shows ~1); words ok = the pins showed every pattern sent, in order')
    return 0


if __name__ == '__main__':
    sys.exit(main())
