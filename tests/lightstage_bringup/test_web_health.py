"""The operator's page never shows a dead, frozen or unarmed stage as healthy, and other
websites cannot use it: `lightstage web` beside the simulated stage, in headless Chromium.

The camera and the page's server run for the module; each test starts the driver (and the
acquisition node) it needs in a supervisor of its own and leaves them stopped, so each test
passes alone and in any order. Checked: a driver stopped is shown stopped (the time it took
is printed); a deactivated driver is shown not armed and the page's Activate arms it again; a
frozen driver's status turns STALE, never stays OK; a page served from another origin (a
second server on loopback) can neither read the event stream nor cancel or start a job; a
capture whose acquisition node is killed ends failed with the reason, after which a capture
is accepted again; a second page server finds the capture the first one started and cancels
it. Screenshots are kept with LIGHTSTAGE_WEB_SCREENSHOTS=DIR.
"""
import asyncio
import contextlib
import http.server
import json
import os
import shutil
import signal
import threading
import time
import urllib.error
import urllib.request

import pytest
from lightstage_bringup.supervisor import Supervisor
from lightstage_graph.names import ACQUISITION_NODE, IMAGE_TOPIC, resolved

from helpers.browser import Browser, screenshot_stats
from helpers.suite import GraphClient, fresh_domain_id, stage_graph_params, start_nodes, write_params
from helpers.web import served

pytestmark = [pytest.mark.ros, pytest.mark.process]

DRIVER_STATUS = 'driver: light stage link'


@pytest.fixture(scope='module')
def base(stage_capture, tmp_path_factory):
    tmp = tmp_path_factory.mktemp('web_health')
    domain_id = fresh_domain_id()
    params = write_params(tmp / 'params.yaml', stage_graph_params(
        stage_capture, 'banana-real/s0/p00', 5,
        driver={'port': 'sim', 'reconnect_period_s': 60.0},
        acquisition={'preview': False, 'exposure_us': 5000}))
    client = GraphClient(domain_id)
    try:
        with Supervisor(sigint_timeout_s=5.0) as supervisor:
            start_nodes(supervisor, client, ['camera'], domain_id, params, wait_links=False)
            with served('web', domain_id) as (server, url):
                yield {'client': client, 'url': url, 'server': server, 'tmp': tmp,
                       'domain_id': domain_id, 'params': params}
    finally:
        client.close()


@pytest.fixture
def nodes(base):
    """start(*names): those nodes in a supervisor of the test's own, stopped when it ends."""
    with contextlib.ExitStack() as stack:
        def start(*names):
            supervisor = stack.enter_context(Supervisor(sigint_timeout_s=5.0))
            start_nodes(supervisor, base['client'], list(names), base['domain_id'], base['params'],
                        wait_links=False)
            return supervisor
        yield start


def _request(url, method='GET', body=None):
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(url, data=data, method=method)
    if data is not None:
        request.add_header('Content-Type', 'application/json')
    try:
        with urllib.request.urlopen(request, timeout=30) as r:
            return r.status, json.loads(r.read() or b'{}')
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read() or b'{}')


def _state(base, url=None):
    return _request((url or base['url']) + '/api/state')[1]


def _wait(what, predicate, timeout_s=60.0):
    deadline = time.monotonic() + timeout_s
    while not (value := predicate()):
        assert time.monotonic() < deadline, f'{what}: not within {timeout_s:g} s'
        time.sleep(0.2)
    return value


def _in_browser(base, steps, url=None):
    async def run():
        browser = Browser(base['tmp'] / 'chromium-profile')
        try:
            await browser.start()
            page = await browser.page()
            await page.send('Page.navigate', url=(url or base['url'] + '/'))
            return await steps(page)
        finally:
            await browser.close()
    return asyncio.run(run())


async def _page_ready(page):
    await page.wait_for("typeof state !== 'undefined' && state !== null", 30, 'the page\'s state')


