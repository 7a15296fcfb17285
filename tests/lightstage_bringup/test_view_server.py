"""`lightstage view`'s Foxglove protocol server on its own (no ROS): a client offering either
subprotocol name gets serverInfo with ROS_DISTRO, the channels, and each message of the
channels it subscribed to as a messageData frame; a client that stops reading loses its own
oldest messages, bounded in bytes, while another keeps receiving every message."""
import asyncio
import json
import struct

import pytest

from lightstage_bringup.view_server import FoxgloveServer

MESSAGE_DATA = 0x01


@pytest.fixture
def server():
    s = FoxgloveServer('test', metadata={'ROS_DISTRO': 'jazzy'}, backlog_bytes=4 << 20)
    s.start('127.0.0.1', 0)
    try:
        yield s
    finally:
        s.stop()


def channel(server, topic='/camera/image_raw'):
    return server.add_channel(topic, encoding='cdr', schema_name='sensor_msgs/msg/Image',
                              schema='uint32 height', schema_encoding='ros2msg')


async def subscribed(session, server, channel_id, subprotocol='foxglove.websocket.v1', sub_id=3):
    """A connected client subscribed to `channel_id` (its serverInfo and advertise read)."""
    ws = await session.ws_connect(f'ws://127.0.0.1:{server.port}', protocols=[subprotocol],
                                  max_msg_size=16 << 20)
    info = json.loads((await ws.receive(timeout=10)).data)
    advertised = json.loads((await ws.receive(timeout=10)).data)
    await ws.send_str(json.dumps({'op': 'subscribe', 'subscriptions': [{'id': sub_id, 'channelId': channel_id}]}))
    return ws, info, advertised


async def first_data(ws):
    while True:
        message = await ws.receive(timeout=10)
        if isinstance(message.data, bytes):
            return message.data


@pytest.mark.parametrize('subprotocol', ['foxglove.websocket.v1', 'foxglove.sdk.v1'])
def test_a_client_of_either_name_gets_server_info_channels_and_messages(server, subprotocol):
    import aiohttp
    image = channel(server)

    async def run():
        async with aiohttp.ClientSession() as session:
            ws, info, advertised = await subscribed(session, server, image, subprotocol)
            assert ws.protocol == subprotocol
            while True:   # the subscription is in once a message logged after it arrives
                server.log(image, b'\x01\x02', 42)
                try:
                    return info, advertised, await asyncio.wait_for(first_data(ws), 0.5)
                except asyncio.TimeoutError:
                    continue

    info, advertised, frame = asyncio.run(run())
    assert info['op'] == 'serverInfo' and info['metadata'] == {'ROS_DISTRO': 'jazzy'}
    (c,) = advertised['channels']
    assert (c['id'], c['topic'], c['encoding'], c['schemaEncoding']) == (image, '/camera/image_raw', 'cdr', 'ros2msg')
    assert struct.unpack_from('<BIQ', frame) == (MESSAGE_DATA, 3, 42) and frame[13:] == b'\x01\x02'


def test_a_client_that_stops_reading_loses_its_own_oldest_messages_only(server):
    import aiohttp
    image = channel(server)
    payload = bytes(1 << 20)   # 1 MiB, a 1024 x 512 mono16 image

    async def run():
        async with aiohttp.ClientSession() as session:
            stalled, _, _ = await subscribed(session, server, image, sub_id=1)
            reader, _, _ = await subscribed(session, server, image, sub_id=2)
            received = 0
            for n in range(64):   # 64 MiB, one message at a time as the reader takes them
                while True:
                    server.log(image, payload, n)
                    try:
                        frame = await asyncio.wait_for(first_data(reader), 2.0)
                    except asyncio.TimeoutError:
                        continue   # not subscribed yet
                    break
                if struct.unpack_from('<BIQ', frame)[2] == n:
                    received += 1
            (slow,) = [c for c in server._clients if 1 in c.subscriptions]
            await stalled.close()
            return received, slow.dropped, slow.queued_bytes

    received, dropped, queued = asyncio.run(run())
    assert received == 64
    assert dropped > 0 and queued <= 4 << 20
