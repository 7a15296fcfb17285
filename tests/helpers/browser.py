"""Headless Chromium (Debian's `chromium`) driven over the Chrome DevTools protocol, for the
operator page's tests; and the checks on a screenshot. Only ever pointed at 127.0.0.1.

The CDP client is aiohttp's WebSocket client (aiohttp is the page server's framework, so no
other dependency): `Browser.start()` runs chromium with `--remote-debugging-port=0` (it writes
the port it took into DevToolsActivePort in its profile folder), `page()` attaches to its tab.
"""
from __future__ import annotations

import asyncio
import base64
import io
import itertools
import json
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np

CHROMIUM_FLAGS = ['--headless', '--no-sandbox', '--disable-gpu', '--no-first-run',
                  '--no-default-browser-check', '--disable-background-networking',
                  '--disable-component-update', '--disable-sync', '--disable-extensions',
                  '--disable-default-apps', '--metrics-recording-only', '--mute-audio',
                  '--remote-debugging-address=127.0.0.1', '--remote-debugging-port=0',
                  '--window-size=1400,1100', '--hide-scrollbars']


def chromium_path() -> str | None:
    return shutil.which('chromium')


class Page:
    """One tab, over its DevTools WebSocket."""

    def __init__(self, ws):
        self.ws = ws
        self._ids = itertools.count(1)

    async def send(self, method: str, **params) -> dict:
        call_id = next(self._ids)
        await self.ws.send_str(json.dumps({'id': call_id, 'method': method, 'params': params}))
        while True:
            message = json.loads((await self.ws.receive(timeout=30)).data)
            if message.get('id') == call_id:
                if 'error' in message:
                    raise RuntimeError(f'{method}: {message["error"]}')
                return message.get('result', {})

    async def evaluate(self, expression: str):
        """The value of a JavaScript expression in the page (awaited if a promise)."""
        r = await self.send('Runtime.evaluate', expression=expression, returnByValue=True,
                            awaitPromise=True)
        if 'exceptionDetails' in r:
            raise RuntimeError(f'{expression}: {r["exceptionDetails"]}')
        return r['result'].get('value')

    async def wait_for(self, expression: str, timeout_s: float, what: str):
        """Until the expression is truthy (polled); its value."""
        deadline = time.monotonic() + timeout_s
        while True:
            value = await self.evaluate(expression)
            if value:
                return value
            if time.monotonic() > deadline:
                raise AssertionError(f'timed out after {timeout_s:g} s waiting for {what}; the page '
                                     f'says: {await self.evaluate("document.body.innerText")}')
            await asyncio.sleep(0.1)

    async def screenshot(self, path: Path) -> bytes:
        data = base64.b64decode((await self.send('Page.captureScreenshot', format='png'))['data'])
        path.write_bytes(data)
        return data


class Browser:
    def __init__(self, profile: Path):
        self.profile = profile
        self.proc: subprocess.Popen | None = None
        self.session = None

    async def start(self, timeout_s: float = 30.0) -> None:
        import aiohttp
        # not a skip: the bootstrap installs it, and a page left untested must not pass unseen
        assert chromium_path(), ('Debian\'s chromium is not installed: run `bash scripts/bootstrap.sh --with test` '
                                 '(`make test` does)')
        self.profile.mkdir(parents=True, exist_ok=True)
        (self.profile / 'DevToolsActivePort').unlink(missing_ok=True)  # a previous browser's
        self.proc = subprocess.Popen([chromium_path(), *CHROMIUM_FLAGS,
                                      f'--user-data-dir={self.profile}', 'about:blank'],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        active = self.profile / 'DevToolsActivePort'
        deadline = time.monotonic() + timeout_s
        while not (active.is_file() and active.read_text().strip()):
            if self.proc.poll() is not None:
                raise RuntimeError(f'chromium exited ({self.proc.returncode}): '
                                   f'{self.proc.stderr.read().decode(errors="replace")[-2000:]}')
            assert time.monotonic() < deadline, 'chromium did not open its DevTools port'
            await asyncio.sleep(0.1)
        self.port = int(active.read_text().split()[0])
        self.session = aiohttp.ClientSession()

    async def page(self, timeout_s: float = 20.0) -> Page:
        import aiohttp
        deadline = time.monotonic() + timeout_s
        while True:  # the port file can come a moment before the port accepts
            try:
                async with self.session.get(f'http://127.0.0.1:{self.port}/json/list') as r:
                    targets = await r.json()
                break
            except aiohttp.ClientConnectionError:
                assert time.monotonic() < deadline, f'chromium\'s DevTools port {self.port} refuses'
                await asyncio.sleep(0.2)
        target = next(t for t in targets if t['type'] == 'page')
        ws = await self.session.ws_connect(target['webSocketDebuggerUrl'], max_msg_size=64 << 20)
        page = Page(ws)
        await page.send('Page.enable')
        await page.send('Runtime.enable')
        await page.send('Emulation.setDeviceMetricsOverride', width=1400, height=1100,
                        deviceScaleFactor=1, mobile=False)
        return page

    async def close(self) -> None:
        if self.session is not None:
            await self.session.close()
        if self.proc is not None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def screenshot_stats(png: bytes) -> dict:
    """What tells a rendered page from a blank one: size, gray-level spread, colours used."""
    from PIL import Image
    image = np.asarray(Image.open(io.BytesIO(png)).convert('RGB'))
    colours = np.unique(image.reshape(-1, 3)[::7], axis=0)
    return {'width': image.shape[1], 'height': image.shape[0], 'std': float(image.std()),
            'colours': len(colours)}
