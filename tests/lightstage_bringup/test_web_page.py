"""`lightstage web` beside the graph on the simulated stage, driven in headless Chromium.

One graph (driver on the simulated firmware, camera, classifier), one page server and one
browser for the module, in this order: the page classifies (the label in the DOM is the
Classify service's own answer, seen on its introspection topic), bad API requests get 4xx
with a reason and the graph goes on, a capture started from the page reports its progress
(and one cancelled ends canceled), a lost frame shows as an alert, and a driver fault (its
firmware simulator killed) shows on the page as an ERROR, as does the classify that then
fails. The classify and the fault are screenshotted and the screenshots checked not to be
blank.
"""
import asyncio
import json
import os
import shutil
import signal
import urllib.error
import urllib.request

import pytest
from lightstage_bringup.supervisor import Supervisor

from helpers.browser import Browser, screenshot_stats
from helpers.proc_sockets import sockets_of
from helpers.suite import GraphClient, fresh_domain_id, stage_graph_params, start_nodes, write_params
from helpers.web import served

pytestmark = [pytest.mark.ros, pytest.mark.process]

DRIVER_STATUS = 'driver: light stage link'


@pytest.fixture(scope='module')
def stage(stage_capture, stage_artifact_path, tmp_path_factory):
    """The graph, a graph client watching the Classify calls, the page server."""
    from lightstage_interfaces.srv import Classify
    tmp = tmp_path_factory.mktemp('web')
    domain_id = fresh_domain_id()
    params = write_params(tmp / 'params.yaml', stage_graph_params(
        stage_capture, 'banana-real/s0/p00', 5, stage_artifact_path,
        # a killed simulator stays down for the fault test (the driver retries every 60 s)
        driver={'port': 'sim', 'reconnect_period_s': 60.0},
        acquisition={'preview': False, 'exposure_us': 5000}))
    client = GraphClient(domain_id)
    answers = []   # the Classify service's responses, from its introspection events
    client.node.create_subscription(Classify.Event, '/lightstage/classify/_service_event',
                                    lambda e: answers.extend(e.response), 10)
    try:
        with Supervisor(sigint_timeout_s=5.0) as supervisor:
            start_nodes(supervisor, client, ['driver', 'camera', 'classifier', 'acquisition'],
                        domain_id, params)
            with served('web', domain_id) as (server, url):
                yield {'client': client, 'answers': answers, 'url': url, 'server': server,
                       'supervisor': supervisor, 'tmp': tmp}
    finally:
        client.close()


def _keep(png_path):
    """LIGHTSTAGE_WEB_SCREENSHOTS=DIR keeps the screenshots (docs/ took its picture so)."""
    if os.environ.get('LIGHTSTAGE_WEB_SCREENSHOTS'):
        shutil.copy(png_path, os.environ['LIGHTSTAGE_WEB_SCREENSHOTS'])


def _assert_not_blank(png: bytes) -> None:
    stats = screenshot_stats(png)
    assert stats['width'] >= 1000 and stats['height'] >= 800, stats
    # a blank page is one colour; the rendered page has text, bars, the camera image, LEDs
    assert stats['std'] > 20 and stats['colours'] > 200, stats


def _in_browser(stage, steps):
    async def run():
        browser = Browser(stage['tmp'] / 'chromium-profile')
        try:
            await browser.start()
            page = await browser.page()
            await page.send('Page.navigate', url=stage['url'] + '/')
            await page.wait_for("typeof state !== 'undefined' && state !== null", 30, 'the page\'s state')
            return await steps(page)
        finally:
            await browser.close()
    return asyncio.run(run())


def _spin_until(stage, predicate, what, timeout_s=20.0):
    stage['client'].spin_until(predicate, timeout_s, what)


