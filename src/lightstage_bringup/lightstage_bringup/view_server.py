"""The Foxglove WebSocket protocol server of `lightstage view` (asyncio + aiohttp, no rclpy).

The part of the protocol a live ROS graph needs (github.com/foxglove/ws-protocol, the messages
foxglove_bridge sends): `serverInfo` (with the metadata ``ROS_DISTRO``, which Foxglove reads to
decode ROS 2 types), `advertise` / `unadvertise` of channels, the client's `subscribe` /
`unsubscribe`, and each message as a binary `messageData` frame (opcode 1, subscription id
u32, log time u64 [ns], payload), little-endian.

Why not foxglove-sdk's server: its handshake accepts only the subprotocol names
``foxglove.sdk.v1`` / ``foxglove.sdk.v1.1`` (0.30.3, the latest release; its
`websocket/handshake.rs`), so Foxglove's own client library (@foxglove/ws-protocol 0.8.0) and
Lichtblick releases before its ``foxglove.sdk.v1`` support, which offer only
``foxglove.websocket.v1``, get HTTP 400; it has no serverInfo metadata and no check of the
Host and Origin headers. Foxglove says the two names carry the same messages, so both are
served here, whichever the client offers first.

Guarded against other websites (a browser lets any page open a WebSocket to 127.0.0.1):
a request whose Host is not one of the server's own names (DNS rebinding) or whose Origin is
not allowed gets HTTP 403 before the upgrade. Allowed origins: none (a program, not a
page), the loopback names with any port and scheme (a self-hosted Lichtblick or Foxglove
page), ``file://`` (the desktop apps), the Foxglove web app, and those given
(`lightstage view --allow-origin`).

A slow client loses its oldest messages (at most `backlog` messages and `backlog_bytes` queued
per client), never stalls the graph or the other clients; one that does not take the control
messages (advertise, status) is disconnected.
"""
from __future__ import annotations

import asyncio
import collections
import concurrent.futures
import ipaddress
import json
import struct
import threading
import time
from dataclasses import dataclass, field
from urllib.parse import urlsplit

from aiohttp import WSMsgType, web

SUBPROTOCOLS = ('foxglove.sdk.v1', 'foxglove.websocket.v1')
MESSAGE_DATA = 0x01
LOOPBACK_NAMES = ('localhost', '127.0.0.1', '::1')
# the web apps that open a Foxglove WebSocket connection from a browser
APP_ORIGINS = ('https://app.foxglove.dev',)
DEFAULT_BACKLOG = 1024   # messages queued per client (foxglove-sdk's default) ...
DEFAULT_BACKLOG_BYTES = 64 << 20   # ... and bytes (20 full-size 1440 x 1080 mono16 images)


def host_name(value: str) -> str:
    """'Host' header -> the name without the port ('[::1]:8765' -> '::1'), lower case."""
    value = value.strip().lower()
    if value.startswith('['):
        return value[1:value.find(']')] if ']' in value else value
    return value.rsplit(':', 1)[0] if value.count(':') == 1 else value


def is_loopback_name(name: str) -> bool:
    if name == 'localhost' or name.endswith('.localhost'):
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False


@dataclass
class Guard:
    """Which Host and Origin headers a connection may come with."""
    hosts: tuple[str, ...] = ()            # names besides the loopback ones (e.g. the bound address)
    origins: tuple[str, ...] = APP_ORIGINS  # besides loopback pages and file://

    def refusal(self, host: str | None, origin: str | None) -> str:
        """Why a request with these headers is refused, '' when it is not."""
        name = host_name(host or '')
        if not (is_loopback_name(name) or name in {h.lower() for h in self.hosts}):
            return (f'Host {host!r} is not this server\'s (a loopback name'
                    + (f' or {", ".join(self.hosts)}' if self.hosts else '')
                    + '); connect to ws://127.0.0.1:PORT, or allow the name with --allow-host')
        if origin is None:
            return ''   # not a browser page
        origin = origin.strip().lower()
        if origin == 'file://' or origin.rstrip('/') in {o.lower().rstrip('/') for o in self.origins}:
            return ''
        parts = urlsplit(origin)
        if parts.scheme in ('http', 'https') and is_loopback_name((parts.hostname or '').lower()):
            return ''
        return (f'Origin {origin!r} may not connect (a page of another website); allow it with '
                '--allow-origin if it is a Foxglove or Lichtblick app you trust')


