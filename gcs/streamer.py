"""Formation flight over MAVLink: the formation engine's setpoints streamed to every drone in OFFBOARD.

Targets live in the swarm frame; each drone gets SET_POSITION_TARGET_LOCAL_NED (position with velocity and
acceleration feed-forward) in its own local frame, whose origin is recovered from its HOME_POSITION
(gcs/frames.py explains the choice). PX4 accepts OFFBOARD only while setpoints arrive, so the first setpoints go
out before the mode switch, and then at SETPOINT_STREAM_HZ. Used by ``swarm fly`` and by ``swarm up``'s
``formation`` command alike.
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink

from gcs.formation import Formation, FormationEngine, TransitionLimits
from gcs.frames import DroneFrame, SwarmFrame, Vec3, origin_from_home
from gcs.swarm import Swarm, SwarmError, check
from sitl.dynamics.plant import GeoPoint

# Position setpoint with velocity and acceleration feed-forward; yaw and yaw rate ignored (type_mask bits 10, 11).
TYPE_MASK_POS_VEL_ACC = 0b0000_1100_0000_0000
OFFBOARD_MODE = (1.0, 6.0, 0.0)  # DO_SET_MODE: custom mode enabled, main mode OFFBOARD
DEFAULT_LIMITS = TransitionLimits(max_speed_mps=1.5, max_accel_mps2=1.0)


class FormationStreamer:
    def __init__(self, swarm: Swarm, frame: SwarmFrame, limits: TransitionLimits = DEFAULT_LIMITS) -> None:
        self.swarm = swarm
        self.swarm_frame = frame
        self.engine = FormationEngine(limits)
        self.active = False
        self.formation: Formation | None = None
        self._frames: dict[int, DroneFrame] = {}

    def drone_frame(self, sysid: int) -> DroneFrame | None:
        """The drone's local frame, once its HOME_POSITION has arrived."""
        frame = self._frames.get(sysid)
        if frame is None:
            view = self.swarm.fleet.drones.get(sysid)
            if view is None or view.home is None or view.home_local_ned_m is None:
                return None
            home = GeoPoint(lat_deg=view.home[0], lon_deg=view.home[1], alt_amsl_m=view.home[2])
            frame = self._frames[sysid] = self.swarm_frame.drone_frame(origin_from_home(home, view.home_local_ned_m))
        return frame

    def positions(self) -> dict[int, Vec3]:
        """Every drone's reported position in the swarm frame (drones without a home yet are left out)."""
        out = {}
        for sysid in self.swarm.sysids:
            frame = self.drone_frame(sysid)
            view = self.swarm.fleet.drones.get(sysid)
            if frame is not None and view is not None and all(math.isfinite(v) for v in view.local_ned_m):
                out[sysid] = frame.to_swarm(view.local_ned_m)
        return out

    def command(self, formation: Formation, now_s: float) -> None:
        """Plan the transition into ``formation`` and make sure every drone is flying it in OFFBOARD."""
        positions = self.positions()
        missing = sorted(set(self.swarm.sysids) - set(positions))
        if missing:
            raise SwarmError(f"no position yet from sysid {missing}: cannot plan a formation")
        if not all(self.swarm.fleet.drones[s].armed for s in self.swarm.sysids):
            raise SwarmError("every drone must be armed and flying before a formation (swarm takeoff)")
        self.engine.command(formation, now_s, positions)
        self.formation = formation
        if not self.active:
            self.active = True
            self.tick(now_s)  # PX4 accepts OFFBOARD only once setpoints are arriving
            check(self.swarm.command_all(mavlink.MAV_CMD_DO_SET_MODE, *OFFBOARD_MODE), "offboard")

    def stop(self) -> None:
        """Stop streaming (before a land or RTL command takes the drones out of OFFBOARD)."""
        self.active = False

    def targets(self, now_s: float) -> dict[int, Vec3]:
        return self.engine.targets(now_s) if self.active else {}

    def tick(self, now_s: float) -> None:
        if not self.active:
            return
        boot_ms = int(now_s * 1000) & 0xFFFFFFFF
        for sysid, sp in self.engine.setpoints(now_s).items():
            frame = self.drone_frame(sysid)
            if frame is None:
                continue
            x, y, z = frame.to_local(sp.pos_ned_m)
            vx, vy, vz = frame.vector_to_local(sp.vel_ned_mps)
            ax, ay, az = frame.vector_to_local(sp.acc_ned_mps2)
            msg = mavlink.MAVLink_set_position_target_local_ned_message(
                boot_ms, sysid, 1, mavlink.MAV_FRAME_LOCAL_NED, TYPE_MASK_POS_VEL_ACC,
                x, y, z, vx, vy, vz, ax, ay, az, 0.0, 0.0,
            )  # fmt: skip
            self.swarm.send(sysid, msg)
