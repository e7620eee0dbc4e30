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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from sitl.dynamics.geodesy import geo_from_ned
from sitl.dynamics.plant import GeoPoint
from sitl.harness.factory import DroneFactory, FactoryError, ForkedProcess
from sitl.harness.zygote import die_with_parent
from sitl.world.linkmodel import LinkProfile, link_arguments
from sitl.world.mesh import MeshSettings
from swarmcommon.cpus import usable_cpus

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
    drones_per_process: int | Literal["auto"] = 1  # drones one process hosts; "auto": one process per usable CPU
    signing_key_file: Path | None = None  # every drone signs with this key and requires signed messages
    links: LinkProfile = field(default_factory=LinkProfile)  # every drone's link model settings (--link)
    mesh: MeshSettings | None = None  # the drone-to-drone mesh radio of every drone (--mesh-range-m); None: off
    behaviour: str | None = None  # the onboard behaviour every drone runs (path/file.py:Class, absolute); None: none
    wind_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)  # steady wind every drone flies in (--wind)
    gust_mps: float = 0.0  # gust RMS intensity (--gust), each drone's own seeded draw

    @property
    def n_drones(self) -> int:
        return len(self.offsets_ne_m)

    def hosts(self, usable_cpus: int) -> list[list[int]]:
        """The drones (0-based, spawn order) each process runs: ``host_groups`` with this plan's setting."""
        return host_groups(self.n_drones, self.drones_per_process, usable_cpus)

    def homes(self) -> list[GeoPoint]:
        """Each drone's home, placed by the simulation's geodesy (where the bodies really stand)."""
        return [geo_from_ned((north, east, 0.0), self.origin) for north, east in self.offsets_ne_m]


def host_groups(n_drones: int, per_process: int | Literal["auto"], usable_cpus: int) -> list[list[int]]:
    """Which drones (0-based, spawn order) each process runs: runs of ``per_process`` consecutive drones (the last
    may be shorter); "auto" makes one process per usable CPU (fewer when there are fewer drones), their sizes
    differing by at most one. Consecutive drones stand side by side in the layouts, so a host's drones are
    neighbours and their mutual camera and contact reads touch memory the host has just written."""
    if per_process == "auto":
        hosts = max(1, min(n_drones, usable_cpus))
        base, extra = divmod(n_drones, hosts)
        sizes = [base + (1 if h < extra else 0) for h in range(hosts)]
    else:
        if per_process < 1:
            raise ValueError(f"a process runs at least one drone, got {per_process}")
        sizes = [min(per_process, n_drones - k) for k in range(0, n_drones, per_process)]
    groups, start = [], 0
    for size in sizes:
        groups.append(list(range(start, start + size)))
        start += size
    return groups


@dataclass(slots=True)
class DroneProcess:
    """A drone and the process that runs it; ``hosted`` when that process runs other drones too (then ending the
    drone is asked of its host through the shared world, not done with a signal)."""

    instance: int
    sysid: int
    home: GeoPoint
    process: ForkedProcess
    log_path: Path | None
    hosted: bool = False

    def last_log_line(self) -> str:
        if self.log_path is None or not self.log_path.exists():
            return ""
        lines = [ln for ln in self.log_path.read_text(errors="replace").splitlines() if ln.strip()]
        return lines[-1] if lines else ""


def _home_arg(home: GeoPoint) -> str:
    """``--home=LAT,LON,ALT`` in one word: a value that starts with a minus sign (south of the equator, west of
    Greenwich) would be taken for an option of its own."""
    return f"--home={home.lat_deg:.9f},{home.lon_deg:.9f},{home.alt_amsl_m:.3f}"


def sitl_args(plan: LaunchPlan, instance: int, home: GeoPoint, gcs_port: int, world: str | None) -> list[str]:
    """The ``sitl`` command-line arguments of one drone of the plan, alone in its process."""
    cmd = [
        "--instance", str(instance),
        "--seed", str(plan.seed + instance - plan.first_instance),
        _home_arg(home),
    ]  # fmt: skip
    if plan.camera_dir is not None and instance - plan.first_instance + 1 in plan.camera_drones:
        cmd += ["--camera-frames", str(plan.camera_dir / f"drone-{instance}")]
    return cmd + _common_args(plan, gcs_port, world)


