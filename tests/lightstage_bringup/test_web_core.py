"""The operator page's core without ROS: `PageState` (images matched to their LEDs and to the
classifications, whatever order the topics deliver them in; errors as events), the API's
request checks, and the aiohttp app over a fake bridge (answers, 4xx / 503 with reasons,
one classify and one job at a time, the state pushed on /api/events)."""
import asyncio
import io
import json
import re

import numpy as np
import pytest
from aiohttp.test_utils import TestClient, TestServer
from PIL import Image

from lightstage_bringup.web_app import GraphUnavailable, make_app
from lightstage_bringup.web_state import (Illumination, PageState, RequestError, calibrate_goal,
                                          calibrate_progress, capture_goal, capture_progress,
                                          classify_request, display_image)

pytestmark = pytest.mark.process

STAMP = 1_795_000_000_123_456_789   # past 2**53: the page gets stamps as strings


def illumination(sequence, stamp, lit=(0,)):
    intensities = [0.0] * 32
    for led in lit:
        intensities[led] = 1.0
    return Illumination(sequence, stamp, 7, sequence - 1, 2, intensities, 22500, float('nan'))


def image(value=1000, size=(40, 30)):
    pixels = np.full(size, value, np.uint16)
    pixels[0, 0] = 65535
    return pixels


def result(sequences, label='pear-real'):
    return {'label': label, 'class_names': ['pear-fake', 'pear-real'], 'scores': [-0.5, 0.5],
            'images_used': len(sequences), 'sequences': sequences, 'acquisition_ms': 50.0,
            'compute_ms': 2.0, 'stamp_ns': STAMP}


def test_a_classification_gets_its_images_and_leds_whatever_arrives_first():
    state = PageState()
    state.on_illumination(illumination(1, STAMP, lit=(0, 5)))
    state.on_image(STAMP, image())
    state.on_result(result([1, 2]))                        # trigger 2's messages still on the way
    state.on_image(STAMP + 1000, image(2000))
    state.on_illumination(illumination(2, STAMP + 1000, lit=(31,)))
    snap = json.loads(json.dumps(state.snapshot(), allow_nan=False))   # valid JSON for a browser
    (entry,) = snap['history']
    assert [i['sequence'] for i in entry['images']] == [1, 2]
    assert [i['image']['stamp_ns'] for i in entry['images']] == [str(STAMP), str(STAMP + 1000)]
    assert [np.flatnonzero(i['illumination']['intensities']).tolist() for i in entry['images']] == [[0, 5], [31]]
    assert snap['live']['stamp_ns'] == str(STAMP + 1000)
    assert snap['live']['illumination']['sequence'] == 2 and snap['live']['illumination']['gain_db'] is None
    png = Image.open(io.BytesIO(state.png(str(STAMP))))
    assert png.size == (30, 40) and png.mode == 'L'
    assert state.png('live') == state.png(str(STAMP + 1000))


def test_images_are_stretched_and_report_their_brightest_pixel():
    pixels = np.zeros((100, 100), np.uint16)
    pixels[:, 50:] = 4096
    shown, peak = display_image(pixels, 800)
    assert shown.dtype == np.uint8 and shown.max() == 255 and shown.min() == 0
    assert peak == pytest.approx(4096 / 65535)
    small, _ = display_image(np.ones((800, 800), np.uint16), 240)
    assert max(small.shape) <= 240
    dark, peak = display_image(np.zeros((8, 8), np.uint16), 800)
    assert not dark.any() and peak == 0


def test_the_history_keeps_its_size_and_forgets_the_images_it_drops():
    state = PageState(history_size=2, image_buffer=1)   # the live ring keeps the newest only
    for n in range(1, 4):
        state.on_illumination(illumination(n, STAMP + n))
        state.on_image(STAMP + n, image())
        state.on_result(result([n], label=f'c{n}'))
    assert [h['label'] for h in state.snapshot()['history']] == ['c3', 'c2']
    with pytest.raises(RequestError) as gone:
        state.png(str(STAMP + 1))
    assert gone.value.status == 404 and 'is kept' in str(gone.value)
    assert state.png(str(STAMP + 2))


