"""Drone processes forked by the drone factory (sitl/harness/zygote.py) instead of started from scratch.

``DroneFactory`` starts one ``python -m sitl.harness.zygote`` and asks it for drones; each comes back as a
``ForkedProcess``, which answers like ``subprocess.Popen`` (``pid``, ``poll``, ``wait``, ``send_signal``, ``kill``,
``returncode``) so the process group treats both alike. The drones are the factory's children: it reaps them and
reports their exit codes over its stdout, which ``collect`` reads. Signals go through a pidfd taken right after the
fork, so a signal can never reach another process that reused the PID of a drone already reaped.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import selectors
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

START_TIMEOUT_S = 60.0  # the factory imports the drone code once (about 0.5 s of CPU; far longer on a loaded machine)
CLOSE_WAIT_S = 8.0  # the factory's own grace period for its drones is 5 s


class FactoryError(RuntimeError):
    """The factory could not start or fork a drone; the message is one line."""


class ForkedProcess:
    """A drone forked by the factory, with the part of ``subprocess.Popen``'s interface the process group uses."""

    def __init__(self, pid: int, factory: DroneFactory) -> None:
        self.pid = pid
        self.returncode: int | None = None
        self._factory = factory
        self._pidfd: int | None = None
        with contextlib.suppress(OSError, AttributeError):
            self._pidfd = os.pidfd_open(pid)

    def poll(self) -> int | None:
        if self.returncode is None:
            self._factory.collect(0.0)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        deadline = math.inf if timeout is None else time.monotonic() + timeout
        while self.returncode is None:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise subprocess.TimeoutExpired(f"drone pid {self.pid}", timeout or 0.0)
            self._factory.collect(min(remaining, 0.1))
        return self.returncode

    def send_signal(self, sig: int) -> None:
        if self.returncode is not None:
            return  # reaped: the PID may belong to someone else now
        with contextlib.suppress(ProcessLookupError):
            if self._pidfd is not None:
                signal.pidfd_send_signal(self._pidfd, sig)
            else:
                os.kill(self.pid, sig)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)

    def _exited(self, code: int) -> None:
        self.returncode = code
        if self._pidfd is not None:
            os.close(self._pidfd)
            self._pidfd = None


class DroneFactory:
    def __init__(self, log_path: Path | None = None, preexec_fn: Callable[[], None] | None = None) -> None:
        errors: IO[bytes] | int = log_path.open("wb") if log_path is not None else subprocess.DEVNULL
        try:
            self._process = subprocess.Popen(
                [sys.executable, "-m", "sitl.harness.zygote"],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=errors,
                start_new_session=True,
                preexec_fn=preexec_fn,
            )
        finally:
            if not isinstance(errors, int):
                errors.close()
        assert self._process.stdin is not None and self._process.stdout is not None
        self._stdin = self._process.stdin
        self._stdout_fd = self._process.stdout.fileno()
        os.set_blocking(self._stdout_fd, False)
        self._selector = selectors.DefaultSelector()
        self._selector.register(self._stdout_fd, selectors.EVENT_READ)
        self._pending = b""
        self._replies: list[dict[str, Any]] = []
        self._drones: dict[int, ForkedProcess] = {}
        self._early_exits: dict[int, int] = {}
        self._closed = False
        self.log_path = log_path
        try:
            self._await_reply("ready", START_TIMEOUT_S)
        except BaseException:  # no answer, or interrupted (Ctrl-C, SIGTERM): nobody else knows of this process
            self._process.kill()
            self._process.wait()
            self._selector.close()
            self._process.stdout.close()
            self._stdin.close()
            raise

    @property
    def pid(self) -> int:
        return self._process.pid

    def spawn(self, argv: list[str], log: Path | None, nice: int) -> ForkedProcess:
        """Fork one drone running ``sitl.cli.main(argv)``; FactoryError when the factory cannot."""
        request = {"argv": argv, "log": str(log) if log is not None else None, "nice": nice}
        try:
            self._stdin.write((json.dumps(request) + "\n").encode())
            self._stdin.flush()
        except OSError:
            raise FactoryError(self._gone_message()) from None
        reply = self._await_reply("pid", START_TIMEOUT_S)
        pid = int(reply["pid"])
        drone = ForkedProcess(pid, self)
        self._drones[pid] = drone
        if pid in self._early_exits:  # it ended before its pid reply was read
            drone._exited(self._early_exits.pop(pid))
        return drone

    def collect(self, wait_s: float) -> None:
        """Read what the factory has said (exit codes, replies), waiting up to ``wait_s`` for the first word."""
        if self._closed:
            return
        if wait_s > 0 and not self._selector.select(wait_s):
            return
        while True:
            try:
                data = os.read(self._stdout_fd, 65536)
            except BlockingIOError:
                return
            if not data:  # the factory is gone: its drones got SIGTERM from the kernel (PR_SET_PDEATHSIG)
                self._closed = True
                for drone in self._drones.values():
                    if drone.returncode is None:
                        drone._exited(-signal.SIGTERM)
                return
            self._pending += data
            *lines, self._pending = self._pending.split(b"\n")
            for line in lines:
                self._note(json.loads(line))

    def _note(self, event: dict[str, Any]) -> None:
        if "exit" in event:
            pid, code = int(event["exit"]), int(event["code"])
            drone = self._drones.get(pid)
            if drone is not None:
                drone._exited(code)
            else:
                self._early_exits[pid] = code
        else:
            self._replies.append(event)

    def _await_reply(self, key: str, timeout_s: float) -> dict[str, Any]:
        deadline = time.monotonic() + timeout_s
        while True:
            for reply in self._replies:
                self._replies.remove(reply)
                if "error" in reply:
                    raise FactoryError(f"drone factory: {reply['error']}")
                if key in reply:
                    return reply
            if self._closed:
                raise FactoryError(self._gone_message())
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise FactoryError(f"drone factory (pid {self.pid}) did not answer within {timeout_s:g} s")
            self.collect(min(remaining, 0.1))

    def _gone_message(self) -> str:
        code = self._process.poll()
        detail = ""
        if self.log_path is not None and self.log_path.exists():
            lines = [ln for ln in self.log_path.read_text(errors="replace").splitlines() if ln.strip()]
            detail = f": {lines[-1]}" if lines else ""
        return f"drone factory exited with code {code}{detail}"

    def close(self) -> None:
        """Stop the factory (it stops any drone still running first) and reap it."""
        with contextlib.suppress(OSError):
            self._stdin.close()
        try:
            self._process.wait(timeout=CLOSE_WAIT_S)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()
        self.collect(0.0)
        self._selector.close()
        if self._process.stdout is not None:
            self._process.stdout.close()