@dataclass
class _Channel:
    id: int
    topic: str
    encoding: str
    schema_name: str
    schema: str
    schema_encoding: str

    def advertised(self) -> dict:
        return {'id': self.id, 'topic': self.topic, 'encoding': self.encoding,
                'schemaName': self.schema_name, 'schema': self.schema,
                'schemaEncoding': self.schema_encoding}


@dataclass(eq=False)   # a connection: hashed by identity
class _Client:
    ws: web.WebSocketResponse
    backlog: int
    backlog_bytes: int
    subscriptions: dict[int, int] = field(default_factory=dict)   # subscription id -> channel id
    control: collections.deque = field(default_factory=collections.deque)
    data: collections.deque = field(default_factory=collections.deque)
    ready: asyncio.Event = field(default_factory=asyncio.Event)
    dropped: int = 0
    queued_bytes: int = 0

    def send_json(self, message: dict) -> None:
        if len(self.control) >= self.backlog:
            raise OverflowError('the client does not read its control messages')
        self.control.append(json.dumps(message, separators=(',', ':')))
        self.ready.set()

    def send_data(self, frame: bytes) -> None:
        self.data.append(frame)
        self.queued_bytes += len(frame)
        while len(self.data) > 1 and (len(self.data) > self.backlog
                                      or self.queued_bytes > self.backlog_bytes):
            self.queued_bytes -= len(self.data.popleft())
            self.dropped += 1
        self.ready.set()

    def next_data(self) -> bytes:
        frame = self.data.popleft()
        self.queued_bytes -= len(frame)
        return frame


