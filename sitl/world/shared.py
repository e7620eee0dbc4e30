"""The shared world: every drone's true state in one shared-memory table, for collisions (and the camera).

Simulation truth is kept apart from communication: what a drone knows of its neighbours comes over MAVLink, but
physics needs to know where the other bodies really are. The supervisor creates one table per swarm
(``multiprocessing.shared_memory``) and passes its name to every drone (``sitl --world NAME``); drone i writes row i
and reads all rows. Positions are geodetic, so drones with different homes share one table without agreeing on a
frame; over a swarm's extent the local flat-earth conversion is exact to millimetres.

Row layout (float64): valid, time_s, lat_deg, lon_deg, alt_amsl_m, vn, ve, vd, radius_m, crashed, then the
lockstep column: physics steps completed (infinite while the row is no lockstep member), then the seconds the drone
has spent so far on physics, control, perception and MAVLink (read by ``swarm bench``), a lockstep member's
"waiting to be woken" flag, then ``ended`` (1 once the drone's process is gone) and ``rest_alt_amsl_m``, the altitude
its centre has when it rests on the ground below it (terrain elevation plus the centre's height on its gear), a stop
request and the cause of the row's end (hosted drones), and the datagrams the supervisor and the drone have sent each
other (lockstep delivery). After the rows, a small header holds the lockstep gate (sitl/world/lockstep.py); then the
declared obstacles, the two lockstep snapshots of the rows (``WorldParticipant``), the link model's counts, and the
drone-to-drone mesh: each drone's ring of the position reports it has broadcast (the simulated radio medium,
sitl/world/mesh.py) and its counts of what it heard.

A drone whose process ends (a normal exit, or SIGKILL noticed by the supervisor, which calls ``mark_ended``) leaves
its body behind: from its last written state (position, velocity, time) it falls ballistically under gravity and
then rests on the ground, its horizontal velocity carried until it lands. Nobody writes the row any more; every
reader computes the body from the row and its own simulated time with one pure function (``body_geo_at``), so all
readers see the same body at the same time, and in lockstep, where every drone's clock is the same, the fall is
exactly reproducible. Paced drones' clocks differ by their start-up offsets (tens of milliseconds), and a reader sees
the fall that much earlier or later. Falling or resting, the body stays an obstacle: contacts and the cameras see it
where it is at the reader's time. A single writer per cell and a reader that tolerates
a torn row for one sample (it is re-read next time) need no lock; step counts only grow, so a stale read only ever
makes a drone wait a little longer, never run ahead.
"""

from __future__ import annotations

import contextlib
import math
import mmap
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from multiprocessing import shared_memory
from pathlib import Path

import numpy as np
import numpy.typing as npt

from sitl.mathutil import GRAVITY_MPS2
from sitl.world.linkmodel import DIRECTIONS, Direction, LinkCounters
from swarmcommon.links import LINK_CLASSES, LinkClass

MAX_DRONES = 256
COLUMNS = 22
VALID, TIME, LAT, LON, ALT, VN, VE, VD, RADIUS, CRASHED, STEP = range(11)
CPU_PHYSICS, CPU_CONTROL, CPU_PERCEPTION, CPU_LINK = range(11, 15)  # seconds spent so far, for benchmarks
WAITING = 15  # 1 while a lockstep member sleeps until woken
ENDED, REST_ALT = 16, 17  # 1 once the drone's process is gone (its body falls); its centre's altitude at rest
# A drone hosted with others in one process (sitl/host.py) cannot be ended by a signal without ending its hosts'
# other drones: STOP_REQUEST = 1 asks its host to end it as if its own process had been killed. END_CAUSE says why a
# row ended, for whoever did not end it (the supervisor learns of a hosted drone's end from here).
STOP_REQUEST, END_CAUSE = 18, 19
END_UNKNOWN, END_EXITED, END_STOPPED, END_FAILED = 0.0, 1.0, 2.0, 3.0  # END_CAUSE values
# Lockstep delivery (sitl/process/runtime.py, gcs/fleet/swarm.py): the datagrams the supervisor has sent to the drone's
# ground-station link, and the datagrams the drone has sent to the supervisor, each counted by its sender. Loopback UDP
# may hand a datagram over a little after ``sendto`` returns (the kernel finishes the delivery in a deferred
# routine, later on a busy machine), so a receiver that has not yet read as many as were sent waits for the rest
# before it moves on: every message is then used at the same simulated time in every run.
SUPERVISOR_SENT, DRONE_SENT = 20, 21
HEADER_SLOTS = 4
GATE_STEP, GATE_OPEN = range(2)  # header: steps every member may complete; 1 once the supervisor opened the gate
EARTH_RADIUS_M = 6_371_000.0


