"""The local control channel between ``swarm`` commands and a running ``swarm up`` supervisor.

One JSON object per line over TCP on 127.0.0.1 (loopback only): a request ``{"cmd": "status", ...}`` gets one
response ``{"ok": true, ...}`` or ``{"ok": false, "error": "..."}``. The supervisor writes its port to a state file
so commands from another terminal find it; the file is removed on exit. The server side is non-blocking and is
polled from the supervisor's loop, so a slow client cannot stall the swarm.
"""

from __future__ import annotations

import contextlib
import json
import os
import selectors
import socket
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

MAX_REQUEST_BYTES = 65536
CLIENT_TIMEOUT_S = 30.0

Handler = Callable[[dict[str, Any]], dict[str, Any]]


def state_file(environ: Mapping[str, str] = os.environ) -> Path:
    """Where a running supervisor publishes its control port (one supervisor per user), in ``environ`` (a client
    in the same process as several supervisors, as the tests are, passes each one's own)."""
    base = environ.get("SWARM_STATE_DIR") or environ.get("XDG_RUNTIME_DIR") or str(Path.home() / ".cache")
    return Path(base) / "swarmsitl" / "supervisor.json"


class ControlError(RuntimeError):
    """No supervisor, or it did not answer: one line for the user."""


class ControlServer:
    def __init__(self, handler: Handler, path: Path | None = None) -> None:
        self.handler = handler
        self.path = path or state_file()
        if self.path.exists():
            try:
                ControlClient(self.path).request({"cmd": "ping"}, timeout_s=1.0)
            except ControlError:
                pass  # a stale file from a supervisor that died: take over
            else:
                raise ControlError(f"a swarm supervisor is already running (see {self.path})")
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.sock.setblocking(False)
        self._selector = selectors.DefaultSelector()
        self._selector.register(self.sock, selectors.EVENT_READ, None)
        self._buffers: dict[socket.socket, bytearray] = {}
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.path.write_text(json.dumps({"port": self.port, "pid": os.getpid()}))

    @property
    def port(self) -> int:
        return int(self.sock.getsockname()[1])

    def poll(self) -> None:
        """Accept connections and answer complete requests; never blocks."""
        for key, _ in self._selector.select(0):
            if key.fileobj is self.sock:
                try:
                    conn, _addr = self.sock.accept()
                except OSError:
                    continue
                conn.setblocking(False)
                self._buffers[conn] = bytearray()
                self._selector.register(conn, selectors.EVENT_READ, None)
                continue
            conn = key.fileobj  # type: ignore[assignment]
            try:
                data = conn.recv(MAX_REQUEST_BYTES)
            except OSError:
                data = b""
            buf = self._buffers.get(conn)
            if not data or buf is None:
                self._drop(conn)
                continue
            buf += data
            if b"\n" in buf or len(buf) > MAX_REQUEST_BYTES:
                self._answer(conn, bytes(buf.split(b"\n", 1)[0]))

    def _answer(self, conn: socket.socket, line: bytes) -> None:
        try:
            request = json.loads(line)
            if not isinstance(request, dict) or not isinstance(request.get("cmd"), str):
                raise ValueError("request must be a JSON object with a 'cmd' string")
            response = self.handler(request)
        except (ValueError, TypeError) as exc:
            response = {"ok": False, "error": str(exc)}
        try:
            conn.setblocking(True)
            conn.settimeout(2.0)
            conn.sendall(json.dumps(response).encode() + b"\n")
        except OSError:
            pass
        self._drop(conn)

    def _drop(self, conn: socket.socket) -> None:
        self._buffers.pop(conn, None)
        with contextlib.suppress(KeyError, ValueError):
            self._selector.unregister(conn)
        conn.close()

    def close(self) -> None:
        for conn in list(self._buffers):
            self._drop(conn)
        self._selector.close()
        self.sock.close()
        try:
            if json.loads(self.path.read_text()).get("pid") == os.getpid():
                self.path.unlink()
        except (OSError, ValueError):
            pass


class ControlClient:
    def __init__(self, path: Path | None = None) -> None:
        self.path = path or state_file()

    def request(self, request: dict[str, Any], timeout_s: float = CLIENT_TIMEOUT_S) -> dict[str, Any]:
        try:
            port = int(json.loads(self.path.read_text())["port"])
        except (OSError, ValueError, KeyError, TypeError):
            raise ControlError("no swarm is running (start one with 'swarm up -n N')") from None
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=timeout_s) as conn:
                conn.sendall(json.dumps(request).encode() + b"\n")
                data = bytearray()
                while not data.endswith(b"\n"):
                    chunk = conn.recv(65536)
                    if not chunk:
                        break
                    data += chunk
        except OSError as exc:
            raise ControlError(f"the swarm supervisor on port {port} did not answer ({exc.strerror or exc})") from None
        try:
            response = json.loads(data)
        except ValueError:
            raise ControlError("the swarm supervisor sent an unreadable answer") from None
        if not isinstance(response, dict):
            raise ControlError("the swarm supervisor sent an unreadable answer")
        return response