async def _shot(base, page, name):
    await asyncio.sleep(0.3)   # the last render drawn
    png = await page.screenshot(base['tmp'] / name)
    stats = screenshot_stats(png)
    assert stats['width'] >= 1000 and stats['std'] > 20, stats   # not blank
    if os.environ.get('LIGHTSTAGE_WEB_SCREENSHOTS'):
        shutil.copy(base['tmp'] / name, os.environ['LIGHTSTAGE_WEB_SCREENSHOTS'])
    return png


DRIVER_OK = (f"state.nodes.driver && state.nodes.driver.state === 'active' && "
             f"state.diagnostics.some(d => d.name === '{DRIVER_STATUS}' && d.level === 'OK')")
DRIVER_DIAG = f"document.querySelector('.diag[data-name=\"{DRIVER_STATUS}\"]')"


def test_a_stopped_driver_is_shown_stopped_and_its_status_not_ok(base, nodes):
    driver = nodes('driver')['driver']

    async def steps(page):
        await _page_ready(page)
        await page.wait_for(DRIVER_OK, 30, 'the driver active and OK')
        driver.popen.send_signal(signal.SIGINT)
        await asyncio.get_running_loop().run_in_executor(None, driver.popen.wait, 30)
        stopped = time.monotonic()
        await page.wait_for("document.querySelector('.pill[data-node=\"driver\"]')?.dataset.state === 'stopped'",
                            30, 'the driver shown stopped')
        took = time.monotonic() - stopped
        print(f'the driver exited -> shown stopped on the page after {took:.1f} s')
        alert = await page.evaluate("document.querySelector('.alert.node[data-source=\"driver\"]').textContent")
        diag = await page.evaluate(f"{DRIVER_DIAG}.className + ' ' + {DRIVER_DIAG}.textContent")
        await _shot(base, page, 'web_driver_stopped.png')
        return alert, diag

    alert, diag = _in_browser(base, steps)
    assert 'stopped: the node left the graph' in alert and 'lightstage up driver' in alert
    assert diag.startswith('diag STALE') and 'the driver node is not running' in diag
    (shown,) = [d for d in _state(base)['diagnostics'] if d['name'] == DRIVER_STATUS]
    assert shown['level'] == 'STALE' and shown['reported_level'] == 'OK'


def test_a_deactivated_driver_is_shown_not_armed_and_the_page_activates_it(base, nodes):
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState
    nodes('driver')

    async def steps(page):
        await _page_ready(page)
        await page.wait_for(DRIVER_OK, 30, 'the driver active and OK')
        answer = await asyncio.get_running_loop().run_in_executor(None, lambda: base['client'].call(
            ChangeState, '/driver/change_state',
            ChangeState.Request(transition=Transition(id=Transition.TRANSITION_DEACTIVATE))))
        assert answer.success
        alert = await page.wait_for(
            "document.querySelector('.alert.node[data-source=\"driver\"]')?.textContent", 30,
            'the driver shown not armed')
        diag = await page.evaluate(f"{DRIVER_DIAG}.className + ' ' + {DRIVER_DIAG}.textContent")
        pill = await page.evaluate("document.querySelector('.pill[data-node=\"driver\"]').className")
        await _shot(base, page, 'web_driver_inactive.png')
        await page.evaluate("document.querySelector('.alert.node[data-source=\"driver\"] button.activate').click()")
        await page.wait_for(DRIVER_OK + " && !document.querySelector('.alert.node[data-source=\"driver\"]')",
                            30, 'the driver active again')
        return alert, diag, pill

    alert, diag, pill = _in_browser(base, steps)
    assert 'not armed: the driver is inactive' in alert and 'Activate' in alert
    assert diag.startswith('diag WARN') and 'not armed' in diag
    assert 'warn' in pill.split()