def test_classify_in_the_page_shows_the_service_answer(stage):
    answers = stage['answers']

    async def steps(page):
        # the classify service, and the driver's and camera's topics matched (a trigger sent
        # before the page's reader of /illumination is matched never reaches the page)
        await page.wait_for('state.connected.classify && state.connected.driver && '
                            'state.connected.camera', 30, 'the classify service and the topics')
        await page.evaluate("document.getElementById('classify').click()")
        label = await page.wait_for(
            "document.getElementById('label').dataset.pending === undefined && "
            "document.getElementById('label').dataset.success === '1' && "
            "document.getElementById('label').textContent", 60, 'the label')
        # the images of that classification arrive with its result on /lightstage/result
        n_thumbs = await page.wait_for(
            "(() => { const n = [...document.querySelectorAll('#class-images .thumb img')]"
            ".filter(i => i.complete && i.naturalWidth > 0).length;"
            " return state.history.length && n === state.history[0].images_used ? n : 0; })()",
            20, 'its images, loaded')
        bars = await page.evaluate("document.querySelectorAll('#scores .bar').length")
        lit = await page.evaluate("document.querySelectorAll('#class-images svg [data-lit=\"1\"]').length")
        history = await page.evaluate("document.querySelectorAll('#history tbody tr').length")
        await page.wait_for("document.getElementById('live').naturalWidth > 0", 10, 'the live image')
        # the classifier's /diagnostics: which classifier, and its inner estimate
        model = await page.wait_for(
            "(() => { const d = document.querySelector('.diag[data-name=\"classifier: model\"]');"
            " return d ? d.textContent : ''; })()", 30, "the classifier's model")
        await asyncio.sleep(0.5)  # the images finish drawing
        png = await page.screenshot(stage['tmp'] / 'web_classify.png')
        return label, n_thumbs, bars, lit, history, model, png

    label, n_thumbs, bars, lit, history, model, png = _in_browser(stage, steps)
    _spin_until(stage, lambda: answers, 'the Classify service\'s answer on its event topic')
    (answer,) = answers
    assert answer.success, answer.message
    assert label == answer.label
    assert bars == len(answer.class_names) == 4
    assert n_thumbs == answer.images_used
    assert lit > 0          # the LED pictures of its images show what was lit
    assert history == 1
    assert model.startswith('OKclassifier: model: 4 classes') and 'inner estimate' in model, model
    _assert_not_blank(png)
    _keep(stage['tmp'] / 'web_classify.png')


def _request(url, method='GET', body=None, content_type='application/json', host=None):
    data = None if body is None else (body if isinstance(body, bytes) else json.dumps(body).encode())
    request = urllib.request.Request(url, data=data, method=method)
    if data is not None:
        request.add_header('Content-Type', content_type)
    if host:
        request.add_header('Host', host)
    try:
        with urllib.request.urlopen(request, timeout=30) as r:
            return r.status, json.loads(r.read() or b'{}')
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read() or b'{}')


@pytest.mark.parametrize('method, path, body, status, reason', [
    ('POST', '/api/classify', {'max_images': -1}, 400, 'max_images must be an integer from 0'),
    ('POST', '/api/classify', {'timeout_s': 1e10}, 400, 'timeout_s must be 0'),
    ('POST', '/api/classify', {'images': 3}, 400, 'unknown field(s) images'),
    ('POST', '/api/classify', [1, 2], 400, 'the body must be a JSON object'),
    ('POST', '/api/classify', b'{not json', 400, 'not valid JSON'),
    ('POST', '/api/capture', {'output_dir': 'x', 'target': 'banana'}, 400, 'expected label/sample/pose'),
    ('POST', '/api/capture', {'target': 'a/b/c'}, 400, 'output_dir: give the capture folder'),
    ('POST', '/api/capture', {'output_dir': 'x', 'target': 'a/b/c=3'}, 400, '=SIM_SAMPLE is for the command line'),
    ('POST', '/api/calibrate', {'levels': 'many'}, 400, 'levels must be a whole number'),
    ('POST', '/api/jobs/cancel', {}, 409, 'no capture or calibration is running'),
    ('GET', '/api/images/12345.png', None, 404, 'no image with stamp 12345'),
    ('GET', '/api/images/nothing.png', None, 400, 'expected "live" or an image stamp'),
    ('GET', '/api/nothing', None, 404, 'no API GET /api/nothing'),
    ('GET', '/api/classify', None, 405, '/api/classify takes POST, not GET'),
])
def test_bad_requests_get_4xx_with_the_reason(stage, method, path, body, status, reason):
    code, answer = _request(stage['url'] + path, method, body)
    assert (code, reason in answer.get('error', '')) == (status, True), answer


