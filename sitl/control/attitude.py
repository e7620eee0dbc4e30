"""Attitude stage: thrust direction and yaw to an attitude setpoint, then a quaternion P loop to body rates.

Two PX4 pieces, in plain float arithmetic:

- ``thrust_to_attitude`` is ``ControlMath::bodyzToAttitude``: the body z axis points against the thrust vector
  and the nose is turned towards the yaw setpoint as far as the tilt allows.
- ``AttitudeController`` follows ``AttitudeControl::update`` (Brescianini, Hehn, D'Andrea 2013, "Nonlinear
  quadrocopter attitude control"): the error is split into a reduced attitude (the tilt that aligns the thrust
  axis) and the remaining heading error, of which only a share ``MC_YAW_WEIGHT`` is used, so that a large
  heading change never steals the roll/pitch authority that keeps the vehicle in the air (yaw is the weakest
  axis of a multirotor). The yaw gain is divided by the weight so the small-error yaw response is still
  ``MC_YAW_P``. One deliberate difference: PX4 multiplies the tilt and the weighted heading rotations into one
  error quaternion, whose cross term turns the tilt correction about the thrust axis by half the weighted
  heading error; with a 5 m step flown together with a 180 degree heading change that swung the true tilt 5
  degrees past MPC_TILTMAX_AIR on the toy plant. Here the tilt error drives roll/pitch rates and the heading
  error drives the yaw rate, separately, which keeps the tilt correction on the shortest path.

Quaternions are (w, x, y, z) tuples rotating FRD body vectors into NED.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from sitl.control import Vec3f

Quat4f = tuple[float, float, float, float]


@dataclass(frozen=True, slots=True, kw_only=True)
class AttitudeConfig:
    roll_p_per_s: float  # MC_ROLL_P
    pitch_p_per_s: float  # MC_PITCH_P
    yaw_p_per_s: float  # MC_YAW_P
    yaw_weight: float  # MC_YAW_WEIGHT, in [0, 1]
    roll_rate_max_radps: float  # MC_ROLLRATE_MAX
    pitch_rate_max_radps: float  # MC_PITCHRATE_MAX
    yaw_rate_max_radps: float  # MC_YAWRATE_MAX


def quat_mul(a: Quat4f, b: Quat4f) -> Quat4f:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def _conj_mul(a: Quat4f, b: Quat4f) -> Quat4f:
    """conj(a) * b for unit quaternions: the rotation from a to b."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw + ax * bx + ay * by + az * bz,
        aw * bx - ax * bw - ay * bz + az * by,
        aw * by + ax * bz - ay * bw - az * bx,
        aw * bz - ax * by + ay * bx - az * bw,
    )


def dcm_columns_to_quat(
    c0: Vec3f,
    c1: Vec3f,
    c2: Vec3f,
) -> Quat4f:
    """Unit quaternion (w >= 0) of the rotation matrix with columns c0, c1, c2 (Shepperd's method)."""
    r00, r10, r20 = c0
    r01, r11, r21 = c1
    r02, r12, r22 = c2
    return _dcm_to_quat(r00, r01, r02, r10, r11, r12, r20, r21, r22)


