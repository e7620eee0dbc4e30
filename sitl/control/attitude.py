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

import numpy as np

from sitl.control import Vec3f
from sitl.kernels import cascade as ck

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


def dcm_columns_to_quat(
    c0: Vec3f,
    c1: Vec3f,
    c2: Vec3f,
) -> Quat4f:
    """Unit quaternion (w >= 0) of the rotation matrix with columns c0, c1, c2 (Shepperd's method)."""
    r00, r10, r20 = c0
    r01, r11, r21 = c1
    r02, r12, r22 = c2
    return ck.dcm_to_quat(r00, r01, r02, r10, r11, r12, r20, r21, r22)


def thrust_to_attitude(thrust_ned_n: Vec3f, yaw_rad: float) -> Quat4f:
    """Attitude whose body z axis opposes the thrust vector, with the heading closest to ``yaw_rad`` (the kernel)."""
    tx, ty, tz = thrust_ned_n
    return ck.thrust_to_attitude(tx, ty, tz, yaw_rad)


class AttitudeController:
    """Quaternion attitude P controller with roll/pitch priority; ``update`` returns FRD body-rate
    setpoints. The arithmetic is the kernel ``attitude_rates`` (sitl/kernels/cascade.py)."""

    def __init__(self, config: AttitudeConfig) -> None:
        self.config = config

    @property
    def config(self) -> AttitudeConfig:
        return self._config

    @config.setter
    def config(self, config: AttitudeConfig) -> None:
        self._config = config
        row = np.empty(ck.ATTITUDE_SIZE)
        row[ck.A_ROLL_P] = config.roll_p_per_s
        row[ck.A_PITCH_P] = config.pitch_p_per_s
        row[ck.A_YAW_P] = config.yaw_p_per_s
        row[ck.A_YAW_WEIGHT] = config.yaw_weight
        row[ck.A_ROLL_MAX] = config.roll_rate_max_radps
        row[ck.A_PITCH_MAX] = config.pitch_rate_max_radps
        row[ck.A_YAW_MAX] = config.yaw_rate_max_radps
        self.row = row  # the configuration as the kernels take it

    def reset(self) -> None:
        """Nothing to forget: the attitude loop has no memory."""

    def update(self, att_q: Quat4f, att_sp_q: Quat4f, yawspeed_ff_radps: float = math.nan) -> Vec3f:
        """Body-rate setpoint (rad/s, FRD) steering ``att_q`` to ``att_sp_q``; NaN yaw-rate feed-forward =
        none.

        The yaw-rate feed-forward is about the NED down axis (a heading rate), projected into the body frame.
        """
        qw, qx, qy, qz = att_q
        dw, dx, dy, dz = att_sp_q
        return ck.attitude_rates(qw, qx, qy, qz, dw, dx, dy, dz, yawspeed_ff_radps, self.row)
