"""A toy quadrotor for controller tests: 6-DOF rigid body, first-order motors, quadratic drag, flat ground.

It exists so the cascade can be tuned and checked in closed loop in milliseconds, without JSBSim. Everything comes
from the Airframe (mass, inertia, rotor positions, spin directions, coefficients, motor lag); rotor forces and
torques are summed from cross products of the rotor positions, independently of the control allocation, so a
wrong mixer shows up as a crash rather than cancelling out. Integration is RK4 with rotor speeds held over the
step. ``NoisyEstimate`` stands in for the estimator: seeded white noise and a fixed delay on the true state.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sitl.dynamics.airframe import Airframe
from sitl.mathutil import GRAVITY_MPS2, quat_from_euler, quat_to_dcm, quat_to_euler

CONTROL_DT_S = 1.0 / 400.0


@dataclass(frozen=True, slots=True, kw_only=True)
class ToyState:
    """Fits the cascade's EstimatedState protocol."""

    time_s: float
    pos_ned_m: np.ndarray
    vel_ned_mps: np.ndarray
    att_q_frd_to_ned: np.ndarray
    rates_frd_radps: np.ndarray


def _quat_derivative(q: np.ndarray, w: np.ndarray) -> np.ndarray:
    qw, qx, qy, qz = q.tolist()
    wx, wy, wz = w.tolist()
    return 0.5 * np.array(
        (
            -qx * wx - qy * wy - qz * wz,
            qw * wx + qy * wz - qz * wy,
            qw * wy - qx * wz + qz * wx,
            qw * wz + qx * wy - qy * wx,
        )
    )


