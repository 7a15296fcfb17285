#!/usr/bin/env python3
"""Recording figures: bag writer speed, recorder throughput for 800 x 800 images, bag size
per classification.

1. writer: `BagWriter.write` of serialized 800 x 800 mono16 images (1.28 MB each), lz4 and
   uncompressed, and `BagReader.messages` reading them back;
2. recorder: a publisher in this process sends N images over a reliable topic (keep-last
   depth 32, as the camera) to the recorder node in its own process, as fast as it can and
   at a fixed rate; what arrived in the bag, and at what rate;
3. size: bytes per classification in a recorded bag (default bags/sim_session), per topic,
   as recorded (120 px images) and with each image at full resolution (--full-size, 800 px:
   the same session written again by `BagWriter`, every image replaced by a camera-like frame
   of that size with the same header);
4. verify: `BagReader.info` trusting the summaries vs reading every chunk back and checking
   its CRC (what `lightstage bag info` does by default), on both bags of 3.

The frames are synthetic but camera-like: a smooth gradient plus Gaussian noise of about
Sigma3's level, 10-bit values MSB-aligned in 16 bits as the camera publishes them (random
noise compresses little; these compress as the camera's frames do).

    .venv/bin/python benchmarks/bench_recording.py
    .venv/bin/python benchmarks/bench_recording.py --images 100 --size 800 --rates 30 60 --bag bags/sim_session
    .venv/bin/python benchmarks/bench_recording.py --parts size verify     # 3 and 4 only (~1 min)
    .venv/bin/python benchmarks/bench_recording.py --quick   # 20 images of 200 px, 30 Hz
"""
from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from lightstage_graph.graph_client import GraphClient
from lightstage_graph.ros_env import apply_ros_environment, ros_environment

from _common import bag_results, parse_args, write_params


def frames(n: int, size: int, seed: int = 0) -> list[bytes]:
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import Image
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:size, :size]
    base = 200 + 500 * (xx + yy) / (2 * size)
    out = []
    for i in range(n):
        gray = np.clip(np.rint(base + rng.normal(0, 6.0, base.shape)), 0, 1023).astype(np.uint16)
        m = Image(height=size, width=size, encoding='mono16', step=2 * size)
        m.header.stamp.sec, m.header.stamp.nanosec = 1_700_000_000, i
        m.data = (gray << 6).tobytes()
        out.append(serialize_message(m))
    return out


def bench_writer(data: list[bytes], tmp: Path) -> None:
    from lightstage_recording import BagReader, BagWriter
    mb = sum(len(d) for d in data) / 1e6
    print(f'writer: {len(data)} images of {len(data[0]) / 1e6:.2f} MB')
    for compression in ('lz4', 'none'):
        path = tmp / f'writer_{compression}'
        t0 = time.perf_counter()
        with BagWriter(path, compression=compression) as w:
            w.add_topic('/image_raw', 'sensor_msgs/msg/Image')
            for i, d in enumerate(data):
                w.write('/image_raw', d, 1_700_000_000_000_000_000 + i * 33_000_000)
        write_s = time.perf_counter() - t0
        size = sum(f.stat().st_size for f in path.iterdir())
        t0 = time.perf_counter()
        n = sum(1 for _ in BagReader(path).messages())
        read_s = time.perf_counter() - t0
        assert n == len(data)
        print(f'  {compression:<5} write {len(data) / write_s:6.0f} images/s ({mb / write_s:5.0f} MB/s), '
              f'file {size / 1e6:6.1f} MB ({100 * size / (mb * 1e6):3.0f} %), '
              f'read {len(data) / read_s:6.0f} images/s')
        shutil.rmtree(path)


def bench_recorder(data: list[bytes], tmp: Path, rates: list[float], domain_id: int) -> None:
    from rclpy.duration import Duration
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    from lightstage_recording import BagReader
    from lightstage_bringup.launcher import NODE_REGISTRY, node_command

    client = GraphClient(domain_id, 'bench_recording_publisher')
    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=32, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.VOLATILE)
    pub = client.node.create_publisher(Image, '/image_raw', qos)
    mb = len(data[0]) / 1e6
    print(f'recorder process: {len(data)} images of {mb:.2f} MB over a reliable keep-last-32 topic')
    try:
        for rate in [0.0] + rates:
            bag = tmp / f'rec_{rate:g}'
            params = write_params(tmp / 'params.yaml', {
                'recorder': {'output_dir': str(bag), 'topics': ['/image_raw']}})
            proc = subprocess.Popen(node_command(NODE_REGISTRY['recorder'].module, 'recorder', params),
                                    env=ros_environment(domain_id), stdout=subprocess.PIPE,
                                    stderr=subprocess.STDOUT, text=True)
            try:
                client.spin_until(lambda: pub.get_subscription_count() > 0, 30.0,
                                  'the recorder to subscribe')
                time.sleep(0.5)
                t0 = time.perf_counter()
                for i, d in enumerate(data):
                    if rate:
                        wait = t0 + i / rate - time.perf_counter()
                        if wait > 0:
                            time.sleep(wait)
                    pub.publish(d)
                send_s = time.perf_counter() - t0
                pub.wait_for_all_acked(Duration(seconds=30))
            finally:
                proc.send_signal(signal.SIGINT)
                proc.communicate(timeout=60)
            got = list(BagReader(bag).messages())
            latency = np.array([m.log_time_ns - m.publish_time_ns for m in got]) / 1e6
            if rate:
                print(f'  at {rate:5.0f} Hz ({rate * mb:4.0f} MB/s): recorded {len(got)}/{len(data)}, '
                      f'send->receive p50 {np.median(latency):.1f} ms, p99 '
                      f'{np.percentile(latency, 99):.1f} ms')
            else:
                print(f'  as fast as sent ({len(data) / send_s:.0f}/s, {len(data) * mb / send_s:.0f} MB/s): '
                      f'recorded {len(got)}/{len(data)} (keep-last 32: what the recorder could not '
                      f'take in time was overwritten)')
            shutil.rmtree(bag)
    finally:
        client.close()


