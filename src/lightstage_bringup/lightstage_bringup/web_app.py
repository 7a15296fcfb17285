"""The operator page's web server: an aiohttp application over a `PageState` and a bridge to
the graph (no rclpy here; `web_node` is the bridge).

    GET  /                     the page (static files from web_static/, no build step, nothing
                               fetched from elsewhere)
    GET  /api/state            everything the page shows, as JSON
    GET  /api/events           WebSocket: the state as JSON whenever it changes (<= 10 per s;
                               the history only when it changed)
    GET  /api/images/live.png  the camera's latest image; /api/images/STAMP.png one of history
    POST /api/classify         {max_images, timeout_s} -> the Classify service's answer
    POST /api/capture          {output_dir, target, ...} -> 202, a job (progress in the state)
    POST /api/calibrate        {output_path, plot_path, ...} -> 202, a job
    POST /api/jobs/cancel      cancel the running capture / calibration

A request the server cannot serve as asked gets a 4xx with {"error": reason}; POSTs must be
JSON (`Content-Type: application/json`: a browser then lets no other site's page post here
without asking) and the Host header must name this machine's loopback (no DNS rebinding).
"""
from __future__ import annotations

import asyncio
import json
import logging
from pathlib import Path
from typing import Protocol

from aiohttp import WSMsgType, web

from lightstage_bringup.web_state import (PageState, RequestError, calibrate_goal, capture_goal,
                                          classify_request)

STATIC_DIR = Path(__file__).resolve().parent / 'web_static'
PUSH_PERIOD_S = 0.1
LOOPBACK_HOSTS = ('127.0.0.1', 'localhost', '[::1]', '::1')
log = logging.getLogger('lightstage.web')


class GraphUnavailable(Exception):
    """The node that would serve the request is not there (HTTP 503)."""


class Bridge(Protocol):
    """What the server asks of the graph (web_node.WebBridge; a fake in the tests)."""

    async def classify(self, max_images: int, timeout_s: float) -> dict: ...
    async def start_job(self, kind: str, goal: dict) -> None: ...
    async def cancel_job(self) -> bool: ...


# typed application keys (aiohttp's AppKey: no NotAppKeyWarning, and the values' types are known)
ALLOWED_HOSTS = web.AppKey('allowed_hosts', object)
WEBSOCKETS = web.AppKey('websockets', set)


def _error(status: int, reason: str) -> web.Response:
    return web.json_response({'error': reason}, status=status)


@web.middleware
async def api_errors(request: web.Request, handler):
    """Every failure of an /api request as JSON with its reason; nothing escapes as a crash."""
    host = request.host.rsplit(':', 1)[0] if not request.host.startswith('[') else \
        request.host.split(']')[0] + ']'
    allowed = request.app[ALLOWED_HOSTS]
    if allowed is not None and host not in allowed:
        return _error(403, f'Host {request.host!r} is not this server ({", ".join(allowed)}): '
                           'open the page at http://127.0.0.1:PORT/')
    try:
        return await handler(request)
    except RequestError as exc:
        return _error(exc.status, str(exc))
    except GraphUnavailable as exc:
        return _error(503, str(exc))
    except web.HTTPException as exc:
        if not request.path.startswith('/api/') or exc.status < 400:
            raise
        return _error(exc.status, exc.reason if exc.text is None or exc.text.startswith(str(exc.status))
                      else exc.text)
    except asyncio.CancelledError:
        raise
    except Exception as exc:  # noqa: BLE001 (the page's server outlives any one request)
        log.exception('request %s %s failed', request.method, request.path)
        return _error(500, f'internal error: {type(exc).__name__}: {exc}')


async def _json_body(request: web.Request):
    if request.content_type != 'application/json':
        raise RequestError(f'send the request body as JSON (Content-Type: application/json); '
                           f'got {request.content_type!r}', status=415)
    text = await request.text()
    if not text.strip():
        return {}
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise RequestError(f'the body is not valid JSON: {exc}') from None


