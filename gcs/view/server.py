"""The live view's web server: the page, its static files, and a stream of frames to every tab that watches.

It runs aiohttp on an asyncio loop in a thread of its own, beside the supervisor's loop (a synchronous select loop,
or the lockstep clock), which only hands it the latest frame (``publish``: one reference swapped, no copy, no wait).
Each WebSocket client is woken by each frame the supervisor publishes (at most ``RATE_HZ`` a wall second, encoded
once for all clients) and gets the newest; a slow client skips frames rather than queueing them, so nothing a
browser does can slow the simulation or grow the supervisor's memory. Nobody watching, no frame is built. Why
aiohttp: it serves files and WebSockets from one small, well-kept asyncio library, and the project's other asyncio
code (the Python API, MAVSDK) already runs on asyncio loops in threads.

The socket is bound in the caller's thread, before anything flies, so a port in use or a bad address is one line
(``ViewError``) rather than an error in a thread nobody watches. Loopback by default.
"""

from __future__ import annotations

import asyncio
import json
import math
import socket
import threading
import time
from importlib import resources
from typing import TYPE_CHECKING, Any, Final

from gcs.mavlink.images import CameraImage

if TYPE_CHECKING:  # aiohttp is imported when a view is served: every `swarm` command would wait for it otherwise
    from aiohttp import web

RATE_HZ: Final = 10.0  # frames per second to each client, at most
WATCH_HOLD_S: Final = 3.0  # after the last /frame request, frames are still built this long
FRESH_WAIT_S: Final = 1.0  # /frame waits this long at most for a fresh frame after nobody watched
CAMERA_WANTED_S: Final = 3.0  # a drone's camera is asked for while a page has fetched its image this recently
DEFAULT_PORT: Final = 8765
DEFAULT_PORTS_TRIED: Final = 10  # without an explicit port: DEFAULT_PORT and the next ones, then any free port
STATIC = resources.files("gcs.view") / "static"


class ViewError(ValueError):
    """The view cannot be served (one line)."""


