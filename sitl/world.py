"""The shared world: every drone's true state in one shared-memory table, for collisions (and the camera).

Simulation truth is kept apart from communication: what a drone knows of its neighbours comes over MAVLink, but
physics needs to know where the other bodies really are. The supervisor creates one table per swarm
(``multiprocessing.shared_memory``) and passes its name to every drone (``sitl --world NAME``); drone i writes row i
and reads all rows. Positions are geodetic, so drones with different homes share one table without agreeing on a
frame; over a swarm's extent the local flat-earth conversion is exact to millimetres.

Row layout (float64): valid, time_s, lat_deg, lon_deg, alt_amsl_m, vn, ve, vd, radius_m, crashed, then the
lockstep column: physics steps completed (infinite while the row is no lockstep member), then the seconds the drone
has spent so far on physics, control, perception and MAVLink (read by ``swarm bench``), and a lockstep member's
"waiting to be woken" flag. After the
rows, a small header holds the lockstep gate (sitl/lockstep.py). A single writer per cell and a reader that tolerates
a torn row for one sample (it is re-read next time) need no lock; step counts only grow, so a stale read only ever
makes a drone wait a little longer, never run ahead.
"""

from __future__ import annotations

import contextlib
import math
import mmap
from dataclasses import dataclass
from multiprocessing import shared_memory
from pathlib import Path

import numpy as np
import numpy.typing as npt

from sitl.dynamics.plant import PlantState

MAX_DRONES = 256
COLUMNS = 16
VALID, TIME, LAT, LON, ALT, VN, VE, VD, RADIUS, CRASHED, STEP = range(11)
CPU_PHYSICS, CPU_CONTROL, CPU_PERCEPTION, CPU_LINK = range(11, 15)  # seconds spent so far, for benchmarks
WAITING = 15  # 1 while a lockstep member sleeps until woken
HEADER_SLOTS = 4
GATE_STEP, GATE_OPEN = range(2)  # header: steps every member may complete; 1 once the supervisor opened the gate
EARTH_RADIUS_M = 6_371_000.0


class WorldError(RuntimeError):
    """The shared table cannot be created or opened (one line for the user)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Contact:
    """Another body closer than the two collision radii together (``obstacle`` set when it is a static one)."""

    instance: int
    distance_m: float
    obstacle: int | None = None

    def text(self) -> str:
        """The STATUSTEXT a drone sends when it hits this body."""
        if self.obstacle is not None:
            return f"Collision with obstacle {self.obstacle + 1} at {self.distance_m:.2f} m"
        return f"Collision with drone {self.instance + 1} at {self.distance_m:.2f} m"


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
SIZE_BYTES = OBSTACLES_OFFSET + MAX_OBSTACLES * OBSTACLE_COLUMNS * 8
SHM_DIR = Path("/dev/shm")


class SharedWorld:
    """The creator owns the segment (``multiprocessing.shared_memory``, whose tracker unlinks it even if the
    supervisor is killed); drones map it directly from /dev/shm, so attaching neither starts a tracker process per
    drone nor lets a drone's exit remove the table."""

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
        return world

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
              vel_ned_mps: tuple[float, float, float], radius_m: float, crashed: bool) -> None:  # fmt: skip
        row = self.table[instance]
        row[TIME], row[LAT], row[LON], row[ALT] = time_s, geo[0], geo[1], geo[2]
        row[VN], row[VE], row[VD] = vel_ned_mps
        row[RADIUS], row[CRASHED] = radius_m, 1.0 if crashed else 0.0
        row[VALID] = 1.0

    def write_cpu(self, instance: int, physics_s: float, control_s: float, perception_s: float, link_s: float) -> None:
        self.table[instance, CPU_PHYSICS : CPU_LINK + 1] = (physics_s, control_s, perception_s, link_s)

    def clear(self, instance: int) -> None:
        self.table[instance, VALID] = 0.0

    def others_ned_m(self, instance: int) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]:
        """Instances and NED offsets (from drone ``instance``) of every other valid body."""
        table = self.table
        me = table[instance]
        valid = table[:, VALID] == 1.0
        valid[instance] = False
        ids = np.nonzero(valid)[0]
        rows = table[ids]
        north = np.radians(rows[:, LAT] - me[LAT]) * EARTH_RADIUS_M
        east = np.radians(rows[:, LON] - me[LON]) * EARTH_RADIUS_M * math.cos(math.radians(me[LAT]))
        down = me[ALT] - rows[:, ALT]
        return ids, np.column_stack((north, east, down))

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
        me = self.table[instance]
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

    def contacts(self, instance: int) -> list[Contact]:
        """Bodies closer to drone ``instance`` than the sum of both collision radii, static obstacles included."""
        own_radius = float(self.table[instance, RADIUS])
        found: list[Contact] = []
        ids, offsets = self.others_ned_m(instance)
        if len(ids):
            distance = np.sqrt(np.einsum("ij,ij->i", offsets, offsets))
            hits = np.flatnonzero(distance < self.table[ids, RADIUS] + own_radius)
            found = [Contact(instance=int(ids[k]), distance_m=float(distance[k])) for k in hits]
        if self.obstacle_table[:, O_VALID].any():
            for ob in self.obstacles_from(instance):
                n, e, d = ob.offset_ned_m
                if ob.cylinder:  # distance to the pole's surface, within its height
                    gap = math.hypot(n, e) - ob.radius_m
                    touching = gap < own_radius and abs(d) < ob.height_m / 2.0 + own_radius
                else:
                    gap = math.sqrt(n * n + e * e + d * d) - ob.radius_m
                    touching = gap < own_radius
                if touching:
                    found.append(Contact(instance=-1, distance_m=max(0.0, gap), obstacle=ob.index))
        return found

    def close(self) -> None:
        self.table = np.zeros((0, COLUMNS))
        self.header = np.zeros(HEADER_SLOTS)
        self.obstacle_table = np.zeros((0, OBSTACLE_COLUMNS))
        if self._map is not None:
            self._map.close()
        if self._shm is not None:
            self._shm.close()
            with contextlib.suppress(FileNotFoundError):
                self._shm.unlink()


class WorldParticipant:
    """One drone's side of the shared world: publishes its truth and crashes on contact, every few steps."""

    def __init__(self, world: SharedWorld, instance: int, radius_m: float, every_n_steps: int = 4) -> None:
        self.world = world
        self.instance = instance
        self.radius_m = radius_m
        self.every_n_steps = every_n_steps
        self._count = 0

    def after_step(self, truth: PlantState, crashed: bool) -> list[Contact]:
        """Call after every physics step: every ``every_n_steps`` steps publishes the truth and returns the contacts
        (``update``); on the steps between it costs a counter."""
        self._count += 1
        if self._count < self.every_n_steps:
            return []
        self._count = 0
        geo, v = truth.geo, truth.vel_ned_mps
        return self.update(truth.time_s, (geo.lat_deg, geo.lon_deg, geo.alt_amsl_m),
                           (float(v[0]), float(v[1]), float(v[2])), crashed)  # fmt: skip

    def update(self, time_s: float, geo: tuple[float, float, float], vel_ned_mps: tuple[float, float, float],
               crashed: bool) -> list[Contact]:  # fmt: skip
        """Publish this drone's truth; returns the contacts it has (none once crashed)."""
        self.world.write(self.instance, time_s, geo, vel_ned_mps, self.radius_m, crashed)
        return [] if crashed else self.world.contacts(self.instance)

    def close(self) -> None:
        self.world.clear(self.instance)
        self.world.close()
