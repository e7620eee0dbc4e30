"""A drone's side of the shared world (sitl/world/shared.py): where the other bodies are from it, what it touches, and
the participant that publishes its truth every few steps.

Apart from the table itself because only drones need it: this geometry runs in compiled kernels
(sitl/kernels/world.py), and the ground station, which reads the table through the harness, never loads them (a
``swarm`` command that does not fly starts without numba)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sitl.dynamics.plant import PlantState
from sitl.kernels import world as wk
from sitl.world.shared import (
    ALT,
    EARTH_RADIUS_M,
    END_CAUSE,
    END_EXITED,
    END_UNKNOWN,
    ENDED,
    LAT,
    LON,
    O_VALID,
    PUBLISH_EVERY_STEPS,
    RADIUS,
    SNAPSHOTS,
    STOP_REQUEST,
    TIME,
    VALID,
    SharedWorld,
    body_geo_at,
)

# The columns sitl/kernels/world.py reads, in its order.
_WORLD_COLUMNS = np.array((VALID, LAT, LON, ALT, ENDED, RADIUS), dtype=np.int64)


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


def others_ned_m(world: SharedWorld, instance: int) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]:
    """Instances and NED offsets (from drone ``instance``) of every other valid body, ended ones where they have
    fallen to at drone ``instance``'s last published time."""
    table = world.bodies
    ids = np.empty(len(table), np.int64)
    offsets = np.empty((len(table), 3))
    n = wk.others_offsets(table, instance, _WORLD_COLUMNS, EARTH_RADIUS_M, ids, offsets)
    if n >= 0:
        return ids[:n], offsets[:n]
    # A body has ended: where it has fallen to depends on time (``body_geo_at``), worked out for all at once.
    me = table[instance]
    valid = table[:, VALID] == 1.0
    valid[instance] = False
    ids = np.nonzero(valid)[0]
    rows = table[ids]
    lat, lon, alt = body_geo_at(rows, float(me[TIME])).T
    north = np.radians(lat - me[LAT]) * EARTH_RADIUS_M
    east = np.radians(lon - me[LON]) * EARTH_RADIUS_M * math.cos(math.radians(me[LAT]))
    down = me[ALT] - alt
    return ids, np.column_stack((north, east, down))


def contacts(world: SharedWorld, instance: int) -> list[Contact]:
    """Bodies closer to drone ``instance`` than the sum of both collision radii, static obstacles included."""
    own_radius = float(world.table[instance, RADIUS])
    table = world.bodies
    ids, offsets = np.empty(len(table), np.int64), np.empty((len(table), 3))
    hit_ids, hit_distances = np.empty(len(table), np.int64), np.empty(len(table))
    hits_n = wk.touching(table, instance, _WORLD_COLUMNS, EARTH_RADIUS_M, own_radius, ids, offsets, hit_ids,
                         hit_distances)  # fmt: skip
    if hits_n >= 0:
        found = [Contact(instance=int(hit_ids[k]), distance_m=float(hit_distances[k])) for k in range(hits_n)]
    else:  # a body has ended: where it has fallen to is worked out in numpy, the length in the kernel's order
        ids, offsets = others_ned_m(world, instance)
        north, east, down = offsets[:, 0], offsets[:, 1], offsets[:, 2]
        distance = np.sqrt((north * north + down * down) + east * east)
        hits = np.flatnonzero(distance < world.bodies[ids, RADIUS] + own_radius)
        found = [Contact(instance=int(ids[k]), distance_m=float(distance[k])) for k in hits]
    if world.obstacle_table[:, O_VALID].any():
        for ob in world.obstacles_from(instance):
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