class ViewServer:
    """Serve the live view on ``host:port`` (port 0: any free port); ``url`` once started."""

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT) -> None:
        if not 0 <= port <= 65535:
            raise ViewError(f"view port must be 0..65535, got {port}")
        self.host, self.port = host, port
        self._frame: dict[str, Any] | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._runner: web.AppRunner | None = None
        self._stopping: asyncio.Event | None = None
        self.clients = 0
        # Camera images: the newest of each drone (set by the supervisor's thread), and when a page last asked for a
        # drone's (set by this server's thread, read by the supervisor's to decide whom to ask over MAVLink).
        self._images: dict[int, CameraImage] = {}
        self._camera_wanted: dict[int, float] = {}
        self._frame_asked_s = -math.inf  # when /frame was last asked for (wall clock, time.monotonic)
        self._frame_built_s = -math.inf  # when the newest frame was published
        self._published: asyncio.Future[None] | None = None  # resolved by the next publish (in the view's loop)
        self._encoded: tuple[dict[str, Any] | None, str] = (None, "")

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}/"

    def start(self) -> str:
        """Bind, then serve in a thread; the page's address."""
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            sock.bind((self.host, self.port))
        except OSError as exc:
            sock.close()
            raise ViewError(f"cannot serve the view on {self.host}:{self.port}: {exc.strerror}") from None
        sock.listen(16)
        self.port = sock.getsockname()[1]
        ready = threading.Event()
        self._thread = threading.Thread(target=self._serve, args=(sock, ready), name="view", daemon=True)
        self._thread.start()
        ready.wait(10.0)
        return self.url

    def publish(self, frame: dict[str, Any]) -> None:
        """The newest frame (the caller builds a fresh dict each time and does not touch it again)."""
        self._frame = frame
        self._frame_built_s = time.monotonic()
        loop = self._loop
        if self.clients and loop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(self._announce)

    def watched(self, now_wall_s: float) -> bool:
        """Whether anyone is looking: a page connected, or /frame asked for within WATCH_HOLD_S."""
        return self.clients > 0 or now_wall_s - self._frame_asked_s <= WATCH_HOLD_S

    def publish_image(self, image: CameraImage) -> None:
        self._images[image.sysid] = image

    def cameras_wanted(self, now_wall_s: float) -> list[int]:
        """The drones whose camera a page has asked for within CAMERA_WANTED_S (wall clock, ``time.monotonic``)."""
        return [sysid for sysid, t in list(self._camera_wanted.items()) if now_wall_s - t <= CAMERA_WANTED_S]

    def stop(self) -> None:
        loop, stopping = self._loop, self._stopping
        if loop is not None and stopping is not None and not loop.is_closed():
            loop.call_soon_threadsafe(stopping.set)
        if self._thread is not None:
            self._thread.join(10.0)

    # ---- in the view's thread -----------------------------------------------------------------------------------
    def _serve(self, sock: socket.socket, ready: threading.Event) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._main(sock, ready))
        finally:
            loop.close()

    async def _main(self, sock: socket.socket, ready: threading.Event) -> None:
        from aiohttp import web

        self._stopping = asyncio.Event()
        self._published = asyncio.get_running_loop().create_future()
        app = web.Application()
        app.router.add_get("/", self._index)
        app.router.add_get("/frame", self._latest)
        app.router.add_get("/ws", self._websocket)
        app.router.add_get("/camera/{sysid:[0-9]+}", self._camera)
        app.router.add_get("/static/{path:.+}", self._static)
        self._runner = web.AppRunner(app, access_log=None)
        await self._runner.setup()
        await web.SockSite(self._runner, sock).start()
        ready.set()
        await self._stopping.wait()
        await self._runner.cleanup()

    async def _index(self, _request: web.Request) -> web.StreamResponse:
        from aiohttp import web

        return web.Response(text=(STATIC / "index.html").read_text(), content_type="text/html")

    async def _static(self, request: web.Request) -> web.StreamResponse:
        from aiohttp import web

        parts = request.match_info["path"].split("/")
        if any(p in ("", ".", "..") for p in parts):
            raise web.HTTPNotFound()
        target = STATIC.joinpath(*parts)
        if not target.is_file():
            raise web.HTTPNotFound()
        kind = {"js": "text/javascript", "css": "text/css", "html": "text/html"}.get(parts[-1].rpartition(".")[2])
        return web.Response(body=target.read_bytes(), content_type=kind or "application/octet-stream")

    async def _latest(self, _request: web.Request) -> web.StreamResponse:
        """The newest frame; after a pause with nobody watching (no frame built), the next one, within a second."""
        from aiohttp import web

        asked = self._frame_asked_s = time.monotonic()
        if asked - self._frame_built_s > 2.0 / RATE_HZ:  # stale: wait for the feed to notice a page is watching
            while self._frame_built_s < asked and time.monotonic() - asked < FRESH_WAIT_S:
                await asyncio.sleep(0.02)
        return web.Response(text=self._text(self._frame) if self._frame is not None else "null",
                            content_type="application/json")  # fmt: skip

    async def _camera(self, request: web.Request) -> web.StreamResponse:
        """The newest image of drone ``sysid``'s camera (204 while there is none yet); asking for it is what makes
        the ground station request images from that drone, for CAMERA_WANTED_S."""
        from aiohttp import web

        sysid = int(request.match_info["sysid"])
        self._camera_wanted[sysid] = time.monotonic()
        image = self._images.get(sysid)
        if image is None:
            return web.Response(status=204, headers={"Cache-Control": "no-store"})
        headers = {"Cache-Control": "no-store", "X-Image-Time-S": f"{image.time_s:.3f}"}
        return web.Response(body=image.data, content_type=image.mime, headers=headers)

    def _announce(self) -> None:
        """In the view's loop: wake every client's task for the frame just published."""
        waiter, self._published = self._published, asyncio.get_running_loop().create_future()
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    def _text(self, frame: dict[str, Any]) -> str:
        """A frame's JSON, encoded once for every client."""
        if self._encoded[0] is not frame:
            self._encoded = (frame, json.dumps(frame, separators=(",", ":")))
        return self._encoded[1]

    async def _websocket(self, request: web.Request) -> web.StreamResponse:
        from aiohttp import web

        ws = web.WebSocketResponse(heartbeat=10.0)
        await ws.prepare(request)
        self.clients += 1
        reader = asyncio.ensure_future(self._drain(ws))
        try:
            sent: dict[str, Any] | None = None
            while not ws.closed and not reader.done():
                frame = self._frame
                if frame is not None and frame is not sent:
                    await ws.send_str(self._text(frame))  # a slow tab: the newest frame after this one, no queue
                    sent = frame
                if self._frame is sent:  # wait for the next one (each publish wakes every client)
                    assert self._published is not None
                    await asyncio.wait({self._published, reader}, timeout=1.0,
                                       return_when=asyncio.FIRST_COMPLETED)  # fmt: skip
        except (ConnectionError, RuntimeError):
            pass  # the tab went away mid-send
        finally:
            self.clients -= 1
            reader.cancel()
        return ws

    @staticmethod
    async def _drain(ws: web.WebSocketResponse) -> None:
        """Read what the page sends (nothing yet) so that its close is noticed."""
        from aiohttp import WSMsgType

        async for msg in ws:
            if msg.type in (WSMsgType.CLOSE, WSMsgType.ERROR):
                break


def serve_view(port: int | None, host: str = "127.0.0.1") -> ViewServer:
    """A started view server: on ``port`` (ViewError if it cannot be had), or with None on the first free port from
    DEFAULT_PORT on (several swarms on one machine each get their own page), else any free port."""
    if port is not None:
        server = ViewServer(host, port)
        server.start()
        return server
    for candidate in [*range(DEFAULT_PORT, DEFAULT_PORT + DEFAULT_PORTS_TRIED), 0]:
        server = ViewServer(host, candidate)
        try:
            server.start()
        except ViewError:
            continue
        return server
    raise ViewError(f"no free port to serve the view on {host}")
