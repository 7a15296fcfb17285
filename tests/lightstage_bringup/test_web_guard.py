"""The operator page's server closed to other websites and to clients that hold it up, and
its health that ages (no ROS here: the aiohttp app over a fake bridge, `PageState` with a
clock of the test's): requests from another origin refused (`Origin`, `Sec-Fetch-Site`),
WebSocket upgrades too; the token a server beyond loopback needs; 400 for every malformed
body; one stalled /api/events reader dropped while the others go on; connections bounded and
timed out; diagnostics shown STALE once they age, a stopped node's at once, an inactive
lifecycle node's OK shown as not armed; a goal found running on the node shown as a job."""
import asyncio
import json
import socket

import pytest
from aiohttp import WSServerHandshakeError, web
from aiohttp.test_utils import TestClient, TestServer

from lightstage_bringup.web_app import guard_connections, make_app, parse_json_body
from lightstage_bringup.web_state import PageState, RequestError

DRIVER = {'name': 'driver: light stage link', 'level': 0, 'message': 'connected',
          'hardware_id': '', 'values': {}}


class Bridge:
    def __init__(self, state):
        self.state = state
        self.cancelled = 0

    async def classify(self, max_images, timeout_s):
        return {'success': True, 'message': '', 'label': 'x', 'class_names': ['x'], 'scores': [1.0],
                'images_used': 1, 'acquisition_ms': 1.0, 'compute_ms': 1.0}

    async def start_job(self, kind, goal):
        self.state.start_job(kind, goal)

    async def cancel_job(self):
        self.cancelled += 1
        return True

    async def activate(self, node):
        return 'active'


def _with_app(check, **app_args):
    async def run():
        state = PageState()
        bridge = Bridge(state)
        async with TestClient(TestServer(make_app(state, bridge, **app_args), host='127.0.0.1')) as client:
            await check(client, state, bridge)
    asyncio.run(run())


FOREIGN = [{'Origin': 'http://evil.example'}, {'Origin': 'null'},
           {'Origin': 'http://127.0.0.1:1'},   # another port of this machine: another origin
           {'Sec-Fetch-Site': 'cross-site'}, {'Sec-Fetch-Site': 'same-site'}]


@pytest.mark.parametrize('headers', FOREIGN)
def test_requests_from_another_website_are_refused(headers):
    async def check(client, state, bridge):
        own = f'http://{client.server.host}:{client.server.port}'
        # the cancel reads no body: a text/plain post (no CORS preflight) must not pass either
        cancel = await client.post('/api/jobs/cancel', data='x', headers={'Content-Type': 'text/plain', **headers})
        capture = await client.post('/api/capture', json={'output_dir': '/tmp/x', 'target': 'a/b/c'},
                                    headers=headers)
        activate = await client.post('/api/nodes/driver/activate', json={}, headers=headers)
        for response in (cancel, capture, activate):
            assert response.status == 403, (response.status, await response.text())
            assert 'another website' in (await response.json())['error']
        with pytest.raises(WSServerHandshakeError) as refused:
            await client.ws_connect('/api/events', headers=headers)
        assert refused.value.status == 403
        assert bridge.cancelled == 0 and not state.snapshot()['jobs']
        # the page's own requests pass: its origin, same-origin fetches, and clients that send neither
        for mine in ({'Origin': own, 'Sec-Fetch-Site': 'same-origin'}, {}):
            ws = await client.ws_connect('/api/events', headers=mine)
            assert 'version' in json.loads((await ws.receive(timeout=5)).data)
            await ws.close()
            ok = await client.post('/api/jobs/cancel', json={}, headers=mine)
            assert ok.status == 200
        assert bridge.cancelled == 2
    _with_app(check)


def test_a_cancel_must_be_json_like_every_post():
    async def check(client, state, bridge):
        plain = await client.post('/api/jobs/cancel', data='', headers={'Content-Type': 'text/plain'})
        assert plain.status == 415 and bridge.cancelled == 0
    _with_app(check)


