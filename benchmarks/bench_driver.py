#!/usr/bin/env python3
"""Driver round trips over a real pty, beside the serial line's physical limit.

For each command: latency p50 / p99 and rate, measured through `LightStage` (framing,
CRC, pyserial, pty, the firmware) against a firmware backend, next to the time the bytes
alone need on a real 8N1 line at the baud rate (command frame + reply frame, 10 bits per
byte). A pty moves bytes without baud timing, so the Python simulator can beat the line
limit unless `--emulate-baud` makes it wait the wire time; simavr simulates the UART's
baud timing itself.

    .venv/bin/python benchmarks/bench_driver.py --backend python
    .venv/bin/python benchmarks/bench_driver.py --backend avr
    .venv/bin/python benchmarks/bench_driver.py --quick   # python backend, 20 round trips
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from lightstage_driver import protocol as p
from lightstage_driver.stage import LightStage

from _common import parse_args

FIRE_EXPOSURE_US = 20     # shortest exposure: the figures are about the link, not the exposure


def make_backend(kind: str, emulate_baud: int):
    if kind == 'python':
        from lightstage_driver.sim_backend import PythonSimBackend
        return PythonSimBackend(emulate_baud=emulate_baud, pwm_bits=8)   # graded, as the AVR firmware
    from lightstage_driver.simavr_backend import SimavrBackend
    return SimavrBackend()


def timed(fn, n: int) -> np.ndarray:
    out = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter()
        fn(i)
        out[i] = time.perf_counter() - t0
    return out


def line_ms(command_payload: int, reply_payload: int, baud: int, exposure_us: float = 0.0) -> float:
    n_bytes = p.frame_bytes(command_payload) + p.frame_bytes(reply_payload)
    return p.line_seconds(n_bytes, baud) * 1e3 + exposure_us / 1e3


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--backend', choices=('python', 'avr'), default='python')
    parser.add_argument('-n', type=int, default=500, help='round trips per command')
    parser.add_argument('--baud', type=int, default=115200)
    parser.add_argument('--emulate-baud', action='store_true',
                        help='python backend: delay replies by the wire time at --baud')
    args = parse_args(parser, argv, n=20)

    backend = make_backend(args.backend, args.baud if args.emulate_baud else 0)
    backend.start()
    rng = np.random.default_rng(0)
    patterns = (rng.random((args.n, 32)) > 0.5).astype(float)
    # graded: every LED at a level of its own (0..255 / 255)
    graded = rng.integers(0, 256, size=(args.n, 32)) / 255.0
    try:
        with LightStage(backend.port, baud=args.baud, timeout_s=0.5) as stage:
            ident = stage.identity
            seq_len = ident.max_sequence
            for _ in range(20):    # warm up
                stage.heartbeat()
            rows = [
                ('HEARTBEAT', timed(lambda i: stage.heartbeat(), args.n), line_ms(0, 7, args.baud), 1),
                ('SET_PATTERN (show now)', timed(lambda i: stage.set_pattern(patterns[i]), args.n),
                 line_ms(5, 4, args.baud), 1),
                ('FIRE 20 us', timed(lambda i: stage.fire(FIRE_EXPOSURE_US), args.n),
                 line_ms(4, 8, args.baud, FIRE_EXPOSURE_US), 1),
                ('pattern apply (SET_PATTERN + FIRE)',
                 timed(lambda i: stage.apply(patterns[i], FIRE_EXPOSURE_US), args.n),
                 line_ms(5, 4, args.baud) + line_ms(4, 8, args.baud, FIRE_EXPOSURE_US), 1),
            ]
            n_seq = max(10, args.n // seq_len)
            seq_patterns = patterns[:seq_len]
            # RUN_SEQUENCE + reply + one EVT_TRIGGER per pattern + EVT_SEQUENCE_DONE
            seq_line = (line_ms(5 + 8 * seq_len, 1, args.baud)
                        + seq_len * p.line_seconds(p.frame_bytes(9), args.baud) * 1e3
                        + p.line_seconds(p.frame_bytes(2), args.baud) * 1e3
                        + seq_len * FIRE_EXPOSURE_US / 1e3)
            rows.append((f'sequence of {seq_len} (RUN_SEQUENCE)',
                         timed(lambda i: stage.apply(seq_patterns, FIRE_EXPOSURE_US), n_seq), seq_line, seq_len))
            rows.append(('graded apply (SET_LEVELS + FIRE)',
                         timed(lambda i: stage.apply(graded[i], FIRE_EXPOSURE_US), args.n),
                         line_ms(1 + 2 * 32, 4, args.baud) + line_ms(4, 8, args.baud, FIRE_EXPOSURE_US), 1))
            # the table in 4-row frames, then RUN_LEVEL_SEQUENCE + reply + events
            table_frames = -(-seq_len // p.TABLE_ROWS_PER_FRAME)
            graded_line = (table_frames * line_ms(1 + 32 * p.TABLE_ROWS_PER_FRAME, 2, args.baud)
                           + line_ms(5 + 5 * seq_len, 1, args.baud)
                           + seq_len * p.line_seconds(p.frame_bytes(9), args.baud) * 1e3
                           + p.line_seconds(p.frame_bytes(2), args.baud) * 1e3
                           + seq_len * FIRE_EXPOSURE_US / 1e3)
            rows.append((f'graded sequence of {seq_len} (level table)',
                         timed(lambda i: stage.apply(graded[(i % (args.n // seq_len)) * seq_len:][:seq_len], FIRE_EXPOSURE_US),
                               n_seq), graded_line, seq_len))
            stats = stage.link.stats
    finally:
        if hasattr(backend, 'close'):
            backend.close()
        else:
            backend.stop()

    print(f'backend {args.backend} ({ident.name} {ident.version_string}), {args.baud} baud 8N1'
          + (', python sim emulating the wire time' if args.emulate_baud else '')
          + f', n={args.n} per command; retries {stats.retries}, timeouts {stats.timeouts}')
    header = f'{"command":38s} {"p50 ms":>8s} {"p99 ms":>8s} {"per s":>9s} {"line ms":>8s} {"line per s":>10s}'
    print(header)
    print('-' * len(header))
    for name, seconds, line, patterns_per in rows:
        p50, p99 = np.percentile(seconds * 1e3, [50, 99])
        rate = 1.0 / seconds.mean()
        unit = '' if patterns_per == 1 else f' ({rate * patterns_per:.0f} patterns/s, line {1e3 / line * patterns_per:.0f})'
        print(f'{name:38s} {p50:8.3f} {p99:8.3f} {rate:9.0f} {line:8.3f} {1e3 / line:10.0f}{unit}')
    print('line = the bytes of command + reply (+ events) on a real serial line at this baud, plus the '
          'exposure; per s = 1 / mean latency')
    return 0


if __name__ == '__main__':
    sys.exit(main())
