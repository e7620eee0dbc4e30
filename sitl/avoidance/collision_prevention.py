"""Collision prevention in the autopilot: the avoidance algorithm (sitl/avoidance/algorithm.py) applied to the setpoint.

Every mode that flies a position (offboard position or velocity setpoints, missions, hold, goto, RTL) ends in one
``TrajectorySetpoint``; this module turns it into the velocity the position loop would ask for, lets ``avoid`` bend
that velocity away from what the drone perceives, and when a correction is needed hands the cascade a horizontal
velocity setpoint instead (altitude keeps its own setpoint). With nothing near, the setpoint passes through untouched,
so avoidance costs nothing to a drone flying alone and changes nothing in its flight.

Inputs come from outside the autopilot at their own rates - camera detections (relative positions measured at the
capture time) and relayed neighbours (absolute positions in this drone's local frame) - and are aged to "now" here.
Avoidance itself runs at ``AVOID_RATE_HZ`` (PX4's position loop rate) and its velocity is held between runs.
An *episode* starts when a correction first applies and ends after ``EPISODE_END_S`` without one; its start and end
are STATUSTEXTs ("Avoidance: ...", counted in the flight report): the start says why (``episode_text``: the body, its
predicted closest approach and when), the end the closest approach the drone perceived.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sitl.avoidance.algorithm import AvoidanceConfig, Conflict, Obstacle, config_row, conflict_of, new_obstacle
from sitl.control.cascade import TrajectorySetpoint
from sitl.control.position import PositionController
from sitl.kernels import avoidance as ak
from sitl.mathutil import Vec3, fast_constructor
from sitl.params import ParamStore

Vec3f = tuple[float, float, float]

AVOID_RATE_HZ = 50.0
EPISODE_END_S = 1.0
INPUT_TIMEOUT_S = 1.0  # camera frames older than this are forgotten (the relay's own ages are handled by fuse)
# Relayed neighbours fused per obstacle ``avoid`` keeps: the nearest by reported position, with room for the
# distances fusion brings up to date (a report is at most a second old).
RELAY_CANDIDATES_PER_OBSTACLE = 2


@dataclass(frozen=True, slots=True, kw_only=True)
class RelayedNeighbour:
    """A neighbour as the relay reported it, converted to this drone's local frame."""

    sysid: int
    pos_ned_m: tuple[float, float, float]
    vel_ned_mps: tuple[float, float, float]
    received_s: float  # when the position was true: the sender's time in lockstep, else its arrival
    cooperative: bool = True  # a swarm neighbour, which avoids in turn; False: traffic (ADSB_VEHICLE), which does not
    stale_s: float = 0.0  # how old the sender's knowledge of it was when reported (traffic's tslc)


_new_relayed = fast_constructor(RelayedNeighbour)
NO_CAMERA = np.zeros((0, ak.CAMERA_SIZE))  # an empty frame's rows
Rows = npt.NDArray[np.float64]
# What a run takes besides the drone's state and setpoint (``CollisionPrevention.run_inputs``)
RunInputs = tuple[Rows, float, Rows, float, float, float, int, Rows, bool, Rows]
_NO_NEIGHBOURS = np.zeros((0, ak.NEIGHBOUR_SIZE))


def neighbour_rows(neighbours: Sequence[RelayedNeighbour]) -> npt.NDArray[np.float64]:
    """Relayed neighbours as collision prevention holds them (sitl/kernels/avoidance.py, ``N_*``)."""
    return np.array(
        [(*n.pos_ned_m, *n.vel_ned_mps, n.received_s, n.stale_s, 1.0 if n.cooperative else 0.0, n.sysid)
         for n in neighbours], dtype=np.float64,
    ).reshape(-1, ak.NEIGHBOUR_SIZE)  # fmt: skip