@pytest.mark.parametrize('body, reason', [
    (b'\xff\xfe{}', 'not UTF-8'),
    (b'[' * 30000 + b']' * 30000, 'nested too deep'),
    (b'{"max_images": 1,', 'not valid JSON'),
    (b'nope', 'not valid JSON'),
])
def test_every_malformed_body_is_a_400_with_the_reason(body, reason):
    with pytest.raises(RequestError, match=reason) as refused:
        parse_json_body(body)
    assert refused.value.status == 400

    async def check(client, state, bridge):
        for path in ('/api/classify', '/api/capture', '/api/calibrate', '/api/jobs/cancel'):
            r = await client.post(path, data=body, headers={'Content-Type': 'application/json'})
            assert r.status == 400 and reason in (await r.json())['error'], (path, r.status)
    _with_app(check)


def test_beyond_loopback_every_request_needs_the_token():
    token = 'k' * 24

    async def check(client, state, bridge):
        for path in ('/', '/api/state', '/static/app.js'):
            r = await client.get(path, headers={'Host': '192.0.2.7:8088'})
            assert r.status == 401 and 'needs its token' in (await r.json())['error']
        wrong = await client.get('/api/state?token=' + 'x' * 24)
        assert wrong.status == 401
        page = await client.get(f'/?token={token}')
        assert page.status == 200 and page.cookies['lightstage_token'].value == token
        assert page.cookies['lightstage_token']['samesite'] == 'Strict'
        # the cookie the page got carries its later requests (the client keeps it)
        assert (await client.get('/api/state')).status == 200
        client.session.cookie_jar.clear()
        assert (await client.get('/api/state')).status == 401
        bearer = await client.get('/api/state', headers={'Authorization': f'Bearer {token}'})
        assert bearer.status == 200
    _with_app(check, allowed_hosts=None, token=token)
    with pytest.raises(ValueError, match='needs a token'):
        make_app(PageState(), Bridge(None), allowed_hosts=None)


def test_a_stalled_event_reader_is_dropped_and_the_others_keep_getting_the_state():
    """A reader that never reads: the server's socket buffers fill, then its queue; it is
    dropped, and a reader beside it receives every state up to the last."""
    async def check(client, state, bridge):
        host, port = client.server.host, client.server.port
        stalled = socket.socket()
        stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)   # before connect: a small window
        stalled.connect((host, port))
        stalled.sendall(f'GET /api/events HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n'
                        'Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n'
                        'Sec-WebSocket-Version: 13\r\n\r\n'.encode())
        reader = await client.ws_connect('/api/events', max_msg_size=0)
        await reader.receive(timeout=10)
        big = 'x' * 4000      # each state about 200 kB: the stalled socket's buffers fill quickly
        last = None
        for n in range(100):
            state.event('info', 'test', f'{n} {big}')
            if n % 2 == 1:    # the reader takes what comes, as a page does
                while True:
                    msg = await reader.receive(timeout=30)
                    last = json.loads(msg.data)
                    if last['version'] == state.version:
                        break
        assert last['events'][0]['text'].startswith('99 ')
        # the stalled one was dropped: its connection ends once its buffers are read out
        stalled.settimeout(30)
        while stalled.recv(1 << 20):
            pass
        stalled.close()
        await reader.close()
    _with_app(check)


def test_connections_are_bounded_and_one_that_sends_no_request_is_closed():
    async def run():
        app = make_app(PageState(), Bridge(None))
        runner = web.AppRunner(app, access_log=None)
        await runner.setup()
        guard_connections(runner.server, limit=3, header_timeout_s=1.0)
        site = web.TCPSite(runner, '127.0.0.1', 0)
        await site.start()
        port = runner.addresses[0][1]
        loop = asyncio.get_running_loop()
        try:
            idle = [socket.create_connection(('127.0.0.1', port)) for _ in range(3)]
            idle[0].sendall(b'GET /api/state HTTP/1.1\r\nHost: 127.0.0.1\r\n')   # never ends its head
            extra = socket.create_connection(('127.0.0.1', port))
            extra.settimeout(20)
            assert await loop.run_in_executor(None, extra.recv, 100) == b''   # over the limit: closed
            for s in idle:   # no whole request head within the timeout: closed
                s.settimeout(20)
                assert await loop.run_in_executor(None, s.recv, 100) == b''
                s.close()
            reader, writer = await asyncio.open_connection('127.0.0.1', port)
            writer.write(b'GET /api/state HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n')
            assert (await reader.readline()).startswith(b'HTTP/1.1 200')
            writer.close()
        finally:
            await runner.cleanup()
    asyncio.run(run())


class Clock:
    def __init__(self):
        self.now = 1000.0

    def __call__(self):
        return self.now