def test_requests_that_are_not_json_or_name_another_host_are_refused(stage):
    code, answer = _request(stage['url'] + '/api/classify', 'POST', b'max_images=1',
                            content_type='application/x-www-form-urlencoded')
    assert code == 415 and 'Content-Type: application/json' in answer['error']
    code, answer = _request(stage['url'] + '/api/state', host='evil.example:80')
    assert code == 403 and "Host 'evil.example:80' is not this server" in answer['error']


def test_the_page_listens_on_loopback_only_and_survives_the_bad_requests(stage):
    listening = [s for s in sockets_of(stage['server'].pid) if s.proto.startswith('tcp') and s.state == '0A']
    assert listening and all(s.loopback for s in listening), [str(s) for s in listening]
    assert stage['server'].poll() is None and not stage['supervisor'].exited()
    import time
    deadline = time.monotonic() + 30   # the page looks at the graph each second
    while not (state := _request(stage['url'] + '/api/state')[1])['connected'].get('classify'):
        assert time.monotonic() < deadline, state['connected']
        time.sleep(0.2)


def test_a_capture_started_from_the_page_reports_its_progress_and_result(stage):
    import time
    _wait_connected(stage, 'capture')
    out = stage['tmp'] / 'capture'
    code, job = _request(stage['url'] + '/api/capture', 'POST',
                         {'output_dir': str(out), 'target': 'banana-real/s0/p00', 'frames_averaged': 1})
    assert code == 202 and job['kind'] == 'capture' and job['state'] == 'running', job
    code, again = _request(stage['url'] + '/api/calibrate', 'POST', {})
    assert code == 409 and 'a capture is running' in again['error']
    progress = set()
    deadline = time.monotonic() + 60
    while True:
        (job,) = [j for j in _request(stage['url'] + '/api/state')[1]['jobs'] if j['id'] == job['id']]
        if job['state'] != 'running':
            break
        progress.add(job['progress'])
        assert time.monotonic() < deadline, job
        time.sleep(0.05)
    assert job['state'] == 'succeeded', job
    assert job['fraction'] == 1.0 and job['result']['images_captured'] == 32
    assert any(p.endswith('LED images (s0_red)') or '/32 LED images' in p for p in progress), progress
    assert len(list((out / 'banana-real' / 's0' / 'p00').glob('*.png'))) == 32


def test_a_noise_calibration_started_from_the_page_reports_its_progress_and_fit(stage):
    import time
    _wait_connected(stage, 'calibrate')
    noise_file = stage['tmp'] / 'noise.yaml'
    code, job = _request(stage['url'] + '/api/calibrate', 'POST',
                         {'output_path': str(noise_file), 'frames_per_level': 8, 'levels': 3})
    assert code == 202 and job['kind'] == 'calibrate', job
    progress = set()
    deadline = time.monotonic() + 60
    while (job := _job(stage, job['id']))['state'] == 'running':
        progress.add(job['progress'])
        assert time.monotonic() < deadline, job
        time.sleep(0.05)
    assert job['state'] == 'succeeded', job
    assert job['result']['sigma_p2'] > 0 and job['result']['output_path'] == str(noise_file)
    assert noise_file.is_file()
    assert any(p.startswith('level ') and '/3 (' in p for p in progress), progress


def test_a_capture_cancelled_from_the_page_ends_canceled_and_writes_nothing(stage):
    import time
    _wait_connected(stage, 'capture')
    out = stage['tmp'] / 'cancelled'
    code, job = _request(stage['url'] + '/api/capture', 'POST',
                         {'output_dir': str(out), 'target': 'banana-real/s0/p01', 'frames_averaged': 8})
    assert code == 202, job
    deadline = time.monotonic() + 60
    while not _job(stage, job['id'])['progress'].startswith(('1/', '2/', '3/')):
        assert time.monotonic() < deadline, _job(stage, job['id'])
        time.sleep(0.05)
    code, answer = _request(stage['url'] + '/api/jobs/cancel', 'POST', {})
    assert code == 200 and answer == {'cancelling': True}
    while _job(stage, job['id'])['state'] in ('running', 'cancelling'):
        assert time.monotonic() < deadline, _job(stage, job['id'])
        time.sleep(0.05)
    assert _job(stage, job['id'])['state'] == 'canceled'
    assert not (out / 'banana-real' / 's0' / 'p01').exists()


