"""Spawns and supervises drone processes: the launch plan, each drone's command line, and a shutdown with no orphans.

Three layers make sure no ``sitl`` outlives the ground station that asked for it:
- a normal exit (Ctrl-C, ``swarm down``, an error) lands or disarms every drone over MAVLink (the ground station's
  part), then the harness sends SIGTERM, waits, SIGKILLs what is left and reaps every child;
- children run in their own session, so a Ctrl-C typed in the terminal reaches only the ground station, which then
  shuts them down in order instead of leaving them mid-flight;
- each child asks the kernel for SIGTERM when its parent dies (Linux ``PR_SET_PDEATHSIG``), which covers a
  ground station killed with SIGKILL, where no Python code runs at all.
Processes are only ever signalled by the PIDs this group started.
"""

from __future__ import annotations

import signal
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

from sitl.dynamics.geodesy import geo_from_ned
from sitl.dynamics.plant import GeoPoint
from sitl.harness.factory import DroneFactory, FactoryError, ForkedProcess
from sitl.zygote import die_with_parent

TERMINATE_WAIT_S = 5.0
# Drones run at a lower scheduling priority than the supervisor. When the drones want more CPU than there is, the
# supervisor (setpoints, the relay, readiness, commands) still gets its share instead of starving among N busy
# processes, which left 50 drones on 2 cores never all ready; the drones then fall behind real time, which pacing
# reports (rtf < 1), instead of the whole swarm going deaf.
DRONE_NICE = 10


class SpawnError(RuntimeError):
    """A drone could not be started; the message names it and says why, in one line."""


def process_exit_cause(returncode: int) -> str:
    """One line for how a drone process ended: a negative return code is the signal that ended it (as Popen)."""
    if returncode < 0:
        try:
            name = signal.Signals(-returncode).name
        except ValueError:
            name = f"signal {-returncode}"
        return f"process killed by {name}"
    return f"process exited with code {returncode}"


@dataclass(frozen=True, slots=True, kw_only=True)
class LaunchPlan:
    """The drones to start and how: each drone's spawn point as north/east metres from the origin (spawn order),
    instances from ``first_instance``."""

    origin: GeoPoint
    offsets_ne_m: tuple[tuple[float, float], ...]
    speed_factor: float = 1.0  # with lockstep: 0 = as fast as the CPU allows, else a pace for the common clock
    lockstep: bool = False
    lockstep_quantum: int = 1  # physics steps every drone runs between waits (the skew bound)
    first_instance: int = 0
    airframe: str | None = None
    seed: int = 0
    log_dir: Path | None = None  # each drone's stdout/stderr goes to drone-<i>.log here
    camera_drones: frozenset[int] = frozenset()  # drones (1..n, in spawn order) whose camera frames are saved...
    camera_dir: Path | None = None  # ...as PNG under camera_dir/drone-<instance>/

    @property
    def n_drones(self) -> int:
        return len(self.offsets_ne_m)

    def homes(self) -> list[GeoPoint]:
        """Each drone's home, placed by the simulation's geodesy (where the bodies really stand)."""
        return [geo_from_ned((north, east, 0.0), self.origin) for north, east in self.offsets_ne_m]


@dataclass(slots=True)
class DroneProcess:
    instance: int
    sysid: int
    home: GeoPoint
    process: ForkedProcess
    log_path: Path | None

    def last_log_line(self) -> str:
        if self.log_path is None or not self.log_path.exists():
            return ""
        lines = [ln for ln in self.log_path.read_text(errors="replace").splitlines() if ln.strip()]
        return lines[-1] if lines else ""


def sitl_args(plan: LaunchPlan, instance: int, home: GeoPoint, gcs_port: int, world: str | None) -> list[str]:
    """The ``sitl`` command-line arguments of one drone of the plan."""
    cmd = [
        "--instance", str(instance),
        "--speed", "0" if plan.lockstep else f"{plan.speed_factor:g}",
        "--seed", str(plan.seed + instance),
        "--home", f"{home.lat_deg:.9f},{home.lon_deg:.9f},{home.alt_amsl_m:.3f}",
        "--gcs-remote", f"127.0.0.1:{gcs_port}",
    ]  # fmt: skip
    if plan.airframe is not None:
        cmd += ["--airframe", plan.airframe]
    if plan.camera_dir is not None and instance - plan.first_instance + 1 in plan.camera_drones:
        cmd += ["--camera-frames", str(plan.camera_dir / f"drone-{instance}")]
    if world is not None:
        cmd += ["--world", world]
        if plan.lockstep:
            cmd += ["--lockstep", "--lockstep-quantum", str(plan.lockstep_quantum)]
    return cmd


class ProcessGroup:
    """The drone processes of one swarm, forked by one drone factory (sitl/harness/factory.py)."""

    def __init__(self) -> None:
        self.drones: list[DroneProcess] = []
        self.factory: DroneFactory | None = None

    def spawn(self, plan: LaunchPlan, gcs_port: int, world: str | None = None) -> None:
        if plan.log_dir is not None:
            plan.log_dir.mkdir(parents=True, exist_ok=True)
        if self.factory is None:
            log = plan.log_dir / "drone-factory.log" if plan.log_dir is not None else None
            try:
                self.factory = DroneFactory(log, preexec_fn=die_with_parent)
            except FactoryError as exc:
                raise SpawnError(str(exc)) from None
        for k, home in enumerate(plan.homes()):
            instance = plan.first_instance + k
            log_path = plan.log_dir / f"drone-{instance}.log" if plan.log_dir is not None else None
            try:
                process = self.factory.spawn(sitl_args(plan, instance, home, gcs_port, world), log_path, DRONE_NICE)
            except FactoryError as exc:
                raise SpawnError(f"drone {instance}: {exc}") from None
            self.drones.append(
                DroneProcess(instance=instance, sysid=instance + 1, home=home, process=process, log_path=log_path)
            )

    def exited(self) -> list[DroneProcess]:
        """The drones that have ended: the factory's news read once, not once per drone (this runs every tick)."""
        if self.factory is not None:
            self.factory.collect(0.0)
        return [d for d in self.drones if d.process.returncode is not None]

    def terminate(self, wait_s: float = TERMINATE_WAIT_S) -> None:
        """SIGTERM every child still running, then SIGKILL after ``wait_s``; always reaps."""
        for d in self.drones:
            if d.process.poll() is None:
                d.process.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + wait_s
        for d in self.drones:
            remaining = max(0.0, deadline - time.monotonic())
            try:
                d.process.wait(timeout=remaining)
            except subprocess.TimeoutExpired:
                d.process.kill()
                d.process.wait()
        if self.factory is not None:
            self.factory.close()
            self.factory = None
