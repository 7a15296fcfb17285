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
    POST /api/nodes/NAME/activate   configure (if needed) and activate a lifecycle node

A request the server cannot serve as asked gets a 4xx with {"error": reason}. Closed to other
websites a person's browser may have open (the page controls the stage):
- the Host header must name this machine's loopback (no DNS rebinding);
- every /api request that carries `Origin` must come from the page's own origin
  (`http://` + the Host it was served as), and one whose `Sec-Fetch-Site` says another site
  (`cross-site`, `same-site`: another port of this machine is the same site) is refused;
  WebSocket upgrades too (a browser lets any page open a WebSocket anywhere);
- POSTs must be JSON (`Content-Type: application/json`), and a malformed body is a 400;
- served beyond loopback (`make_app(token=...)`), every request needs the token: `?token=`
  once (the page then keeps it in a SameSite=Strict cookie), or `Authorization: Bearer`.
Each /api/events reader has a bounded send queue of its own: a reader that does not keep up
is dropped, the others go on. `guard_connections` bounds the connections and the time a
connection may take to send its request's headers.
"""
from __future__ import annotations

import asyncio
import hmac
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
SEND_QUEUE = 20           # states queued for one /api/events reader before it is dropped
SEND_TIMEOUT_S = 10.0     # one state sent to a reader within this, or the reader is dropped
MAX_CONNECTIONS = 200     # open TCP connections at once; more are closed at once
HEADER_TIMEOUT_S = 10.0   # a connection sends its request's headers within this
KEEPALIVE_TIMEOUT_S = 30.0  # an idle keep-alive connection is closed after this
TOKEN_COOKIE = 'lightstage_token'
SAFE_FETCH_SITES = ('same-origin', 'none')   # Sec-Fetch-Site values of the page's own requests
log = logging.getLogger('lightstage.web')


class GraphUnavailable(Exception):
    """The node that would serve the request is not there (HTTP 503)."""


class Bridge(Protocol):
    """What the server asks of the graph (web_node.WebBridge; a fake in the tests)."""

    async def classify(self, max_images: int, timeout_s: float) -> dict: ...
    async def start_job(self, kind: str, goal: dict) -> None: ...
    async def cancel_job(self) -> bool: ...
    async def activate(self, node: str) -> str: ...


# typed application keys (aiohttp's AppKey: no NotAppKeyWarning, and the values' types are known)
ALLOWED_HOSTS = web.AppKey('allowed_hosts', object)
WEBSOCKETS = web.AppKey('websockets', dict)
TOKEN = web.AppKey('token', object)


def _error(status: int, reason: str) -> web.Response:
    return web.json_response({'error': reason}, status=status)


def _foreign(request: web.Request) -> str:
    """Why a request comes from another website ('' if it does not)."""
    site = request.headers.get('Sec-Fetch-Site')
    if site is not None and site.lower() not in SAFE_FETCH_SITES:
        return f'Sec-Fetch-Site: {site}'
    origin = request.headers.get('Origin')
    if origin is not None and origin.lower() != f'{request.scheme}://{request.host}'.lower():
        return f'Origin {origin}'
    return ''


def _token_given(request: web.Request, token: str) -> bool:
    given = [request.query.get('token', ''), request.cookies.get(TOKEN_COOKIE, '')]
    auth = request.headers.get('Authorization', '')
    if auth.lower().startswith('bearer '):
        given.append(auth[7:].strip())
    return any(g and hmac.compare_digest(g.encode(), token.encode()) for g in given)


@web.middleware
async def api_errors(request: web.Request, handler):
    """Every failure of an /api request as JSON with its reason; nothing escapes as a crash.
    Requests from other hosts and websites, and without the token where one is set, are
    refused first."""
    host = request.host.rsplit(':', 1)[0] if not request.host.startswith('[') else \
        request.host.split(']')[0] + ']'
    allowed = request.app[ALLOWED_HOSTS]
    if allowed is not None and host not in allowed:
        return _error(403, f'Host {request.host!r} is not this server ({", ".join(allowed)}): '
                           'open the page at http://127.0.0.1:PORT/')
    token = request.app[TOKEN]
    if token is not None and not _token_given(request, token):
        return _error(401, 'this page needs its token: open the address `lightstage web` printed '
                           '(it ends in ?token=...)')
    if request.path.startswith('/api/'):
        foreign = _foreign(request)
        if foreign:
            return _error(403, f'refused: a request from another website ({foreign}); the page '
                               f'answers only itself, at http://{request.host}/')
    try:
        response = await handler(request)
        if token is not None and request.query.get('token') and not response.prepared:
            response.set_cookie(TOKEN_COOKIE, token, httponly=True, samesite='Strict', path='/')
        return response
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
    except Exception as exc:  # the page's server outlives any one request
        log.exception('request %s %s failed', request.method, request.path)
        return _error(500, f'internal error: {type(exc).__name__}: {exc}')


async def _json_body(request: web.Request):
    if request.content_type != 'application/json':
        raise RequestError(f'send the request body as JSON (Content-Type: application/json); '
                           f'got {request.content_type!r}', status=415)
    return parse_json_body(await request.read())


def parse_json_body(raw: bytes):
    """A request body -> its JSON value; RequestError (400) for anything else: not UTF-8,
    not JSON, nested too deep for the parser (an empty body is {})."""
    try:
        text = raw.decode('utf-8')
    except UnicodeDecodeError as exc:
        raise RequestError(f'the body is not UTF-8 text: {exc}') from None
    if not text.strip():
        return {}
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise RequestError(f'the body is not valid JSON: {exc}') from None
    except RecursionError:
        raise RequestError('the body is not valid JSON here: nested too deep') from None


def make_app(state: PageState, bridge: Bridge, allowed_hosts=LOOPBACK_HOSTS,
             token: str | None = None) -> web.Application:
    """`allowed_hosts`: the names the Host header may give (None: any, for a server bound
    to another interface on purpose, which then needs a `token`)."""
    if allowed_hosts is None and not token:
        raise ValueError('a server that answers any Host needs a token')
    app = web.Application(middlewares=[api_errors], client_max_size=64 * 1024)
    app[ALLOWED_HOSTS] = None if allowed_hosts is None else tuple(allowed_hosts)
    app[WEBSOCKETS] = {}
    app[TOKEN] = token or None

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

    async def job_plot(request):
        """The noise plot a succeeded calibration wrote (only the file its result names)."""
        try:
            job_id = int(request.match_info['id'])
        except ValueError:
            raise RequestError(f'job {request.match_info["id"]!r}: expected a job number') from None
        path = state.job_plot_path(job_id)
        if path is None or not Path(path).is_file():
            raise RequestError(f'job {job_id} has no noise plot', status=404)
        return web.FileResponse(path, headers={'Cache-Control': 'no-store'})

    async def classify(request):
        fields = classify_request(await _json_body(request))
        state.begin_classify()
        try:
            answer = await bridge.classify(**fields)
        except GraphUnavailable as exc:   # a failure the history keeps too
            state.on_classify_answer({'success': False, 'message': str(exc)})
            raise
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

    async def cancel(request):
        await _json_body(request)   # JSON like every POST: no other site posts it unasked
        if not await bridge.cancel_job():
            raise RequestError('no capture or calibration is running', status=409)
        return web.json_response({'cancelling': True})

    async def activate(request):
        await _json_body(request)
        return web.json_response({'state': await bridge.activate(request.match_info['node'])})

    async def sender(ws, queue: asyncio.Queue, transport):
        """One reader's states, in order; a reader that takes longer than SEND_TIMEOUT_S for
        one is dropped (its connection aborted), never waited for by the others."""
        while True:
            text = await queue.get()
            try:
                await asyncio.wait_for(ws.send_str(text), SEND_TIMEOUT_S)
            except (asyncio.TimeoutError, ConnectionError, RuntimeError):
                if transport is not None:
                    transport.abort()
                return

    async def events(request):
        ws = web.WebSocketResponse(heartbeat=20.0, max_msg_size=4096)
        await ws.prepare(request)
        queue: asyncio.Queue = asyncio.Queue(SEND_QUEUE)
        queue.put_nowait(json.dumps(state.snapshot()))   # all of it, then the changes
        task = asyncio.create_task(sender(ws, queue, request.transport))
        app[WEBSOCKETS][ws] = (queue, request.transport)
        try:
            async for msg in ws:  # the page sends nothing; this waits for it to go
                if msg.type == WSMsgType.ERROR:
                    break
        finally:
            app[WEBSOCKETS].pop(ws, None)
            task.cancel()
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
    app.router.add_post('/api/nodes/{node}/activate', activate)
    app.router.add_get('/api/jobs/{id}/plot.png', job_plot)
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
                for ws, (queue, transport) in list(app[WEBSOCKETS].items()):
                    try:
                        queue.put_nowait(text)
                    except asyncio.QueueFull:   # it does not keep up: dropped, the others go on
                        log.warning('an /api/events reader fell %d states behind: dropped', SEND_QUEUE)
                        app[WEBSOCKETS].pop(ws, None)
                        if transport is not None:
                            transport.abort()
            await asyncio.sleep(PUSH_PERIOD_S)

    async def pusher(app_):
        task = asyncio.create_task(push(app_))
        yield
        task.cancel()
        for ws in list(app[WEBSOCKETS]):
            try:
                await asyncio.wait_for(ws.close(), 1.0)
            except (asyncio.TimeoutError, ConnectionError, RuntimeError):
                pass

    app.cleanup_ctx.append(pusher)
    return app


def guard_connections(server: web.Server, limit: int = MAX_CONNECTIONS,
                      header_timeout_s: float = HEADER_TIMEOUT_S) -> None:
    """Bound `server`'s (an AppRunner's `.server`) open connections to `limit` (one more is
    closed at once) and close a connection that has not sent a whole request head within
    `header_timeout_s` (a half-open or trickling client holds no socket for long)."""
    made, lost = server.connection_made, server.connection_lost
    open_: set = set()
    refused = {'n': 0, 'logged': 0.0}

    def connection_made(handler, transport) -> None:
        made(handler, transport)
        loop = asyncio.get_running_loop()
        if len(open_) >= limit:
            refused['n'] += 1
            if loop.time() - refused['logged'] > 10.0:
                log.warning('%d connections open (the limit): %d refused', limit, refused['n'])
                refused['logged'] = loop.time()
            transport.abort()
            return
        open_.add(handler)

        def no_request_yet() -> None:
            # aiohttp counts a request once its head is parsed
            if handler in open_ and getattr(handler, '_request_count', 1) == 0:
                transport.abort()
        loop.call_later(header_timeout_s, no_request_yet)

    def connection_lost(handler, exc) -> None:
        open_.discard(handler)
        lost(handler, exc)

    server.connection_made = connection_made
    server.connection_lost = connection_lost