def make_app(state: PageState, bridge: Bridge, allowed_hosts=LOOPBACK_HOSTS) -> web.Application:
    """`allowed_hosts`: the names the Host header may give (None: any, for a server bound
    to another interface on purpose)."""
    app = web.Application(middlewares=[api_errors], client_max_size=64 * 1024)
    app[ALLOWED_HOSTS] = None if allowed_hosts is None else tuple(allowed_hosts)
    app[WEBSOCKETS] = set()

    async def index(_request):
        return web.FileResponse(STATIC_DIR / 'index.html')

    async def get_state(_request):
        return web.json_response(state.snapshot())

    async def image(request):
        name = request.match_info['name']
        # made on first request (stretch + PNG: tens of ms for a large frame): off the loop
        png = await asyncio.get_running_loop().run_in_executor(None, state.png, name)
        return web.Response(body=png, content_type='image/png',
                            headers={'Cache-Control': 'no-store' if name == 'live' else 'max-age=3600'})

    async def classify(request):
        fields = classify_request(await _json_body(request))
        state.begin_classify()
        try:
            answer = await bridge.classify(**fields)
        finally:
            state.end_classify()
        state.on_classify_answer(answer)
        return web.json_response(answer)

    async def start(kind, goal_of, request):
        goal = goal_of(await _json_body(request))
        await bridge.start_job(kind, goal)
        job = state.running_job()
        return web.json_response(job.as_dict() if job else {}, status=202)

    async def capture(request):
        return await start('capture', capture_goal, request)

    async def calibrate(request):
        return await start('calibrate', calibrate_goal, request)

    async def cancel(_request):
        if not await bridge.cancel_job():
            raise RequestError('no capture or calibration is running', status=409)
        return web.json_response({'cancelling': True})

    async def events(request):
        ws = web.WebSocketResponse(heartbeat=20.0)
        await ws.prepare(request)
        try:
            await ws.send_str(json.dumps(state.snapshot()))   # all of it, then the changes
            app[WEBSOCKETS].add(ws)
            async for msg in ws:  # the page sends nothing; this waits for it to go
                if msg.type == WSMsgType.ERROR:
                    break
        finally:
            app[WEBSOCKETS].discard(ws)
        return ws

    api = {'/api/state': ('GET', get_state), '/api/events': ('GET', events),
           '/api/classify': ('POST', classify), '/api/capture': ('POST', capture),
           '/api/calibrate': ('POST', calibrate), '/api/jobs/cancel': ('POST', cancel)}

    async def api_not_found(request):
        if request.path in api:
            raise RequestError(f'{request.path} takes {api[request.path][0]}, not {request.method}',
                               status=405)
        raise RequestError(f'no API {request.method} {request.path}; see docs/WEB.md', status=404)

    app.router.add_get('/', index)
    app.router.add_static('/static/', STATIC_DIR, follow_symlinks=False)
    for path, (method, handler) in api.items():
        app.router.add_route(method, path, handler)
    app.router.add_get('/api/images/{name}.png', image)
    app.router.add_route('*', '/api/{tail:.*}', api_not_found)

    async def push(_app):
        """Send the state to every open page when it changed, at most every PUSH_PERIOD_S."""
        sent, sent_history = -1, None
        changed = asyncio.Event()
        loop = asyncio.get_running_loop()
        state.on_change = lambda: loop.call_soon_threadsafe(changed.set)
        while True:
            await changed.wait()
            changed.clear()
            if state.version != sent and app[WEBSOCKETS]:
                snap = state.snapshot(history_since=sent_history)   # each page got the last one
                sent, sent_history = snap['version'], snap['history_version']
                text = json.dumps(snap)
                for ws in list(app[WEBSOCKETS]):
                    try:
                        await ws.send_str(text)
                    except (ConnectionError, RuntimeError):
                        app[WEBSOCKETS].discard(ws)
            await asyncio.sleep(PUSH_PERIOD_S)

    async def pusher(app_):
        task = asyncio.create_task(push(app_))
        yield
        task.cancel()
        for ws in list(app[WEBSOCKETS]):
            await ws.close()

    app.cleanup_ctx.append(pusher)
    return app
