"""`lightstage view` beside the graph on the simulated stage, seen by a Foxglove-protocol
client offering only the subprotocol `foxglove.websocket.v1`, as Foxglove's own client library
(@foxglove/ws-protocol 0.8.0) and Lichtblick's WebSocket player before its `foxglove.sdk.v1`
support do (the ws-protocol's messages over aiohttp's WebSocket client): serverInfo names the
ROS distribution; during a classify it receives the camera images, the illumination states
and the result, each decoded from its CDR bytes with the ros2msg schema the server advertised
(as Foxglove does it), with the right sizes; the shipped layout names only topics the server
serves and shows a full-scale camera frame as white; the server listens on loopback only.
"""
import asyncio
import json
import os
import struct

import pytest
from lightstage_bringup.supervisor import Supervisor

from helpers.proc_sockets import sockets_of
from helpers.suite import REPO, GraphClient, fresh_domain_id, stage_graph_params, start_nodes, write_params
from helpers.web import served

pytestmark = [pytest.mark.ros, pytest.mark.process]

SUBPROTOCOL = 'foxglove.websocket.v1'   # the only name the released clients offer
MESSAGE_DATA = 0x01   # binary opcode: subscription id (u32), log time (u64), payload
WANTED = {'/camera/image_raw': 'sensor_msgs/msg/Image',
          '/illumination': 'lightstage_interfaces/msg/IlluminationState',
          '/lightstage/result': 'lightstage_interfaces/msg/ClassificationResult',
          '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray'}
# the statuses the three nodes publish on /diagnostics, each every second
STATUSES = {'driver: light stage link', 'camera: camera', 'classifier: model'}


def decoder(channel: dict):
    """What a Foxglove client does with a cdr / ros2msg channel: parse the schema text."""
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory
    schema = Schema(id=channel['id'], name=channel['schemaName'], encoding=channel['schemaEncoding'],
                    data=channel['schema'].encode())
    return DecoderFactory().decoder_for(channel['encoding'], schema)


def layout_topics(layout: dict) -> set[str]:
    """The topics a Foxglove layout's panels read (topic paths start with the topic)."""
    found = set()

    def walk(value):
        if isinstance(value, dict):
            for key, v in value.items():
                if key in ('topicPath', 'imageTopic', 'topicToRender', 'value') and isinstance(v, str):
                    found.add(v.split('.')[0])
                walk(v)
        elif isinstance(value, list):
            for v in value:
                walk(v)
    walk(layout['configById'])
    return found


