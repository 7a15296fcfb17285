"""The bag core without a graph: what is written (against rosbag2's layout and two independent
readers, rosbags and mcap_ros2), reading it back, and damaged bags."""
import json
import os
import shutil
import subprocess

import pytest
import yaml
from rclpy.serialization import deserialize_message, serialize_message

import lightstage_recording as lr
from lightstage_recording.bag_ros import message_class
from lightstage_recording.qos import INFINITE_NS, dump_qos_profiles, parse_qos_profiles
from helpers.recording import (apply_event, classify_event, fields_equal, illumination, image,
                               mcap_ros2_decode, recover, result)
from helpers.suite import lightstage_command

pytestmark = pytest.mark.process

T0 = 1_700_000_000_000_000_000
TOPICS = {'/illumination': 'lightstage_interfaces/msg/IlluminationState',
          '/image_raw': 'sensor_msgs/msg/Image',
          '/lightstage/result': 'lightstage_interfaces/msg/ClassificationResult',
          '/lightstage/classify/_service_event': 'lightstage_interfaces/srv/Classify_Event',
          '/lightstage/apply_patterns/_service_event': 'lightstage_interfaces/srv/ApplyPatterns_Event'}
RELIABLE = lr.QosProfile(history='unknown', depth=0)
LATCHED = lr.QosProfile(history='unknown', depth=0, durability='transient_local')


def _messages():
    """(topic, message, log_time, publish_time) of a small session, in log time order."""
    out = []
    t = T0
    for i in range(8):
        out.append(('/illumination', illumination(index=i % 4, seq=i), t, t - 40_000))
        out.append(('/image_raw', image(seed=i), t + 5_000_000, t + 4_000_000))
        t += 30_000_000
    out.insert(0, ('/lightstage/classify/_service_event', classify_event('request'), T0 - 1000, T0 - 2000))
    out.insert(1, ('/lightstage/apply_patterns/_service_event', apply_event(), T0 - 500, T0 - 900))
    out.append(('/lightstage/result', result(), t, t - 1000))
    out.append(('/lightstage/classify/_service_event', classify_event('response'), t + 10, t + 5))
    return out


def _write(path, messages=None, **kwargs):
    messages = _messages() if messages is None else messages
    with lr.BagWriter(path, **kwargs) as w:
        for topic, type_name in TOPICS.items():
            w.add_topic(topic, type_name, [LATCHED if topic == '/lightstage/result' else RELIABLE])
        for topic, msg, log_t, pub_t in messages:
            w.write(topic, serialize_message(msg), log_t, pub_t)
            if kwargs.get('chunk_size_bytes'):
                w.flush()
    return messages


@pytest.fixture(scope='module')
def bag(tmp_path_factory):
    path = tmp_path_factory.mktemp('bags') / 'session'
    return path, _write(path)


def test_bag_directory_layout_and_metadata_yaml(bag):
    path, messages = bag
    assert sorted(p.name for p in path.iterdir()) == ['metadata.yaml', 'session_0.mcap']
    info = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['version'] == 9 and info['storage_identifier'] == 'mcap'
    assert info['relative_file_paths'] == ['session_0.mcap']
    assert info['message_count'] == len(messages)
    assert info['starting_time']['nanoseconds_since_epoch'] == min(m[2] for m in messages)
    assert info['duration']['nanoseconds'] == max(m[2] for m in messages) - min(m[2] for m in messages)
    by_topic = {t['topic_metadata']['name']: t for t in info['topics_with_message_count']}
    assert set(by_topic) == set(TOPICS)
    img = by_topic['/image_raw']
    assert img['message_count'] == 8
    assert img['topic_metadata']['type'] == 'sensor_msgs/msg/Image'
    assert img['topic_metadata']['serialization_format'] == 'cdr'
    assert img['topic_metadata']['type_description_hash'].startswith('RIHS01_')
    (qos,) = by_topic['/lightstage/result']['topic_metadata']['offered_qos_profiles']
    assert qos['durability'] == 'transient_local' and qos['reliability'] == 'reliable'
    assert qos['deadline'] == {'sec': 9223372036, 'nsec': 854775807}