def full_size_copy(bag: Path, size: int, out: Path) -> Path:
    """The session of `bag` written again with every image at size x size (camera-like
    content, the recorded header), everything else as recorded."""
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import Image

    from lightstage_recording import BagReader, BagWriter
    reader = BagReader(bag)
    info = reader.info()
    frame = deserialize_message(frames(1, size)[0], Image)
    with BagWriter(out) as w:
        for t in info.topics.values():
            w.add_topic(t.name, t.type, t.offered_qos, type_hash=t.type_hash,
                        schema=(t.schema_encoding, t.schema_text))
        for i, m in enumerate(reader.messages()):
            data = m.data
            if m.type == 'sensor_msgs/msg/Image':
                frame.header = deserialize_message(m.data, Image).header
                frame.data = deserialize_message(frames(1, size, seed=i)[0], Image).data
                data = serialize_message(frame)
            w.write(m.topic, data, m.log_time_ns, m.publish_time_ns, m.sequence)
    return out


def bench_verify(bags: list[Path]) -> None:
    from lightstage_recording import BagReader
    print('verify: `lightstage bag info` trusting the summaries vs reading every chunk back (CRCs)')
    for bag in bags:
        times = {}
        for verify in (False, True):
            best = float('inf')
            for _ in range(3):
                t0 = time.perf_counter()
                info = BagReader(bag).info(verify=verify)
                best = min(best, time.perf_counter() - t0)
            times[verify] = best
        size = sum(f.stat().st_size for f in info.files)
        print(f'  {bag.name}: {size / 1e6:.1f} MB, {info.message_count} messages recorded in '
              f'{info.duration_ns / 1e9:.1f} s: summary {1e3 * times[False]:.0f} ms, every chunk '
              f'checked {1e3 * times[True]:.0f} ms ({size / 1e6 / times[True]:.0f} MB/s, '
              f'{100 * times[True] / (info.duration_ns / 1e9):.1f} % of the recording\'s duration)')


def bench_size(bag: Path) -> None:
    from lightstage_recording import BagReader
    reader = BagReader(bag)
    info = reader.info()
    by_topic: dict[str, int] = {}
    for m in reader.messages():
        by_topic[m.topic] = by_topic.get(m.topic, 0) + len(m.data)
    results = bag_results(bag)
    n = len(results)
    images = sum(r.images_used for r in results)
    file_size = sum(f.stat().st_size for f in info.files)
    raw = sum(by_topic.values())
    print(f'size: {bag}: {n} classifications, {images} images, file {file_size / 1e3:.0f} kB '
          f'({100 * file_size / raw:.0f} % of the {raw / 1e3:.0f} kB of messages)')
    per_class = ['/illumination', '/camera/image_raw', '/lightstage/result', '/lightstage/classify/_service_event',
                 '/lightstage/apply_patterns/_service_event']
    for t in per_class:
        if t in by_topic:
            print(f'  {t:<45} {by_topic[t] / n / 1e3:8.1f} kB per classification')
    stage = sum(by_topic.get(t, 0) for t in per_class)
    print(f'  {"all of the above":<45} {stage / n / 1e3:8.1f} kB per classification '
          f'({stage / images / 1e3:.1f} kB per image; file ~{file_size * stage / raw / n / 1e3:.0f} kB '
          f'per classification after compression)')
    print(f'  the whole file per classification (with the graph\'s other topics): '
          f'{file_size / n / 1e3:.0f} kB')


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--images', type=int, default=200)
    p.add_argument('--size', type=int, default=800)
    p.add_argument('--rates', type=float, nargs='*', default=[30.0, 60.0, 120.0],
                   help='fixed send rates [Hz] (default 30 60 120)')
    p.add_argument('--bag', default=str(Path(__file__).resolve().parents[1] / 'bags' / 'sim_session'))
    p.add_argument('--full-size', type=int, default=800,
                   help='image size [px] of the full-resolution copy of --bag (default 800)')
    p.add_argument('--parts', nargs='+', default=['writer', 'recorder', 'size', 'verify'],
                   choices=['writer', 'recorder', 'size', 'verify'])
    p.add_argument('--domain-id', type=int, default=int(os.environ.get('ROS_DOMAIN_ID') or 61))
    args = parse_args(p, argv, images=20, size=200, rates=[30.0], full_size=200)
    apply_ros_environment(args.domain_id)
    with tempfile.TemporaryDirectory() as tmp:
        if {'writer', 'recorder'} & set(args.parts):
            data = frames(args.images, args.size)
            if 'writer' in args.parts:
                bench_writer(data, Path(tmp))
            if 'recorder' in args.parts:
                bench_recorder(data, Path(tmp), args.rates, args.domain_id)
        bags = [Path(args.bag)]
        if {'size', 'verify'} & set(args.parts):
            bags.append(full_size_copy(bags[0], args.full_size,
                                       Path(tmp) / f'{bags[0].name}_{args.full_size}px'))
        if 'size' in args.parts:
            for bag in bags:
                bench_size(bag)
        if 'verify' in args.parts:
            bench_verify(bags)
    return 0


if __name__ == '__main__':
    sys.exit(main())
