"""`lightstage bag export`: a bag recorded with the defaults (service events included) opens in
rosbags' AnyReader, rosbags-convert and mcap_ros2's iter_decoded_messages() once exported, every
message decoded as rclpy decodes it. The recorded bag itself does not open in them, nor does a
bag whose service event schema is what rosbag2 (Jazzy) writes: the evidence docs/RECORDING.md
gives. No ROS graph (the graph test `test_record_replay_graph.py` exports a fresh recording)."""
import subprocess
import sys
from pathlib import Path

import pytest
from rclpy.serialization import serialize_message

from lightstage_recording import BagError, BagReader, BagWriter, msg_definitions
from lightstage_recording.export import export_bag, exported_schema_text, exported_type
from helpers.recording import REPO, classify_event, illumination
from helpers.suite import lightstage_command
from test_reader_recipes import _check  # every decoded message equal to rclpy's decoding

pytestmark = pytest.mark.process

BUNDLED = REPO / 'bags' / 'sim_session'  # recorded by `lightstage record` with its defaults
BAG_MESSAGES = BagReader(BUNDLED).info().message_count
EVENT_TOPIC = '/lightstage/classify/_service_event'


@pytest.fixture(scope='module')
def exported(tmp_path_factory):
    dst = tmp_path_factory.mktemp('export') / 'sim_session_export'
    p = subprocess.run(lightstage_command('bag', 'export', str(BUNDLED), '-o', str(dst)),
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stdout + p.stderr
    assert ('renamed lightstage_interfaces/srv/Classify_Event -> '
            'lightstage_interfaces/msg/ClassifyEvent') in p.stdout, p.stdout
    return dst


def test_the_recorded_bag_does_not_open_in_anyreader_and_the_export_does(exported):
    from rosbags.highlevel import AnyReader
    with pytest.raises(KeyError, match=r'lightstage_interfaces/srv/\w+_Event'):
        with AnyReader([BUNDLED]):
            pass
    with AnyReader([exported]) as reader:
        decoded = [(c.topic, t, reader.deserialize(raw, c.msgtype))
                   for c, t, raw in reader.messages()]
    assert len(decoded) == BAG_MESSAGES
    assert _check(decoded, BUNDLED) == 16  # the service events among them


def test_rosbags_convert_converts_every_message_of_the_export(exported, tmp_path):
    convert = Path(sys.executable).with_name('rosbags-convert')
    p = subprocess.run([str(convert), '--src', str(exported), '--dst', str(tmp_path / 'x.bag')],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout + p.stderr
    from rosbags.rosbag1 import Reader
    with Reader(tmp_path / 'x.bag') as reader:
        assert reader.message_count == BAG_MESSAGES
        assert {c.topic for c in reader.connections} == set(BagReader(BUNDLED).info().topics)
    p = subprocess.run([str(convert), '--src', str(BUNDLED), '--dst', str(tmp_path / 'y.bag')],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 1 and "KeyError('lightstage_interfaces/srv/" in p.stdout + p.stderr


def test_mcap_ros2_decodes_every_message_of_the_export(exported):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    decoded = []
    for path in BagReader(exported).files:
        with open(path, 'rb') as f:
            for _, channel, message, msg in make_reader(
                    f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
                decoded.append((channel.topic, message.log_time, msg))
    assert len(decoded) == BAG_MESSAGES
    assert _check(decoded, BUNDLED) == 16


def test_the_export_keeps_everything_but_the_renamed_types(exported):
    src, dst = BagReader(BUNDLED), BagReader(exported)
    a, b = src.info(), dst.info()
    assert [(m.topic, m.data, m.log_time_ns, m.publish_time_ns, m.sequence) for m in src.messages()] \
        == [(m.topic, m.data, m.log_time_ns, m.publish_time_ns, m.sequence) for m in dst.messages()]
    for name, t in a.topics.items():
        e = b.topics[name]
        assert e.offered_qos == t.offered_qos
        if t.is_service_event:
            assert e.type == exported_type(t.type) and e.type_hash == ''
        else:
            assert (e.type, e.type_hash, e.schema_text) == (t.type, t.type_hash, t.schema_text)
    assert b.custom_data['exported_from'] == str(BUNDLED)
    assert 'lightstage_interfaces/srv/ApplyPatterns_Event -> ' in b.custom_data['renamed_types']


def rosbag2_style_bag(path, encoding):
    """A bag whose service event schema is what rosbag2 Jazzy writes (rosbag2_cpp 0.26,
    LocalMessageDefinitionSource::get_full_text of the service type): a line of 80 `=`,
    `SRV: pkg/srv/Name`, the raw .srv, then `MSG:` sections of its message-typed fields; encoding
    ros2msg, or `unknown` when the service has none (Classify.srv has none)."""
    srv = msg_definitions._interface_file('lightstage_interfaces', 'srv', 'Classify.srv').read_text()
    with BagWriter(path) as w:
        w.add_topic('/illumination', 'lightstage_interfaces/msg/IlluminationState')
        w.add_topic(EVENT_TOPIC, 'lightstage_interfaces/srv/Classify_Event',
                    schema=(encoding, f'{"=" * 80}\nSRV: lightstage_interfaces/srv/Classify\n{srv}'))
        w.write('/illumination', serialize_message(illumination()), 10**18)
        w.write(EVENT_TOPIC, serialize_message(classify_event('request')), 10**18 + 1)
    return path


@pytest.mark.parametrize('encoding', ['unknown', 'ros2msg'])
def test_rosbag2_s_own_service_event_schema_fails_in_the_readers_and_exports(encoding, tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.highlevel import AnyReader
    bag = rosbag2_style_bag(tmp_path / 'rosbag2_style', encoding)
    with pytest.raises(Exception, match="unknown|Could not parse"):
        with AnyReader([bag]):
            pass
    with pytest.raises(Exception, match='no decoder|invalid message name'):
        with open(BagReader(bag).files[0], 'rb') as f:
            list(make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages())
    result, renamed = export_bag(bag, tmp_path / 'export')
    assert renamed == {'lightstage_interfaces/srv/Classify_Event': 'lightstage_interfaces/msg/ClassifyEvent'}
    with AnyReader([tmp_path / 'export']) as reader:
        decoded = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()]
    assert decoded[1].request[0].max_images == 8


def test_exported_schema_text_renames_every_reference():
    text = ('service_msgs/ServiceEventInfo info\npkg/Name_Request[<=1] request\n'
            '# pkg/Not_A_Type in a comment\nuint8 FLAG_ONE = 1\n'
            f'{"=" * 80}\nMSG: pkg/Name_Request\nName_Part[] parts\nstring<=8 s\n')
    assert exported_schema_text(text) == (
        'service_msgs/ServiceEventInfo info\npkg/NameRequest[<=1] request\n'
        '# pkg/Not_A_Type in a comment\nuint8 FLAG_ONE = 1\n'
        f'{"=" * 80}\nMSG: pkg/NameRequest\nNamePart[] parts\nstring<=8 s\n')
    assert exported_type('pkg/action/Capture_FeedbackMessage') == 'pkg/msg/CaptureFeedbackMessage'
    assert exported_type('sensor_msgs/msg/Image') == 'sensor_msgs/msg/Image'


def test_an_existing_output_is_refused(tmp_path):
    (tmp_path / 'out').mkdir()
    (tmp_path / 'out' / 'x').write_text('keep')
    with pytest.raises(BagError, match='not empty'):
        export_bag(BUNDLED, tmp_path / 'out')
    assert (tmp_path / 'out' / 'x').read_text() == 'keep'