def test_a_foxglove_client_sees_images_illumination_and_result_of_a_classify(
        stage_capture, stage_artifact_path, tmp_path):
    import aiohttp
    from lightstage_interfaces.srv import Classify
    domain_id = fresh_domain_id()
    params = write_params(tmp_path / 'params.yaml', stage_graph_params(
        stage_capture, 'orange-fake/s1/p01', 9, stage_artifact_path, driver={'port': 'sim'}))
    client = GraphClient(domain_id)

    async def watch(url):
        channels, received = {}, {topic: [] for topic in WANTED}
        async with aiohttp.ClientSession() as session:
            async with session.ws_connect(url, protocols=[SUBPROTOCOL], max_msg_size=64 << 20) as ws:
                assert ws.protocol == SUBPROTOCOL
                info = json.loads((await ws.receive(timeout=10)).data)
                assert info['op'] == 'serverInfo' and info['name'] == 'lightstage'
                assert info['metadata']['ROS_DISTRO'] == (os.environ.get('ROS_DISTRO') or 'jazzy')
                deadline = asyncio.get_running_loop().time() + 30
                while not set(WANTED) <= set(channels):  # topics are advertised as discovered
                    message = await ws.receive(timeout=max(0.1, deadline - asyncio.get_running_loop().time()))
                    if message.type == aiohttp.WSMsgType.TEXT:
                        op = json.loads(message.data)
                        if op['op'] == 'advertise':
                            channels.update({c['topic']: c for c in op['channels']})
                # the view's readers matched with the graph's writers (a reliable writer gives a
                # reader only what it publishes after they matched)
                await asyncio.to_thread(client.wait_for_subscriptions, 'view',
                                        ['/camera/image_raw', '/illumination', '/lightstage/result'], 20.0)
                subscriptions = {i: channels[topic] for i, topic in enumerate(WANTED, start=1)}
                await ws.send_str(json.dumps({'op': 'subscribe', 'subscriptions': [
                    {'id': i, 'channelId': c['id']} for i, c in subscriptions.items()]}))
                while True:   # the subscription is on once its first message comes (diagnostics: 1/s)
                    message = await ws.receive(timeout=10)
                    if message.type == aiohttp.WSMsgType.BINARY:
                        break
                    op = json.loads(message.data)
                    assert op['op'] != 'status' or op['level'] < 2, op   # 2: error
                call = asyncio.create_task(asyncio.to_thread(
                    client.call, Classify, '/lightstage/classify',
                    Classify.Request(max_images=4, timeout_s=10.0), timeout_s=30.0))
                statuses = set()   # the driver's, the camera's and the classifier's, each every second
                read_diagnostics = decoder(channels['/diagnostics'])
                while not (call.done() and received['/lightstage/result'] and statuses >= STATUSES
                           and len(received['/camera/image_raw']) >= 4):
                    assert asyncio.get_running_loop().time() < deadline + 60, \
                        {'statuses': statuses, **{t: len(m) for t, m in received.items()}}
                    message = await ws.receive(timeout=30)
                    if message.type == aiohttp.WSMsgType.TEXT:
                        op = json.loads(message.data)
                        assert op['op'] != 'status' or op['level'] < 2, op   # 2: error
                    if message.type == aiohttp.WSMsgType.BINARY:
                        opcode, sub_id, _log_time = struct.unpack_from('<BIQ', message.data)
                        assert opcode == MESSAGE_DATA
                        topic = subscriptions[sub_id]['topic']
                        received[topic].append(message.data[13:])
                        if topic == '/diagnostics':
                            statuses |= {s.name for s in read_diagnostics(message.data[13:]).status}
                return channels, received, await call

    try:
        with Supervisor(sigint_timeout_s=5.0) as supervisor:
            start_nodes(supervisor, client, ['driver', 'camera', 'classifier'], domain_id, params)
            with served('view', domain_id) as (server, url):
                try:
                    channels, received, answer = asyncio.run(watch(url))
                except AssertionError as exc:
                    raise AssertionError(f'{exc}\nlightstage view said:\n{server.output()}') from None
                listening = [s for s in sockets_of(server.pid) if s.proto.startswith('tcp') and s.state == '0A']
    finally:
        client.close()

    assert answer.success, answer.message
    for topic, type_name in WANTED.items():
        c = channels[topic]
        assert (c['encoding'], c['schemaEncoding'], c['schemaName']) == ('cdr', 'ros2msg', type_name)
    decode = {topic: decoder(channels[topic]) for topic in WANTED}

    images = [decode['/camera/image_raw'](data) for data in received['/camera/image_raw']]
    assert len(images) == answer.images_used == 4
    for image in images:   # the camera renders the 120 px capture: mono16, 2 bytes a pixel
        assert (image.width, image.height, image.encoding, image.step) == (120, 120, 'mono16', 240)
        assert len(image.data) == image.height * image.step
    lit = [decode['/illumination'](data) for data in received['/illumination']]
    assert len(lit) == 4 and all(len(m.intensities) == 32 and m.count_in_request == 4 for m in lit)
    assert sorted((m.header.stamp.sec, m.header.stamp.nanosec) for m in lit) == \
        sorted((i.header.stamp.sec, i.header.stamp.nanosec) for i in images)
    (result,) = [decode['/lightstage/result'](data) for data in received['/lightstage/result']]
    assert result.label == answer.label and result.images_used == 4
    assert len(result.scores) == len(result.class_names) == 4
    # the answer's decision, exposures of its budget and calibration reach the client too
    assert (result.decision, result.images_budget, result.calibrated) == ('accepted', 4, False)
    assert len(result.probabilities) == 0 and result.probabilities is not None
    assert sorted(result.sequences) == sorted(m.sequence for m in lit)
    diagnostics = [decode['/diagnostics'](data) for data in received['/diagnostics']]
    assert {s.name for d in diagnostics for s in d.status} == STATUSES

    assert listening and all(s.loopback for s in listening), [str(s) for s in listening]
    layout = json.loads((REPO / 'src/lightstage_bringup/config/foxglove_layout.json').read_text())
    assert layout_topics(layout) <= set(channels), layout_topics(layout)
    plotted = [p['value'] for p in layout['configById']['Plot!scores']['paths']]
    assert '/lightstage/result.probabilities' in plotted
    assert max(int(image_pixels(image).max()) for image in images) <= full_scale_mono16()


def image_pixels(image):
    import numpy as np
    return np.frombuffer(bytes(image.data), dtype='<u2')


def full_scale_mono16(bit_depth: int = 10) -> int:
    """The largest value of the camera's MSB-aligned mono16 images (10 bits: 1023 << 6)."""
    import numpy as np
    from lightstage_camera.camera_backend import to_mono16
    return int(to_mono16(np.array([(1 << bit_depth) - 1]), bit_depth)[0])


def test_the_layouts_image_panel_shows_a_full_scale_frame_as_white():
    """Foxglove's and Lichtblick's image panel map a mono16 value v to the gradient's colour at
    (v - minValue) / (maxValue - minValue), clamped (the ImageModeConfig fields: "Minimum
    (black) value" / "Maximum (white) value" for single-channel images): black at 0, white at
    the 10-bit camera's largest value, 65472, not 65535."""
    layout = json.loads((REPO / 'src/lightstage_bringup/config/foxglove_layout.json').read_text())
    image_mode = layout['configById']['Image!camera']['imageMode']
    assert image_mode.get('colorMode', 'gradient') == 'gradient'
    assert image_mode.get('gradient', ['#000000', '#ffffff']) == ['#000000', '#ffffff']
    assert (image_mode['minValue'], image_mode['maxValue']) == (0, full_scale_mono16())
