"""The simulation harness: everything about a simulated swarm that only the simulation may know, behind one face.

A ground station flying real drones knows them only over MAVLink. Flying simulated drones it also needs someone to
start them, to tell it when one has ended, to crash one on request and, in lockstep, to let the simulated time run
on: that is this class, and nothing more. The ground station is handed a ``SitlHarness`` by its composition root
and sees it through the interface it declares itself (gcs/fleet/harness.py ``SimulationHarness``): sysids, causes as one
line of text, geodetic tuples, simulated seconds. Processes, PIDs, world rows and columns, the lockstep gate and
the drone factory stay on this side, so that the way drones are run (one process each, or several drones hosted by
one process) can change without the ground station noticing.

What it owns:
- the drone processes (sitl/harness/processes.py, forked by the drone factory sitl/harness/factory.py), their log
  files (in a temporary directory removed at ``close`` unless the plan names one);
- the shared world (sitl/world/shared.py): created before the drones, which attach to it by name; a drone that ended is
  marked there once (its body falls from its last state), obstacles are declared there;
- the lockstep gate (sitl/world/lockstep.py) in lockstep: its wake-up socket, how far the drones have got, how far they
  may go.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import signal
import subprocess
import tempfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import numpy.typing as npt

from sitl.dynamics.plant import PHYSICS_RATE_HZ
from sitl.harness.processes import DroneProcess, LaunchPlan, ProcessGroup, process_exit_cause
from sitl.harness.simulation import contact_distance_m
from sitl.world.lockstep import LockstepGate
from sitl.world.shared import (
    ALT,
    CPU_LINK,
    CPU_PHYSICS,
    DRONE_SENT,
    END_FAILED,
    END_STOPPED,
    LAT,
    LINK_CHANNELS,
    LINK_FIELDS,
    LON,
    MESH_FIELDS,
    STEP,
    SUPERVISOR_SENT,
    TIME,
    VALID,
    SharedWorld,
)

# A live drone's body (crashed or silent, still writing its row) is "down" once it is this close to its launch
# altitude (the ground, in this flat world).
ON_GROUND_M = 0.3
# How a hosted drone ended by ``kill`` is reported: it stops as a killed process stops, but no signal was sent.
HOSTED_KILL_CAUSE = "killed inside its host process"
KILL_WAIT_S = 5.0  # wall seconds a kill at the lockstep gate waits for the killed process to be gone
REST_TOLERANCE_M = 0.01  # an ended drone's falling body is down once within this of where it comes to rest

FloatArray = npt.NDArray[np.float64]


# The report's name for what the drones heard over the drone-to-drone mesh, next to the link model's channels.
MESH_CHANNEL = "neighbour mesh"


class SitlHarness:
    """One simulated swarm: its drones, their shared world and, in lockstep, the gate of their common clock.

    Drones are named by sysid (instance + 1) on this face, as the ground station knows them."""

    def __init__(self, plan: LaunchPlan) -> None:
        self.plan = plan
        self._temp_logs: str | None = None
        self._processes = ProcessGroup()
        self._world: SharedWorld | None = None
        self._gate: LockstepGate | None = None
        self._name_released = False  # the world's name leaves /dev/shm once every drone has mapped it
        self._ended: dict[int, str] = {}  # sysid -> cause, for every drone seen ended (marked in the world once)
        self._radius_m: float | None = None  # the swarm's drones' collision radius (an external body's default size)
        self._final_time_s = 0.0  # the common lockstep time when the gate closed
        self._final_link_counters: dict[str, dict[str, float]] = {}  # the link model's counts when the world closed
        self._kills_at_gate: list[DroneProcess] = []  # lockstep: killed at the next gate (``kill``)

    # ---- lifecycle -------------------------------------------------------------------------------------------------
    def launch(self, gcs_port: int) -> list[int]:
        """Create the shared world, start every drone of the plan sending to the ground station's UDP ``gcs_port``,
        and open the lockstep gate if the plan asks for lockstep. Returns the drones' sysids in spawn order.
        SpawnError (a RuntimeError, one line) when a drone cannot be started."""
        if self.plan.log_dir is None:
            # Drone output always goes to log files, so a drone that fails to start can be explained; without a
            # log directory from the user they live in a temporary one removed at ``close``.
            self._temp_logs = tempfile.mkdtemp(prefix="swarm-logs-")
            self.plan = dataclasses.replace(self.plan, log_dir=Path(self._temp_logs))
        self._world = SharedWorld.create()  # simulation truth for collisions; the drones attach to it by name
        self._name_released = False
        self._processes.spawn(self.plan, gcs_port, self._world.name)
        if self.plan.lockstep:
            self._gate = LockstepGate(self._world, 1.0 / PHYSICS_RATE_HZ)
        return [d.sysid for d in self._processes.drones]

    def close(self) -> None:
        """Terminate and reap every drone (SIGTERM, then SIGKILL after a grace period), close the gate and the
        shared world, remove temporary logs. Safe to call after a failed ``launch``."""
        if self._gate is not None:  # before the drones leave the gate
            self._final_time_s = self._gate.time_s()
        try:
            self._processes.terminate()
        finally:
            self._final_link_counters = self.link_counters()  # the drones published their last counts as they ended
            if self._gate is not None:
                self._gate.close()
                self._gate = None
            if self._world is not None:
                self._world.close()
                self._world = None
            if self._temp_logs is not None:
                shutil.rmtree(self._temp_logs, ignore_errors=True)

    def note_sent_to_drones(self, datagrams: Mapping[int, int]) -> None:
        """Lockstep delivery (``SimulationHarness``): into each drone's row, before the gate opens."""
        if self._world is None:
            return
        table = self._world.table
        for d in self._processes.drones:
            count = datagrams.get(d.sysid)
            if count is not None:
                table[d.instance, SUPERVISOR_SENT] = float(count)

    def sent_by_drones(self) -> dict[int, int]:
        """Lockstep delivery (``SimulationHarness``): each drone's count, from its row."""
        if self._world is None:
            return {}
        table = self._world.table
        return {d.sysid: int(table[d.instance, DRONE_SENT]) for d in self._processes.drones}

    def link_counters(self) -> dict[str, dict[str, float]]:
        """What the link model did to the swarm's traffic, summed over the drones (``SimulationHarness``)."""
        if self._world is None:
            return self._final_link_counters
        rows = self._world.link_table[[d.instance for d in self._processes.drones]]
        totals = rows.sum(axis=0)
        out: dict[str, dict[str, float]] = {}
        for k, (link_class, direction) in enumerate(LINK_CHANNELS):
            if totals[k, 0] > 0:
                out[f"{link_class} {direction}"] = {
                    name: float(v) for name, v in zip(LINK_FIELDS, totals[k], strict=True)
                }
        mesh = dict(zip(MESH_FIELDS, self._world.mesh_stats[[d.instance for d in self._processes.drones]].sum(axis=0),
                        strict=True))  # fmt: skip
        if mesh["frames_offered"] > 0:  # what the drones heard over the mesh (sitl/world/mesh.py), in the same terms
            lost = mesh["lost_range"] + mesh["lost_path"] + mesh["lost_model"] + mesh["lost_overrun"]
            out[MESH_CHANNEL] = {"frames_lost": float(lost), **{k: float(v) for k, v in mesh.items()}}
        return out

    # ---- ends and faults -------------------------------------------------------------------------------------------
    def ended(self) -> dict[int, str]:
        """Every drone that has ended, by sysid, with one line saying how (``process killed by SIGKILL``).

        A drone seen ended for the first time leaves the shared world's living (its body falls from its last state)
        and the lockstep gate (it holds nobody back)."""
        for d in self._processes.exited():
            if d.sysid in self._ended:
                continue
            code = d.process.returncode
            assert code is not None
            self._note_end(d, process_exit_cause(code) if not d.hosted else f"its host {process_exit_cause(code)}")
        world = self._world
        if world is not None and not self._name_released:
            living = [d.instance for d in self._processes.drones if d.sysid not in self._ended]
            if world.all_mapped(living):
                world.release_name()
                self._name_released = True
        if world is not None:
            for d in self._processes.drones:
                if d.hosted and d.sysid not in self._ended and (cause := world.end_cause(d.instance)) is not None:
                    self._note_end(d, hosted_end_cause(cause, d))
        return dict(self._ended)

    def _note_end(self, d: DroneProcess, cause: str) -> None:
        self._ended[d.sysid] = cause
        if self._world is not None:
            self._world.mark_ended(d.instance)
        if self._gate is not None:
            self._gate.remove(d.instance)

    def end_report(self, sysid: int) -> str:
        """One line about an ended drone for a user who asked for it to start: which drone, its exit code and the
        last line it wrote (its error)."""
        d = self._drone(sysid)
        detail = d.last_log_line() or "no output"
        return f"drone {d.instance} (sysid {d.sysid}) exited with code {d.process.returncode}: {detail}"

    def kill(self, sysid: int) -> str | None:
        """Crash drone ``sysid``'s flight software (SIGKILL to its process, by PID; a hosted drone is stopped by its
        host as SIGKILL would stop it); returns what was done, in one line, or None when the drone had already ended
        (or is to be killed already).

        Paced, now; the end shows in ``ended`` once it is noticed. In lockstep, at the next gate, when every drone
        stands at it (``advance_lockstep``): the drones are flying the frame the supervisor opened while it reads
        the last one, and a kill between two gates would land at whatever step the drone had reached, so the same
        flight would lose its drone a few steps apart from run to run. At the gate the drone's last step, its
        last words and the moment the others see its body fall are the same in every run, and the harness reports
        the end at once (``ended``), without waiting to notice it."""
        d = self._drone(sysid)
        if d.process.returncode is not None or d.process.poll() is not None or sysid in self.ended():
            return None
        if d in self._kills_at_gate:
            return None
        gate = self._gate
        if gate is not None and gate.is_open():
            self._kills_at_gate.append(d)
            at = f" at the lockstep gate of t={gate.gate_step() * gate.dt_s:.3f} s"
        else:
            self._kill_now(d)
            at = ""
        if d.hosted:
            return f"killed inside its host process {d.process.pid}{at}; the host's other drones fly on"
        return f"process {d.process.pid} killed with SIGKILL{at}"

    def _kill_now(self, d: DroneProcess) -> None:
        if d.hosted:  # a signal would end the host's other drones too: the host ends this one as SIGKILL would
            assert self._world is not None
            self._world.request_stop(d.instance)
        else:
            d.process.kill()

    def _kill_at_gate(self) -> None:
        """Carry out the kills asked for since the last gate, every drone standing at this one: a hosted drone's
        host sees the stop before it reads or steps again (sitl/process/runtime.py), a drone's own process is gone
        before the gate moves on; each end is recorded now, as the supervisor asked for it."""
        kills, self._kills_at_gate = self._kills_at_gate, []
        for d in kills:
            if d.sysid in self._ended:
                continue
            self._kill_now(d)
            if d.hosted:
                self._note_end(d, HOSTED_KILL_CAUSE)
                continue
            try:
                code = d.process.wait(timeout=KILL_WAIT_S)
            except subprocess.TimeoutExpired:
                code = -signal.SIGKILL  # it is going: no step can follow, as the gate is not moved for it
            self._note_end(d, process_exit_cause(code))

    # ---- the shared world ------------------------------------------------------------------------------------------
    def drone_time_s(self) -> float | None:
        """The slowest running drone's own simulated time (each drone publishes it every few physics steps); None
        before every running drone has published it."""
        if self._world is None:
            return None
        ended = self.ended()
        instances = [d.instance for d in self._processes.drones if d.sysid not in ended]
        table = self._world.table
        if not instances or not (table[instances, VALID] == 1.0).all():
            return None
        return float(table[instances, TIME].min())

    def grounded_body_geo(self, sysid: int, time_s: float) -> tuple[float, float, float] | None:
        """Latitude, longitude (deg) and altitude (m) where drone ``sysid``'s body lies at ``time_s`` on the common
        simulated clock, once it lies on the ground; None while it is in the air (or has no body).

        An ended drone's body falls in the shared world from its last state: it is down once it is where it comes
        to rest. A live drone (crashed, or silent) writes its own row: it is down within ON_GROUND_M of its launch
        altitude."""
        world = self._world
        if world is None:
            return None
        d = self._drone(sysid)
        if world.ended(d.instance):
            now, rest = world.body_geo(d.instance, time_s), world.body_geo(d.instance, math.inf)
            if now is None or rest is None or abs(now[2] - rest[2]) > REST_TOLERANCE_M:
                return None
            return (float(now[0]), float(now[1]), float(now[2]))
        row = world.table[d.instance]
        if row[VALID] != 1.0 or float(row[ALT]) - d.home.alt_amsl_m > ON_GROUND_M:
            return None
        return float(row[LAT]), float(row[LON]), float(row[ALT])

    def add_obstacle(self, *, cylinder: bool, centre_geo: tuple[float, float, float], radius_m: float,
                     height_m: float) -> None:  # fmt: skip
        """Declare a static obstacle (a vertical cylinder or a sphere) that cameras see and contact crashes into."""
        assert self._world is not None, "launch first"
        self._world.add_obstacle(cylinder=cylinder, centre=centre_geo, radius_m=radius_m, height_m=height_m)

    # ---- lockstep --------------------------------------------------------------------------------------------------
    def place_external_body(self, sysid: int, geo: tuple[float, float, float],
                            vel_ned_mps: tuple[float, float, float], radius_m: float | None) -> None:  # fmt: skip
        """An attached vehicle's body in the world, on the row of its sysid (its instance would be sysid - 1): never a
        lockstep member (its step count stays infinite, as a row that is none), never ended, so it neither falls nor
        holds anyone back."""
        world = self._world
        if world is None:
            return
        instance = sysid - 1
        radius = self._drone_radius_m() if radius_m is None else radius_m
        world.write(instance, 0.0, geo, vel_ned_mps, radius, False, rest_alt_amsl_m=-math.inf)

    def remove_external_body(self, sysid: int) -> None:
        if self._world is not None:
            self._world.table[sysid - 1, VALID] = 0.0

    def _drone_radius_m(self) -> float:
        if self._radius_m is None:  # read once: bodies are moved at every pump
            self._radius_m = contact_distance_m(self.plan.airframe) / 2.0
        return self._radius_m

    def wake_fileno(self) -> int | None:
        """A descriptor that becomes readable when the lockstep drones reach the gate (the ground station
        waits on it with its MAVLink socket); None when not in lockstep."""
        return self._gate.wake_socket.fileno() if self._gate is not None else None

    def lockstep_time_s(self) -> float:
        """The drones' common simulated time: the steps every lockstep drone has completed; 0 before any joined,
        and where it stood once ``close`` has stopped the drones."""
        return self._gate.time_s() if self._gate is not None else self._final_time_s

    def advance_lockstep(self, lead_s: float) -> float | None:
        """Let the lockstep drones run on to ``lead_s`` past their common time; returns
        the common time, or None while not every drone has joined (nobody starts before the rest). Clears pending
        wake-ups first, so the next one is news. The kills asked for since the last gate land first, when every
        drone stands at the gate (``kill``)."""
        gate = self._gate
        if gate is None:
            return None
        gate.drain_wakes()
        if self._kills_at_gate and gate.all_at_gate():
            self._kill_at_gate()
        steps = gate.completed_steps()
        now = steps * gate.dt_s
        if steps == 0 and gate.members() < len(self._processes.drones):
            return None
        gate.open_until(now + lead_s)
        return now

    # ---- measurement (the bench) -----------------------------------------------------------------------------------
    def process_ids(self) -> dict[int, int]:
        """The PID of the process that runs each drone, by sysid: for reading its CPU time and memory in /proc, as
        ``top`` would. Not for signalling: ``kill`` does that."""
        return {d.sysid: int(d.process.pid) for d in self._processes.drones}

    def clock_columns(self) -> tuple[FloatArray, FloatArray]:
        """Each drone's published simulated time and lockstep step count (spawn order), as one read of the shared
        world: cells have separate writers, so a read may be torn (read twice and compare to know)."""
        assert self._world is not None, "launch first"
        rows = [d.instance for d in self._processes.drones]
        table = self._world.table
        return table[rows, TIME].copy(), table[rows, STEP].copy()

    def cpu_parts_s(self) -> FloatArray:
        """Each drone's CPU seconds so far in physics, control, perception and MAVLink (one row per drone, spawn
        order), as the drones publish them."""
        assert self._world is not None, "launch first"
        rows = [d.instance for d in self._processes.drones]
        return self._world.table[rows, CPU_PHYSICS : CPU_LINK + 1].copy()

    # ---- internals -------------------------------------------------------------------------------------------------
    def _drone(self, sysid: int) -> DroneProcess:
        for d in self._processes.drones:
            if d.sysid == sysid:
                return d
        raise KeyError(f"no drone with sysid {sysid}")


def hosted_end_cause(cause: float, d: DroneProcess) -> str:
    """One line for how a hosted drone ended while its host process runs on (the ``END_*`` cause its host wrote)."""
    if cause == END_FAILED:
        log = f" (traceback in {d.log_path.name})" if d.log_path is not None else ""
        return f"drone software failed{log}"
    if cause == END_STOPPED:
        return HOSTED_KILL_CAUSE
    return "flight software exited"