def _relayed_records(rows: npt.NDArray[np.float64]) -> tuple[RelayedNeighbour, ...]:
    return tuple(
        _new_relayed(sysid=int(sysid), pos_ned_m=(px, py, pz), vel_ned_mps=(vx, vy, vz), received_s=received,
                     cooperative=cooperative != 0.0, stale_s=stale)
        for px, py, pz, vx, vy, vz, received, stale, cooperative, sysid in rows.tolist()
    )  # fmt: skip


class CollisionPrevention:
    def __init__(self, params: ParamStore, position: PositionController, own_radius_m: float,
                 event: Callable[[int, str], None]) -> None:  # fmt: skip
        self._params = params
        self._position = position
        self._own_radius_m = own_radius_m
        self._event = event
        self._config_version = -1
        self._config = AvoidanceConfig()
        self._config_row = config_row(self._config)
        # The inputs as rows (sitl/kernels/avoidance.py): camera detections (``CAMERA_SIZE``: relative position,
        # radius, age at capture) and relayed neighbours (``NEIGHBOUR_SIZE``); their records are built only for a
        # reader that asks (an onboard behaviour), once per update.
        self._camera_rows = NO_CAMERA
        self._camera_records: tuple[Obstacle, ...] | None = ()
        self._camera_time_s = -math.inf
        self._relay_rows = _NO_NEIGHBOURS
        self._relay_records: tuple[RelayedNeighbour, ...] | None = ()
        self._next_run_s = -math.inf
        self._run_out = np.empty(ak.RUN_SIZE)  # what a run found (sitl/kernels/avoidance.py ``RUN_*``)
        self._vel_xy: tuple[float, float] | None = None  # the held correction, None when not correcting
        self._episode_closest_m = math.inf
        self._last_active_s: float | None = None
        self.episodes = 0
        self.closest_m = math.inf  # over the whole flight, while correcting

    # ---- inputs ----------------------------------------------------------------------------------------------------
    def set_camera(self, detections: Sequence[Obstacle], capture_time_s: float) -> None:
        """Camera detections (``rel_pos_ned_m`` as measured at ``capture_time_s``)."""
        rows = np.array([(*d.rel_pos_ned_m, d.radius_m, d.age_s) for d in detections], dtype=np.float64)
        self.set_camera_rows(rows.reshape(-1, ak.CAMERA_SIZE), capture_time_s)
        self._camera_records = tuple(detections)

    def set_camera_rows(self, rows: npt.NDArray[np.float64], capture_time_s: float) -> None:
        """Camera detections as rows (``CAMERA_SIZE``: relative position as measured at ``capture_time_s``, radius,
        age then), as the detector's rig pass leaves them (sitl/perception/detector.py ``rig_ned_rows``): no record
        is built for a frame nobody but the avoidance reads."""
        self._camera_rows = rows
        self._camera_records = None
        self._camera_time_s = capture_time_s

    def set_relay(self, neighbours: Sequence[RelayedNeighbour]) -> None:
        self.set_relay_rows(neighbour_rows(neighbours))
        self._relay_records = tuple(neighbours)

    def set_relay_rows(self, rows: npt.NDArray[np.float64]) -> None:
        """Relayed neighbours as rows (``NEIGHBOUR_SIZE``, in this drone's local frame)."""
        self._relay_rows = rows
        self._relay_records = None

    def relayed(self) -> tuple[RelayedNeighbour, ...]:
        """The neighbours as last converted to this drone's frame (an onboard behaviour reads them too)."""
        if self._relay_records is None:
            self._relay_records = _relayed_records(self._relay_rows)
        return self._relay_records

    def camera(self) -> tuple[Obstacle, ...]:
        """The last frame's detections (an onboard behaviour reads them too)."""
        if self._camera_records is None:
            self._camera_records = tuple(
                new_obstacle(rel_pos_ned_m=(x, y, z), radius_m=radius, source="camera", age_s=age)
                for x, y, z, radius, age in self._camera_rows.tolist()
            )
        return self._camera_records

    def config(self) -> AvoidanceConfig:
        """The algorithm's configuration from the parameter table (rebuilt only when a parameter changed)."""
        if self._config_version != self._params.version:
            p = self._params
            self._config_version = p.version
            self._config = AvoidanceConfig(
                enabled=p["AVOID_ENABLE"] == 1,
                own_radius_m=self._own_radius_m,
                min_distance_m=p["AVOID_MIN_DIST"],
                horizon_s=p["AVOID_HORIZON"],
                max_correction_mps=p["AVOID_MAX_CORR"],
                max_speed_mps=p["MPC_XY_VEL_MAX"],
                max_accel_mps2=p["MPC_ACC_HOR"],
            )
            self._config_row = config_row(self._config)
        return self._config

    def _inputs(self, now_s: float) -> tuple[npt.NDArray[np.float64], float, int, float, float]:
        """What the obstacles are made from at ``now_s`` besides the relayed rows: the camera's rows and how much older
        they are now (no rows once a frame is INPUT_TIMEOUT_S old), how many relayed neighbours to fuse, and the
        growth of a stale report's keep-out (AVOID_STALE_RATE, AVOID_STALE_MAX)."""
        config = self.config()
        camera, camera_age_s = NO_CAMERA, 0.0
        if now_s - self._camera_time_s <= INPUT_TIMEOUT_S and len(self._camera_rows):
            camera, camera_age_s = self._camera_rows, now_s - self._camera_time_s  # aged to now
        # ``avoid`` keeps the nearest few; fusing neighbours it will drop anyway is most of the cost in a crowd.
        keep = RELAY_CANDIDATES_PER_OBSTACLE * config.max_obstacles if config.max_obstacles > 0 else 0
        # The keep-out around a vehicle last known some seconds ago is wider: it may have moved since; its body, seen
        # by the camera, does not grow.
        p = self._params
        return camera, camera_age_s, keep, p["AVOID_STALE_RATE"], p["AVOID_STALE_MAX"]

    def obstacles(self, pos_ned_m: Vec3f, own_vel_ned_mps: Vec3f, now_s: float) -> npt.NDArray[np.float64]:
        """The obstacles a run at ``now_s`` avoids, as fusion's rows (sitl/kernels/avoidance.py ``obstacles``; the swarm
        flies one airframe, and a relay report carries no size, so a neighbour is as large as this drone)."""
        camera, camera_age_s, keep, stale_rate, stale_max = self._inputs(now_s)
        neighbours = self._relay_rows
        out = np.empty((len(camera) + len(neighbours), ak.OBSTACLE_SIZE))
        x, y, z = pos_ned_m
        vx, vy, vz = own_vel_ned_mps
        n = ak.obstacles(x, y, z, vx, vy, vz, camera, camera_age_s, neighbours, now_s, self._own_radius_m, stale_rate,
                         stale_max, keep, self._config_row, out)  # fmt: skip
        return out[:n]

    # ---- the correction --------------------------------------------------------------------------------------------
    def apply(
        self, setpoint: TrajectorySetpoint, pos_ned_m: Vec3, vel_ned_mps: Vec3, now_s: float
    ) -> TrajectorySetpoint:
        """The setpoint to fly: unchanged unless a neighbour is in the way."""
        config = self.config()
        if not config.enabled or (not len(self._camera_rows) and not len(self._relay_rows)):
            self._vel_xy = None
            self._end_episode(now_s)
            return setpoint
        if now_s >= self._next_run_s:
            self._next_run_s = now_s + 1.0 / AVOID_RATE_HZ
            pos = (float(pos_ned_m[0]), float(pos_ned_m[1]), float(pos_ned_m[2]))
            vel = (float(vel_ned_mps[0]), float(vel_ned_mps[1]), float(vel_ned_mps[2]))
            self._run(setpoint, pos, vel, now_s)
        return self.held(setpoint)

    def held(self, setpoint: TrajectorySetpoint) -> TrajectorySetpoint:
        """``setpoint`` with the correction the last run decided (``corrected``); ``setpoint`` itself when none is
        held."""
        if self._vel_xy is None:
            return setpoint
        return corrected(setpoint, self._vel_xy[0], self._vel_xy[1])

    def holds(self, now_s: float) -> bool:
        """Would ``apply`` at ``now_s`` change nothing and give ``held``'s setpoint: no run due, or nothing to avoid
        with no correction and no episode to end? A steady tick (sitl/autopilot/flight_tick.py) then flies
        ``held(setpoint)`` without the estimate ``apply`` is given."""
        config = self.config()
        if not config.enabled or (not len(self._camera_rows) and not len(self._relay_rows)):
            return self._vel_xy is None and self._last_active_s is None
        return now_s < self._next_run_s

    def due(self, now_s: float) -> bool:
        """Would ``apply`` at ``now_s`` run (avoidance on, something to avoid, a run due)? A steady tick then makes the
        run in its own kernel (sitl/kernels/between_ticks.py ``steady_tick_avoiding``, with ``run_inputs``) and hands
        it back with ``ran``."""
        return (self.config().enabled and (len(self._camera_rows) > 0 or len(self._relay_rows) > 0)
                and now_s >= self._next_run_s)  # fmt: skip

    def run_inputs(self, now_s: float) -> RunInputs:
        """What a run at ``now_s`` takes besides the drone's state and setpoint, in the order sitl/kernels/avoidance.py
        ``run`` takes it: the camera's rows and their age, the relayed rows, this drone's radius, the stale keep-out's
        growth, how many neighbours to fuse, the configuration, whether a correction is held, the row it writes."""
        camera, camera_age_s, keep, stale_rate, stale_max = self._inputs(now_s)
        return (camera, camera_age_s, self._relay_rows, self._own_radius_m, stale_rate, stale_max, keep,
                self._config_row, self._vel_xy is not None, self._run_out)  # fmt: skip

    def ran(self, now_s: float) -> None:
        """The run ``due`` announced was made elsewhere, into the row ``run_inputs`` gave: taken as ``apply`` takes its
        own (the correction held, an episode's start or end said)."""
        self._next_run_s = now_s + 1.0 / AVOID_RATE_HZ
        self._take_run(now_s)

    def _run(self, setpoint: TrajectorySetpoint, pos: Vec3f, own_vel: Vec3f, now_s: float) -> None:
        """One run, in one kernel (sitl/kernels/avoidance.py ``run``: the obstacles from the inputs, ORCA, the conflict
        that starts a correction, the pace a correction aims for); the correction held, and an episode's start and end
        said, here.

        Whether to correct is decided on what the drone would really fly (the position loop's demand, which may be a
        sprint to catch up with its setpoint), not on the capped pace: a pace that is clear says nothing about a
        sprint, and two drones sprinting to catch up after a detour met at 6 m/s closing speed that way. A correction
        starts only for a conflict: a body closer than the separation, or predicted to come closer within the horizon
        at the drone's current or desired velocity (the body keeping its own). ORCA anchors its half-planes at the
        measured velocity, so a demand that differs from it by half the margin towards a neighbour (a hovering
        drone's tracking error and estimate noise, 0.05-0.2 m/s, against 0.1 m/s for two drones 2 m apart) was
        trimmed, and announced, with nothing predicted to come near. Once correcting, ORCA alone decides when to
        stop: releasing a crowd on the prediction alone lets neighbours that each see a clear way turn back into one
        another at once. A correction flies around the mission's pace, not the sprint: a drone held back by its
        neighbours falls behind a moving setpoint and its position loop asks for ever more speed (6 m/s behind a
        2 m/s setpoint in an eight-drone swap), which pushes every drone into the crowd harder than it can clear."""
        camera, camera_age_s, keep, stale_rate, stale_max = self._inputs(now_s)
        (sp_x, sp_y, sp_z), (ff_x, ff_y, ff_z) = setpoint.pos_ned_m, setpoint.vel_ned_mps
        ak.run(pos[0], pos[1], pos[2], own_vel[0], own_vel[1], own_vel[2], sp_x, sp_y, sp_z, ff_x, ff_y, ff_z,
               self._position.row, camera, camera_age_s, self._relay_rows, now_s, self._own_radius_m, stale_rate,
               stale_max, keep, self._config_row, self._vel_xy is not None, self._run_out)  # fmt: skip
        self._take_run(now_s)

    def _take_run(self, now_s: float) -> None:
        """What a run found (``_run_out``): the correction held, or none; an episode's start and end said."""
        ran = self._run_out.tolist()
        if ran[ak.RUN_ACTIVE] == 0.0:
            self._vel_xy = None
            self._end_episode(now_s)
            return
        self._vel_xy = (ran[ak.RUN_VEL], ran[ak.RUN_VEL + 1])
        closest_m = ran[ak.RUN_CLOSEST]
        if self._last_active_s is None and ran[ak.RUN_CONFLICT] != 0.0:  # an episode starts only with a correction
            self.episodes += 1
            self._episode_closest_m = math.inf
            self._event(6, episode_text(conflict_of(ran[ak.RUN_SYSID], ran[ak.RUN_SOURCE], ran[ak.RUN_PREDICTED],
                                                    ran[ak.RUN_IN_S], ran[ak.RUN_SEPARATION])))  # fmt: skip
        self._last_active_s = now_s
        self._episode_closest_m = min(self._episode_closest_m, closest_m)
        self.closest_m = min(self.closest_m, closest_m)

    def _end_episode(self, now_s: float) -> None:
        if self._last_active_s is not None and now_s - self._last_active_s >= EPISODE_END_S:
            self._last_active_s = None
            self._event(6, f"Avoidance ended: closest approach {self._episode_closest_m:.2f} m")


