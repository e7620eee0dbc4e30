"""The controller cascade of one drone: estimated state + setpoint in, motor commands out.

A thin composition of the pure stages (position -> velocity -> attitude -> rate -> allocation). It owns the
things the stages must not: the parameter store (configs are rebuilt when ``ParamStore.version`` changes,
so a gain set in flight takes effect at the next step), the little memory that sits between stages (the
allocation's saturation report fed back to the rate integrator, the held heading) and the loop rates.

Loop rates, as in PX4: the attitude, rate and allocation stages run at every call (the physics rate); the
position and velocity loops, and the attitude setpoint they produce, run at ``MPC_LOOP_HZ`` and are held in
between, with the velocity loop's integrator and derivative using the time actually elapsed since their last run.
A new setpoint (one that differs from the last) or a parameter change is acted on at once, so the lower rate
only spaces out the updates of a setpoint that holds still (hover, hold, a formation slot between two streamed
setpoints). At or above the physics rate the outer loops run at every call, and the cascade is single-rate.

Two entry points, matching the MAVLink setpoints a PX4 vehicle accepts:
- ``update`` with a ``TrajectorySetpoint`` (SET_POSITION_TARGET_*: position, velocity, acceleration, yaw, yaw
  rate, any field NaN = not set), used by every autopilot mode;
- ``update_attitude`` with an ``AttitudeSetpoint`` (attitude or body rates, and a collective thrust).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import numpy.typing as npt

from sitl.control import Vec3f
from sitl.control.allocation import AllocationResult, ControlAllocator, result_from
from sitl.control.attitude import AttitudeController, Quat4f
from sitl.control.configs import attitude_config, heading_config, position_config, rate_config, velocity_config
from sitl.control.heading import HeadingConfig
from sitl.control.params import outer_loop_period_s
from sitl.control.position import PositionController
from sitl.control.rate import RateController
from sitl.control.velocity import VelocityController
from sitl.dynamics.airframe import Airframe
from sitl.kernels import cascade as ck
from sitl.mathutil import fast_constructor
from sitl.params import ParamStore

_NAN = math.nan
NAN3: Vec3f = (_NAN, _NAN, _NAN)

VecLike = npt.NDArray[np.float64] | Sequence[float]


class EstimatedState(Protocol):
    """What the cascade flies on: the estimator's output (``PlantState`` also fits, for truth-fed tests)."""

    @property
    def pos_ned_m(self) -> VecLike: ...

    @property
    def vel_ned_mps(self) -> VecLike: ...

    @property
    def att_q_frd_to_ned(self) -> VecLike: ...  # (w, x, y, z)

    @property
    def rates_frd_radps(self) -> VecLike: ...


@dataclass(frozen=True, slots=True, kw_only=True)
class TrajectorySetpoint:
    """Position/velocity/acceleration/heading target in local NED. NaN = not set (MAVLink type_mask).

    Per axis: a position is tracked with the velocity as feed-forward; without a position the velocity is
    tracked; with neither, the acceleration is flown open loop; with nothing at all the axis holds zero
    velocity. The acceleration, when set, is always a feed-forward. Yaw NaN with a yaw rate = turn at that
    rate; both NaN = keep the last heading setpoint (or the current heading if there was none).
    """

    pos_ned_m: Vec3f = NAN3
    vel_ned_mps: Vec3f = NAN3
    acc_ned_mps2: Vec3f = NAN3
    yaw_rad: float = _NAN
    yawspeed_radps: float = _NAN


@dataclass(frozen=True, slots=True, kw_only=True)
class AttitudeSetpoint:
    """An attitude (or None for body-rate control) and a collective thrust in newtons: what SET_ATTITUDE_TARGET asks
    (the MAVLink services scale its normalised thrust by the vehicle's ``collective_max_n``) and what a mode that
    flies attitudes asks (Descend), one type for both, as PX4's vehicle_attitude_setpoint.
    """

    att_q: Quat4f | None
    thrust_n: float
    yawspeed_ff_radps: float = _NAN  # heading-rate feed-forward when att_q is set
    rates_sp_frd_radps: Vec3f = (0.0, 0.0, 0.0)  # the setpoint when att_q is None


@dataclass(frozen=True, slots=True, kw_only=True)
class CascadeOutput:
    motor_cmds: tuple[float, ...]  # in [0, 1], airframe rotor order: what the plant takes
    vel_sp_ned_mps: Vec3f  # NaN on axes not under velocity control, and in attitude mode
    acc_sp_ned_mps2: Vec3f
    thrust_sp_ned_n: Vec3f
    att_sp_q: Quat4f
    rates_sp_frd_radps: Vec3f
    torque_sp_frd_nm: Vec3f
    collective_sp_n: float
    allocation: AllocationResult