def _driver_shown(state):
    (d,) = [d for d in state.snapshot()['diagnostics'] if d['name'] == DRIVER['name']]
    return d


def test_diagnostics_age_to_stale_and_a_stopped_or_inactive_node_is_never_shown_ok():
    clock = Clock()
    state = PageState(clock=clock)
    state.on_diagnostics([DRIVER])
    state.set_node('driver', 'active', lifecycle=True)
    assert _driver_shown(state)['level'] == 'OK'
    clock.now += 5.5           # no update for longer than diagnostic_aggregator's 5 s
    version = state.version
    state.tick()
    assert state.version > version   # the page is told
    shown = _driver_shown(state)
    assert shown['level'] == 'STALE' and shown['reported_level'] == 'OK'
    assert shown['message'] == 'no update for more than 5 s (last report OK: connected)'
    state.on_diagnostics([DRIVER])
    assert _driver_shown(state)['level'] == 'OK'
    state.set_node('driver', 'inactive', lifecycle=True)
    shown = _driver_shown(state)
    assert shown['level'] == 'WARN' and shown['message'] == 'not armed: the node is inactive (connected)'
    state.set_node('driver', 'stopped', lifecycle=True)
    shown = _driver_shown(state)   # at once, not after the stale time
    assert shown['level'] == 'STALE' and 'the driver node is not running' in shown['message']
    texts = [e['text'] for e in state.snapshot()['events']]
    assert texts[:2] == ['the driver node stopped: it left the graph',
                         'the driver node is inactive: not armed']
    assert state.snapshot()['nodes']['driver'] == {'state': 'stopped', 'lifecycle': True}


def test_a_goal_running_on_the_node_that_the_page_did_not_start_is_shown_and_ends():
    state = PageState()
    state.on_active_goals('capture', ['ab' * 16])
    (job,) = state.snapshot()['jobs']
    assert job['state'] == 'running' and not job['known'] and job['goal_id'] == 'ab' * 16
    assert 'this page did not start' in job['message']
    with pytest.raises(RequestError, match='a capture is running'):
        state.start_job('calibrate', {})
    state.on_active_goals('capture', [])
    (job,) = state.snapshot()['jobs']
    assert job['state'] == 'ended' and 'no longer running' in job['message']
    state.start_job('capture', {})     # the stage is free again
    ours = state.running_job()
    state.update_job(ours, state='running', goal_id='cd' * 16)
    state.on_active_goals('capture', ['cd' * 16])
    assert len(state.snapshot()['jobs']) == 2   # its own goal is not taken for another's


def test_failures_the_page_asked_for_go_to_the_history():
    from lightstage_bringup.web_app import GraphUnavailable

    class Gone(Bridge):
        async def classify(self, max_images, timeout_s):
            raise GraphUnavailable('the service /lightstage/classify is not available')

    async def run():
        state = PageState()
        async with TestClient(TestServer(make_app(state, Gone(state)), host='127.0.0.1')) as client:
            r = await client.post('/api/classify', json={})
            assert r.status == 503
        (failed,) = state.snapshot()['history']
        assert not failed['success'] and 'not available' in failed['message']
    asyncio.run(run())


@pytest.mark.parametrize('host', ['0.0.0.0', '::', '0', '192.0.2.7'])
def test_a_host_beyond_loopback_needs_the_explicit_flag(host, capsys):
    from lightstage_bringup import web_cli
    assert web_cli.main(['--host', host]) == 2
    err = capsys.readouterr().err
    assert f'--host {host} is beyond this machine\'s loopback' in err and '--allow-network' in err


@pytest.mark.ros
def test_served_on_every_address_it_warns_and_every_request_needs_the_printed_token():
    import re
    import urllib.error
    import urllib.request
    from helpers.suite import fresh_domain_id
    from helpers.web import served
    with served('web', fresh_domain_id(), '--host', '0.0.0.0', '--allow-network') as (server, url):
        output = server.output()
        assert 'WARNING: listening on 0.0.0.0, beyond this machine' in output
        token = re.search(r'\?token=([\w-]+)', url).group(1)
        port = re.search(r':(\d+)/', url).group(1)
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(f'http://127.0.0.1:{port}/api/state', timeout=30)
        assert refused.value.code == 401
        with urllib.request.urlopen(f'http://127.0.0.1:{port}/api/state?token={token}', timeout=30) as r:
            assert r.status == 200 and 'version' in json.loads(r.read())