def corrected(setpoint: TrajectorySetpoint, vel_x_mps: float, vel_y_mps: float) -> TrajectorySetpoint:
    """``setpoint`` flying the horizontal velocity (``vel_x_mps``, ``vel_y_mps``) instead of its horizontal position and
    acceleration; altitude keeps its own setpoint (sitl/kernels/between_ticks.py ``steady_tick_avoiding`` writes the
    same row)."""
    z_pos, z_vel, z_acc = setpoint.pos_ned_m[2], setpoint.vel_ned_mps[2], setpoint.acc_ned_mps2[2]
    return TrajectorySetpoint(
        pos_ned_m=(math.nan, math.nan, z_pos),
        vel_ned_mps=(vel_x_mps, vel_y_mps, z_vel),
        acc_ned_mps2=(math.nan, math.nan, z_acc),
        yaw_rad=setpoint.yaw_rad,
        yawspeed_radps=setpoint.yawspeed_radps,
    )


def compared(setpoint: TrajectorySetpoint, last: TrajectorySetpoint | None) -> tuple[bool, float, float]:
    """Whether ``setpoint`` corrected to any horizontal velocity would equal ``last`` (the setpoint the outer loops
    last ran for) but for that velocity, by Python's own comparison, and ``last``'s horizontal velocity: what a kernel
    needs to say whether the corrected setpoint is a new one (sitl/kernels/between_ticks.py ``steady_tick_avoiding``).
    """
    if last is None:
        return False, math.nan, math.nan
    last_vx, last_vy = last.vel_ned_mps[0], last.vel_ned_mps[1]
    return corrected(setpoint, last_vx, last_vy) == last, last_vx, last_vy


def episode_text(conflict: Conflict) -> str:
    """The STATUSTEXT that starts an episode: "Avoidance: drone 3 predicted 1.21 m in 0.8 s (keeping 1.50 m)", or
    "Avoidance: drone 3 at 1.41 m (keeping 1.50 m)" for a body already inside its separation."""
    when = f"predicted {conflict.predicted_m:.2f} m in {conflict.in_s:.1f} s" if conflict.in_s > 0.0 else (
        f"at {conflict.predicted_m:.2f} m")  # fmt: skip
    return f"Avoidance: {conflict.describe()} {when} (keeping {conflict.separation_m:.2f} m)"