def test_mcap_records_are_those_rosbag2_writes(bag):
    from mcap.reader import make_reader
    path, messages = bag
    with open(path / 'session_0.mcap', 'rb') as f:
        reader = make_reader(f)
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
        schemas = {s.name: s for s in summary.schemas.values()}
        assert set(schemas) == set(TOPICS.values())
        assert {s.encoding for s in schemas.values()} == {'ros2msg'}
        for channel in summary.channels.values():
            assert channel.message_encoding == 'cdr'
            assert set(channel.metadata) == {'offered_qos_profiles', 'topic_type_hash'}
            assert parse_qos_profiles(channel.metadata['offered_qos_profiles'])
        (meta,) = [m for m in reader.iter_metadata() if m.name == 'rosbag2']
        assert meta.metadata['ROS_DISTRO'] == 'jazzy'
        assert yaml.safe_load(meta.metadata['serialized_metadata'])['message_count'] == len(messages)
        times = [(m.log_time, m.publish_time) for _, _, m in reader.iter_messages(log_time_order=True)]
    assert times == [(m[2], m[3]) for m in messages]


def test_reader_gives_back_every_message_with_its_times(bag):
    path, messages = bag
    reader = lr.BagReader(path)
    info = reader.info()
    assert info.complete and not info.problems and info.has_metadata_yaml
    assert info.message_count == len(messages)
    assert {t.name: t.count for t in info.topics.values()} == {
        t: sum(m[0] == t for m in messages) for t in TOPICS}
    got = list(reader.messages())
    assert [(m.topic, m.log_time_ns, m.publish_time_ns) for m in got] == \
        [(m[0], m[2], m[3]) for m in messages]
    for m, (_, original, _, _) in zip(got, messages):
        assert fields_equal(deserialize_message(m.data, message_class(m.type)), original)
    only = list(reader.messages(['/lightstage/result'], start_ns=T0))
    assert [m.topic for m in only] == ['/lightstage/result']


