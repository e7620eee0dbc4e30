"""A drone factory: one process that has imported the drone code once and forks a ready interpreter per drone.

Starting a drone with ``python -m sitl.cli`` costs some 0.5 s of CPU before it simulates anything: the interpreter,
numpy, JSBSim, pymavlink's message tables and OpenCV. Nine drones on two cores spent over two seconds of wall time on
that alone, fifty more than twelve. A fork of a process that already holds all of it costs a few milliseconds, and
the children share those pages copy-on-write instead of each holding its own copy (the factory freezes its objects
out of the garbage collector's sight before it forks, so the children's collections do not copy them).

The simulation harness (sitl/harness/processes.py) starts ``python -m sitl.harness.zygote`` and talks to it over its
stdin and stdout, one JSON object per line:

- request ``{"argv": [...], "log": PATH or null, "nice": N}``: fork a drone running ``sitl.cli.main(argv)`` with
  stdout and stderr in ``log`` (or /dev/null), at niceness ``nice``;
  answer ``{"pid": PID}``, or ``{"error": TEXT}`` when the fork failed;
- event ``{"exit": PID, "code": C}`` when a drone ends (``-SIGNUM`` when a signal ended it), as ``Popen.returncode``.

The children are the factory's, so it reaps them and reports their exit codes. Each child asks for SIGTERM when the
factory dies (``PR_SET_PDEATHSIG``), as the factory does for the supervisor; when its stdin closes, the factory stops
its children (SIGTERM, then SIGKILL after a grace period) and exits. It must not start threads before forking, so the
numerical libraries are told to use one thread before they are imported.
"""

from __future__ import annotations

import contextlib
import ctypes
import gc
import json
import os
import selectors
import signal
import sys
import time
import traceback
from typing import Any

from swarmcommon.process_end import ending

PR_SET_PDEATHSIG = 1
PR_SET_NAME = 15
REAP_INTERVAL_S = 0.05
STOP_GRACE_S = 5.0


def die_with_parent() -> None:
    """Ask the kernel for SIGTERM when the parent process dies (Linux PR_SET_PDEATHSIG); also used by the
    supervisor for the factory itself, between fork and exec."""
    with contextlib.suppress(OSError):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


def _preload() -> None:
    """Import everything a drone imports, so that forked drones start with it in memory."""
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    # The drone's whole import graph (simulation, autopilot, MAVLink, world), and OpenCV, which a drone imports
    # when its camera first runs.
    import sitl.cli
    import sitl.perception.detector
    import sitl.process.app  # noqa: F401

    # Everything imported so far goes into the collector's permanent generation: a drone's collections then never
    # walk (and so never write to) the objects it shares with the factory, and the pages that hold them stay shared.
    # A host of 25 drones held 95.8 MB (PSS) after a circle flight, 80.4 MB with this (docs/benchmark-history.md).
    gc.collect()
    gc.freeze()


def _lower_priority(nice: int) -> None:
    """Run this drone at niceness ``nice``, and the factory's whole session with it.

    With autogroup scheduling (Linux's default on desktops and many servers, /proc/sys/kernel/sched_autogroup_enabled)
    the CPU is first shared equally between sessions, and a process's nice value only ranks it within its own
    session. Drones that each called setsid() therefore each got one session's share, exactly as much as the
    supervisor: with 50 drones on two cores the supervisor got 4 % of the CPU whatever the drones' nice value, and
    the swarm never became ready. So the drones stay in the factory's session (which the supervisor starts apart from
    its own, so that Ctrl-C in a terminal reaches the supervisor alone), and that session's own niceness is lowered
    through /proc/self/autogroup: the supervisor keeps its priority over the whole swarm. Without autogroup the file
    is absent and the process's nice value does the same job. The kernel limits unprivileged writes to one per 100
    ms; the value is the same for every drone, so a refused write changes nothing."""
    with contextlib.suppress(OSError):
        os.nice(nice)
    with contextlib.suppress(OSError), open("/proc/self/autogroup", "w") as autogroup:
        autogroup.write(str(nice))


