"""Start, watch and stop `sitl` drone processes for the integration tests.

Policy, so that a suite run never disturbs anything else on the machine:
- loopback only: the drone binds 127.0.0.1 and streams to 127.0.0.1; the ground-station link streams to a sink
  socket this module owns, never to 14550 where a user's QGroundControl may listen;
- instance numbers come from a range far from the default instance 0 (see ``InstanceAllocator``), and an instance
  is used only after its three UDP ports were found free;
- readiness is the drone's first HEARTBEAT on its API port, never a sleep;
- every process started here is stopped by its PID (SIGTERM, then SIGKILL after a grace period) and reaped. The
  process also gets a parent-death signal, so a test runner killed with SIGKILL does not leave drones flying.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Final

from pymavlink.dialects.v20 import common as mavlink

from sitl.process.ports import MAX_INSTANCE, instance_ports
from sitl.world.shared import SharedWorld

LOOPBACK: Final = "127.0.0.1"
AUTOPILOT_COMPID: Final = 1
READY_TIMEOUT_S: Final = 30.0  # wall clock: Python + JSBSim start-up on a loaded 2-core machine
STOP_GRACE_S: Final = 10.0  # SIGTERM is answered within a loop iteration; SIGKILL after this
PR_SET_PDEATHSIG: Final = 1

# Runs in the child before the drone: ask the kernel for SIGTERM when the parent dies, then become the drone (same
# PID, so stopping by PID still works). The check of the parent PID closes the race of a parent dying before prctl.
_PDEATHSIG_EXEC: Final = (
    "import ctypes, os, signal, sys\n"
    f"ctypes.CDLL(None, use_errno=True).prctl({PR_SET_PDEATHSIG}, int(signal.SIGTERM), 0, 0, 0)\n"
    "if os.getppid() != int(sys.argv[1]):\n"
    "    sys.exit(3)\n"
    "os.execv(sys.argv[2], sys.argv[2:])\n"
)


class SitlStartError(RuntimeError):
    """The drone process exited or stayed silent instead of becoming ready."""


@dataclass(frozen=True, slots=True, kw_only=True)
class DronePorts:
    """The UDP ports of one instance, as the drone computes them (sitl/process/ports.py: PX4 SITL's below instance
    40)."""

    instance: int

    @property
    def sysid(self) -> int:
        return self.instance + 1

    @property
    def api_remote(self) -> int:
        return instance_ports(self.instance).api_remote

    @property
    def api_bind(self) -> int:
        return instance_ports(self.instance).api_bind

    @property
    def gcs_bind(self) -> int:
        return instance_ports(self.instance).gcs_bind

    def all(self) -> tuple[int, int, int]:
        return (self.api_remote, self.api_bind, self.gcs_bind)


def udp_port_is_free(port: int) -> bool:
    """True if nobody holds ``port`` on loopback (a bind to 127.0.0.1 also fails against a 0.0.0.0 holder)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.bind((LOOPBACK, port))
        except OSError:
            return False
    return True


USER_INSTANCES: Final = range(10)  # instances a user may run by hand while the suite runs
GCS_PORT: Final = 14550


def instance_is_clear_of_user_ports(instance: int) -> bool:
    """True if none of the instance's ports is one that a user's drones 0-9 or a ground station use."""
    ports = DronePorts(instance=instance).all()
    user_ports = {GCS_PORT} | {p for i in USER_INSTANCES for p in DronePorts(instance=i).all()}
    return instance not in USER_INSTANCES and not user_ports & set(ports)


class InstanceAllocator:
    """Hands out instance numbers from ``[base, base + span)`` round robin, skipping those with a busy port.

    Round robin rather than always the lowest free number, so that a test never receives stray datagrams still in
    flight to the ports of the previous test's drone.
    """

    def __init__(self, base: int, span: int) -> None:
        if base < 1 or span < 2 or base + span > MAX_INSTANCE + 1:
            raise ValueError(f"instance range {base}..{base + span - 1} must lie within 1..{MAX_INSTANCE}")
        self._base = base
        self._span = span
        self._next = 0
        self._taken: set[int] = set()

    def take(self, count: int = 1) -> list[int]:
        """``count`` adjacent instances whose ports are all free."""
        for _ in range(self._span):
            first = self._base + self._next
            self._next = (self._next + 1) % self._span
            block = list(range(first, first + count))
            if block[-1] >= self._base + self._span or any(self._unusable(i) for i in block):
                continue
            self._taken.update(block)
            return block
        raise SitlStartError(
            f"no {count} adjacent instances in {self._base}..{self._base + self._span - 1} have their UDP ports free"
        )

    def _unusable(self, instance: int) -> bool:
        return (
            instance in self._taken
            or not instance_is_clear_of_user_ports(instance)
            or not all(udp_port_is_free(p) for p in DronePorts(instance=instance).all())
        )

    def give_back(self, instance: int) -> None:
        self._taken.discard(instance)