def test_rosbags_reads_the_bag_and_decodes_every_message(bag):
    """rosbags (pure Python, its own CDR code) with nothing but what the bag holds."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    path, messages = bag
    store = get_typestore(Stores.EMPTY)
    decoded = []
    with Reader(path) as reader:
        assert reader.message_count == len(messages)
        by_topic = {c.topic: c for c in reader.connections}
        assert {t: c.msgtype for t, c in by_topic.items()} == TOPICS
        assert by_topic['/lightstage/result'].ext.offered_qos_profiles[0].durability.name == 'TRANSIENT_LOCAL'
        for c in reader.connections:
            types = get_types_from_msg(c.msgdef.data, c.msgtype)
            # rosbags files every type under pkg/msg/ (pkg/srv/msg/Name for service events):
            # register the root under the topic's own type name
            types[c.msgtype] = types.pop(next(iter(types)))
            store.register(types)
        for connection, timestamp, raw in reader.messages():
            decoded.append((connection.topic, timestamp, store.deserialize_cdr(raw, connection.msgtype)))
    assert [(t, ts) for t, ts, _ in decoded] == [(m[0], m[2]) for m in messages]
    for (topic, _, d), (_, original, _, _) in zip(decoded, messages):
        if topic == '/illumination':
            assert d.request_id == original.request_id and list(d.intensities) == list(original.intensities)
            assert d.header.stamp.nanosec == original.header.stamp.nanosec
        elif topic == '/image_raw':
            assert (d.width, d.encoding, bytes(d.data)) == (original.width, 'mono16', bytes(original.data))
        elif topic == '/lightstage/result':
            assert d.label == original.label and list(d.sequences) == list(original.sequences)
        elif topic == '/lightstage/classify/_service_event':
            assert d.info.event_type == original.info.event_type
            if original.request:
                assert d.request[0].max_images == 8 and not d.response
            else:
                assert d.response[0].label == 'banana-real' and list(d.response[0].class_names) == ['a', 'b']
        else:
            assert d.request[0].trigger and len(d.request[0].patterns) == 2
            assert d.request[0].patterns[0].intensities[4] == 1.0


def test_mcap_ros2_decodes_the_message_topics(bag):
    """mcap-ros2-support decodes with the schema text alone. (Its parser refuses type names
    with an underscore, so it cannot decode service events of any bag: rosbags does above.)"""
    path, messages = bag
    topics = ['/illumination', '/image_raw', '/lightstage/result']
    got = mcap_ros2_decode(path / 'session_0.mcap', topics)
    expected = [m for m in messages if m[0] in topics]
    assert len(got) == len(expected)
    for (g_topic, g_log_t, g), (topic, original, log_t, _) in zip(got, expected):
        assert g_topic == topic and g_log_t == log_t
        if topic == '/illumination':
            assert list(g.intensities) == list(original.intensities)
            assert g.count_in_request == original.count_in_request
        elif topic == '/image_raw':
            assert bytes(g.data) == bytes(original.data) and g.step == original.step
        else:
            assert g.label == original.label and list(g.scores) == [-0.5, 0.75]


def test_qos_profiles_round_trip_and_accept_version_8_numbers():
    q = lr.QosProfile(history='keep_last', depth=7, reliability='best_effort',
                      durability='transient_local', deadline_ns=1_500_000_000)
    (back,) = parse_qos_profiles(dump_qos_profiles([q]))
    assert back == q
    assert q.to_dict()['deadline'] == {'sec': 1, 'nsec': 500_000_000}
    v8 = lr.QosProfile.from_dict({'history': 3, 'depth': 0, 'reliability': 1, 'durability': 1,
                                  'deadline': {'sec': 9223372036, 'nsec': 854775807},
                                  'lifespan': {'sec': 9223372036, 'nsec': 854775807},
                                  'liveliness': 1, 'liveliness_lease_duration':
                                  {'sec': 9223372036, 'nsec': 854775807},
                                  'avoid_ros_namespace_conventions': False})
    assert (v8.history, v8.reliability, v8.durability) == ('unknown', 'reliable', 'transient_local')
    assert v8.deadline_ns == INFINITE_NS
    with pytest.raises(ValueError, match='reliability'):
        lr.QosProfile.from_dict({'reliability': 'sometimes'})


def test_writer_refuses_to_overwrite_and_unknown_topics(tmp_path):
    (tmp_path / 'taken').mkdir()
    (tmp_path / 'taken' / 'x').write_text('x')
    with pytest.raises(lr.BagError, match='already exists'):
        lr.BagWriter(tmp_path / 'taken')
    with lr.BagWriter(tmp_path / 'b') as w:
        with pytest.raises(lr.BagError, match='add_topic first'):
            w.write('/nothing', b'\x00\x01\x00\x00', 1)
        w.add_topic('/a', 'sensor_msgs/msg/Image')
        with pytest.raises(lr.BagError, match='one bag topic has one type'):
            w.add_topic('/a', 'std_msgs/msg/String')
    with pytest.raises(lr.BagError, match='compression'):
        lr.BagWriter(tmp_path / 'c', compression='bz2')


def test_a_type_without_definition_is_recorded_without_schema(tmp_path):
    with lr.BagWriter(tmp_path / 'b') as w:
        w.add_topic('/odd', 'no_such_pkg/msg/Odd')
        w.write('/odd', b'\x00\x01\x00\x00abc', T0)
    assert 'no_such_pkg/msg/Odd' in w.warnings[0]
    reader = lr.BagReader(tmp_path / 'b')
    (m,) = reader.messages()
    assert (m.topic, m.type, m.data) == ('/odd', 'no_such_pkg/msg/Odd', b'\x00\x01\x00\x00abc')


# ----------------------------------------------------------------------------- damage


@pytest.fixture(scope='module')
def chunked(tmp_path_factory):
    """A bag flushed after every message: one chunk per message, as a recorder writes it."""
    path = tmp_path_factory.mktemp('bags') / 'chunked'
    return path, _write(path, chunk_size_bytes=1024)


def _copy_mcap(src_dir, dst_dir):
    dst_dir.mkdir()
    (mcap,) = src_dir.glob('*.mcap')
    shutil.copy(mcap, dst_dir / f'{dst_dir.name}_0.mcap')
    return dst_dir / f'{dst_dir.name}_0.mcap'


@pytest.mark.parametrize('fraction', [0.1, 0.35, 0.5, 0.8, 0.97])
def test_a_cut_off_bag_yields_every_message_before_the_cut(chunked, tmp_path, fraction):
    """A recorder killed mid-write: no summary, no footer, no metadata.yaml."""
    src, messages = chunked
    mcap = _copy_mcap(src, tmp_path / 'cut')
    os.truncate(mcap, int(mcap.stat().st_size * fraction))
    reader = lr.BagReader(tmp_path / 'cut')
    info = reader.info()
    assert not info.complete
    assert any('no metadata.yaml' in p for p in info.problems)
    assert any('cut off' in p or 'without the MCAP footer' in p for p in info.problems)
    got = list(reader.messages())
    n = len(got)
    assert n == info.message_count
    assert [(m.topic, m.log_time_ns) for m in got] == [(m[0], m[2]) for m in messages[:n]]
    if fraction >= 0.5:
        assert n >= len(messages) // 3  # one message per chunk: little is lost
    text = lr.format_info(info)
    assert 'INCOMPLETE BAG' in text and 'lightstage bag recover' in text
    # recover: a complete bag with exactly those messages
    info2 = recover(tmp_path / 'cut', tmp_path / 'fixed')
    assert info2.complete and info2.message_count == n
    assert [m.data for m in lr.BagReader(tmp_path / 'fixed').messages()] == [m.data for m in got]


def test_a_damaged_chunk_costs_only_its_own_messages(chunked, tmp_path):
    src, messages = chunked
    mcap = _copy_mcap(src, tmp_path / 'bad')
    data = bytearray(mcap.read_bytes())
    # the 6th /image_raw payload: find its bytes and flip some of them
    needle = serialize_message(messages[2 + 2 * 5 + 1][1])[200:232]
    at = data.find(needle)
    assert at > 0
    data[at:at + 8] = bytes(255 - b for b in data[at:at + 8])
    mcap.write_bytes(bytes(data))
    reader = lr.BagReader(tmp_path / 'bad')
    got = list(reader.messages())
    assert len(got) == len(messages) - 1
    assert any('damaged' in p and 'skipped' in p for p in reader.problems)
    lost = messages[2 + 2 * 5 + 1]
    assert (lost[0], lost[2]) not in [(m.topic, m.log_time_ns) for m in got]


def test_files_that_are_no_bag_are_clear_errors(tmp_path, bag):
    path, _ = bag
    cases = {
        'missing': (tmp_path / 'nowhere', 'does not exist'),
        'text': (tmp_path / 'notes.mcap', 'not an MCAP file'),
        'sqlite': (tmp_path / 'old.db3', 'sqlite3'),
        'empty': (tmp_path / 'empty.mcap', 'empty'),
        'emptydir': (tmp_path / 'emptydir', 'no metadata.yaml and no .mcap'),
    }
    (tmp_path / 'notes.mcap').write_text('hello')
    (tmp_path / 'old.db3').write_bytes(b'SQLite format 3\x00' + bytes(100))
    (tmp_path / 'empty.mcap').write_bytes(b'')
    (tmp_path / 'emptydir').mkdir()
    for name, (p, message) in cases.items():
        with pytest.raises(lr.BagError, match=message):
            lr.BagReader(p)
    # metadata.yaml naming a file the directory lacks
    broken = tmp_path / 'broken'
    shutil.copytree(path, broken)
    (broken / 'session_0.mcap').unlink()
    with pytest.raises(lr.BagError, match='lists session_0.mcap.*copy the whole bag'):
        lr.BagReader(broken)
    # an unreadable metadata.yaml: the .mcap is read directly, with a note
    shutil.copytree(path, tmp_path / 'garbled')
    (tmp_path / 'garbled' / 'metadata.yaml').write_text(': : [unclosed')
    reader = lr.BagReader(tmp_path / 'garbled')
    assert reader.info().message_count == len(_messages())
    assert any('metadata.yaml is unreadable' in p for p in reader.problems)


def test_bag_cli_info_json_and_exit_codes(bag, chunked, tmp_path):
    path, messages = bag
    run = lightstage_command('bag')
    p = subprocess.run(run + ['info', str(path)], capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    assert 'Topic: /image_raw' in p.stdout and 'Count: 8' in p.stdout
    assert 'Service: /lightstage/classify' in p.stdout and 'Event Count: 2' in p.stdout
    assert 'Service: /lightstage/apply_patterns' in p.stdout
    p = subprocess.run(run + ['info', '--json', '--verify', str(path)], capture_output=True, text=True,
                       timeout=60)
    doc = json.loads(p.stdout)
    assert doc['complete'] and doc['message_count'] == len(messages)
    cut = _copy_mcap(chunked[0], tmp_path / 'cut')
    os.truncate(cut, cut.stat().st_size // 2)
    p = subprocess.run(run + ['info', str(tmp_path / 'cut')], capture_output=True, text=True, timeout=60)
    assert p.returncode == 1 and 'INCOMPLETE BAG' in p.stdout
    p = subprocess.run(run + ['recover', str(tmp_path / 'cut')], capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == 0, p.stderr
    assert (tmp_path / 'cut_recovered' / 'metadata.yaml').is_file()
    p = subprocess.run(run + ['info', str(tmp_path / 'nowhere')], capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == 2 and 'does not exist' in p.stderr


def test_reads_a_bag_another_writer_made_with_zstd_chunks(tmp_path):
    """rosbags writes rosbag2 bags independently (here: MCAP, zstd-compressed chunks, as
    `ros2 bag record -s mcap` does by default); this reader takes them as they are."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
    from rosbags.typesys import Stores, get_typestore
    messages = [m for m in _messages() if m[0] in ('/illumination', '/image_raw')]
    store = get_typestore(Stores.ROS2_JAZZY)
    from rosbags.typesys import get_types_from_msg
    from lightstage_recording.msg_definitions import full_definition
    store.register(get_types_from_msg(full_definition(TOPICS['/illumination']), TOPICS['/illumination']))
    writer = Writer(tmp_path / 'other', version=9, storage_plugin=StoragePlugin.MCAP)
    writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    payloads = [bytes(serialize_message(m[1])) for m in messages]  # (CDR padding is not zeroed)
    with writer:
        connections = {t: writer.add_connection(t, TOPICS[t], typestore=store)
                       for t in ('/illumination', '/image_raw')}
        for (topic, _, log_t, _), data in zip(messages, payloads):
            writer.write(connections[topic], log_t, data)
    reader = lr.BagReader(tmp_path / 'other')
    info = reader.info(verify=True)
    assert info.complete and info.message_count == len(messages)
    got = list(reader.messages())
    assert [(m.topic, m.log_time_ns) for m in got] == [(m[0], m[2]) for m in messages]
    assert [m.data for m in got] == payloads
    with open(next((tmp_path / 'other').glob('*.mcap')), 'rb') as f:
        assert b'zstd' in f.read()