def body_geo_at(rows: npt.NDArray[np.float64], time_s: float) -> npt.NDArray[np.float64]:
    """Where the bodies of ``rows`` (an (n, COLUMNS) block of the table) are at ``time_s``: (n, 3) lat, lon, alt AMSL.

    A live row is where it was last written. An ended row falls from its last written state: free fall (no drag:
    a tumbling quadrotor falling a few metres barely slows) with the written velocity, until its centre reaches
    ``rest_alt_amsl_m``, and then lies there; horizontal motion stops on landing. Before the last written time the
    body is where it was written (a reader whose clock lags sees no fall yet). Pure, so every reader agrees."""
    alt = rows[:, ALT]
    vn, ve, vd = rows[:, VN], rows[:, VE], rows[:, VD]
    height = np.maximum(alt - rows[:, REST_ALT], 0.0)
    height = np.where(np.isfinite(height), height, 0.0)  # no known ground: the body stays where it was
    # landing time: alt - vd t - g t^2 / 2 = rest
    landing_s = (np.sqrt(vd * vd + 2.0 * GRAVITY_MPS2 * height) - vd) / GRAVITY_MPS2
    fall_s = np.where(rows[:, ENDED] == 1.0, np.clip(time_s - rows[:, TIME], 0.0, landing_s), 0.0)
    down = vd * fall_s + 0.5 * GRAVITY_MPS2 * fall_s * fall_s
    lat = rows[:, LAT] + np.degrees(vn * fall_s / EARTH_RADIUS_M)
    # cos(lat) only where a body falls (elsewhere fall_s is 0 and the quotient 0 whatever it is), with the C library's
    # cos: numpy's SIMD cos differs between CPUs in the last bit (sitl/kernels/__init__.py).
    cos_lat = np.ones(len(rows))
    for i in np.flatnonzero(fall_s).tolist():
        cos_lat[i] = math.cos(math.radians(rows[i, LAT]))
    lon = rows[:, LON] + np.degrees(ve * fall_s / (EARTH_RADIUS_M * cos_lat))
    return np.column_stack((lat, lon, np.fmax(alt - down, np.fmin(alt, rows[:, REST_ALT]))))


class WorldError(RuntimeError):
    """The shared table cannot be created or opened (one line for the user)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class StaticObstacle:
    """A declared obstacle seen from one drone: its centre's NED offset (mid-height for a cylinder)."""

    index: int
    cylinder: bool
    offset_ned_m: tuple[float, float, float]
    radius_m: float
    height_m: float


# Static obstacles a mission declares, after the header: one row each, written once by the supervisor.
MAX_OBSTACLES = 32
OBSTACLE_COLUMNS = 7
O_VALID, O_KIND, O_LAT, O_LON, O_ALT, O_RADIUS, O_HEIGHT = range(OBSTACLE_COLUMNS)
SPHERE, CYLINDER = 0.0, 1.0  # O_KIND; a cylinder stands vertically, O_ALT is its mid-height
TABLE_BYTES = MAX_DRONES * COLUMNS * 8
OBSTACLES_OFFSET = TABLE_BYTES + HEADER_SLOTS * 8
# In lockstep the bodies are also published into one of two snapshot tables (see ``WorldParticipant``), after the
# obstacles: the copy of the table as it was at the last epoch every member has completed.
SNAPSHOTS = 2
SNAPSHOTS_OFFSET = OBSTACLES_OFFSET + MAX_OBSTACLES * OBSTACLE_COLUMNS * 8
# What the link model did to each drone's traffic (sitl/world/linkmodel.py), for the flight report: one row per drone,
# for each (class, direction) channel in LINK_CHANNELS order the frames offered, lost and delayed and the total delay.
LINK_CHANNELS: tuple[tuple[LinkClass, Direction], ...] = tuple((c, d) for c in LINK_CLASSES for d in DIRECTIONS)
LINK_FIELDS = ("frames_offered", "frames_lost", "delayed", "total_delay_s")
LINKS_OFFSET = SNAPSHOTS_OFFSET + SNAPSHOTS * TABLE_BYTES
MESH_OFFSET = LINKS_OFFSET + MAX_DRONES * len(LINK_CHANNELS) * len(LINK_FIELDS) * 8
# The drone-to-drone mesh (sitl/world/mesh.py): one ring per drone of the frames it broadcast, each slot with the
# physics step and simulated time it was sent at and its length. 64 slots are 6.4 s of 10 Hz reports, more than a
# lockstep reader can be behind (twice the largest quantum, 400 steps, is 3.2 s at 250 Hz); 64 bytes hold a signed
# GLOBAL_POSITION_INT (53). Then each drone's counts of what it heard, for the flight report.
MESH_SLOTS = 64
MESH_SLOT_BYTES = 64
MESH_STEP, MESH_TIME, MESH_LENGTH = range(3)
MESH_FIELDS = ("frames_offered", "frames_delivered", "lost_range", "lost_path", "lost_model", "lost_overrun",
               "delayed", "total_delay_s", "relay_updates", "link_updates", "mesh_updates")  # fmt: skip
