"""Offboard setpoints: SET_POSITION_TARGET_LOCAL_NED, SET_POSITION_TARGET_GLOBAL_INT and SET_ATTITUDE_TARGET.

The decoders are pure functions from a message and the vehicle's current pose to one setpoint in absolute local NED,
with NaN for every component the ``type_mask`` ignores, so the autopilot never deals with frames or masks:
- frame 1 LOCAL_NED: as sent;
- frame 7 LOCAL_OFFSET_NED: position is an offset from the current position, velocity/acceleration are NED;
- frame 8 BODY_NED: velocity/acceleration rotated from the heading frame into NED, position ignored (PX4);
- frame 9 BODY_OFFSET_NED: position offset and velocity/acceleration rotated by the heading, offset added;
- SET_POSITION_TARGET_GLOBAL_INT: lat/lon/alt (AMSL, or above home in the RELATIVE_ALT frames) converted to the
  local frame around ``local_origin`` with sitl/dynamics/geodesy.py, the same conversion the vehicle reports with.
"Heading frame" means rotation by yaw only, as PX4 does for body-frame setpoints.

A setpoint is rejected (``SetpointRejected``) when a component it asks for is not finite, when it asks for nothing
(all of position, velocity and acceleration ignored), for force setpoints, unknown frames, or when the reference it
needs (local position, origin, home) is missing. ``OffboardService`` forwards good setpoints to the vehicle and turns
rejections into a rate-limited STATUSTEXT; it never answers setpoints on the wire, exactly like PX4.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot.vehicle_api import (
    NAN3,
    GeoPoint,
    Vec3,
    VehicleApi,
    VehicleSnapshot,
)
from sitl.control.cascade import AttitudeSetpoint, TrajectorySetpoint
from sitl.dynamics.geodesy import ned_from_geo
from sitl.protocol.core import (
    Effect,
    Identity,
    MAVLinkMessage,
    PeerInputError,
    Send,
    addressed_to,
    check_now,
    message_id,
    read_float,
    read_floats,
    read_int,
)
from sitl.protocol.statustext import Severity, StatusTextEncoder

NAN = math.nan
REJECT_TEXT_INTERVAL_S: Final = 5.0  # one STATUSTEXT per rejection reason per this long (setpoints come at 20 Hz)

X_IGNORE: Final = mavlink.POSITION_TARGET_TYPEMASK_X_IGNORE
Y_IGNORE: Final = mavlink.POSITION_TARGET_TYPEMASK_Y_IGNORE
Z_IGNORE: Final = mavlink.POSITION_TARGET_TYPEMASK_Z_IGNORE
VX_IGNORE: Final = mavlink.POSITION_TARGET_TYPEMASK_VX_IGNORE
VY_IGNORE: Final = mavlink.POSITION_TARGET_TYPEMASK_VY_IGNORE
VZ_IGNORE: Final = mavlink.POSITION_TARGET_TYPEMASK_VZ_IGNORE
AX_IGNORE: Final = mavlink.POSITION_TARGET_TYPEMASK_AX_IGNORE
AY_IGNORE: Final = mavlink.POSITION_TARGET_TYPEMASK_AY_IGNORE
AZ_IGNORE: Final = mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE
FORCE_SET: Final = mavlink.POSITION_TARGET_TYPEMASK_FORCE_SET
YAW_IGNORE: Final = mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE
YAW_RATE_IGNORE: Final = mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE

ATT_ROLL_RATE_IGNORE: Final = mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
ATT_PITCH_RATE_IGNORE: Final = mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE
ATT_YAW_RATE_IGNORE: Final = mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE
ATT_THROTTLE_IGNORE: Final = mavlink.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE
ATT_ATTITUDE_IGNORE: Final = mavlink.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE

_LOCAL_FRAMES: Final = frozenset(
    {
        mavlink.MAV_FRAME_LOCAL_NED,
        mavlink.MAV_FRAME_LOCAL_OFFSET_NED,
        mavlink.MAV_FRAME_BODY_NED,
        mavlink.MAV_FRAME_BODY_OFFSET_NED,
    }
)
_GLOBAL_AMSL: Final = frozenset({mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT})
_GLOBAL_RELATIVE: Final = frozenset({mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT})


class SetpointRejected(PeerInputError):
    """An offboard setpoint that cannot be used; the message says why."""


@dataclass(frozen=True, slots=True, kw_only=True)
class VehiclePose:
    """The references frame conversions need; NaN / None when the vehicle does not have them."""

    pos_ned_m: Vec3 = NAN3
    yaw_rad: float = NAN
    local_origin: GeoPoint | None = None
    home_alt_amsl_m: float = NAN

    @classmethod
    def from_snapshot(cls, snap: VehicleSnapshot) -> VehiclePose:
        return cls(
            pos_ned_m=snap.pos_ned_m,
            yaw_rad=snap.euler_rad[2],
            local_origin=snap.local_origin,
            home_alt_amsl_m=snap.home.position.alt_amsl_m if snap.home is not None else NAN,
        )


_NO_POSE: Final = VehiclePose()  # for the frames whose decoding reads no pose


def _axes(values: tuple[float, float, float], mask: int, bits: tuple[int, int, int], what: str) -> Vec3:
    """Components not ignored by ``mask``; NaN for ignored ones. A used component must be finite."""
    out = []
    for value, bit, axis in zip(values, bits, "xyz", strict=True):
        if mask & bit:
            out.append(NAN)
        elif not math.isfinite(value):
            raise SetpointRejected(f"{what} {axis} is not a finite number")
        else:
            out.append(value)
    return out[0], out[1], out[2]


def _is_set(v: Vec3) -> bool:
    return any(math.isfinite(c) for c in v)


def _rotate_heading(v: Vec3, yaw_rad: float, what: str) -> Vec3:
    """Rotate the horizontal part of a heading-frame vector into NED; an ignored horizontal axis counts as 0."""
    if math.isnan(v[0]) and math.isnan(v[1]):
        return v
    if not math.isfinite(yaw_rad):
        raise SetpointRejected(f"body-frame {what} needs a valid heading")
    fwd = 0.0 if math.isnan(v[0]) else v[0]
    right = 0.0 if math.isnan(v[1]) else v[1]
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return c * fwd - s * right, s * fwd + c * right, v[2]


def _offset(base: Vec3, offset: Vec3) -> Vec3:
    """Current position plus an offset, axis by axis; ignored axes stay NaN."""
    out = []
    for b, o in zip(base, offset, strict=True):
        if math.isnan(o):
            out.append(NAN)
        elif not math.isfinite(b):
            raise SetpointRejected("offset setpoint needs a valid local position")
        else:
            out.append(b + o)
    return out[0], out[1], out[2]


def _yaw_fields(msg: MAVLinkMessage, mask: int) -> tuple[float, float]:
    yaw = NAN if mask & YAW_IGNORE else read_float(msg, "yaw")
    yaw_rate = NAN if mask & YAW_RATE_IGNORE else read_float(msg, "yaw_rate")
    if not (mask & YAW_IGNORE) and not math.isfinite(yaw):
        raise SetpointRejected("yaw is not a finite number")
    if not (mask & YAW_RATE_IGNORE) and not math.isfinite(yaw_rate):
        raise SetpointRejected("yaw rate is not a finite number")
    return yaw, yaw_rate


def _vel_acc(msg: MAVLinkMessage, mask: int) -> tuple[Vec3, Vec3]:
    vel = _axes(
        (read_float(msg, "vx"), read_float(msg, "vy"), read_float(msg, "vz")),
        mask,
        (VX_IGNORE, VY_IGNORE, VZ_IGNORE),
        "velocity",
    )
    acc = _axes(
        (read_float(msg, "afx"), read_float(msg, "afy"), read_float(msg, "afz")),
        mask,
        (AX_IGNORE, AY_IGNORE, AZ_IGNORE),
        "acceleration",
    )
    if mask & FORCE_SET and _is_set(acc):
        raise SetpointRejected("force setpoints are not supported")
    return vel, acc


def _finish(pos: Vec3, vel: Vec3, acc: Vec3, yaw: float, yaw_rate: float) -> TrajectorySetpoint:
    if not (_is_set(pos) or _is_set(vel) or _is_set(acc)):
        raise SetpointRejected("setpoint has no position, velocity or acceleration")
    return TrajectorySetpoint(pos_ned_m=pos, vel_ned_mps=vel, acc_ned_mps2=acc, yaw_rad=yaw, yawspeed_radps=yaw_rate)


def decode_local_ned(msg: MAVLinkMessage, pose: VehiclePose) -> TrajectorySetpoint:
    """SET_POSITION_TARGET_LOCAL_NED -> absolute local NED setpoint (see the module docstring for frames)."""
    frame = read_int(msg, "coordinate_frame", lo=0, hi=255)
    mask = read_int(msg, "type_mask", lo=0, hi=0xFFFF)
    if frame not in _LOCAL_FRAMES:
        raise SetpointRejected(f"SET_POSITION_TARGET_LOCAL_NED frame {frame} unsupported")
    pos = _axes(
        (read_float(msg, "x"), read_float(msg, "y"), read_float(msg, "z")),
        mask,
        (X_IGNORE, Y_IGNORE, Z_IGNORE),
        "position",
    )
    vel, acc = _vel_acc(msg, mask)
    yaw, yaw_rate = _yaw_fields(msg, mask)
    if frame == mavlink.MAV_FRAME_LOCAL_OFFSET_NED:
        pos = _offset(pose.pos_ned_m, pos)
    elif frame == mavlink.MAV_FRAME_BODY_NED:
        if _is_set(pos) and not (_is_set(vel) or _is_set(acc)):
            raise SetpointRejected("BODY_NED setpoints carry velocity or acceleration, not position")
        pos = NAN3
        vel = _rotate_heading(vel, pose.yaw_rad, "velocity")
        acc = _rotate_heading(acc, pose.yaw_rad, "acceleration")
    elif frame == mavlink.MAV_FRAME_BODY_OFFSET_NED:
        pos = _offset(pose.pos_ned_m, _rotate_heading(pos, pose.yaw_rad, "position"))
        vel = _rotate_heading(vel, pose.yaw_rad, "velocity")
        acc = _rotate_heading(acc, pose.yaw_rad, "acceleration")
    return _finish(pos, vel, acc, yaw, yaw_rate)


def decode_global_int(msg: MAVLinkMessage, pose: VehiclePose) -> TrajectorySetpoint:
    """SET_POSITION_TARGET_GLOBAL_INT -> absolute local NED setpoint (projected around the local origin)."""
    frame = read_int(msg, "coordinate_frame", lo=0, hi=255)
    mask = read_int(msg, "type_mask", lo=0, hi=0xFFFF)
    if frame not in _GLOBAL_AMSL | _GLOBAL_RELATIVE:
        raise SetpointRejected(f"SET_POSITION_TARGET_GLOBAL_INT frame {frame} unsupported")
    lat_e7, lon_e7 = read_int(msg, "lat_int"), read_int(msg, "lon_int")
    alt = read_float(msg, "alt")
    vel, acc = _vel_acc(msg, mask)
    yaw, yaw_rate = _yaw_fields(msg, mask)
    use_lat, use_lon, use_alt = not mask & X_IGNORE, not mask & Y_IGNORE, not mask & Z_IGNORE
    if use_lat != use_lon:
        raise SetpointRejected("latitude and longitude must be set together")
    north = east = down = NAN
    if use_lat or use_alt:
        origin = pose.local_origin
        if origin is None:
            raise SetpointRejected("global setpoint needs a local origin (no global position yet)")
        if use_lat:
            if not (-900_000_000 <= lat_e7 <= 900_000_000 and -1_800_000_000 <= lon_e7 <= 1_800_000_000):
                raise SetpointRejected("latitude/longitude out of range")
            target = GeoPoint(lat_deg=lat_e7 * 1e-7, lon_deg=lon_e7 * 1e-7, alt_amsl_m=origin.alt_amsl_m)
            north, east, _ = ned_from_geo(target, origin)
        if use_alt:
            if not math.isfinite(alt):
                raise SetpointRejected("altitude is not a finite number")
            alt_amsl = alt
            if frame in _GLOBAL_RELATIVE:
                if not math.isfinite(pose.home_alt_amsl_m):
                    raise SetpointRejected("relative altitude needs a home position")
                alt_amsl = pose.home_alt_amsl_m + alt
            down = origin.alt_amsl_m - alt_amsl
    return _finish((north, east, down), vel, acc, yaw, yaw_rate)


def decode_attitude_target(msg: MAVLinkMessage, collective_max_n: float) -> AttitudeSetpoint:
    """SET_ATTITUDE_TARGET -> attitude (None when ignored) or body rates (0 for an ignored axis), and the collective
    thrust in newtons: the normalised one (0 when ignored) times the vehicle's ``collective_max_n``."""
    mask = read_int(msg, "type_mask", lo=0, hi=255)
    q_raw = read_floats(msg, "q", 4)
    q = (NAN, NAN, NAN, NAN)
    if not mask & ATT_ATTITUDE_IGNORE:
        norm = math.sqrt(sum(c * c for c in q_raw)) if all(math.isfinite(c) for c in q_raw) else NAN
        if not (math.isfinite(norm) and abs(norm - 1.0) < 0.1):
            raise SetpointRejected("attitude quaternion is not a unit quaternion")
        q = (q_raw[0] / norm, q_raw[1] / norm, q_raw[2] / norm, q_raw[3] / norm)
    rates = _axes(
        (read_float(msg, "body_roll_rate"), read_float(msg, "body_pitch_rate"), read_float(msg, "body_yaw_rate")),
        mask,
        (ATT_ROLL_RATE_IGNORE, ATT_PITCH_RATE_IGNORE, ATT_YAW_RATE_IGNORE),
        "body rate",
    )
    thrust = NAN
    if not mask & ATT_THROTTLE_IGNORE:
        thrust = read_float(msg, "thrust")
        if not math.isfinite(thrust) or not -1.0 <= thrust <= 1.0:
            raise SetpointRejected("thrust must be within [-1, 1]")
        thrust = max(0.0, thrust)  # a multicopter cannot push down
    if math.isnan(q[0]) and not _is_set(rates):
        raise SetpointRejected("attitude setpoint has neither attitude nor body rates")
    return AttitudeSetpoint(
        att_q=q if all(math.isfinite(c) for c in q) else None,
        thrust_n=(thrust if math.isfinite(thrust) else 0.0) * collective_max_n,
        rates_sp_frd_radps=(_or_zero(rates[0]), _or_zero(rates[1]), _or_zero(rates[2])),
    )