class WorldParticipant:
    """One drone's side of the shared world: publishes its truth and crashes on contact, every few steps.

    Paced, a drone reads the live table: whatever the others last wrote. In lockstep (``epoch_steps`` given) that
    would make a flight depend on the machine: a drone in another process may be a step ahead or behind (the
    barrier's skew), so a camera frame or a contact check would see it one step or another. There, every member
    also publishes its row into snapshot ``k % 2`` at the end of epoch k (step ``k * epoch_steps``), and during the
    steps of epoch k + 1 reads the others from that snapshot only: every member has completed epoch k by then (an
    epoch is a whole number of lockstep quanta, and a quantum's end is a barrier), and none can have reached the end
    of epoch k + 2, which would overwrite it. So every drone sees every other at one simulated time, the same in
    every run, and contacts are judged on that same picture at the first step of each epoch."""

    def __init__(self, world: SharedWorld, instance: int, radius_m: float, *, rest_alt_amsl_m: float,
                 every_n_steps: int = PUBLISH_EVERY_STEPS, epoch_steps: int | None = None) -> None:  # fmt: skip
        self.world = world
        self.instance = instance
        self.radius_m = radius_m
        self.rest_alt_amsl_m = rest_alt_amsl_m
        self.every_n_steps = every_n_steps if epoch_steps is None else epoch_steps
        self.epoch_steps = epoch_steps
        self._count = 0
        self._steps = 0
        world.table[instance, STOP_REQUEST] = 0.0  # a row reused by a new drone starts with no request, no end
        world.table[instance, END_CAUSE] = END_UNKNOWN
        if epoch_steps is not None:
            world.snapshots[:, instance, VALID] = 0.0  # nothing from an earlier drone on this row
            world.bodies = world.snapshots[0]  # epoch 0's picture, empty until its end: nobody has published yet

    def after_step(self, truth: PlantState, crashed: bool) -> list[Contact]:
        """Call after every physics step: every ``every_n_steps`` steps publishes the truth and returns the contacts
        (``update``); on the steps between it costs a counter."""
        if self.epoch_steps is not None:
            return self._after_lockstep_step(truth, crashed)
        self._count += 1
        if self._count < self.every_n_steps:
            return []
        self._count = 0
        geo, v = truth.geo, truth.vel_ned_mps
        return self.update(truth.time_s, (geo.lat_deg, geo.lon_deg, geo.alt_amsl_m),
                           (float(v[0]), float(v[1]), float(v[2])), crashed)  # fmt: skip

    def _after_lockstep_step(self, truth: PlantState, crashed: bool) -> list[Contact]:
        """Step ``s`` done: at the first step of an epoch read the others from the snapshot of the last one and look
        for contacts in it; at an epoch's last step publish into its snapshot."""
        self._steps += 1
        steps, epoch = self._steps, self.epoch_steps
        assert epoch is not None
        world = self.world
        found: list[Contact] = []
        if (steps - 1) % epoch == 0:
            world.bodies = world.snapshots[((steps - 1) // epoch) % SNAPSHOTS]
            if steps > 1 and not crashed:
                found = contacts(world, self.instance)
        if steps % epoch == 0:
            geo, v = truth.geo, truth.vel_ned_mps
            world.write(self.instance, truth.time_s, (geo.lat_deg, geo.lon_deg, geo.alt_amsl_m),
                        (float(v[0]), float(v[1]), float(v[2])), self.radius_m, crashed,
                        rest_alt_amsl_m=self.rest_alt_amsl_m)  # fmt: skip
            world.snapshots[(steps // epoch) % SNAPSHOTS, self.instance] = world.table[self.instance]
        return found

    def update(self, time_s: float, geo: tuple[float, float, float], vel_ned_mps: tuple[float, float, float],
               crashed: bool) -> list[Contact]:  # fmt: skip
        """Publish this drone's truth; returns the contacts it has (none once crashed)."""
        self.world.write(self.instance, time_s, geo, vel_ned_mps, self.radius_m, crashed,
                         rest_alt_amsl_m=self.rest_alt_amsl_m)  # fmt: skip
        return [] if crashed else contacts(self.world, self.instance)

    def close(self, cause: float = END_EXITED) -> None:
        """Leave the world as a killed drone does: the body falls from its last published state and stays."""
        self.world.mark_ended(self.instance, cause)
        self.world.close()
