"""Camera backends: trigger-to-image latency (p50 / p99) and frames/s, in one run.

* ``basler``: pylon's emulated camera (pypylon, emulation transport layer only: no network
  discovery), software trigger, Mono16, at 120 x 120, at the paper's camera's 1920 x 1200
  (acA1920-150um) and at the emulator's largest size;
* ``sim``: the simulated camera on a synthetic capture at 120 x 120 (noise auto).

Latency = from `backend.trigger(...)` to the frame's `deliver` callback, one trigger at a
time (each waits for its frame); frames/s = a burst of triggers handed over at once, until
the last frame is delivered. Run it in a private network namespace (loopback only):

    unshare --net sh -c 'ip link set lo up && .venv/bin/python benchmarks/bench_camera.py'
        [--triggers 200] [--burst 200] [--json OUT.json] [--quick: 10 and 10]
"""
from __future__ import annotations

import argparse
import json
import os
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

os.environ.setdefault('PYLON_CAMEMU', '1')  # before pylon's transport layer is first created

from lightstage_camera.camera_backend import Trigger

from _common import parse_args


class Timed:
    """deliver / lost callbacks that record when each trigger's outcome came."""

    def __init__(self):
        self.done = {}
        self.lost = []
        self.cond = threading.Condition()

    def deliver(self, frame):
        with self.cond:
            self.done[frame.trigger.sequence] = time.perf_counter()
            self.cond.notify_all()

    def on_lost(self, lost):
        with self.cond:
            self.lost.append(lost)
            self.done[lost.trigger.sequence] = time.perf_counter()
            self.cond.notify_all()

    def wait(self, sequence, limit_s=30.0):
        with self.cond:
            return self.cond.wait_for(lambda: sequence in self.done, limit_s)


def trigger(seq, exposure_us):
    return Trigger(stamp_ns=seq, sequence=seq, led_intensities=np.full(32, 0.3, np.float32),
                   exposure_us=exposure_us, gain_db=15.0)


def measure(backend, timed, n_triggers, burst, exposure_us):
    latencies = []
    for seq in range(n_triggers):
        start = time.perf_counter()
        backend.trigger(trigger(seq, exposure_us))
        assert timed.wait(seq), f'trigger {seq} got no frame'
        latencies.append(timed.done[seq] - start)
    first = n_triggers
    start = time.perf_counter()
    for seq in range(first, first + burst):
        backend.trigger(trigger(seq, exposure_us))
    assert timed.wait(first + burst - 1, 120.0)
    elapsed = max(timed.done[s] for s in range(first, first + burst)) - start
    ms = np.asarray(latencies) * 1e3
    return {'latency_ms_p50': float(np.percentile(ms, 50)), 'latency_ms_p99': float(np.percentile(ms, 99)),
            'frames_per_s': burst / elapsed, 'lost': len(timed.lost),
            'lost_reasons': sorted({lost.reason for lost in timed.lost})}


def bench_basler(width, height, n_triggers, burst, exposure_us):
    from lightstage_camera.basler_backend import BaslerBackend
    timed = Timed()
    backend = BaslerBackend(timed.deliver, timed.on_lost, transport_layer='BaslerCamEmu',
                            pixel_format='Mono16', trigger_source='Software', exposure_us=exposure_us,
                            gain_db=15.0, features=['OffsetX=0', 'OffsetY=0', f'Width={width}',
                                                    f'Height={height}'])
    try:
        if not backend.wait_open(15.0):
            raise SystemExit(f'emulated Basler camera did not open: {backend.status().message}')
        return measure(backend, timed, n_triggers, burst, exposure_us)
    finally:
        backend.close()


def emulator_max_size():
    from pypylon import pylon
    layer = pylon.TlFactory.GetInstance().CreateTl('BaslerCamEmu')
    camera = pylon.InstantCamera(layer.CreateDevice(layer.EnumerateDevices()[0]))
    camera.Open()
    try:
        return int(camera.WidthMax.Value), int(camera.HeightMax.Value)
    finally:
        camera.Close()
        camera.DestroyDevice()


def bench_sim(n_triggers, burst, exposure_us):
    from lightstage_physics import synth
    from lightstage_camera.sim_camera import SimCameraBackend
    with tempfile.TemporaryDirectory() as tmp:
        capture = synth.generate(Path(tmp) / 'capture', image_size=120, n_samples_per_class=1,
                                 n_poses=1, object_types=('banana',), n_jobs=1)
        timed = Timed()
        backend = SimCameraBackend.from_capture(timed.deliver, capture, noise='auto', seed=0)
        return measure(backend, timed, n_triggers, burst, exposure_us)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--triggers', type=int, default=200, help='triggers timed one by one per case')
    p.add_argument('--burst', type=int, default=200, help='triggers of the frames/s burst per case')
    p.add_argument('--exposure-us', type=int, default=1000)
    p.add_argument('--json', default='', help='also write the results here')
    args = parse_args(p, argv, triggers=10, burst=10)
    interfaces = sorted(name for _i, name in socket.if_nameindex())
    if interfaces != ['lo']:
        print(f'refusing to enumerate cameras with network interfaces {interfaces}: run in a private '
              "namespace: unshare --net sh -c 'ip link set lo up && .venv/bin/python "
              "benchmarks/bench_camera.py'", file=sys.stderr)
        return 2
    max_w, max_h = emulator_max_size()
    cases = [('basler (emulated)', 120, 120), ('basler (emulated)', 1920, 1200),
             ('basler (emulated)', max_w, max_h)]
    results = []
    for name, w, h in cases:
        r = bench_basler(w, h, args.triggers, args.burst if w * h < 8e6 else max(20, args.burst // 10),
                         args.exposure_us)
        results.append({'backend': name, 'size': f'{w}x{h}', **r})
    results.append({'backend': 'sim', 'size': '120x120',
                    **bench_sim(args.triggers, args.burst, args.exposure_us)})
    print(f'exposure {args.exposure_us} us, {args.triggers} timed triggers per case')
    print(f'{"backend":<20}{"size":>11}{"p50 ms":>9}{"p99 ms":>9}{"frames/s":>10}{"lost":>6}')
    for r in results:
        print(f'{r["backend"]:<20}{r["size"]:>11}{r["latency_ms_p50"]:>9.2f}{r["latency_ms_p99"]:>9.2f}'
              f'{r["frames_per_s"]:>10.1f}{r["lost"]:>6}')
    for r in results:
        for reason in r['lost_reasons']:
            print(f'lost ({r["backend"]} {r["size"]}): {reason}')
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2))
    return 0


if __name__ == '__main__':
    sys.exit(main())