def _or_zero(value: float) -> float:
    return value if math.isfinite(value) else 0.0


class OffboardService:
    """Feeds valid offboard setpoints of one link to the vehicle; explains rejected ones with a STATUSTEXT."""

    handles: frozenset[int] = frozenset(
        {
            mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED,
            mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT,
            mavlink.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET,
        }
    )

    def __init__(self, identity: Identity, vehicle: VehicleApi, *, statustext: StatusTextEncoder | None = None) -> None:
        self._identity = identity
        self._vehicle = vehicle
        self._statustext = statustext or StatusTextEncoder()
        self._last_text_s: dict[str, float] = {}
        self.rejected_count = 0

    def handle(self, msg: MAVLinkMessage, now_s: float) -> list[Effect]:
        now_s = check_now(now_s)
        msg_id = message_id(msg)
        if msg_id not in self.handles:
            return []
        try:
            if not addressed_to(msg, self._identity):
                return []
            setpoint: TrajectorySetpoint | AttitudeSetpoint
            if msg_id == mavlink.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET:
                setpoint = decode_attitude_target(msg, self._vehicle.snapshot().collective_max_n)
            else:
                # An absolute local NED setpoint (what a ground station streams at 20 Hz) needs no pose, and a
                # vehicle snapshot is most of what decoding one would cost; every other frame reads the pose.
                absolute = (
                    msg_id == mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED
                    and read_int(msg, "coordinate_frame", lo=0, hi=255) == mavlink.MAV_FRAME_LOCAL_NED
                )
                pose = _NO_POSE if absolute else VehiclePose.from_snapshot(self._vehicle.snapshot())
                if msg_id == mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED:
                    setpoint = decode_local_ned(msg, pose)
                else:
                    setpoint = decode_global_int(msg, pose)
        except SetpointRejected as exc:
            self.rejected_count += 1
            return self._explain(str(exc), now_s)
        except PeerInputError:
            self.rejected_count += 1
            return []
        self._vehicle.set_offboard_setpoint(setpoint, now_s)
        return []

    def poll(self, now_s: float) -> list[Effect]:
        check_now(now_s)
        return []

    def _explain(self, reason: str, now_s: float) -> list[Effect]:
        last = self._last_text_s.get(reason)
        if last is not None and now_s - last < REJECT_TEXT_INTERVAL_S:
            return []
        self._last_text_s[reason] = now_s
        return [Send(m) for m in self._statustext.encode(Severity.CRITICAL, f"Offboard: {reason}")]