class FoxgloveServer:
    """`add_channel` and `log` may be called from any thread; the server runs on its own
    asyncio loop (`start` starts a thread for it)."""

    def __init__(self, name: str, *, metadata: dict[str, str] | None = None,
                 guard: Guard | None = None, backlog: int = DEFAULT_BACKLOG,
                 backlog_bytes: int = DEFAULT_BACKLOG_BYTES, report=None):
        self.name = name
        self.metadata = dict(metadata or {})
        self.guard = guard or Guard()
        self.backlog, self.backlog_bytes = backlog, backlog_bytes
        self.report = report               # report(text): each distinct refusal, once
        self._reported: set[str] = set()
        self.session_id = str(time.time_ns())
        self.port: int | None = None
        self._channels: dict[int, _Channel] = {}
        self._next_channel = 1
        self._lock = threading.Lock()      # _channels and _next_channel, from any thread
        self._clients: set[_Client] = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._runner: web.AppRunner | None = None

    # ------------------------------------------------------------------ life
    def start(self, host: str, port: int) -> int:
        """Listen on host:port (0: any free port) in a thread of its own; the port. OSError
        when the address cannot be bound."""
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name='foxglove-server',
                                        daemon=True)
        self._thread.start()
        try:
            self.port = asyncio.run_coroutine_threadsafe(self._listen(host, port), self._loop).result()
        except BaseException:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join()
            raise
        return self.port

    async def _listen(self, host: str, port: int) -> int:
        app = web.Application()
        app.router.add_get('/', self._handle)
        self._runner = web.AppRunner(app, handle_signals=False, access_log=None)
        await self._runner.setup()
        site = web.TCPSite(self._runner, host, port)
        try:
            await site.start()
        except BaseException:
            await self._runner.cleanup()
            raise
        return self._runner.addresses[0][1]

    def stop(self) -> None:
        if self._loop is None:
            return
        if self._runner is not None:
            try:   # a client that does not answer the close handshake is not waited for longer
                asyncio.run_coroutine_threadsafe(self._close(), self._loop).result(timeout=10)
            except concurrent.futures.TimeoutError:
                pass
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout=10)
        self._loop = None

    async def _close(self) -> None:
        await asyncio.gather(*(c.ws.close() for c in list(self._clients)), return_exceptions=True)
        await self._runner.cleanup()

    # ------------------------------------------------------------------ from any thread
    def add_channel(self, topic: str, *, encoding: str, schema_name: str, schema: str,
                    schema_encoding: str) -> int:
        """A new channel, advertised to every client now and to each that connects later."""
        with self._lock:
            channel = _Channel(self._next_channel, topic, encoding, schema_name, schema, schema_encoding)
            self._next_channel += 1
            self._channels[channel.id] = channel
        self._call(self._broadcast, {'op': 'advertise', 'channels': [channel.advertised()]})
        return channel.id

    def log(self, channel_id: int, payload: bytes, log_time_ns: int) -> None:
        """Send `payload` to every client subscribed to the channel."""
        self._call(self._dispatch, channel_id, bytes(payload), int(log_time_ns))

    def _call(self, fn, *args) -> None:
        if self._loop is not None:
            self._loop.call_soon_threadsafe(fn, *args)

    # ------------------------------------------------------------------ on the loop
    def _broadcast(self, message: dict) -> None:
        for client in list(self._clients):
            self._send_json(client, message)

    def _send_json(self, client: _Client, message: dict) -> None:
        try:
            client.send_json(message)
        except OverflowError:
            self._clients.discard(client)
            asyncio.ensure_future(client.ws.close(message=b'too slow: control messages not read'))

    def _dispatch(self, channel_id: int, payload: bytes, log_time_ns: int) -> None:
        for client in self._clients:
            for sub_id, subscribed in client.subscriptions.items():
                if subscribed == channel_id:
                    client.send_data(struct.pack('<BIQ', MESSAGE_DATA, sub_id, log_time_ns) + payload)

    async def _handle(self, request: web.Request):
        why = self.guard.refusal(request.headers.get('Host'), request.headers.get('Origin'))
        if why:
            if self.report is not None and why not in self._reported and len(self._reported) < 100:
                self._reported.add(why)
                self.report(f'refused a connection: {why}')
            return web.Response(status=403, text=why + '\n')
        offered = [p.strip() for h in request.headers.getall('Sec-WebSocket-Protocol', [])
                   for p in h.split(',')]
        chosen = next((p for p in offered if p in SUBPROTOCOLS), None)
        if chosen is None:
            return web.Response(status=400, text=f'offer the WebSocket subprotocol {SUBPROTOCOLS[1]} '
                                                 f'or {SUBPROTOCOLS[0]} (the Foxglove protocol)\n')
        # no per-message compression: images do not shrink enough to pay for it in Python
        ws = web.WebSocketResponse(protocols=(chosen,), max_msg_size=1 << 20, compress=False)
        await ws.prepare(request)
        client = _Client(ws, self.backlog, self.backlog_bytes)
        with self._lock:
            channels = [c.advertised() for c in self._channels.values()]
        client.send_json({'op': 'serverInfo', 'name': self.name, 'capabilities': [],
                          'supportedEncodings': [], 'metadata': self.metadata,
                          'sessionId': self.session_id})
        client.send_json({'op': 'advertise', 'channels': channels})
        self._clients.add(client)
        writer = asyncio.ensure_future(self._write(client))
        try:
            async for message in ws:
                if message.type == WSMsgType.TEXT:
                    self._on_text(client, message.data)
                elif message.type == WSMsgType.BINARY:
                    self._status(client, 1, 'this server takes no client messages (binary)')
        finally:
            self._clients.discard(client)
            writer.cancel()
        return ws

    async def _write(self, client: _Client) -> None:
        try:
            while not client.ws.closed:
                await client.ready.wait()
                client.ready.clear()
                while client.control or client.data:
                    if client.control:
                        await client.ws.send_str(client.control.popleft())
                    else:
                        await client.ws.send_bytes(client.next_data())
        except (ConnectionError, RuntimeError):
            pass   # the client went away: its handler ends it

    def _status(self, client: _Client, level: int, text: str) -> None:
        self._send_json(client, {'op': 'status', 'level': level, 'message': text})   # 0 info 1 warn 2 error

    def _on_text(self, client: _Client, text: str) -> None:
        try:
            message = json.loads(text)
            op = message['op']
        except (ValueError, TypeError, KeyError):
            self._status(client, 2, f'not a JSON message with an "op": {text[:80]!r}')
            return
        if op == 'subscribe':
            for sub in message.get('subscriptions', []):
                try:
                    sub_id, channel_id = int(sub['id']), int(sub['channelId'])
                except (KeyError, TypeError, ValueError):
                    self._status(client, 2, f'a subscription needs "id" and "channelId": {sub!r}')
                    continue
                if sub_id in client.subscriptions:
                    self._status(client, 2, f'subscription id {sub_id} is in use; ignored')
                elif channel_id not in self._channels:
                    self._status(client, 2, f'no channel {channel_id}; subscription {sub_id} ignored')
                else:
                    client.subscriptions[sub_id] = channel_id
        elif op == 'unsubscribe':
            for sub_id in message.get('subscriptionIds', []):
                client.subscriptions.pop(sub_id, None)
        else:
            self._status(client, 1, f'operation {op!r} is not offered by this server (capabilities: none)')