MESH_META_OFFSET = MESH_OFFSET + MAX_DRONES * 8
MESH_STATS_OFFSET = MESH_META_OFFSET + MAX_DRONES * MESH_SLOTS * 3 * 8
MESH_FRAMES_OFFSET = MESH_STATS_OFFSET + MAX_DRONES * len(MESH_FIELDS) * 8
SIZE_BYTES = MESH_FRAMES_OFFSET + MAX_DRONES * MESH_SLOTS * MESH_SLOT_BYTES
PUBLISH_EVERY_STEPS = 4  # a drone publishes its truth (and looks for contacts) every this many physics steps
SHM_DIR = Path("/dev/shm")


class SharedWorld:
    """The creator owns the segment (``multiprocessing.shared_memory``) and removes its name once every drone has
    mapped it (``release_name``), so no kill of any process can leave it in /dev/shm; drones map it directly from
    /dev/shm, so attaching neither starts a tracker process per drone nor lets a drone's exit remove the table."""

    def __init__(self, name: str, buffer: memoryview | mmap.mmap, shm: shared_memory.SharedMemory | None) -> None:
        self._name = name
        self._shm = shm
        self._map = buffer if isinstance(buffer, mmap.mmap) else None
        self.table: npt.NDArray[np.float64] = np.ndarray((MAX_DRONES, COLUMNS), dtype=np.float64, buffer=buffer)
        self.header: npt.NDArray[np.float64] = np.ndarray(
            (HEADER_SLOTS,), dtype=np.float64, buffer=buffer, offset=TABLE_BYTES
        )
        self.obstacle_table: npt.NDArray[np.float64] = np.ndarray(
            (MAX_OBSTACLES, OBSTACLE_COLUMNS), dtype=np.float64, buffer=buffer, offset=OBSTACLES_OFFSET
        )
        self.snapshots: npt.NDArray[np.float64] = np.ndarray(
            (SNAPSHOTS, MAX_DRONES, COLUMNS), dtype=np.float64, buffer=buffer, offset=SNAPSHOTS_OFFSET
        )
        self.link_table: npt.NDArray[np.float64] = np.ndarray(
            (MAX_DRONES, len(LINK_CHANNELS), len(LINK_FIELDS)), dtype=np.float64, buffer=buffer, offset=LINKS_OFFSET
        )
        self.mesh_posts: npt.NDArray[np.float64] = np.ndarray(
            (MAX_DRONES,), dtype=np.float64, buffer=buffer, offset=MESH_OFFSET
        )
        self.mesh_meta: npt.NDArray[np.float64] = np.ndarray(
            (MAX_DRONES, MESH_SLOTS, 3), dtype=np.float64, buffer=buffer, offset=MESH_META_OFFSET
        )
        self.mesh_stats: npt.NDArray[np.float64] = np.ndarray(
            (MAX_DRONES, len(MESH_FIELDS)), dtype=np.float64, buffer=buffer, offset=MESH_STATS_OFFSET
        )
        self.mesh_frames: npt.NDArray[np.uint8] = np.ndarray(
            (MAX_DRONES, MESH_SLOTS, MESH_SLOT_BYTES), dtype=np.uint8, buffer=buffer, offset=MESH_FRAMES_OFFSET
        )
        # The table this mapping reads the other bodies from: the live table, or in lockstep the snapshot of the
        # last completed epoch (``WorldParticipant`` switches it; each drone maps the world for itself).
        self.bodies: npt.NDArray[np.float64] = self.table

    @property
    def name(self) -> str:
        return self._name

    @classmethod
    def create(cls) -> SharedWorld:
        shm = shared_memory.SharedMemory(create=True, size=SIZE_BYTES)
        assert shm.buf is not None
        world = cls(shm.name, shm.buf, shm)
        world.table[:] = 0.0
        world.table[:, STEP] = np.inf  # a row that is no lockstep member never holds anyone back
        world.header[:] = 0.0
        world.obstacle_table[:] = 0.0
        world.snapshots[:] = 0.0
        world.link_table[:] = 0.0
        world.mesh_posts[:] = 0.0
        world.mesh_meta[:] = 0.0
        world.mesh_stats[:] = 0.0
        world.mesh_frames[:] = 0
        return world

    def all_mapped(self, instances: Sequence[int]) -> bool:
        """True once every drone of ``instances`` has mapped the world: its row holds a body or a lockstep count. A
        process maps the world for all its drones before any of them steps, so a row written proves that its
        process holds its mappings."""
        rows = self.table[np.asarray(instances, dtype=np.intp)]
        return bool(np.all((rows[:, VALID] == 1.0) | np.isfinite(rows[:, STEP])))

    def release_name(self) -> None:
        """Remove the segment's name from /dev/shm once nobody needs to attach any more (the creator only). Every
        mapping lives on until it is closed, and the kernel frees the memory with the last one, so a supervisor
        killed with SIGKILL (whose tracker dies with it) leaves nothing behind."""
        if self._shm is not None:
            with contextlib.suppress(FileNotFoundError):
                self._shm.unlink()

    @classmethod
    def attach(cls, name: str) -> SharedWorld:
        path = SHM_DIR / name.lstrip("/")
        try:
            with path.open("r+b") as handle:
                mapped = mmap.mmap(handle.fileno(), SIZE_BYTES)
        except (OSError, ValueError) as exc:
            raise WorldError(f"shared world {name!r} cannot be opened: {exc}") from None
        return cls(name, mapped, None)

    def write(self, instance: int, time_s: float, geo: tuple[float, float, float],
              vel_ned_mps: tuple[float, float, float], radius_m: float, crashed: bool, *,
              rest_alt_amsl_m: float) -> None:  # fmt: skip
        row = self.table[instance]
        row[TIME], row[LAT], row[LON], row[ALT] = time_s, geo[0], geo[1], geo[2]
        row[VN], row[VE], row[VD] = vel_ned_mps
        row[RADIUS], row[CRASHED], row[REST_ALT] = radius_m, 1.0 if crashed else 0.0, rest_alt_amsl_m
        row[ENDED] = 0.0  # a row is (re)used by a live drone
        row[VALID] = 1.0

    def mark_ended(self, instance: int, cause: float = END_UNKNOWN) -> None:
        """The drone's process is gone (called once by whoever sees it go: the supervisor for a killed process, the
        drone itself or its host on a normal exit, a stop request or a failure, with the ``END_*`` cause). Its body
        falls from its last written state and then lies on the ground, still an obstacle; it also stops being a
        lockstep member, so it holds nobody back. A row never written (the drone died before its first step) has no
        body and stays empty. A cause already recorded is kept: the first to see the end knows best why."""
        row = self.table[instance]
        row[STEP] = math.inf
        row[WAITING] = 0.0
        if row[END_CAUSE] == END_UNKNOWN:
            row[END_CAUSE] = cause
        if row[VALID] == 1.0:
            row[ENDED] = 1.0
        for snapshot in self.snapshots:  # the body falls for lockstep readers too
            if snapshot[instance, VALID] == 1.0:
                snapshot[instance, ENDED] = 1.0

    def end_cause(self, instance: int) -> float | None:
        """Why row ``instance`` ended (an ``END_*`` value), or None while it has not."""
        row = self.table[instance]
        return None if row[ENDED] != 1.0 and row[END_CAUSE] == END_UNKNOWN else float(row[END_CAUSE])

    def request_stop(self, instance: int) -> None:
        """Ask the host of drone ``instance`` to end it as a killed process ends (sitl/host.py)."""
        self.table[instance, STOP_REQUEST] = 1.0

    def stop_requested(self, instance: int) -> bool:
        return bool(self.table[instance, STOP_REQUEST] == 1.0)

    def ended(self, instance: int) -> bool:
        """True once the drone's process is gone (its body falls or lies on the ground)."""
        return bool(self.table[instance, ENDED] == 1.0)

    def body_geo(self, instance: int, time_s: float) -> tuple[float, float, float] | None:
        """Lat, lon (deg) and alt AMSL (m) of drone ``instance``'s body at ``time_s`` on the drones' simulated clock
        (falling if it ended; ``math.inf`` gives where it comes to rest); None if the row holds no body."""
        row = self.table[instance]
        if row[VALID] != 1.0:
            return None
        lat, lon, alt = body_geo_at(row[np.newaxis, :], time_s)[0]
        return float(lat), float(lon), float(alt)

    def write_cpu(self, instance: int, physics_s: float, control_s: float, perception_s: float, link_s: float) -> None:
        self.table[instance, CPU_PHYSICS : CPU_LINK + 1] = (physics_s, control_s, perception_s, link_s)

    def write_link_counters(self, instance: int, counters: Mapping[tuple[LinkClass, Direction], LinkCounters]) -> None:
        row = self.link_table[instance]
        for k, key in enumerate(LINK_CHANNELS):
            c = counters.get(key)
            if c is not None:
                row[k] = (c.frames_offered, c.frames_lost, c.delayed, c.total_delay_s)

    def add_obstacle(self, *, cylinder: bool, centre: tuple[float, float, float], radius_m: float,
                     height_m: float = 0.0) -> int:  # fmt: skip
        """Declare a static obstacle (centre lat, lon, alt AMSL; mid-height for a cylinder); returns its index."""
        free = np.flatnonzero(self.obstacle_table[:, O_VALID] == 0.0)
        if len(free) == 0:
            raise WorldError(f"at most {MAX_OBSTACLES} obstacles")
        k = int(free[0])
        row = self.obstacle_table[k]
        row[O_KIND] = CYLINDER if cylinder else SPHERE
        row[O_LAT], row[O_LON], row[O_ALT] = centre
        row[O_RADIUS], row[O_HEIGHT] = radius_m, height_m
        row[O_VALID] = 1.0
        return k

    def obstacles_from(self, instance: int) -> list[StaticObstacle]:
        """Every declared obstacle as seen from drone ``instance`` (offsets from its published position)."""
        rows = self.obstacle_table
        me = self.bodies[instance]
        out = []
        cos_lat = math.cos(math.radians(me[LAT]))
        for k in np.flatnonzero(rows[:, O_VALID] == 1.0):
            row = rows[k]
            north = math.radians(row[O_LAT] - me[LAT]) * EARTH_RADIUS_M
            east = math.radians(row[O_LON] - me[LON]) * EARTH_RADIUS_M * cos_lat
            out.append(StaticObstacle(index=int(k), cylinder=row[O_KIND] == CYLINDER,
                                      offset_ned_m=(north, east, float(me[ALT] - row[O_ALT])),
                                      radius_m=float(row[O_RADIUS]), height_m=float(row[O_HEIGHT])))  # fmt: skip
        return out

    def close(self) -> None:
        self.table = self.bodies = np.zeros((0, COLUMNS))
        self.snapshots = np.zeros((0, 0, COLUMNS))
        self.link_table = np.zeros((0, len(LINK_CHANNELS), len(LINK_FIELDS)))
        self.mesh_posts = np.zeros(0)
        self.mesh_meta = np.zeros((0, MESH_SLOTS, 3))
        self.mesh_stats = np.zeros((0, len(MESH_FIELDS)))
        self.mesh_frames = np.zeros((0, MESH_SLOTS, MESH_SLOT_BYTES), dtype=np.uint8)
        self.header = np.zeros(HEADER_SLOTS)
        self.obstacle_table = np.zeros((0, OBSTACLE_COLUMNS))
        if self._map is not None:
            self._map.close()
        if self._shm is not None:
            self._shm.close()
            with contextlib.suppress(FileNotFoundError):
                self._shm.unlink()


def lockstep_epoch_steps(quantum_steps: int) -> int:
    """Steps of a lockstep epoch (``WorldParticipant``): a whole number of quanta, and of publishing periods."""
    return math.lcm(PUBLISH_EVERY_STEPS, quantum_steps)