_new_output = fast_constructor(CascadeOutput)


def _row(v: VecLike) -> npt.NDArray[np.float64]:
    """A vector as the kernels take it: an estimate's own array as it is, anything else (a tuple) copied."""
    return v if type(v) is np.ndarray else np.array(v, dtype=np.float64)


def _heading_row(config: HeadingConfig) -> npt.NDArray[np.float64]:
    """The heading rule as the outer loops' kernel takes it (sitl/kernels/cascade.py ``HD_*``)."""
    row = np.empty(ck.HEADING_SIZE)
    row[ck.HD_FOLLOW] = 1.0 if config.follow_travel else 0.0
    row[ck.HD_RATE_MAX] = config.follow_rate_max_radps
    return row


def _floats(v: VecLike) -> Sequence[float]:
    # Python floats do arithmetic several times faster than numpy scalars.
    return v.tolist() if isinstance(v, np.ndarray) else v


def _floats3(v: VecLike) -> Vec3f:
    x, y, z = v.tolist() if isinstance(v, np.ndarray) else v
    return (x, y, z)


class Cascade:
    """The full multicopter controller for one airframe; call one of the update methods every control step."""

    def __init__(self, airframe: Airframe, params: ParamStore) -> None:
        self.airframe = airframe
        self.params = params
        self.position = PositionController(position_config(params))
        self.velocity = VelocityController(velocity_config(params, airframe))
        self.attitude = AttitudeController(attitude_config(params))
        self.rate = RateController(rate_config(params, airframe))
        self.allocator = ControlAllocator(airframe)
        self._inner_out = np.zeros(ck.O_ROTORS + 2 * self.allocator.rotor_count)
        # The motor commands in the output row, a view made once: read at every step between ticks.
        self._inner_motors = self._inner_out[ck.O_ROTORS : ck.O_ROTORS + self.allocator.rotor_count]
        # The outer loops' last output and held heading, as the inner loops take it (also between ticks,
        # sitl/kernels/between_ticks.py).
        self.held_row = np.zeros(ck.OUTER_SIZE)
        # The setpoint the outer loops fly, as a row (rewritten when another setpoint object arrives).
        self._sp_row = np.zeros(ck.SETPOINT_SIZE)
        self._sp_of_row: TrajectorySetpoint | None = None
        self._heading_row = _heading_row(heading_config(params))
        self._params_version = params.version
        self._outer_period_s = outer_loop_period_s(params)
        self.reset()

    @property
    def collective_max_n(self) -> float:
        return self.allocator.collective_max_n

    def reset(self) -> None:
        """Forget integrators, filters, held heading and saturation feedback (e.g. before take-off)."""
        self.position.reset()
        self.velocity.reset()
        self.attitude.reset()
        self.rate.reset()
        self.allocator.reset()
        self.held_row[ck.U_YAW_PREV] = _NAN
        self._forget_outer()

    def _forget_outer(self) -> None:
        """The next ``update`` runs the position and velocity loops afresh, as on the first step."""
        self._outer_held = False  # does ``held_row`` hold their output (False: run at the next call)
        self._outer_setpoint: TrajectorySetpoint | None = None  # the setpoint they produced it for
        self._outer_elapsed_s = 0.0  # time since their last run

    def outer_due(self, dt_s: float) -> bool:
        """Would ``update`` run the position and velocity loops at a step of ``dt_s`` for the setpoint it last had
        (their MPC_LOOP_HZ period has passed, or they have nothing to hold)?"""
        return not self._outer_held or self._outer_elapsed_s + dt_s >= self._outer_period_s - 1e-9

    def inner_rows(
        self,
    ) -> tuple[
        npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64], float,
        npt.NDArray[np.float64],
    ]:  # fmt: skip
        """What the inner-loop kernel takes: the attitude and rate configurations, the rate controller's state, the
        allocation's rows and maximum thrust, and the output row (read back by ``inner_step_taken``)."""
        allocator = self.allocator
        return (self.attitude.row, self.rate.row, self.rate.state, allocator.rows, allocator.thrust_max_n,
                self._inner_out)  # fmt: skip

    def inner_step_taken(self, dt_s: float) -> tuple[float, ...]:
        """A step of the inner loops alone was taken outside ``update`` (sitl/kernels/between_ticks.py) towards the
        held output of the position loops: count it towards their next run, as ``update`` does, and return its
        motor commands from the output row."""
        self._outer_elapsed_s += dt_s
        return tuple(self._inner_motors.tolist())

    def _refresh_configs(self) -> None:
        store = self.params
        if store.version == self._params_version:
            return
        self._params_version = store.version
        self.position.config = position_config(store)
        self.velocity.config = velocity_config(store, self.airframe)
        self.attitude.config = attitude_config(store)
        self.rate.config = rate_config(store, self.airframe)
        self._heading_row = _heading_row(heading_config(store))
        self._outer_period_s = outer_loop_period_s(store)
        self._outer_held = False  # a new gain takes effect at the next step in the outer loops too

    def fly(
        self, state: EstimatedState, setpoint: TrajectorySetpoint, dt_s: float, *, landed: bool = False
    ) -> tuple[float, ...]:
        """One control step towards a trajectory setpoint, in one kernel (sitl/kernels/cascade.py ``trajectory``): its
        motor commands; ``collective_sp_n`` and the rows hold the rest (``update`` builds the record of it).
        ``landed`` freezes the integrators."""
        due, elapsed_s = self.outer_plan(setpoint, dt_s)
        allocator = self.allocator
        ck.trajectory(_row(state.pos_ned_m), _row(state.vel_ned_mps), _row(state.att_q_frd_to_ned),
                      _row(state.rates_frd_radps), self._sp_row, due, elapsed_s, dt_s, landed, self.position.row,
                      self.velocity.row, self.velocity.state, self._heading_row, self.held_row, self.attitude.row,
                      self.rate.row, self.rate.state, allocator.rows, allocator.thrust_max_n,
                      self._inner_out)  # fmt: skip
        return self.trajectory_flown(setpoint, due, elapsed_s)

    def outer_plan(self, setpoint: TrajectorySetpoint, dt_s: float) -> tuple[bool, float]:
        """Before a control step towards ``setpoint`` (``fly``, or a steady tick's kernel on ``outer_rows``): whether
        the outer loops run in it and the time they integrate over; the setpoint's row is written (and a changed
        parameter taken, as any step takes it). Nothing else changes, so a step planned and not taken leaves the
        cascade as the next step would find it."""
        if self.params.version != self._params_version:
            self._refresh_configs()
        # The outer loops run at MPC_LOOP_HZ, or at once for a new setpoint (identity first: a streamed setpoint is
        # the same object until it changes).
        elapsed_s = self._outer_elapsed_s + dt_s
        last_setpoint = self._outer_setpoint
        due = (
            not self._outer_held
            or elapsed_s >= self._outer_period_s - 1e-9
            or (setpoint is not last_setpoint and setpoint != last_setpoint)
        )
        if setpoint is not self._sp_of_row:
            self._sp_row[:] = (*setpoint.pos_ned_m, *setpoint.vel_ned_mps, *setpoint.acc_ned_mps2, setpoint.yaw_rad,
                               setpoint.yawspeed_radps)  # fmt: skip
            self._sp_of_row = setpoint
        return due, elapsed_s

    def outer_rows(
        self,
    ) -> tuple[
        npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64],
        npt.NDArray[np.float64], npt.NDArray[np.float64],
    ]:  # fmt: skip
        """What the outer loops' kernel takes besides the estimate: the setpoint's row (written by ``outer_plan``), the
        position and velocity configurations, the velocity loop's state, the heading rule and the held output."""
        return (self._sp_row, self.position.row, self.velocity.row, self.velocity.state, self._heading_row,
                self.held_row)  # fmt: skip

    @property
    def outer_setpoint(self) -> TrajectorySetpoint | None:
        """The setpoint the outer loops last ran for (None before they first ran)."""
        return self._outer_setpoint

    def setpoint_row_written(self, setpoint: TrajectorySetpoint) -> None:
        """A kernel wrote ``setpoint`` into the setpoint row itself (sitl/kernels/between_ticks.py
        ``steady_tick_avoiding``, a setpoint corrected by collision prevention): the row is that setpoint's now."""
        self._sp_of_row = setpoint

    def trajectory_flown(self, setpoint: TrajectorySetpoint, due: bool, elapsed_s: float) -> tuple[float, ...]:
        """The control step ``outer_plan`` planned was taken: note when the outer loops ran, and return its motor
        commands from the output row."""
        if due:
            self._outer_held = True
            self._outer_setpoint = setpoint
            self._outer_elapsed_s = 0.0
        else:
            self._outer_elapsed_s = elapsed_s
        return tuple(self._inner_motors.tolist())

    @property
    def collective_sp_n(self) -> float:
        """The collective thrust the outer loops last asked for (newtons)."""
        return float(self.held_row[ck.U_COLLECTIVE])

    def update(
        self, state: EstimatedState, setpoint: TrajectorySetpoint, dt_s: float, *, landed: bool = False
    ) -> CascadeOutput:
        """One control step towards a trajectory setpoint (``fly``), with the record of what every stage produced.
        ``landed`` freezes the integrators."""
        motors = self.fly(state, setpoint, dt_s, landed=landed)
        held = self.held_row.tolist()
        values = self._inner_out.tolist()
        n = self.allocator.rotor_count
        rotors = ck.O_ROTORS
        alloc = result_from(values[rotors : rotors + n], values[rotors + n : rotors + 2 * n],
                            values[ck.O_FLAGS : ck.O_FLAGS + ck.FLAGS_SIZE])  # fmt: skip
        r, t, v, a, u, q = ck.O_RATES_SP, ck.O_TORQUE, ck.U_VEL_SP, ck.U_ACC_SP, ck.U_THRUST, ck.U_ATT_SP
        return _new_output(
            motor_cmds=motors,
            vel_sp_ned_mps=(held[v], held[v + 1], held[v + 2]),
            acc_sp_ned_mps2=(held[a], held[a + 1], held[a + 2]),
            thrust_sp_ned_n=(held[u], held[u + 1], held[u + 2]),
            att_sp_q=(held[q], held[q + 1], held[q + 2], held[q + 3]),
            rates_sp_frd_radps=(values[r], values[r + 1], values[r + 2]),
            torque_sp_frd_nm=(values[t], values[t + 1], values[t + 2]),
            collective_sp_n=held[ck.U_COLLECTIVE],
            allocation=alloc,
        )

    def update_attitude(
        self, state: EstimatedState, setpoint: AttitudeSetpoint, dt_s: float, *, landed: bool = False
    ) -> CascadeOutput:
        """One control step towards an attitude (or body-rate) setpoint with a given collective thrust."""
        self._refresh_configs()
        att_q = _floats(state.att_q_frd_to_ned)
        self.held_row[ck.U_YAW_PREV] = _NAN
        self._forget_outer()  # back on a trajectory setpoint, the outer loops start from the current state
        collective = setpoint.thrust_n
        if setpoint.att_q is None:
            att_sp_q = (att_q[0], att_q[1], att_q[2], att_q[3])
            rates_sp: Vec3f | None = setpoint.rates_sp_frd_radps
        else:
            w, x, y, z = setpoint.att_q
            norm = math.sqrt(w * w + x * x + y * y + z * z)  # as received: not necessarily unit length
            att_sp_q = (w / norm, x / norm, y / norm, z / norm)
            rates_sp = None
        w, x, y, z = att_sp_q
        # The thrust vector this attitude and collective produce, for telemetry.
        thrust = (
            -2.0 * (x * z + w * y) * collective,
            -2.0 * (y * z - w * x) * collective,
            -(1.0 - 2.0 * (x * x + y * y)) * collective,
        )
        rates_sp, torque, alloc = self._inner(
            state, att_q, att_sp_q, setpoint.yawspeed_ff_radps, rates_sp, collective, dt_s, landed
        )
        return _new_output(
            motor_cmds=alloc.motor_cmds,
            vel_sp_ned_mps=NAN3,
            acc_sp_ned_mps2=NAN3,
            thrust_sp_ned_n=thrust,
            att_sp_q=att_sp_q,
            rates_sp_frd_radps=rates_sp,
            torque_sp_frd_nm=torque,
            collective_sp_n=collective,
            allocation=alloc,
        )

    def _inner(
        self,
        state: EstimatedState,
        att_q: Sequence[float],
        att_sp_q: Quat4f,
        yawspeed_ff: float,
        rates_sp: Vec3f | None,
        collective: float,
        dt_s: float,
        landed: bool,
    ) -> tuple[Vec3f, Vec3f, AllocationResult]:
        """Attitude (unless rates are given), rate and allocation stages in one kernel (``inner``); the saturation
        feedback stays in the rate controller's state row."""
        qw, qx, qy, qz = att_q
        dw, dx, dy, dz = att_sp_q
        spx, spy, spz = rates_sp if rates_sp is not None else NAN3
        wx, wy, wz = _floats3(state.rates_frd_radps)
        allocator = self.allocator
        out = self._inner_out
        ck.inner(qw, qx, qy, qz, dw, dx, dy, dz, yawspeed_ff, rates_sp is not None, spx, spy, spz, wx, wy, wz,
                 collective, dt_s, landed, self.attitude.row, self.rate.row, self.rate.state, allocator.rows,
                 allocator.thrust_max_n, out)  # fmt: skip
        values = out.tolist()
        n = allocator.rotor_count
        rotors = ck.O_ROTORS
        alloc = result_from(values[rotors : rotors + n], values[rotors + n : rotors + 2 * n],
                            values[ck.O_FLAGS : ck.O_FLAGS + ck.FLAGS_SIZE])  # fmt: skip
        r, t = ck.O_RATES_SP, ck.O_TORQUE
        return (values[r], values[r + 1], values[r + 2]), (values[t], values[t + 1], values[t + 2]), alloc