def _wait_connected(stage, what, timeout_s=30.0):
    """Until the page sees `what` (it looks at the graph each second; alone, a test comes first)."""
    import time
    deadline = time.monotonic() + timeout_s
    while not _request(stage['url'] + '/api/state')[1]['connected'].get(what):
        assert time.monotonic() < deadline, f'the page did not see {what} in {timeout_s:g} s'
        time.sleep(0.2)


def _job(stage, job_id):
    (job,) = [j for j in _request(stage['url'] + '/api/state')[1]['jobs'] if j['id'] == job_id]
    return job


def test_a_lost_frame_shows_on_the_page(stage):
    # what a camera publishes for a trigger whose frame will not come (the camera's own tests
    # make it lose frames; here the page's side: notice -> the alert a person sees)
    from lightstage_graph.qos import IMAGE_QOS
    from lightstage_interfaces.msg import FrameLost
    client = stage['client']
    client.wait_for_subscriptions('web', ['/camera/frame_lost'], 10.0)
    publisher = client.node.create_publisher(FrameLost, '/camera/frame_lost', IMAGE_QOS)
    client.spin_until(lambda: publisher.get_subscription_count() > 0, 10.0, 'the page to subscribe')
    client.spin_for(0.5)   # the reliable writer matched the page's reader
    publisher.publish(FrameLost(sequence=4242, reason='BlockID gap: frame 17 lost in transfer'))

    async def steps(page):
        return await page.wait_for(
            "[...document.querySelectorAll('.alert')].filter(a => a.dataset.source === 'camera')"
            ".map(a => a.textContent).join('\\n')", 10, 'the lost frame on the page')
    lost = _in_browser(stage, steps)
    client.node.destroy_publisher(publisher)
    assert 'frame of trigger 4242 lost: BlockID gap: frame 17 lost in transfer' in lost


def _driver_status(stage, timeout_s=30.0):
    """The driver's status once the page has one (its first /diagnostics come a second or so
    after the graph is up)."""
    import time
    deadline = time.monotonic() + timeout_s
    while True:
        found = [d for d in _request(stage['url'] + '/api/state')[1]['diagnostics']
                 if d['name'] == DRIVER_STATUS]
        if found:
            return found[0]
        assert time.monotonic() < deadline, f'no {DRIVER_STATUS!r} status on the page in {timeout_s:g} s'
        time.sleep(0.2)


def test_a_driver_fault_and_the_classify_it_fails_show_on_the_page(stage):
    driver = _driver_status(stage)
    assert driver['level'] == 'OK'
    os.kill(int(driver['values']['simulator_pid']), signal.SIGKILL)

    async def steps(page):
        alert = await page.wait_for(
            f"[...document.querySelectorAll('.alert')].filter(a => a.dataset.source === '{DRIVER_STATUS}')"
            ".map(a => a.textContent).join('\\n')", 30, 'the driver\'s ERROR on the page')
        diag = await page.evaluate(f"document.querySelector('.diag.ERROR[data-name=\"{DRIVER_STATUS}\"]').textContent")
        await page.evaluate("document.getElementById('classify').click()")
        failed = await page.wait_for(
            "document.getElementById('label').dataset.pending === undefined && "
            "document.getElementById('label').dataset.success === '0' && "
            "document.getElementById('label').textContent", 60, 'the failed classification')
        history = await page.wait_for("document.querySelector('#history tbody tr td.failed')?.textContent",
                                      10, 'the failed classification in the history')
        png = await page.screenshot(stage['tmp'] / 'web_driver_fault.png')
        return alert, diag, failed, history, png

    alert, diag, failed, history, png = _in_browser(stage, steps)
    assert 'ERROR' in alert and 'link down' in alert and 'firmware simulator' in alert
    assert 'ERROR' in diag and 'link down' in diag
    assert failed.startswith('classification failed:') and 'the link to the stage is down' in failed
    assert history.startswith('failed: ')
    _assert_not_blank(png)
    _keep(stage['tmp'] / 'web_driver_fault.png')
    assert stage['server'].poll() is None   # the page's server goes on