def sitl_command() -> list[str]:
    """The venv's ``sitl`` console script next to this interpreter, else the module."""
    script = Path(sys.executable).with_name("sitl")
    if script.exists():
        return [str(script)]
    return [sys.executable, "-m", "sitl.cli"]


def first_heartbeat(sock: socket.socket, sysid: int, deadline: float, alive: Process | None = None) -> bytes:
    """Wait on ``sock`` for a HEARTBEAT from ``sysid``/compid 1; returns its raw datagram."""
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    while (remaining := deadline - time.monotonic()) > 0:
        if alive is not None:
            alive.raise_if_exited()
        sock.settimeout(min(remaining, 0.2))
        try:
            data, _ = sock.recvfrom(65535)
        except TimeoutError:
            continue
        for msg in parser.parse_buffer(data) or []:
            if (
                msg.get_type() == "HEARTBEAT"
                and msg.get_srcSystem() == sysid
                and msg.get_srcComponent() == AUTOPILOT_COMPID
            ):
                return data
    raise TimeoutError(f"no HEARTBEAT from sysid {sysid} within the deadline")


class Process:
    """One running ``sitl``; stop() is idempotent and always reaps."""

    def __init__(
        self, popen: subprocess.Popen[bytes], log_path: Path, log_file: IO[bytes], host_log: Path | None = None
    ) -> None:
        self.popen = popen
        self.log_path = log_path  # a hosted drone's own log; the host's stdout and stderr go to ``host_log``
        self._log_file = log_file
        self._host_log = host_log

    @property
    def pid(self) -> int:
        return self.popen.pid

    def alive(self) -> bool:
        return self.popen.poll() is None

    def log_tail(self, lines: int = 30) -> str:
        if not self._log_file.closed:
            self._log_file.flush()
        text = self.log_path.read_text(errors="replace") if self.log_path.exists() else ""
        if self._host_log is not None:
            text += f"\n--- host log {self._host_log.name} ---\n" + self._host_log.read_text(errors="replace")
        return "\n".join(text.splitlines()[-lines:])

    def raise_if_exited(self) -> None:
        code = self.popen.poll()
        if code is not None:
            raise SitlStartError(f"sitl (pid {self.pid}) exited with code {code}; log:\n{self.log_tail()}")

    def signal(self, sig: signal.Signals) -> None:
        if self.alive():
            self.popen.send_signal(sig)

    def wait(self, timeout_s: float) -> int:
        return self.popen.wait(timeout=timeout_s)

    def stop(self, grace_s: float = STOP_GRACE_S) -> int:
        """SIGTERM, wait up to ``grace_s``, then SIGKILL; returns the exit code (negative: killed by a signal)."""
        try:
            if self.alive():
                self.popen.send_signal(signal.SIGTERM)
                try:
                    return self.popen.wait(timeout=grace_s)
                except subprocess.TimeoutExpired:
                    self.popen.kill()
            return self.popen.wait(timeout=grace_s)
        finally:
            self._log_file.close()


@dataclass(frozen=True, slots=True, kw_only=True)
class SitlDrone:
    """A started, ready drone and everything needed to talk to it and to stop it."""

    ports: DronePorts
    process: Process
    speed_factor: float
    gcs_sink: socket.socket  # receives the ground-station link's stream, so it never reaches 14550

    @property
    def sysid(self) -> int:
        return self.ports.sysid


def start_drone(
    *,
    instance: int,
    speed_factor: float,
    seed: int,
    log_dir: Path,
    extra_args: tuple[str, ...] = (),
    ready_timeout_s: float = READY_TIMEOUT_S,
) -> SitlDrone:
    """Start ``sitl --instance instance`` and return once its first HEARTBEAT arrived on its API remote port.

    The caller owns the result and must pass it to ``stop_drone``; if start-up fails, everything started here is
    stopped and reaped before the error propagates.
    """
    (drone,) = start_drones(
        instances=[instance], speed_factor=speed_factor, seed=seed, log_dir=log_dir, extra_args=extra_args,
        ready_timeout_s=ready_timeout_s, hosted=False,
    )  # fmt: skip
    return drone


def start_drones(
    *,
    instances: Sequence[int],
    speed_factor: float,
    seed: int,
    log_dir: Path,
    extra_args: tuple[str, ...] = (),
    ready_timeout_s: float = READY_TIMEOUT_S,
    hosted: bool,
) -> list[SitlDrone]:
    """Start drones on ``instances``, each in its own process or (``hosted``) all in one ``sitl --instances``
    process, and return once every one's first HEARTBEAT arrived on its API remote port; drone i's seed is
    ``seed + (i - instances[0])``. A hosted drone's ``process`` is its host (stopping one stops them all) and its
    log is its own ``drone-<i>.log``.

    The caller owns the result and must pass each to ``stop_drone``; if start-up fails, everything started here is
    stopped and reaped before the error propagates.
    """
    if hosted:
        return _start_process(instances, speed_factor, seed, log_dir, extra_args, ready_timeout_s)
    started: list[SitlDrone] = []
    try:
        for k, instance in enumerate(instances):
            started += _start_process([instance], speed_factor, seed + k, log_dir, extra_args, ready_timeout_s)
    except BaseException:
        for drone in started:
            stop_drone(drone)
        raise
    return started