def _dcm_to_quat(
    r00: float, r01: float, r02: float, r10: float, r11: float, r12: float, r20: float, r21: float, r22: float
) -> Quat4f:
    tr = r00 + r11 + r22
    if tr > 0.0:
        s = math.sqrt(tr + 1.0) * 2.0
        w, x, y, z = 0.25 * s, (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s
    elif r00 > r11 and r00 > r22:
        s = math.sqrt(1.0 + r00 - r11 - r22) * 2.0
        w, x, y, z = (r21 - r12) / s, 0.25 * s, (r01 + r10) / s, (r02 + r20) / s
    elif r11 > r22:
        s = math.sqrt(1.0 + r11 - r00 - r22) * 2.0
        w, x, y, z = (r02 - r20) / s, (r01 + r10) / s, 0.25 * s, (r12 + r21) / s
    else:
        s = math.sqrt(1.0 + r22 - r00 - r11) * 2.0
        w, x, y, z = (r10 - r01) / s, (r02 + r20) / s, (r12 + r21) / s, 0.25 * s
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:
        n = -n
    return w / n, x / n, y / n, z / n


def thrust_to_attitude(thrust_ned_n: Vec3f, yaw_rad: float) -> Quat4f:
    """Attitude whose body z axis opposes the thrust vector, with the heading closest to ``yaw_rad``."""
    tx, ty, tz = thrust_ned_n
    norm = math.sqrt(tx * tx + ty * ty + tz * tz)
    if norm < 1e-9:
        bz_x, bz_y, bz_z = 0.0, 0.0, 1.0  # no thrust, no direction: level is the safe choice
    else:
        bz_x, bz_y, bz_z = -tx / norm, -ty / norm, -tz / norm
    sin_yaw = math.sin(yaw_rad)
    cos_yaw = math.cos(yaw_rad)
    # body x = (yaw direction rotated by 90 degrees) x body z, which lies in the plane of the yaw heading.
    bx_x = cos_yaw * bz_z
    bx_y = sin_yaw * bz_z
    bx_z = -sin_yaw * bz_y - cos_yaw * bz_x
    if bz_z < 0.0:  # upside down: keep the nose towards the heading
        bx_x, bx_y, bx_z = -bx_x, -bx_y, -bx_z
    if abs(bz_z) < 1e-6:  # thrust in the horizontal plane: heading undefined, any orthogonal x will do
        bx_x, bx_y, bx_z = 0.0, 0.0, 1.0
    n = math.sqrt(bx_x * bx_x + bx_y * bx_y + bx_z * bx_z)
    bx_x /= n
    bx_y /= n
    bx_z /= n
    by_x = bz_y * bx_z - bz_z * bx_y
    by_y = bz_z * bx_x - bz_x * bx_z
    by_z = bz_x * bx_y - bz_y * bx_x
    # The rotation matrix has columns body x, body y, body z.
    return _dcm_to_quat(bx_x, by_x, bz_x, bx_y, by_y, bz_y, bx_z, by_z, bz_z)


def _quat_between(src: Vec3f, dst: Vec3f) -> Quat4f:
    """Shortest rotation taking unit vector src onto unit vector dst."""
    sx, sy, sz = src
    dx, dy, dz = dst
    cx = sy * dz - sz * dy
    cy = sz * dx - sx * dz
    cz = sx * dy - sy * dx
    dot = sx * dx + sy * dy + sz * dz
    if cx * cx + cy * cy + cz * cz < 1e-10 and dot < 0.0:
        # Opposite vectors: rotate half a turn about any axis orthogonal to src (the least aligned base axis).
        ax_, ay_, az_ = abs(sx), abs(sy), abs(sz)
        if ax_ < ay_:
            base = (1.0, 0.0, 0.0) if ax_ < az_ else (0.0, 0.0, 1.0)
        else:
            base = (0.0, 1.0, 0.0) if ay_ < az_ else (0.0, 0.0, 1.0)
        cx = sy * base[2] - sz * base[1]
        cy = sz * base[0] - sx * base[2]
        cz = sx * base[1] - sy * base[0]
        w = 0.0
    else:
        w = dot + 1.0
    n = math.sqrt(w * w + cx * cx + cy * cy + cz * cz)
    return w / n, cx / n, cy / n, cz / n


class AttitudeController:
    """Quaternion attitude P controller with roll/pitch priority; ``update`` returns FRD body-rate
    setpoints."""

    def __init__(self, config: AttitudeConfig) -> None:
        self.config = config

    def reset(self) -> None:
        """Nothing to forget: the attitude loop has no memory."""

    def update(self, att_q: Quat4f, att_sp_q: Quat4f, yawspeed_ff_radps: float = math.nan) -> Vec3f:
        """Body-rate setpoint (rad/s, FRD) steering ``att_q`` to ``att_sp_q``; NaN yaw-rate feed-forward =
        none.

        The yaw-rate feed-forward is about the NED down axis (a heading rate), projected into the body frame.
        """
        cfg = self.config
        qw, qx, qy, qz = att_q
        # Body z axes (third DCM columns) of the current and desired attitude, in NED.
        ez = (2.0 * (qx * qz + qw * qy), 2.0 * (qy * qz - qw * qx), 1.0 - 2.0 * (qx * qx + qy * qy))
        dw, dx, dy, dz = att_sp_q
        ez_d = (2.0 * (dx * dz + dw * dy), 2.0 * (dy * dz - dw * dx), 1.0 - 2.0 * (dx * dx + dy * dy))

        # Reduced setpoint: the current attitude tilted (in the world frame) so that its thrust axis matches.
        tilt = _quat_between(ez, ez_d)
        weight = cfg.yaw_weight
        yaw_gain = cfg.yaw_p_per_s / weight if weight > 1e-4 else cfg.yaw_p_per_s
        if abs(tilt[1]) > 1.0 - 1e-5 or abs(tilt[2]) > 1.0 - 1e-5:
            # Thrust axes exactly opposed: no preferred tilt axis, so steer by the full attitude error.
            ew, ex, ey, ez_ = _conj_mul(att_q, att_sp_q)
            sign = 2.0 if ew >= 0.0 else -2.0
            rate_x = sign * ex * cfg.roll_p_per_s
            rate_y = sign * ey * cfg.pitch_p_per_s
            rate_z = sign * ez_ * cfg.yaw_p_per_s
        else:
            # reduced = tilt * att_q, then conj(att_q) * reduced and conj(reduced) * att_sp_q, written out with
            # only the components used (this runs every control step).
            tw, tx, ty, tz = tilt
            rw = tw * qw - tx * qx - ty * qy - tz * qz
            rx = tw * qx + tx * qw + ty * qz - tz * qy
            ry = tw * qy - tx * qz + ty * qw + tz * qx
            rz = tw * qz + tx * qy - ty * qx + tz * qw
            # Tilt error in the body frame (its axis lies in the body x-y plane), as 2 sin(angle / 2) * axis.
            ex = qw * rx - qx * rw - qy * rz + qz * ry
            ey = qw * ry + qx * rz - qy * rw - qz * rx
            rate_x = 2.0 * ex * cfg.roll_p_per_s
            rate_y = 2.0 * ey * cfg.pitch_p_per_s
            # Remaining heading error about the thrust axis, of which only the weighted share is used.
            mw = rw * dw + rx * dx + ry * dy + rz * dz
            mz = rw * dz - rx * dy + ry * dx - rz * dw
            if mw < 0.0:
                mz = -mz
            mz = mz if mz > -1.0 else -1.0
            mz = mz if mz < 1.0 else 1.0
            rate_z = 2.0 * math.sin(weight * math.asin(mz)) * yaw_gain

        if yawspeed_ff_radps == yawspeed_ff_radps:
            # NED down axis seen from the body: third row of the body->NED rotation matrix.
            rate_x += 2.0 * (qx * qz - qw * qy) * yawspeed_ff_radps
            rate_y += 2.0 * (qy * qz + qw * qx) * yawspeed_ff_radps
            rate_z += (1.0 - 2.0 * (qx * qx + qy * qy)) * yawspeed_ff_radps

        lim = cfg.roll_rate_max_radps
        rate_x = -lim if rate_x < -lim else (lim if rate_x > lim else rate_x)
        lim = cfg.pitch_rate_max_radps
        rate_y = -lim if rate_y < -lim else (lim if rate_y > lim else rate_y)
        lim = cfg.yaw_rate_max_radps
        rate_z = -lim if rate_z < -lim else (lim if rate_z > lim else rate_z)
        return rate_x, rate_y, rate_z
