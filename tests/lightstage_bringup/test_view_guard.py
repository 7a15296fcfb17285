"""`lightstage view` is closed to other websites: a browser lets any page open a WebSocket to
127.0.0.1, so a page of another origin (Origin header) or one reached through a foreign host
name (Host header, DNS rebinding) is refused with HTTP 403 before the upgrade, while the
Foxglove clients connect: programs (no Origin), pages on this machine, the desktop apps
(file://), the Foxglove web app, and origins given with --allow-origin. Either subprotocol
name of the Foxglove protocol is served; a client that offers neither gets HTTP 400."""
import asyncio
import json
from urllib.parse import urlsplit

import pytest

from helpers.suite import fresh_domain_id
from helpers.web import served

from lightstage_bringup.view_server import Guard


@pytest.mark.parametrize('host, origin, refused', [
    ('127.0.0.1:8765', None, False),
    ('localhost:8765', None, False),
    ('[::1]:8765', None, False),
    ('127.0.0.1:8765', 'https://app.foxglove.dev', False),
    ('127.0.0.1:8765', 'http://localhost:8080', False),
    ('127.0.0.1:8765', 'http://127.0.0.1:3000', False),
    ('127.0.0.1:8765', 'file://', False),
    ('127.0.0.1:8765', 'http://evil.example', True),
    ('127.0.0.1:8765', 'null', True),                     # a sandboxed frame of any site
    ('127.0.0.1:8765', 'http://localhost.evil.example', True),
    ('evil.example:8765', None, True),
    ('evil.example:8765', 'https://app.foxglove.dev', True),
    ('', None, True),
])
def test_the_guard_takes_loopback_names_and_the_apps_origins_only(host, origin, refused):
    why = Guard().refusal(host, origin)
    assert bool(why) == refused, why
    if refused:
        assert ('Host' if 'evil' in host or not host else 'Origin') in why


def test_the_guard_takes_the_names_and_origins_it_is_given():
    guard = Guard(hosts=('stage-pc.lab',), origins=('https://viewer.lab',))
    assert guard.refusal('stage-pc.lab:8765', 'https://viewer.lab') == ''
    assert 'Origin' in guard.refusal('stage-pc.lab:8765', 'https://app.foxglove.dev')


@pytest.mark.ros
def test_a_foreign_origin_or_host_is_refused_and_the_foxglove_clients_connect():
    import aiohttp

    async def connect(url, protocols=('foxglove.websocket.v1',), **headers):
        """(HTTP status of a refusal or 101, the subprotocol, the first message's op)."""
        async with aiohttp.ClientSession() as session:
            try:
                async with session.ws_connect(url, protocols=protocols, headers=headers) as ws:
                    first = json.loads((await ws.receive(timeout=10)).data)
                    return 101, ws.protocol, first['op']
            except aiohttp.WSServerHandshakeError as exc:
                return exc.status, None, None

    async def probe(url):
        port = urlsplit(url).port
        return {
            'plain': await connect(url),
            'sdk name': await connect(url, protocols=('foxglove.sdk.v1',)),
            'neither name': await connect(url, protocols=('chat',)),
            'evil origin': await connect(url, Origin='http://evil.example'),
            'evil host': await connect(url, Host=f'evil.example:{port}'),
            'foxglove app': await connect(url, Origin='https://app.foxglove.dev'),
            'local page': await connect(url, Origin='http://localhost:8080'),
            'allowed origin': await connect(url, Origin='https://viewer.lab'),
        }

    with served('view', fresh_domain_id(), '--allow-origin', 'https://viewer.lab') as (server, url):
        seen = asyncio.run(probe(url))
        output = server.output()
    assert seen == {
        'plain': (101, 'foxglove.websocket.v1', 'serverInfo'),
        'sdk name': (101, 'foxglove.sdk.v1', 'serverInfo'),
        'neither name': (400, None, None),
        'evil origin': (403, None, None),
        'evil host': (403, None, None),
        'foxglove app': (101, 'foxglove.websocket.v1', 'serverInfo'),
        'local page': (101, 'foxglove.websocket.v1', 'serverInfo'),
        'allowed origin': (101, 'foxglove.websocket.v1', 'serverInfo'),
    }, output
    assert "refused a connection: Origin 'http://evil.example' may not connect" in output
    assert "refused a connection: Host 'evil.example:" in output