def test_a_frozen_driver_s_status_turns_stale_and_is_never_shown_ok(base, nodes):
    driver = nodes('driver')['driver']

    async def steps(page):
        await _page_ready(page)
        await page.wait_for(DRIVER_OK, 30, 'the driver active and OK')
        # silent; after the DDS lease (5 s, the project's profile) it also leaves the graph,
        # so the status turns STALE for either reason, whichever the page sees first
        os.kill(driver.pid, signal.SIGSTOP)
        try:
            frozen = time.monotonic()
            await page.wait_for(f"{DRIVER_DIAG}.classList.contains('STALE')", 30, 'the status shown STALE')
            print(f'the driver frozen -> its status shown STALE after {time.monotonic() - frozen:.1f} s')
            text = await page.evaluate(f"{DRIVER_DIAG}.textContent")
            await _shot(base, page, 'web_driver_stale.png')
        finally:
            os.kill(driver.pid, signal.SIGCONT)
        return text

    text = _in_browser(base, steps)
    assert text.startswith('STALE') and '(last report OK' in text
    assert ('no update for more than 5 s' in text) or ('the driver node is not running' in text)


class _OtherSite:
    """A second web server on loopback (another origin) whose page tries the operator page's
    API from a browser: read the event stream, cancel, start a capture."""

    def __init__(self, target_url, out_dir):
        script = f'''<!DOCTYPE html><html><body><script>
        const target = {json.dumps(target_url)};
        window.results = {{ws: 'pending', wsMessages: 0}};
        const ws = new WebSocket(target.replace('http', 'ws') + '/api/events');
        ws.onmessage = () => {{ window.results.wsMessages += 1; window.results.ws = 'read'; }};
        ws.onerror = () => {{ if (window.results.ws === 'pending') window.results.ws = 'refused'; }};
        ws.onclose = () => {{ if (window.results.ws === 'pending') window.results.ws = 'refused'; }};
        async function attempt(path, body, type) {{
          try {{
            await fetch(target + path, {{method: 'POST', mode: 'no-cors', body,
                                        headers: {{'Content-Type': type}}}});
            return 'sent';
          }} catch (e) {{ return 'error ' + e; }}
        }}
        (async () => {{
          window.results.cancel = await attempt('/api/jobs/cancel', '{{}}', 'text/plain');
          window.results.captureText = await attempt('/api/capture',
            JSON.stringify({{output_dir: {json.dumps(str(out_dir))}, target: 'evil/s0/p00'}}), 'text/plain');
          try {{
            const r = await fetch(target + '/api/capture', {{method: 'POST',
              headers: {{'Content-Type': 'application/json'}},
              body: JSON.stringify({{output_dir: {json.dumps(str(out_dir))}, target: 'evil/s0/p01'}})}});
            window.results.captureJson = 'answered ' + r.status;
          }} catch (e) {{ window.results.captureJson = 'blocked'; }}
          window.results.done = true;
        }})();
        </script></body></html>'''.encode()

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self):
                self.send_response(200)
                self.send_header('Content-Type', 'text/html')
                self.end_headers()
                self.wfile.write(script)

            def log_message(self, *args):
                pass

        self.server = http.server.ThreadingHTTPServer(('127.0.0.1', 0), Handler)
        self.url = f'http://127.0.0.1:{self.server.server_address[1]}/'
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.server.shutdown()
        self.server.server_close()


def test_a_page_from_another_origin_cannot_read_events_cancel_or_start_a_job(base, nodes):
    nodes('driver', 'acquisition')
    _wait('the capture action on the page', lambda: _state(base)['connected'].get('capture'))
    out = base['tmp'] / 'foreign'
    code, job = _request(base['url'] + '/api/capture', 'POST',
                         {'output_dir': str(base['tmp'] / 'own'), 'target': 'banana-real/s0/p02',
                          'frames_averaged': 64})
    assert code == 202, job
    try:
        with _OtherSite(base['url'], out) as other:
            async def steps(page):
                await page.wait_for('window.results && window.results.done && window.results.ws !== "pending"',
                                    30, 'the other site\'s attempts')
                return await page.evaluate('JSON.stringify(window.results)')
            results = json.loads(_in_browser(base, steps, url=other.url))
        state = _state(base)
        (own,) = [j for j in state['jobs'] if j['id'] == job['id']]
    finally:
        _request(base['url'] + '/api/jobs/cancel', 'POST', {})
    assert results['ws'] == 'refused' and results['wsMessages'] == 0, results
    assert own['state'] in ('running', 'succeeded'), own      # not cancelled by the other site
    assert len(state['jobs']) == 1, state['jobs']               # and nothing started by it
    assert not out.exists()


