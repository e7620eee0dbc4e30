"""Formation flight over MAVLink: the formation engine's setpoints streamed to every drone in OFFBOARD.

Targets live in the swarm frame; each drone gets SET_POSITION_TARGET_LOCAL_NED (position with velocity and
acceleration feed-forward) in its own local frame, whose origin is recovered from its HOME_POSITION
(gcs/flight/frames.py explains the choice). PX4 accepts OFFBOARD only while setpoints arrive, so the first setpoints go
out before the mode switch, and then at SETPOINT_STREAM_HZ. Used by ``swarm fly`` and by ``swarm up``'s
``formation`` command alike.

An attached member (gcs/fleet/attachments.py) flies with the drones: its position comes from its GLOBAL_POSITION_INT
(it has no local frame the ground station knows), and its setpoints go through ``Attachments.setpoint``, which sends
them as SET_POSITION_TARGET_GLOBAL_INT under its safety rules; OFFBOARD is its autopilot's (GUIDED for ArduPilot).

Instead of the formation engine, a behaviour (gcs/flight/behaviours.py: leader-follower, flocking) can be streamed: it
is handed the drones' reported state (``state``) every tick. Its setpoints may leave components out (NaN): the
``type_mask`` then ignores them, e.g. flocking sends a horizontal velocity with acceleration feed-forward and an
altitude (``TYPE_MASK_VEL_XY_POS_Z``).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

from pymavlink.dialects.v20 import common as mavlink

from gcs.fleet.commanding import check
from gcs.fleet.errors import SwarmError
from gcs.fleet.swarm import Swarm
from gcs.flight.behaviours import Behaviour, Flock, FlockSpec, FollowSpec, LeaderFollower, SwarmState
from gcs.flight.crossing import CrossingMove, antipodal_goals
from gcs.flight.formation import (
    SETPOINT_STREAM_HZ,
    Formation,
    FormationEngine,
    FormationError,
    Setpoint,
    TransitionLimits,
)
from gcs.flight.frames import Vec3
from gcs.mavlink.modes import HOLD, OFFBOARD

log = logging.getLogger(__name__)

# Position setpoint with velocity and acceleration feed-forward; yaw and yaw rate ignored (type_mask bits 10, 11).
TYPE_MASK_POS_VEL_ACC = 0b0000_1100_0000_0000
_POS_BITS = (
    mavlink.POSITION_TARGET_TYPEMASK_X_IGNORE,
    mavlink.POSITION_TARGET_TYPEMASK_Y_IGNORE,
    mavlink.POSITION_TARGET_TYPEMASK_Z_IGNORE,
)
_VEL_BITS = (
    mavlink.POSITION_TARGET_TYPEMASK_VX_IGNORE,
    mavlink.POSITION_TARGET_TYPEMASK_VY_IGNORE,
    mavlink.POSITION_TARGET_TYPEMASK_VZ_IGNORE,
)
_ACC_BITS = (
    mavlink.POSITION_TARGET_TYPEMASK_AX_IGNORE,
    mavlink.POSITION_TARGET_TYPEMASK_AY_IGNORE,
    mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE,
)
# Horizontal velocity with acceleration feed-forward, altitude by position (flocking): x, y, vz, az, yaw ignored.
TYPE_MASK_VEL_XY_POS_Z = TYPE_MASK_POS_VEL_ACC | _POS_BITS[0] | _POS_BITS[1] | _VEL_BITS[2] | _ACC_BITS[2]
T = TypeVar("T")
OFFBOARD_ATTEMPTS = 3  # switches asked of a drone that refuses OFFBOARD for want of a setpoint...
OFFBOARD_RETRY_S = 0.5  # ...with this long of setpoints streamed in between (10 at SETPOINT_STREAM_HZ)
DEFAULT_LIMITS = TransitionLimits(max_speed_mps=1.5, max_accel_mps2=1.0)
_SET_MODE = mavlink.MAV_CMD_DO_SET_MODE


@dataclass(slots=True)
class _Rejoin:
    """A drone taken back after its link came back, on its way into OFFBOARD (``FormationStreamer.tick``)."""

    due_s: float  # when to ask for OFFBOARD (after OFFBOARD_RETRY_S of setpoints)
    attempts: int = 0  # switches asked so far
    asked: bool = False  # one is waiting for its answer


def type_mask(sp: Setpoint) -> int:
    """SET_POSITION_TARGET type_mask for a setpoint: every NaN component ignored, yaw used when finite (a crossing
    move faces the way it flies), yaw rate always ignored.

    A horizontal position needs both north and east: one NaN drops both.
    """
    mask = TYPE_MASK_POS_VEL_ACC
    if math.isfinite(sp.yaw_rad):
        mask &= ~mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE
    (pn, pe, pd), (vn, ve, vd), (an, ae, ad) = sp.pos_ned_m, sp.vel_ned_mps, sp.acc_ned_mps2
    if math.isfinite(pn + pe + pd + vn + ve + vd + an + ae + ad):
        return mask  # every component given (a sum is finite only if every term is): the formations' case
    for bits, values in ((_POS_BITS, sp.pos_ned_m), (_VEL_BITS, sp.vel_ned_mps), (_ACC_BITS, sp.acc_ned_mps2)):
        for bit, value in zip(bits, values, strict=True):
            if not math.isfinite(value):
                mask |= bit
    if mask & (_POS_BITS[0] | _POS_BITS[1]):
        mask |= _POS_BITS[0] | _POS_BITS[1]
    return mask


def _finite_or_zero(values: Vec3) -> Vec3:
    return (
        values[0] if math.isfinite(values[0]) else 0.0,
        values[1] if math.isfinite(values[1]) else 0.0,
        values[2] if math.isfinite(values[2]) else 0.0,
    )


class FormationStreamer:
    def __init__(self, swarm: Swarm, limits: TransitionLimits = DEFAULT_LIMITS) -> None:
        self.swarm = swarm
        self.picture = swarm.picture  # where every vehicle is, in the swarm frame: what the streamer plans from
        self.limits = limits
        self.engine = FormationEngine(limits)
        self.active = False
        self.formation: Formation | None = None
        self.behaviour: Behaviour | None = None
        self._rejoining: dict[int, _Rejoin] = {}  # sysid -> its way back into OFFBOARD
        self.observer: Callable[[float], dict[int, Vec3]] | None = None  # slots of drones flying themselves

    def _positions(self) -> dict[int, Vec3]:
        """Every flown vehicle's reported position in the swarm frame (gcs/fleet/picture.py)."""
        return self.picture.positions(self.swarm.flown_sysids)

    def _state(self) -> SwarmState:
        """What a flight law starts from: the flown vehicles that are armed and have said where they are and how
        they move."""
        return self.picture.state(self.swarm.flown_sysids)

    def _check_ready(self, what: str) -> dict[int, Vec3]:
        positions = self._positions()
        active = self.swarm.flown_sysids
        if not active:
            raise SwarmError(f"every drone is lost: cannot plan {what}")
        missing = sorted(set(active) - set(positions))
        if missing:
            raise SwarmError(f"no position yet from sysid {missing}: cannot plan {what}")
        if not all(self.swarm.fleet.drones[s].armed for s in active):
            raise SwarmError(f"every drone must be armed and flying before {what} (swarm takeoff)")
        return positions

    def command(self, formation: Formation, now_s: float) -> None:
        """Plan the transition into ``formation`` and make sure every drone is flying it in OFFBOARD."""
        positions = self._check_ready("a formation")
        self.engine.command(formation, now_s, positions)
        self.formation = formation
        self.behaviour = None
        self._offboard(now_s)

    def command_follow(self, spec: FollowSpec, now_s: float) -> LeaderFollower:
        """Leader-follower flight of every drone (gcs/flight/behaviours.py), in OFFBOARD."""
        self._check_ready("leader-follower")
        behaviour = LeaderFollower(spec, now_s, self._state(), self.limits)
        self._start_behaviour(behaviour, now_s)
        return behaviour

    def command_flock(self, spec: FlockSpec, now_s: float) -> Flock:
        """Reynolds flocking of every drone (gcs/flight/behaviours.py), in OFFBOARD."""
        self._check_ready("flocking")
        behaviour = Flock(spec, now_s, self._state())
        self._start_behaviour(behaviour, now_s)
        return behaviour

    def command_swap(self, speed_mps: float, accel_mps2: float, now_s: float) -> CrossingMove:
        """Every drone straight through the centre to the opposite point (gcs/flight/crossing.py): paths cross on
        purpose."""
        positions = self._check_ready("a swap")
        behaviour = CrossingMove(positions, antipodal_goals(positions), now_s, speed_mps=speed_mps,
                                 accel_mps2=accel_mps2)  # fmt: skip
        self._start_behaviour(behaviour, now_s)
        return behaviour

    def command_behaviour(self, behaviour: Behaviour, now_s: float, what: str = "a controller") -> None:
        """Stream any ``Behaviour`` (a user's controller, gcs/api) to every drone, in OFFBOARD."""
        self._check_ready(what)
        self._start_behaviour(behaviour, now_s)

    def _start_behaviour(self, behaviour: Behaviour, now_s: float) -> None:
        self.behaviour = behaviour
        self.formation = None
        # A later formation starts from where the drones are, not from a plan made before the behaviour.
        self.engine = FormationEngine(self.limits)
        self._offboard(now_s)

    def _offboard(self, now_s: float) -> None:
        """Stream, then switch every drone to OFFBOARD. PX4 accepts OFFBOARD only once setpoints are arriving: a
        drone whose first setpoint was lost on the way (a lossy link) refuses, so the stream goes on for
        OFFBOARD_RETRY_S and the drones that refused are asked again, up to OFFBOARD_ATTEMPTS times. On a perfect
        link the first answer is yes and nothing waits."""
        self._rejoining.clear()  # every drone is asked below
        flown = self.swarm.flown_sysids
        attachments = self.swarm.attachments
        if attachments.vehicles:
            attachments.grounded_notice(flown)
        members = [s for s in flown if s in self.swarm.attachments.vehicles]
        if not self.active:
            self.active = True
            self.tick(now_s)  # (a member whose first setpoint leaves its keep-in is released here: not asked below)
            pending = [s for s in flown if s not in members or attachments.vehicles[s].released is None]
        else:  # the drones fly OFFBOARD already; a member that has joined since is asked
            pending = [s for s in members if s not in attachments.commanded()]
        acks = []
        for attempt in range(OFFBOARD_ATTEMPTS):
            acks = self.swarm.commands.set_mode(OFFBOARD, pending) if pending else []
            pending = [ack.sysid for ack in acks if not ack.ok]
            if not pending or attempt == OFFBOARD_ATTEMPTS - 1:
                break
            self.swarm.pump.run_for(OFFBOARD_RETRY_S, tick=self.tick, tick_s=1.0 / SETPOINT_STREAM_HZ)
        for ack in acks:  # a member that will not fly OFFBOARD (GUIDED) is its pilot's: the drones fly on
            if not ack.ok and ack.sysid in self.swarm.attachments.vehicles:
                answer = "no answer" if ack.result is None else f"result {ack.result}"
                attachments.release(ack.sysid, f"it did not take the mode to fly setpoints ({answer})", hold=False)
        check([ack for ack in acks if ack.sysid not in self.swarm.attachments.vehicles], "offboard")

    def handle_loss(self, sysid: int, now_s: float) -> str | None:
        """Carry on without drone ``sysid`` (already in ``swarm.liveness.losses``): a formation re-plans over the
        survivors with the same synchronised, collision-aware transition as a formation change; a lost leader hands
        over to the next follower; flocking simply goes on without it. Returns one line saying what changed, or
        None."""
        if not self.active:
            return None
        survivors = self._positions()
        if not survivors:
            self.stop()
            return "no drone left to fly"
        if self.behaviour is None and self.formation is not None:
            try:
                transition = self.engine.command(self.formation, now_s, survivors)
            except FormationError as exc:
                return f"formation not re-planned: {exc}"
            return f"formation re-planned over {len(survivors)} drones (arrival in {transition.duration_s:.1f} s)"
        if isinstance(self.behaviour, LeaderFollower):
            behaviour = self.behaviour.without(sysid, now_s, self._state(), self.limits)
            handed_over = behaviour.leader != self.behaviour.leader
            self.behaviour = behaviour
            return f"leader sysid {sysid} lost: sysid {behaviour.leader} leads" if handed_over else None
        if isinstance(self.behaviour, Flock):
            return f"flocking goes on with {len(survivors)} drones"
        return None

    def handle_regain(self, sysid: int, now_s: float) -> str | None:
        """Take drone ``sysid`` back into what is being flown (heard again after a link loss, already out of
        ``swarm.liveness.losses``), if it still flies. A formation re-plans over every drone with it (the same
        synchronised, collision-aware transition as a change); flocking counts it again. Its setpoints stream at
        once, and after OFFBOARD_RETRY_S of them it is switched back to OFFBOARD (``tick``): meanwhile its
        offboard-loss failsafe has it holding or landing. Leader-follower and a swap were planned without it and
        cannot take it in mid-flight: it holds where it is (PX4 Hold) until the next formation or behaviour command.
        A drone that came down meanwhile stays on the ground. Returns one line saying what happened, or None."""
        if not self.active:
            return None
        view = self.swarm.fleet.drones.get(sysid)
        if view is None or not view.armed or view.landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND:
            return f"sysid {sysid} is on the ground: it stays out of the flight"
        if self.behaviour is None and self.formation is not None:
            positions = self._positions()
            try:
                transition = self.engine.command(self.formation, now_s, positions)
            except FormationError as exc:
                self.swarm.commands.set_mode_start(sysid, HOLD)
                return f"formation not re-planned with sysid {sysid} ({exc}): it holds where it is"
            self._rejoining[sysid] = _Rejoin(due_s=now_s + OFFBOARD_RETRY_S)
            return (
                f"formation re-planned over {len(positions)} drones, sysid {sysid} back "
                f"(arrival in {transition.duration_s:.1f} s)"
            )
        if isinstance(self.behaviour, Flock):
            self._rejoining[sysid] = _Rejoin(due_s=now_s + OFFBOARD_RETRY_S)
            return f"sysid {sysid} flocks again"
        self.swarm.commands.set_mode_start(sysid, HOLD)
        return f"sysid {sysid} holds where it is until the next formation or behaviour command"

    def _rejoin_due(self, now_s: float) -> None:
        """Switch the drones taken back into OFFBOARD once their setpoints have streamed for a while; a refusal (a
        setpoint lost on the way) is asked again after OFFBOARD_RETRY_S more, up to OFFBOARD_ATTEMPTS times, as
        ``_offboard`` does. Never waits: the answers are picked up at later ticks."""
        for sysid, rejoin in list(self._rejoining.items()):
            if sysid in self.swarm.liveness.losses:  # lost again on its way back
                del self._rejoining[sysid]
                continue
            if rejoin.asked:
                ack = self.swarm.commands.command_outcome(sysid, _SET_MODE)
                if ack is None and self.swarm.commands.client.in_flight(sysid, _SET_MODE):
                    continue
                rejoin.asked = False
                if ack is None or ack.ok:  # superseded by a later command, or back in OFFBOARD
                    del self._rejoining[sysid]
                    continue
                if rejoin.attempts >= OFFBOARD_ATTEMPTS:
                    log.warning("sysid %s refused OFFBOARD %d times after its link came back", sysid, rejoin.attempts)
                    del self._rejoining[sysid]
                    continue
                rejoin.due_s = now_s + OFFBOARD_RETRY_S
            if now_s >= rejoin.due_s:
                self.swarm.commands.set_mode_start(sysid, OFFBOARD)
                rejoin.attempts += 1
                rejoin.asked = True

    def stop(self) -> None:
        """Stop streaming (once a land, Hold or Return command has taken the drones out of OFFBOARD: ``hand_over``)."""
        self.active = False
        self._rejoining.clear()

    def hand_over(self, command: Callable[[], T]) -> T:
        """Run ``command`` (land, Hold, Return, a mission start: anything that takes the drones out of OFFBOARD)
        while the setpoints still stream, then stop streaming. Stopping first would leave a drone without setpoints
        while the command, or its answer, is lost and sent again on a lossy link: after COM_OF_LOSS_T it enters the
        offboard-loss failsafe before the command arrives (found by the soak, docs/reliability.md)."""
        try:
            return command()
        finally:
            self.stop()

    def targets(self, now_s: float) -> dict[int, Vec3]:
        """Each commanded drone's slot now; while the drones fly themselves (an onboard behaviour), the
        ``observer``'s, if one watches them (gcs/command/onboard_flight.py)."""
        if not self.active:
            return self.observer(now_s) if self.observer is not None else {}
        return self.behaviour.targets() if self.behaviour is not None else self.engine.targets(now_s)

    def tick(self, now_s: float) -> None:
        if not self.active:
            return
        if self._rejoining:
            self._rejoin_due(now_s)
        boot_ms = int(now_s * 1000) & 0xFFFFFFFF
        if self.behaviour is not None:
            state = self._state()
            setpoints = self.behaviour.setpoints(now_s, state)
        else:
            state = None
            setpoints = self.engine.setpoints(now_s)
        attached = self.swarm.attachments.vehicles
        for sysid, sp in setpoints.items():
            frame = self.picture.drone_frame(sysid) if sysid not in attached else None
            if (frame is None and sysid not in attached) or sysid in self.swarm.liveness.losses:
                continue
            mask = type_mask(sp)
            pos = sp.pos_ned_m
            if mask & _POS_BITS[0]:
                # Altitude alone: place it above the drone's reported position (the two tangent planes differ by
                # d^2 / 2R in height, 0.8 mm at 100 m from the swarm origin: negligible, but free to get right).
                row = state.row(sysid) if state is not None else None
                here = state.pos_ned_m[row] if state is not None and row is not None else (0.0, 0.0)
                pos = (float(here[0]), float(here[1]), pos[2])
            if frame is None:  # an attached member: global setpoints, under its safety rules
                yaw = sp.yaw_rad if math.isfinite(sp.yaw_rad) else 0.0
                self.swarm.attachments.setpoint(sysid, _finite_or_zero(pos), _finite_or_zero(sp.vel_ned_mps),
                                                _finite_or_zero(sp.acc_ned_mps2), yaw, mask, now_s)  # fmt: skip
                continue
            x, y, z = frame.to_local(_finite_or_zero(pos))
            vx, vy, vz = frame.vector_to_local(_finite_or_zero(sp.vel_ned_mps))
            ax, ay, az = frame.vector_to_local(_finite_or_zero(sp.acc_ned_mps2))
            msg = mavlink.MAVLink_set_position_target_local_ned_message(
                boot_ms, sysid, 1, mavlink.MAV_FRAME_LOCAL_NED, mask,
                x, y, z, vx, vy, vz, ax, ay, az, sp.yaw_rad if math.isfinite(sp.yaw_rad) else 0.0, 0.0,
            )  # fmt: skip
            self.swarm.router.send(sysid, msg)
