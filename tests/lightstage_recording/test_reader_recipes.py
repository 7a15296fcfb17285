"""rosbags' AnyReader cannot open our bags (nor rosbag2's own) when they
hold service events; docs/RECORDING.md gives recipes for rosbags and mcap_ros2 users. This runs
those recipes exactly as the document writes them, on bags/sim_session and on a split bag, and
compares every decoded message with rclpy's decoding. No ROS graph."""
import array
import re

import numpy as np
import pytest
import yaml
from rclpy.serialization import deserialize_message, serialize_message

from lightstage_recording import BagReader, BagWriter
from helpers.recording import REPO, apply_event, classify_event, illumination, result

pytestmark = pytest.mark.process

BAG = REPO / 'bags' / 'sim_session'
DOC = REPO / 'docs' / 'RECORDING.md'


def _recipes() -> dict:
    """The `# recipe: NAME` python blocks of docs/RECORDING.md, executed."""
    blocks = re.findall(r'```python\n(# recipe: (\S+)\n.*?)```', DOC.read_text(), re.DOTALL)
    assert [name for _, name in blocks] == ['rosbags', 'mcap_ros2']
    namespace: dict = {}
    for code, _ in blocks:
        exec(compile(code, str(DOC), 'exec'), namespace)  # noqa: S102 - the documented recipe
    return namespace


def _files(bag):
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    return [bag / name for name in meta['relative_file_paths']]


def _rclpy_class(type_name):
    from lightstage_recording.bag_ros import message_class
    return message_class(type_name)


def _same(ours, ref) -> bool:
    """A decoded message (rosbags' or mcap_ros2's) equal to rclpy's, field by field."""
    if hasattr(ref, 'get_fields_and_field_types'):
        return all(_same(getattr(ours, f), getattr(ref, f)) for f in ref.get_fields_and_field_types())
    if isinstance(ref, np.generic):
        ref = ref.item()
    if isinstance(ours, np.generic):
        ours = ours.item()
    if isinstance(ref, (list, tuple, np.ndarray, array.array)):
        ref, ours = list(ref), list(ours)
        return len(ref) == len(ours) and all(_same(a, b) for a, b in zip(ours, ref))
    if isinstance(ref, (bytes, bytearray)):  # rclpy's byte / uint8[]: ints elsewhere
        return list(ref) == [int(x) for x in (ours if hasattr(ours, '__len__') else [ours])]
    if isinstance(ref, float) and ref != ref:
        return ours != ours  # NaN
    if isinstance(ref, int) and isinstance(ours, int) and -128 <= ours < 0 and ref >= 128:
        return ours + 256 == ref  # mcap_ros2 reads `char` (ServiceEventInfo.client_gid) signed
    return ours == ref or (isinstance(ref, str) and len(ref) == 1 and ours == ord(ref))


def _check(decoded, bag):
    expected = [(m.topic, m.log_time_ns, deserialize_message(m.data, _rclpy_class(m.type)), m.type)
                for m in BagReader(bag).messages()]
    assert sorted((t, n) for t, n, _ in decoded) == sorted((t, n) for t, n, _, _ in expected)
    by_key = {(t, n): (msg, type_name) for t, n, msg, type_name in expected}
    events = 0
    for topic, log_time, msg in decoded:
        ref, type_name = by_key[(topic, log_time)]
        assert _same(msg, ref), (topic, type_name)
        events += type_name.endswith('_Event')
    return events


def test_anyreader_fails_on_service_events_as_documented():
    from rosbags.highlevel import AnyReader
    with pytest.raises(KeyError, match='lightstage_interfaces/srv/'):
        with AnyReader([BAG]):
            pass


@pytest.fixture(scope='module')
def split_bag(tmp_path_factory):
    """A bag of two files with every kind of topic the stage records."""
    bag = tmp_path_factory.mktemp('recipes') / 'split'
    with BagWriter(bag, max_bag_duration_s=1.0) as w:
        for topic, type_name in [('/illumination', 'lightstage_interfaces/msg/IlluminationState'),
                                 ('/lightstage/result', 'lightstage_interfaces/msg/ClassificationResult'),
                                 ('/lightstage/classify/_service_event', 'lightstage_interfaces/srv/Classify_Event'),
                                 ('/lightstage/apply_patterns/_service_event',
                                  'lightstage_interfaces/srv/ApplyPatterns_Event')]:
            w.add_topic(topic, type_name)
        t0 = 1_700_000_000_000_000_000
        for i in range(4):
            t = t0 + i * 600_000_000
            w.write('/lightstage/classify/_service_event', serialize_message(classify_event('request')), t)
            w.write('/lightstage/apply_patterns/_service_event', serialize_message(apply_event()), t + 1)
            w.write('/illumination', serialize_message(illumination(seq=i)), t + 2)
            w.write('/lightstage/result', serialize_message(result()), t + 3)
            w.write('/lightstage/classify/_service_event', serialize_message(classify_event('response')), t + 4)
    assert len(_files(bag)) == 2
    return bag


@pytest.mark.parametrize('which', ['bundled', 'split'])
def test_the_rosbags_recipe_decodes_every_message(which, split_bag):
    bag = BAG if which == 'bundled' else split_bag
    decoded = list(_recipes()['read_with_rosbags'](bag))
    assert _check(decoded, bag) == (16 if which == 'bundled' else 12)


@pytest.mark.parametrize('which', ['bundled', 'split'])
def test_the_mcap_ros2_recipe_decodes_every_message(which, split_bag):
    bag = BAG if which == 'bundled' else split_bag
    decoded = list(_recipes()['read_with_mcap_ros2'](_files(bag)))
    assert _check(decoded, bag) == (16 if which == 'bundled' else 12)