class ToyPlant:
    def __init__(
        self,
        airframe: Airframe,
        *,
        pos_ned_m: tuple[float, float, float] = (0.0, 0.0, -5.0),
        yaw_rad: float = 0.0,
        dt_s: float = CONTROL_DT_S,
        mass_scale: float = 1.0,
    ) -> None:
        self.airframe = airframe
        self.dt_s = dt_s
        self.mass_kg = airframe.mass_kg * mass_scale  # a scale != 1 models an unknown payload
        self.inertia = np.array(airframe.inertia_diag_kg_m2)
        rotor_pos = np.array([r.pos_frd_m for r in airframe.rotors])
        # Torque (N m, FRD) per newton of each rotor's thrust, which acts along -z at the rotor: r x (0, 0, -1).
        self._torque_per_thrust = np.cross(rotor_pos, np.array((0.0, 0.0, -1.0))).T
        self.spin = np.array([float(r.spin_dir) for r in airframe.rotors])
        self.drag = np.array(airframe.drag_coeff_frd_n_per_mps2)
        self.time_s = 0.0
        self.pos = np.array(pos_ned_m, dtype=np.float64)
        self.vel = np.zeros(3)
        self.q = quat_from_euler(0.0, 0.0, yaw_rad)
        self.rates = np.zeros(3)
        hover_speed = math.sqrt(self.mass_kg * GRAVITY_MPS2 / len(airframe.rotors) / airframe.thrust_coeff_n_per_radps2)
        airborne = pos_ned_m[2] < 0.0
        self.rotor_speeds = np.full(len(airframe.rotors), hover_speed if airborne else 0.0)
        self.wind_ned_mps = np.zeros(3)
        self._motor_alpha = 1.0 - math.exp(-dt_s / airframe.motor_time_constant_s)

    def truth(self) -> ToyState:
        return ToyState(
            time_s=self.time_s,
            pos_ned_m=self.pos.copy(),
            vel_ned_mps=self.vel.copy(),
            att_q_frd_to_ned=self.q.copy(),
            rates_frd_radps=self.rates.copy(),
        )

    def _derivative(
        self, vel: np.ndarray, q: np.ndarray, rates: np.ndarray, thrust_n: float, torque_nm: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        dcm = quat_to_dcm((q / np.linalg.norm(q)).tolist())
        air_body = dcm.T @ (vel - self.wind_ned_mps)
        force_body = -self.drag * air_body * np.abs(air_body)
        force_body[2] -= thrust_n
        acc = dcm @ force_body / self.mass_kg
        acc[2] += GRAVITY_MPS2
        wx, wy, wz = rates.tolist()
        jx, jy, jz = self.airframe.inertia_diag_kg_m2
        gyroscopic = np.array(((jz - jy) * wy * wz, (jx - jz) * wz * wx, (jy - jx) * wx * wy))
        rate_dot = (torque_nm - gyroscopic) / self.inertia
        return vel, acc, _quat_derivative(q, rates), rate_dot

    def step(self, motor_cmds: tuple[float, ...] | list[float]) -> ToyState:
        af = self.airframe
        cmds = np.clip(np.asarray(motor_cmds, dtype=np.float64), 0.0, 1.0)
        self.rotor_speeds += self._motor_alpha * (cmds * af.motor_max_speed_radps - self.rotor_speeds)
        speed_sq = self.rotor_speeds**2
        thrusts = af.thrust_coeff_n_per_radps2 * speed_sq
        torque = self._torque_per_thrust @ thrusts
        torque[2] += float(np.dot(self.spin, speed_sq)) * af.torque_coeff_nm_per_radps2
        total = float(thrusts.sum())

        dt = self.dt_s
        p0, v0, q0, w0 = self.pos, self.vel, self.q, self.rates
        k1 = self._derivative(v0, q0, w0, total, torque)
        k2 = self._derivative(v0 + 0.5 * dt * k1[1], q0 + 0.5 * dt * k1[2], w0 + 0.5 * dt * k1[3], total, torque)
        k3 = self._derivative(v0 + 0.5 * dt * k2[1], q0 + 0.5 * dt * k2[2], w0 + 0.5 * dt * k2[3], total, torque)
        k4 = self._derivative(v0 + dt * k3[1], q0 + dt * k3[2], w0 + dt * k3[3], total, torque)
        self.pos = p0 + dt / 6.0 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        self.vel = v0 + dt / 6.0 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        q = q0 + dt / 6.0 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
        self.q = q / np.linalg.norm(q)
        self.rates = w0 + dt / 6.0 * (k1[3] + 2 * k2[3] + 2 * k3[3] + k4[3])
        self.time_s += dt

        if self.pos[2] >= 0.0:  # flat ground at z = 0: no sinking, no sliding, no bouncing
            self.pos[2] = 0.0
            if self.vel[2] > 0.0:
                self.vel[:] = 0.0
                self.rates[:] = 0.0
        return self.truth()

    @property
    def tilt_rad(self) -> float:
        roll, pitch, _ = quat_to_euler(self.q)
        return math.acos(max(-1.0, min(1.0, math.cos(roll) * math.cos(pitch))))


@dataclass
class NoisyEstimate:
    """The true state seen through seeded white noise and a delay of whole control steps."""

    seed: int = 0
    delay_steps: int = 2
    pos_sigma_m: float = 0.01
    vel_sigma_mps: float = 0.02
    att_sigma_rad: float = math.radians(0.1)
    rate_sigma_radps: float = 0.005
    _rng: np.random.Generator = field(init=False)
    _queue: deque[ToyState] = field(init=False)

    def __post_init__(self) -> None:
        self._rng = np.random.default_rng(self.seed)
        self._queue = deque()

    def __call__(self, truth: ToyState) -> ToyState:
        rng = self._rng
        small_rotation = rng.normal(0.0, self.att_sigma_rad, 3)
        dq = np.array((1.0, *(0.5 * small_rotation)))
        q = truth.att_q_frd_to_ned
        w, x, y, z = q
        a, b, c, d = dq
        noisy_q = np.array(
            (
                w * a - x * b - y * c - z * d,
                w * b + x * a + y * d - z * c,
                w * c - x * d + y * a + z * b,
                w * d + x * c - y * b + z * a,
            )
        )
        noisy = ToyState(
            time_s=truth.time_s,
            pos_ned_m=truth.pos_ned_m + rng.normal(0.0, self.pos_sigma_m, 3),
            vel_ned_mps=truth.vel_ned_mps + rng.normal(0.0, self.vel_sigma_mps, 3),
            att_q_frd_to_ned=noisy_q / np.linalg.norm(noisy_q),
            rates_frd_radps=truth.rates_frd_radps + rng.normal(0.0, self.rate_sigma_radps, 3),
        )
        self._queue.append(noisy)
        if len(self._queue) > self.delay_steps:
            return self._queue.popleft()
        return self._queue[0]


@dataclass
class GustyWind:
    """Steady wind plus first-order Gauss-Markov gusts (seeded), sampled once per control step."""

    mean_ned_mps: tuple[float, float, float]
    gust_sigma_mps: float = 1.5
    gust_time_constant_s: float = 2.0
    seed: int = 0
    _rng: np.random.Generator = field(init=False)
    _gust: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self._rng = np.random.default_rng(self.seed)
        self._gust = np.zeros(3)

    def sample(self, dt_s: float) -> np.ndarray:
        tau = self.gust_time_constant_s
        decay = math.exp(-dt_s / tau)
        spread = self.gust_sigma_mps * math.sqrt(1.0 - decay * decay)
        self._gust = decay * self._gust + spread * self._rng.normal(0.0, 1.0, 3)
        return np.array(self.mean_ned_mps) + self._gust * np.array((1.0, 1.0, 0.3))


@dataclass(frozen=True, slots=True, kw_only=True)
class Flight:
    """What a closed-loop run recorded, one row per control step."""

    time_s: np.ndarray
    pos_ned_m: np.ndarray  # (n, 3), true
    tilt_rad: np.ndarray
    yaw_rad: np.ndarray  # unwrapped
    motor_cmds: np.ndarray  # (n, rotors)


def fly(
    cascade: Any,
    plant: ToyPlant,
    setpoint_at: Callable[[float], Any],
    duration_s: float,
    *,
    estimate: Callable[[ToyState], ToyState] | None = None,
    wind: GustyWind | None = None,
) -> Flight:
    """Close the loop: estimate -> cascade.update -> plant.step, at the plant's rate."""
    steps = round(duration_s / plant.dt_s)
    pos = np.empty((steps, 3))
    tilt = np.empty(steps)
    yaw = np.empty(steps)
    cmds = np.empty((steps, len(plant.airframe.rotors)))
    state = plant.truth()
    for i in range(steps):
        if wind is not None:
            plant.wind_ned_mps = wind.sample(plant.dt_s)
        seen = estimate(state) if estimate is not None else state
        out = cascade.update(seen, setpoint_at(state.time_s), plant.dt_s)
        state = plant.step(out.motor_cmds)
        pos[i] = state.pos_ned_m
        tilt[i] = plant.tilt_rad
        yaw[i] = quat_to_euler(plant.q)[2]
        cmds[i] = out.motor_cmds
    return Flight(
        time_s=(np.arange(steps) + 1) * plant.dt_s,
        pos_ned_m=pos,
        tilt_rad=tilt,
        yaw_rad=np.unwrap(yaw),
        motor_cmds=cmds,
    )