def test_errors_become_events_once_and_a_recovery_is_said():
    state = PageState()
    driver = {'name': 'driver: light stage link', 'level': 0, 'message': 'armed', 'hardware_id': '', 'values': {}}
    state.on_diagnostics([driver])
    state.on_diagnostics([{**driver, 'level': 2, 'message': 'link down: gone'}])
    state.on_diagnostics([{**driver, 'level': 2, 'message': 'link down: gone'}])
    state.on_frame_lost(12, STAMP, 'grab timeout')
    state.on_classify_answer({'success': False, 'message': 'the driver did not apply the patterns'})
    state.on_diagnostics([driver])
    events = [(e['level'], e['source'], e['text']) for e in reversed(state.snapshot()['events'])]
    assert events == [('error', 'driver: light stage link', 'ERROR: link down: gone'),
                      ('error', 'camera', 'frame of trigger 12 lost: grab timeout'),
                      ('error', 'classifier', 'classification failed: the driver did not apply the patterns'),
                      ('info', 'driver: light stage link', 'OK again: armed')]
    (failed,) = state.snapshot()['history']
    assert not failed['success'] and failed['message'] == 'the driver did not apply the patterns'


@pytest.mark.parametrize('body, reason', [
    ({'max_images': True}, 'max_images must be an integer'),
    ({'timeout_s': 'soon'}, 'timeout_s must be 0'),
    ({'timeout_s': 0.01}, 'timeout_s must be 0'),
    ('x', 'the body must be a JSON object'),
])
def test_classify_requests_are_checked_as_the_cli_checks_them(body, reason):
    with pytest.raises(RequestError, match=reason):
        classify_request(body)
    assert classify_request({}) == {'max_images': 0, 'timeout_s': 0.0}
    assert classify_request({'max_images': 4, 'timeout_s': 2}) == {'max_images': 4, 'timeout_s': 2.0}


