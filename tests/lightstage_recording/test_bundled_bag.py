"""bags/sim_session, the recorded session in the repository: what it holds, and replaying it
into a classifier that only observes gives back the recorded labels."""
import pytest
from rclpy.serialization import deserialize_message

from lightstage_recording import BagReader
from helpers.recording import (REPO, assert_replayed_results_match, bag_results, mcap_ros2_decode,
                               replay_into_observing_classifier)

pytestmark = pytest.mark.process

BAG = REPO / 'bags' / 'sim_session'
ARTIFACT = REPO / 'bags' / 'sim_session_classifier.npz'


def _results():
    return bag_results(BAG)


def test_the_bundled_bag_is_complete_and_small():
    info = BagReader(BAG).info(verify=True)
    assert info.complete and not info.problems
    assert sum(f.stat().st_size for f in BAG.iterdir()) + ARTIFACT.stat().st_size < 3 * 2 ** 20
    counts = {t.name: t.count for t in info.topics.values()}
    assert counts['/illumination'] == counts['/camera/image_raw'] == 24
    assert counts['/lightstage/result'] == 4
    assert counts['/lightstage/classify/_service_event'] == 8
    assert [r.label for r in _results()] == ['banana-fake', 'banana-real', 'orange-fake', 'orange-real']
    from rosbags.rosbag2 import Reader  # an independent reader agrees
    with Reader(BAG) as reader:
        assert reader.message_count == info.message_count
        assert {c.topic: c.msgcount for c in reader.connections} == counts


@pytest.mark.ros
def test_replaying_the_bundled_bag_reproduces_its_labels(tmp_path):
    recorded = _results()
    replayed, _ = replay_into_observing_classifier(BAG, ARTIFACT, tmp_path, len(recorded),
                                                   '--rate', '5')
    assert_replayed_results_match(recorded, replayed, rtol=1e-4, atol=1e-5)


def test_independent_readers_decode_the_recorded_messages():
    """rosbags and mcap_ros2 decode what the recorder took off the wire, from the bag alone,
    to the same values as rclpy."""
    from lightstage_interfaces.msg import IlluminationState
    from lightstage_interfaces.srv import ApplyPatterns, Classify
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    from sensor_msgs.msg import Image
    rclpy_types = {'/illumination': IlluminationState, '/camera/image_raw': Image,
                   '/lightstage/classify/_service_event': Classify.Event,
                   '/lightstage/apply_patterns/_service_event': ApplyPatterns.Event}
    store = get_typestore(Stores.EMPTY)
    seen = {t: 0 for t in rclpy_types}
    with Reader(BAG) as reader:
        for c in reader.connections:
            types = get_types_from_msg(c.msgdef.data, c.msgtype)
            types[c.msgtype] = types.pop(next(iter(types)))  # pkg/srv/msg/X_Event -> c.msgtype
            store.register(types)
        for c, _, raw in reader.messages():
            ours = store.deserialize_cdr(raw, c.msgtype)  # every topic decodes
            if c.topic not in rclpy_types:
                continue
            seen[c.topic] += 1
            ref = deserialize_message(bytes(raw), rclpy_types[c.topic])
            if c.topic == '/illumination':
                assert (ours.sequence, ours.request_id, ours.header.stamp.nanosec) == \
                    (ref.sequence, ref.request_id, ref.header.stamp.nanosec)
                assert list(ours.intensities) == list(ref.intensities)
            elif c.topic == '/camera/image_raw':
                assert (ours.width, ours.encoding, bytes(ours.data)) == (ref.width, ref.encoding, bytes(ref.data))
            elif c.topic == '/lightstage/classify/_service_event':
                assert ours.info.event_type == ref.info.event_type
                assert [r.label for r in ours.response] == [r.label for r in ref.response]
                assert [r.max_images for r in ours.request] == [r.max_images for r in ref.request]
            else:
                assert [len(r.patterns) for r in ours.request] == [len(r.patterns) for r in ref.request]
                assert [list(r.sequences) for r in ours.response] == [list(r.sequences) for r in ref.response]
    assert seen == {'/illumination': 24, '/camera/image_raw': 24, '/lightstage/classify/_service_event': 8,
                    '/lightstage/apply_patterns/_service_event': 8}
    topics = ['/illumination', '/camera/image_raw', '/lightstage/result']
    decoded = mcap_ros2_decode(BAG / 'sim_session_0.mcap', topics)
    assert len(decoded) == 24 + 24 + 4
    assert [d.label for t, _, d in decoded if t == '/lightstage/result'] == [r.label for r in _results()]