def _start_process(
    instances: Sequence[int],
    speed_factor: float,
    seed: int,
    log_dir: Path,
    extra_args: tuple[str, ...],
    ready_timeout_s: float,
) -> list[SitlDrone]:
    """One ``sitl`` process running ``instances`` (``--instance`` for one), ready: see ``start_drones``."""
    ports = [DronePorts(instance=i) for i in instances]
    with contextlib.ExitStack() as on_failure:
        # Bound before the drones start, so their very first datagrams are not lost to an unbound port.
        listeners = []
        for p in ports:
            listener = on_failure.enter_context(socket.socket(socket.AF_INET, socket.SOCK_DGRAM))
            listener.bind((LOOPBACK, p.api_remote))
            listeners.append(listener)
        gcs_sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        on_failure.callback(gcs_sink.close)
        gcs_sink.bind((LOOPBACK, 0))
        gcs_port = gcs_sink.getsockname()[1]

        alone = len(instances) == 1
        name = f"sitl-{instances[0]}" if alone else f"sitl-host-{instances[0]}"
        log_path = log_dir / f"{name}.log"
        log_file = log_path.open("wb")
        selection = ["--instance", str(instances[0])] if alone else ["--instances", ",".join(map(str, instances))]
        argv = [
            *sitl_command(),
            *selection,
            "--speed",
            f"{speed_factor:g}",
            "--seed",
            str(seed),
            "--gcs-remote",
            f"{LOOPBACK}:{gcs_port}",
            *([] if alone else ["--log-dir", str(log_dir / name)]),
            *extra_args,
        ]
        env = {k: v for k, v in os.environ.items() if k != "PX4_SIM_SPEED_FACTOR"}
        popen = subprocess.Popen(
            [sys.executable, "-c", _PDEATHSIG_EXEC, str(os.getpid()), *argv],
            stdin=subprocess.DEVNULL,
            stdout=log_file,
            stderr=subprocess.STDOUT,
            env=env,
        )
        host = Process(popen, log_path, log_file)
        on_failure.callback(host.stop)
        processes = [
            host if alone else Process(popen, log_dir / name / f"drone-{i}.log", log_file, host_log=log_path)
            for i in instances
        ]
        deadline = time.monotonic() + ready_timeout_s
        for p, listener, process in zip(ports, listeners, processes, strict=True):
            try:
                first_heartbeat(listener, p.sysid, deadline, alive=process)
            except TimeoutError:
                raise SitlStartError(
                    f"{' '.join(selection)} (pid {popen.pid}) sent no HEARTBEAT to 127.0.0.1:{p.api_remote} "
                    f"within {ready_timeout_s:.0f} s; log:\n{process.log_tail()}"
                ) from None
        on_failure.pop_all()
    for listener in listeners:
        listener.close()
    return [
        SitlDrone(ports=p, process=process, speed_factor=speed_factor, gcs_sink=gcs_sink)
        for p, process in zip(ports, processes, strict=True)
    ]


SpawnDrones = Callable[..., list[SitlDrone]]  # the ``spawn_drones`` fixture: spawn_drones(count=1, speed_factor=...)
# The ``world_drone`` fixture: world_drone(speed_factor=..., log_lines=...), a ``drone_in_world`` of the test's own
WorldDrone = Callable[..., contextlib.AbstractContextManager[tuple[SitlDrone, "SharedWorld"]]]


def stop_drone(drone: SitlDrone) -> int:
    """Stop and reap the drone's process; returns its exit code."""
    try:
        return drone.process.stop()
    finally:
        drone.gcs_sink.close()


@contextlib.contextmanager
def drone_in_world(
    tmp_path: Path, allocator: InstanceAllocator, *, seed: int, speed_factor: float, log_lines: int = 30
) -> Iterator[tuple[SitlDrone, SharedWorld]]:
    """A ``sitl`` on an instance of ``allocator``'s block, publishing its body to a fresh shared world, so a test
    can watch where it flies even when its links are silent. Its log's last lines are printed when it stops."""
    world = SharedWorld.create()
    (instance,) = allocator.take()
    try:
        drone = start_drone(
            instance=instance, speed_factor=speed_factor, seed=seed, log_dir=tmp_path,
            extra_args=("--world", world.name),
        )  # fmt: skip
        try:
            yield drone, world
        finally:
            code = stop_drone(drone)
            print(f"--- sitl instance {instance} (exit code {code}) ---\n{drone.process.log_tail(log_lines)}")
    finally:
        allocator.give_back(instance)
        world.close()