def test_goals_name_the_bad_field_and_make_paths_absolute(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    goal = capture_goal({'output_dir': 'data', 'target': 'banana-fake/s0/p00', 'gain_db': None})
    assert goal == {'output_dir': str(tmp_path / 'data'), 'label': 'banana-fake', 'sample': 's0',
                    'pose': 'p00', 'exposure_us': 0, 'gain_db': None, 'frames_averaged': 0,
                    'overwrite': False}
    assert calibrate_goal({'output_path': 'n.yaml', 'gain_db': 15})['output_path'] == str(tmp_path / 'n.yaml')
    for body, reason in [({'output_dir': 'd', 'target': 'a/b/c', 'gain_db': float('inf')}, 'gain_db must be a finite'),
                         ({'output_dir': 'd', 'target': 'a/b/c', 'overwrite': 'yes'}, 'overwrite must be true or false'),
                         ({'output_dir': 'd', 'target': 'a/b/c', 'exposure_us': -5}, 'exposure_us must be a whole'),
                         ({'output_dir': 3, 'target': 'a/b/c'}, 'output_dir must be a string')]:
        with pytest.raises(RequestError, match=reason):
            capture_goal(body)


def test_progress_texts():
    assert capture_progress(8, 32, 's2_red', 'capturing') == ('8/32 LED images (s2_red)', 0.25)
    assert capture_progress(0, 32, '', 'preview') == ('preview', 0.0)
    text, fraction = calibrate_progress(2, 8, 60, 120, 4, 'capturing')
    assert text == 'level 2/8 (4 LEDs): 60/120 frames' and fraction == pytest.approx(1.5 / 8)


class FakeBridge:
    """The graph as the app sees it: answers on demand, jobs recorded."""

    def __init__(self, state):
        self.state = state
        self.answer = asyncio.Event()
        self.available = True
        self.jobs = []

    async def classify(self, max_images, timeout_s):
        if not self.available:
            raise GraphUnavailable('the service /lightstage/classify is not available')
        await self.answer.wait()
        return {'success': True, 'message': '', 'label': 'pear-real', 'class_names': ['pear-real'],
                'scores': [1.0], 'images_used': max_images, 'acquisition_ms': 1.0, 'compute_ms': 1.0}

    async def start_job(self, kind, goal):
        self.jobs.append(self.state.start_job(kind, goal))

    async def cancel_job(self):
        return False


def _with_app(check):
    async def run():
        state = PageState()
        bridge = FakeBridge(state)
        async with TestClient(TestServer(make_app(state, bridge), host='127.0.0.1')) as client:
            await check(client, state, bridge)
    asyncio.run(run())


def test_the_app_serves_the_page_answers_classify_and_refuses_a_second_at_once():
    async def check(client, state, bridge):
        page = await client.get('/')
        html = await page.text()
        assert page.status == 200 and 'id="classify"' in html
        # nothing from elsewhere: the page's assets are the package's, the script names no site
        assets = re.findall(r'(?:src|href)="([^"]+)"', html)
        assert assets and all(a.startswith('/static/') for a in assets), assets
        for asset in assets:
            text = await (await client.get(asset)).text()
            assert set(re.findall(r'(?:https?|wss?)://[^\'"`\s)]+', text)) <= {
                'http://www.w3.org/2000/svg', 'ws://${location.host}/api/events'}
            assert 'url(' not in text and '@import' not in text
        first = asyncio.create_task(client.post('/api/classify', json={'max_images': 4}))
        while not state.snapshot()['classify_running']:
            await asyncio.sleep(0.01)
        second = await client.post('/api/classify', json={})
        assert second.status == 409 and 'still running' in (await second.json())['error']
        bridge.answer.set()
        answer = await (await first).json()
        assert answer['label'] == 'pear-real' and answer['images_used'] == 4
        assert not state.snapshot()['classify_running']
        bridge.available = False
        gone = await client.post('/api/classify', json={})
        assert gone.status == 503 and 'not available' in (await gone.json())['error']
        assert not state.snapshot()['classify_running']
    _with_app(check)


def test_the_app_runs_one_job_at_a_time_and_pushes_the_state():
    async def check(client, state, bridge):
        ws = await client.ws_connect('/api/events')
        first = json.loads((await ws.receive(timeout=5)).data)
        started = await client.post('/api/capture', json={'output_dir': '/tmp/x', 'target': 'a/b/c'})
        assert started.status == 202 and (await started.json())['kind'] == 'capture'
        busy = await client.post('/api/calibrate', json={})
        assert busy.status == 409 and 'a capture is running' in (await busy.json())['error']
        pushed = json.loads((await ws.receive(timeout=5)).data)
        assert pushed['version'] > first['version'] and pushed['jobs'][0]['state'] == 'starting'
        assert 'history' in first
        state.set_connected('classify', True)
        while pushed['connected'].get('classify') is not True:
            pushed = json.loads((await ws.receive(timeout=5)).data)
        assert 'history' not in pushed   # only when it changed
        state.on_result(result([]))
        while 'history' not in pushed:
            pushed = json.loads((await ws.receive(timeout=5)).data)
        assert pushed['history'][0]['label'] == 'pear-real'
        state.update_job(bridge.jobs[0], state='failed', message='the disk is full')
        while True:
            pushed = json.loads((await ws.receive(timeout=5)).data)
            if pushed['jobs'][0]['state'] == 'failed':
                break
        assert pushed['events'][0]['text'] == 'capture failed: the disk is full'
        nothing = await client.post('/api/jobs/cancel', json={})
        assert nothing.status == 409
        await ws.close()
    _with_app(check)


def test_the_app_refuses_other_hosts_and_non_json_posts():
    async def check(client, state, bridge):
        other = await client.get('/api/state', headers={'Host': 'attacker.example'})
        assert other.status == 403 and 'is not this server' in (await other.json())['error']
        form = await client.post('/api/classify', data='max_images=3',
                                 headers={'Content-Type': 'application/x-www-form-urlencoded'})
        assert form.status == 415
        big = await client.post('/api/classify', data=b'{' + b' ' * (128 * 1024) + b'}',
                                headers={'Content-Type': 'application/json'})
        assert big.status == 413
    _with_app(check)


def test_bad_arguments_of_web_and_view_exit_2_naming_the_option(capsys):
    from lightstage_bringup import view_cli, web_cli
    assert web_cli.main(['--history', '0']) == 2
    assert '--history must be 1..1000' in capsys.readouterr().err
    for bad in (['--port', '70000'], ['--port', 'http']):
        with pytest.raises(SystemExit) as exc:
            web_cli.main(bad)
        assert exc.value.code == 2
        assert 'expected a port number 0..65535' in capsys.readouterr().err
    assert view_cli.main(['--include', '(']) == 2
    assert "--include '(' is not a valid regular expression" in capsys.readouterr().err


def test_a_port_in_use_is_a_clear_error_exit_1():
    import socket
    import subprocess
    from helpers.suite import fresh_domain_id, lightstage_command
    with socket.socket() as taken:
        taken.bind(('127.0.0.1', 0))
        taken.listen()
        port = taken.getsockname()[1]
        for verb in ('web', 'view'):
            p = subprocess.run(lightstage_command(verb, '--port', str(port), '--domain-id',
                                                  str(fresh_domain_id())),
                               capture_output=True, text=True, timeout=60)
            assert p.returncode == 1, (verb, p.stderr)
            assert f'cannot listen on 127.0.0.1:{port}' in p.stderr and 'choose another --port' in p.stderr
