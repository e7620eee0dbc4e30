"""A headless Chromium driven over the Chrome DevTools Protocol, for tests of the live view and the report page.

Chromium comes from the distribution's packages (.ci/run installs it when missing); nothing else is needed: the
protocol is JSON over a WebSocket, spoken here with aiohttp (a dependency already). The browser runs with its own
throw-away profile, loopback only, and is stopped by its PID.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import itertools
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import aiohttp
import pytest

CANDIDATES = ("chromium", "chromium-browser", "google-chrome")


def chromium() -> str:
    """The browser's executable; without one the test is skipped, unless SWARM_REQUIRE_BROWSER is set (CI)."""
    for name in CANDIDATES:
        path = shutil.which(name)
        if path is not None:
            return path
    if os.environ.get("SWARM_REQUIRE_BROWSER"):
        pytest.fail("no Chromium: apt-get install chromium")
    pytest.skip("no Chromium (apt-get install chromium): the browser tests need it")


def group_gone(pgid: int, timeout_s: float) -> None:
    """Wait until no process of group ``pgid`` (one this module started) is left, SIGKILLing what remains after
    ``timeout_s`` and waiting as long again. A helper ended but not yet reaped still counts, so this also waits
    for its reaping."""
    for last in (False, True):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                os.killpg(pgid, 0)
            except ProcessLookupError:
                return
            time.sleep(0.05)
        if not last:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(pgid, signal.SIGKILL)


class Browser:
    """One headless tab; ``evaluate`` runs JavaScript in the page and returns its (JSON) value."""

    def __init__(self, width: int = 1400, height: int = 900) -> None:
        self._profile = tempfile.TemporaryDirectory(prefix="swarm-browser-")
        flags = ["--headless=new", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader",
                 "--use-angle=swiftshader", "--no-first-run", "--disable-extensions",
                 # nothing in the background: no component updates or sync writing into the profile, no connections
                 # refused by a closed network
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--remote-debugging-address=127.0.0.1", "--remote-debugging-port=0",
                 f"--user-data-dir={self._profile.name}", f"--window-size={width},{height}"]  # fmt: skip
        # Its own session (process group): Chromium's helpers (renderer, GPU, crash handler) write into the profile
        # too, and the profile can only be removed once every one of them has ended.
        self.proc = subprocess.Popen([chromium(), *flags, "about:blank"], stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL, start_new_session=True)  # fmt: skip
        self._ids = itertools.count(1)
        self._loop = asyncio.new_event_loop()
        self._session: aiohttp.ClientSession | None = None
        self._ws: aiohttp.ClientWebSocketResponse | None = None
        self._loop.run_until_complete(self._connect())

    async def _connect(self) -> None:
        port_file = Path(self._profile.name) / "DevToolsActivePort"
        deadline = time.monotonic() + 30.0
        while not port_file.exists() or not port_file.read_text().strip():
            if time.monotonic() > deadline or self.proc.poll() is not None:
                raise RuntimeError("Chromium did not open its debugging port")
            await asyncio.sleep(0.1)
        port = int(port_file.read_text().split()[0])
        self._session = aiohttp.ClientSession()
        async with self._session.get(f"http://127.0.0.1:{port}/json/list") as response:
            pages = [t for t in await response.json() if t["type"] == "page"]
        self._ws = await self._session.ws_connect(pages[0]["webSocketDebuggerUrl"], max_msg_size=0)

    async def _call(self, method: str, **params: Any) -> dict[str, Any]:
        assert self._ws is not None
        ident = next(self._ids)
        await self._ws.send_str(json.dumps({"id": ident, "method": method, "params": params}))
        while True:
            msg = json.loads((await self._ws.receive(timeout=60)).data)
            if msg.get("id") == ident:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return dict(msg["result"])

    def call(self, method: str, **params: Any) -> dict[str, Any]:
        return self._loop.run_until_complete(self._call(method, **params))

    def open(self, url: str) -> None:
        self.call("Page.navigate", url=url)

    def evaluate(self, expression: str) -> Any:
        """The value of ``expression`` in the page (awaited if a promise); JavaScript errors raise."""
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        if "exceptionDetails" in result:
            raise RuntimeError(f"{expression}: {result['exceptionDetails'].get('text')}")
        return result["result"].get("value")

    def wait_for(self, expression: str, timeout_s: float) -> Any:
        """Poll ``expression`` until it is truthy (page errors while it loads count as not yet)."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                value = self.evaluate(expression)
            except RuntimeError:
                value = None
            if value:
                return value
            if time.monotonic() > deadline:
                raise TimeoutError(f"{expression} not true within {timeout_s:g} s")
            time.sleep(0.1)

    def screenshot(self, path: Path) -> None:
        path.write_bytes(base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"]))

    def close(self) -> None:
        """Close the browser as a user would (it flushes its profile and ends its helpers), then make sure every
        process of its group has ended before removing the profile: removing it under a helper still writing there
        fails with "Directory not empty"."""

        async def done() -> None:
            if self._ws is not None:
                with contextlib.suppress(Exception):
                    await asyncio.wait_for(self._call("Browser.close"), 5.0)
                await self._ws.close()
            if self._session is not None:
                await self._session.close()

        self._loop.run_until_complete(done())
        self._loop.close()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(10)
        group_gone(self.proc.pid, 10.0)
        self._profile.cleanup()

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()