def test_a_capture_whose_node_is_killed_fails_and_the_next_is_accepted(base, nodes):
    nodes('driver')
    acquisition = nodes('acquisition')['acquisition']
    _wait('the capture action on the page', lambda: _state(base)['connected'].get('capture'))
    code, job = _request(base['url'] + '/api/capture', 'POST',
                         {'output_dir': str(base['tmp'] / 'killed'), 'target': 'banana-real/s0/p00',
                          'frames_averaged': 64})
    assert code == 202, job
    _wait('the capture under way', lambda: next(j for j in _state(base)['jobs'] if j['id'] == job['id'])['progress'])
    os.kill(acquisition.pid, signal.SIGKILL)
    killed = time.monotonic()
    ended = _wait('the capture to end', lambda: next(
        (j for j in _state(base)['jobs'] if j['id'] == job['id'] and j['state'] not in ('running', 'cancelling')),
        None), timeout_s=120)
    print(f'the acquisition node killed -> the capture shown failed after {time.monotonic() - killed:.1f} s')
    assert ended['state'] == 'failed' and 'went away during the capture' in ended['message'], ended
    code, answer = _request(base['url'] + '/api/jobs/cancel', 'POST', {})
    assert code == 409, answer   # nothing left running on the page's side
    nodes('acquisition')
    _wait('the capture action back', lambda: _state(base)['connected'].get('capture'))
    code, again = _request(base['url'] + '/api/capture', 'POST',
                           {'output_dir': str(base['tmp'] / 'again'), 'target': 'banana-real/s0/p00',
                            'frames_averaged': 1})
    assert code == 202, again
    done = _wait('the next capture to end', lambda: next(
        (j for j in _state(base)['jobs'] if j['id'] == again['id'] and j['state'] not in ('starting', 'running')),
        None), timeout_s=120)
    assert done['state'] == 'succeeded', done


def test_a_page_server_started_during_a_capture_shows_it_and_cancels_it(base, nodes):
    nodes('driver', 'acquisition')
    # the running camera matches the new acquisition node's image subscription a little after
    # the graph shows it; images published before are lost, and a capture whose first images
    # are all lost fails (after 10 s) before the second page can cancel it
    base['client'].wait_for_subscriptions(ACQUISITION_NODE, [resolved(IMAGE_TOPIC)], 30.0,
                                          settle_s=2.0)
    _wait('the capture action on the page', lambda: _state(base)['connected'].get('capture'))
    code, job = _request(base['url'] + '/api/capture', 'POST',
                         {'output_dir': str(base['tmp'] / 'restart'), 'target': 'banana-real/s0/p01',
                          'frames_averaged': 64})
    assert code == 202, job
    _wait('the capture under way', lambda: next(j for j in _state(base)['jobs'] if j['id'] == job['id'])['progress'])
    with served('web', base['domain_id']) as (_, second):
        found = _wait('the capture on the second page', lambda: next(
            (j for j in _state(base, second)['jobs'] if not j['known'] and j['state'] == 'running'), None))
        assert 'this page did not start' in found['message']
        code, busy = _request(second + '/api/calibrate', 'POST', {})
        assert code == 409 and 'a capture is running' in busy['error']
        code, answer = _request(second + '/api/jobs/cancel', 'POST', {})
        assert code == 200, answer
        ours = _wait('the first page\'s job to end', lambda: next(
            (j for j in _state(base)['jobs'] if j['id'] == job['id'] and j['state'] not in ('running', 'cancelling')),
            None))
        assert ours['state'] == 'canceled', ours
        theirs = _wait('the second page\'s to end', lambda: next(
            (j for j in _state(base, second)['jobs'] if j['id'] == found['id']
             and j['state'] not in ('running', 'cancelling')), None))
        assert theirs['state'] == 'ended', theirs