def process_name(argv: list[str]) -> str:
    """The name top and ps -o comm show for a drone process: ``sitl-3`` for instance 3, ``sitl-0-24`` for a host of
    instances 0 to 24 (the kernel keeps 15 characters)."""
    for flag in ("--instance", "--instances"):
        if flag in argv[:-1]:
            return f"sitl-{argv[argv.index(flag) + 1]}"
    return "sitl-?"


def _child(argv: list[str], log: str | None, nice: int) -> None:
    """Runs in the forked child; never returns."""
    code = 1
    try:
        die_with_parent()
        # The command line stays the factory's; the name top and ps -o comm show says which drone this is.
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_NAME, process_name(argv).encode()[:15])
        if os.getppid() == 1:  # the factory died between the fork and the line above
            os._exit(1)
        _lower_priority(nice)
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGCHLD):
            signal.signal(sig, signal.SIG_DFL)
        stdin = os.open(os.devnull, os.O_RDONLY)
        out = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644) if log else os.open(os.devnull, os.O_WRONLY)
        os.dup2(stdin, 0)
        os.dup2(out, 1)
        os.dup2(out, 2)
        os.close(stdin)
        os.close(out)
        from sitl.cli import main

        code = main(argv)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    except BaseException:
        traceback.print_exc()
    finally:
        with contextlib.suppress(Exception):
            sys.stdout.flush()
            sys.stderr.flush()
        os._exit(code)


class Factory:
    def __init__(self) -> None:
        self.children: set[int] = set()

    def reply(self, obj: dict[str, Any]) -> None:
        sys.stdout.write(json.dumps(obj) + "\n")
        sys.stdout.flush()

    def handle(self, line: bytes) -> None:
        try:
            request = json.loads(line)
        except (json.JSONDecodeError, UnicodeDecodeError):
            self.reply({"error": "bad request: not JSON"})
            return
        if isinstance(request, dict):
            self.fork(request)
        else:
            self.reply({"error": "bad request: not an object"})

    def fork(self, request: dict[str, Any]) -> None:
        argv = request.get("argv")
        log = request.get("log")
        nice = request.get("nice", 0)
        if (
            not isinstance(argv, list)
            or not all(isinstance(a, str) for a in argv)
            or not (log is None or isinstance(log, str))
            or not isinstance(nice, int)
        ):
            self.reply({"error": f"bad request: {request!r}"})
            return
        sys.stdout.flush()
        sys.stderr.flush()
        try:
            pid = os.fork()
        except OSError as exc:
            self.reply({"error": f"fork failed: {exc.strerror}"})
            return
        if pid == 0:
            _child(argv, log, nice)
        self.children.add(pid)
        self.reply({"pid": pid})

    def reap(self) -> None:
        for pid in list(self.children):
            try:
                done, status = os.waitpid(pid, os.WNOHANG)
            except ChildProcessError:
                self.children.discard(pid)
                continue
            if done:
                self.children.discard(pid)
                self.reply({"exit": pid, "code": os.waitstatus_to_exitcode(status)})

    def stop_all(self) -> None:
        for pid in self.children:
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGTERM)
        deadline = time.monotonic() + STOP_GRACE_S
        while self.children and time.monotonic() < deadline:
            time.sleep(0.02)
            self.reap()
        for pid in self.children:
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
        while self.children:
            time.sleep(0.01)
            self.reap()


def main() -> int:
    _preload()
    factory = Factory()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the supervisor's to handle
    selector = selectors.DefaultSelector()
    stdin = sys.stdin.fileno()
    selector.register(stdin, selectors.EVENT_READ)
    factory.reply({"ready": os.getpid()})
    pending = b""
    try:
        while True:
            if selector.select(REAP_INTERVAL_S):
                data = os.read(stdin, 65536)
                if not data:
                    break  # the supervisor closed the pipe (or died): stop
                pending += data
                *lines, pending = pending.split(b"\n")
                for line in lines:
                    factory.handle(line)
            factory.reap()
    finally:
        factory.stop_all()
    return 0


if __name__ == "__main__":
    sys.exit(ending(main))  # without the last collection over the drones' code (swarmcommon/process_end.py)
