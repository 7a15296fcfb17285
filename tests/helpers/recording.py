"""Helpers of the recording tests: real serialized messages, independent decoding, and
replaying a bag into a classifier that only observes (the graph helpers are helpers.suite)."""
from __future__ import annotations

import array
import io
import subprocess
from pathlib import Path

import numpy as np

from lightstage_graph.ros_env import ros_environment
from lightstage_bringup.supervisor import Supervisor
from helpers.suite import REPO, GraphClient, fresh_domain_id, lightstage_command, start_nodes, write_params  # noqa: F401 (REPO: re-exported to the recording tests)



# ----------------------------------------------------------------------------- messages
def illumination(request_id=3, index=0, count=4, seq=10, stamp_ns=1_700_000_000_123_456_789,
                 lit=(0, 5, 9)):
    from lightstage_interfaces.msg import IlluminationState
    m = IlluminationState(sequence=seq, request_id=request_id, index_in_request=index,
                          count_in_request=count, exposure_us=22500, gain_db=17.5)
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    m.header.frame_id = 'lightstage'
    for i in lit:
        m.intensities[i] = 1.0
    return m


def image(seed=0, size=120):
    from sensor_msgs.msg import Image
    rng = np.random.default_rng(seed)
    m = Image(height=size, width=size, encoding='mono16', is_bigendian=0, step=2 * size)
    m.header.frame_id = 'camera'
    m.header.stamp.sec, m.header.stamp.nanosec = 1_700_000_000, 123_456_789 + seed
    m.data = (rng.integers(0, 1024, size * size, dtype=np.uint16) << 6).tobytes()
    return m


def result(label='banana-real'):
    from lightstage_interfaces.msg import ClassificationResult
    return ClassificationResult(label=label, class_names=['banana-fake', 'banana-real'],
                                scores=[-0.5, 0.75], images_used=8, sequences=list(range(8)),
                                acquisition_ms=201.5, compute_ms=9.25)


def classify_event(kind: str):
    """A Classify service event: 'request' (REQUEST_RECEIVED) or 'response' (RESPONSE_SENT)."""
    from lightstage_interfaces.srv import Classify
    e = Classify.Event()
    e.info.sequence_number = 4
    e.info.client_gid = [7] * 16
    e.info.stamp.sec = 1_700_000_001
    if kind == 'request':
        e.info.event_type = 1
        e.request.append(Classify.Request(max_images=8, timeout_s=5.0))
    else:
        e.info.event_type = 2
        e.response.append(Classify.Response(success=True, message='banana-real from 8 images',
                                            label='banana-real', class_names=['a', 'b'],
                                            scores=[0.1, 0.9], images_used=8,
                                            acquisition_ms=200.0, compute_ms=9.0))
    return e


def apply_event():
    from lightstage_interfaces.msg import Pattern
    from lightstage_interfaces.srv import ApplyPatterns
    e = ApplyPatterns.Event()
    e.info.event_type = 1
    p = Pattern(exposure_us=22500, gain_db=17.5)
    p.intensities[4] = 1.0
    e.request.append(ApplyPatterns.Request(patterns=[p, p], trigger=True))
    return e


def fields_equal(a, b) -> bool:
    """Two messages equal field by field (numpy arrays compared by value)."""
    return _plain(a) == _plain(b)


def _plain(v):
    if hasattr(v, 'get_fields_and_field_types'):
        return {k: _plain(getattr(v, k)) for k in v.get_fields_and_field_types()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, np.ndarray):
        return [_plain(x) for x in v.tolist()]
    if isinstance(v, (bytes, bytearray, array.array)):
        return list(v)
    return v


def bag_results(bag, topic: str = '/lightstage/result') -> list:
    """The ClassificationResult messages of a bag's `topic` (default /lightstage/result), in
    bag order."""
    from lightstage_interfaces.msg import ClassificationResult
    from rclpy.serialization import deserialize_message

    from lightstage_recording import BagReader
    return [deserialize_message(m.data, ClassificationResult) for m in BagReader(bag).messages([topic])]


def recover(src, dst):
    """`lightstage_recording.recover_bag`, for tests that want the new bag or an exception:
    the info of ``dst``; `BagWriteError` if the copy stopped midway, `BagError` if nothing
    could be recovered."""
    from lightstage_recording import BagError, BagWriteError, recover_bag
    result = recover_bag(src, dst)
    if result.error:
        raise BagWriteError(result.error)
    if result.info is None:
        raise BagError(f'nothing could be recovered: {src} holds no intact message '
                       f'({"; ".join(result.source_problems) or "it is empty"}); no bag was written')
    return result.info


def mcap_ros2_decode(path, topics):
    """(topic, log time ns, decoded message) by mcap-ros2-support's decoder, from the schemas."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    with open(path, 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [(channel.topic, message.log_time, decoded) for _, channel, message, decoded
                in reader.iter_decoded_messages(topics=topics)]


# ----------------------------------------------------------------------------- replay
def replay_into_observing_classifier(bag, artifact_path, tmp_path: Path, n_results: int,
                                     *play_args: str):
    """Play the bag's /illumination and /camera/image_raw (`lightstage play ... PLAY_ARGS`, started
    once the classifier subscribes to both) into a classifier node that only observes
    (classify_observed), in a domain of its own, and wait for `n_results` of its results.

    Returns (the results, the `lightstage play` CompletedProcess).
    """
    from lightstage_interfaces.msg import ClassificationResult
    domain_id = fresh_domain_id()
    params = write_params(tmp_path / 'params.yaml', {
        'classifier': {'artifact_path': str(artifact_path), 'classify_observed': True}})
    client = GraphClient(domain_id)
    replayed = []
    client.node.create_subscription(ClassificationResult, '/lightstage/result', replayed.append, 10)
    out = io.StringIO()
    try:
        with Supervisor(stdout=out, stderr=out, sigint_timeout_s=5.0) as supervisor:
            start_nodes(supervisor, client, ['classifier'], domain_id, params)
            client.spin_until(lambda: client.node.count_publishers('/lightstage/result') > 0, 10.0,
                              'the classifier\'s result publisher')
            p = subprocess.run(lightstage_command('play', str(bag),
                                                  '--topics', '/illumination', '/camera/image_raw',
                                                  '--wait-for', '/illumination', '/camera/image_raw',
                                                  '--delay-s', '1', *play_args,
                                                  '--domain-id', str(domain_id)),
                               env=ros_environment(domain_id), capture_output=True, text=True,
                               timeout=120)
            assert p.returncode == 0, p.stdout + p.stderr
            client.spin_until(lambda: len(replayed) >= n_results, 20.0,
                              lambda: f'{n_results} results of the replay (got {len(replayed)})'
                                      f'\n{p.stdout}{p.stderr}\n{out.getvalue()}')
    finally:
        client.close()
    return replayed, p


def assert_replayed_results_match(recorded, replayed, rtol: float, atol: float) -> list:
    """Every recorded ClassificationResult came again from the replay, matched by its trigger
    sequences: same label, image count and scores (to rtol/atol). Returns the (recorded,
    replayed) pairs for further checks."""
    by_sequences = {tuple(r.sequences): r for r in replayed}
    assert len(by_sequences) == len(recorded)
    pairs = [(r, by_sequences[tuple(r.sequences)]) for r in recorded]
    for r, again in pairs:
        assert (again.label, again.images_used) == (r.label, r.images_used)
        np.testing.assert_allclose(again.scores, r.scores, rtol=rtol, atol=atol)
    return pairs