def host_args(
    plan: LaunchPlan, instances: list[int], homes: list[GeoPoint], gcs_port: int, world: str | None
) -> list[str]:
    """The ``sitl --instances`` arguments of one process hosting several drones of the plan: the same drones, with
    the same seeds, homes and camera choices, as ``sitl_args`` would start one by one; each drone's log is
    drone-<instance>.log in the plan's log directory, as when it runs alone."""
    contiguous = instances == list(range(instances[0], instances[-1] + 1))
    selection = f"{instances[0]}-{instances[-1]}" if contiguous else ",".join(map(str, instances))
    cmd = ["--instances", selection, "--seed", str(plan.seed + instances[0] - plan.first_instance)]
    for home in homes:
        cmd.append(_home_arg(home))
    if plan.log_dir is not None:
        cmd += ["--log-dir", str(plan.log_dir)]
    cameras = [i for i in instances if i - plan.first_instance + 1 in plan.camera_drones]
    if plan.camera_dir is not None and cameras:
        cmd += ["--camera-frames", str(plan.camera_dir), "--camera-instances", ",".join(map(str, cameras))]
    return cmd + _common_args(plan, gcs_port, world)


def _common_args(plan: LaunchPlan, gcs_port: int, world: str | None) -> list[str]:
    cmd = ["--speed", "0" if plan.lockstep else f"{plan.speed_factor:g}", "--gcs-remote", f"127.0.0.1:{gcs_port}"]
    if plan.airframe is not None:
        cmd += ["--airframe", plan.airframe]
    cmd += link_arguments(plan.links)
    if world is not None:
        cmd += ["--world", world]
        if plan.mesh is not None:
            cmd += ["--mesh-range-m", repr(plan.mesh.range_m), "--mesh-exponent", repr(plan.mesh.exponent)]
        if plan.lockstep:
            cmd += ["--lockstep", "--lockstep-quantum", str(plan.lockstep_quantum)]
    if plan.signing_key_file is not None:
        cmd += ["--signing-key", str(plan.signing_key_file), "--signing-required"]
    if plan.behaviour is not None:
        cmd += ["--behaviour", plan.behaviour]
    if any(plan.wind_ned_mps) or plan.gust_mps > 0.0:
        # one word each, as _home_arg: a wind blowing south or west starts with a minus sign
        cmd += ["--wind=" + ",".join(repr(float(v)) for v in plan.wind_ned_mps), f"--gust={float(plan.gust_mps)!r}"]
    return cmd


class ProcessGroup:
    """The drone processes of one swarm, forked by one drone factory (sitl/harness/factory.py)."""

    def __init__(self) -> None:
        self.drones: list[DroneProcess] = []
        self.processes: list[ForkedProcess] = []  # each once, whether it runs one drone or hosts several
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
        homes = plan.homes()
        for group in plan.hosts(usable_cpus()):
            instances = [plan.first_instance + k for k in group]
            hosted = len(group) > 1
            if hosted:
                name = f"host-{instances[0]}-{instances[-1]}"
                argv = host_args(plan, instances, [homes[k] for k in group], gcs_port, world)
            else:
                name = f"drone-{instances[0]}"
                argv = sitl_args(plan, instances[0], homes[group[0]], gcs_port, world)
            log_path = plan.log_dir / f"{name}.log" if plan.log_dir is not None else None
            try:
                process = self.factory.spawn(argv, log_path, DRONE_NICE)
            except FactoryError as exc:
                raise SpawnError(f"{name.replace('-', ' ', 1)}: {exc}") from None
            self.processes.append(process)
            for k, instance in zip(group, instances, strict=True):
                own_log = plan.log_dir / f"drone-{instance}.log" if plan.log_dir is not None else None
                self.drones.append(
                    DroneProcess(
                        instance=instance,
                        sysid=instance + 1,
                        home=homes[k],
                        process=process,
                        log_path=own_log,
                        hosted=hosted,
                    )
                )

    def exited(self) -> list[DroneProcess]:
        """The drones that have ended: the factory's news read once, not once per drone (this runs every tick)."""
        if self.factory is not None:
            self.factory.collect(0.0)
        return [d for d in self.drones if d.process.returncode is not None]

    def terminate(self, wait_s: float = TERMINATE_WAIT_S) -> None:
        """SIGTERM every child still running, then SIGKILL after ``wait_s``; always reaps."""
        for process in self.processes:
            if process.poll() is None:
                process.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + wait_s
        for process in self.processes:
            remaining = max(0.0, deadline - time.monotonic())
            try:
                process.wait(timeout=remaining)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
        if self.factory is not None:
            self.factory.close()
            self.factory = None
