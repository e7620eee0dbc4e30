"""Formation geometry and synchronised, rate-limited transitions between formations (pure: time is injected).

A formation is a set of slots that may move in time (``Formation`` protocol: slots as a function of time, plus
the rigid frame the slots move with). The specs here (grid, circle, line, V) are frozen dataclasses; later modes
(leader-follower, flocking) plug in by implementing the same protocol. Everything is in the swarm frame: local NED
in metres around the swarm's geographic origin (gcs/flight/frames.py), altitudes positive up.

When a formation is commanded, ``FormationEngine``:

1. assigns drones to slots by minimising the sum of squared distances (gcs/flight/assignment.py). Together with
   synchronised motion this keeps straight-line paths from crossing: every pair stays at least
   ``min(start gap, goal gap) / sqrt(2)`` apart (3x3 grid at 2 m -> circle of radius 3 m: at least 1.41 m);
2. plans one transition for all drones with a common time profile ``s(t)`` (quintic minimum-jerk, zero velocity
   and acceleration change at both ends) whose duration is the shortest that keeps every drone within the speed
   and acceleration limits. All drones arrive at the same instant.

Moving slots (a rotating circle) are handled without losing that bound: drones are blended in a frame that
spins up with the formation. With ``c_0`` the centre of the start configuration, ``c`` and ``psi`` the centre and
yaw of the formation's own frame, ``omega`` its yaw rate at arrival, ``D`` the duration and ``tau = t / D``::

    pos_i(t) = C(t) + Rz(theta(t)) [ (1 - s) a_i(t) + s b_i(t) ],   C = (1 - s) c_0 + s c(t),
    theta(t) = s (psi(t) - kappa) + omega D (G(tau) - s (tau - 1 + G(1))),   G(tau) = integral of s^3 over [0, tau]

where ``a_i`` is the start relative to ``c_0`` and ``b_i`` the slot in the formation frame rotated by ``kappa``.
Rotating the whole blend rigidly changes no pairwise distance, so the straight-line bound applies to
``(1 - s) a + s b``. For a formation turning at a steady rate ``theta = omega D G(tau)``: the frame starts still and
its yaw rate ``omega s^3`` rises monotonically to the formation's, never above it, and mostly late, once the blend
has nearly the formation's shape and the translation is slowing down (spinning a wide start configuration fast, or
adding the rim speed to the peak of the translation, would call for a longer transition). For any other yaw the
second term vanishes with its first two derivatives at both ends. ``kappa = psi(D) - G(1) omega D`` makes the frame
turn by ``G(1) omega D`` (``G(1) = 26/77``), and the assignment is made against the arrival slots rotated back by
that angle; both depend on ``D``, so each duration the search tries is planned with its own assignment. Position,
velocity and acceleration are continuous at both ends. Drones that are moving when a formation is commanded
(a rotating circle, an unfinished transition) start from their setpoint and its velocity and brake smoothly to rest
along a straight line while the transition proceeds; a rotating ring brakes into a scaled, rotated copy of itself,
so the bound still holds approximately (``planned_min_separation_m`` measures it).

Setpoints carry position and velocity/acceleration feed-forward; velocities come from central differences of the
planned positions (exact to ~1e-7 m/s for these smooth paths), so any new formation only needs positions. They
are meant to be streamed to every drone at ``SETPOINT_STREAM_HZ`` (PX4 leaves OFFBOARD below 2 Hz; the swarm needs
for >= 10 Hz) as SET_POSITION_TARGET_LOCAL_NED in each drone's own frame (the choice is explained in
gcs/flight/frames.py).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Final, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt
from numpy.polynomial import Polynomial

from gcs.flight.assignment import assign_min_squared_distance
from gcs.flight.frames import Vec3
from gcs.flight.geodesy import wrap_pi

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

SETPOINT_STREAM_HZ: Final = 20.0  # streaming rate for setpoints (>= 10 Hz required, PX4 needs > 2 Hz)

_QUINTIC_PEAK_RATE: Final = 15.0 / 8.0  # max ds/dtau of 10 t^3 - 15 t^4 + 6 t^5
_QUINTIC_PEAK_ACCEL: Final = 10.0 / math.sqrt(3.0)  # max d2s/dtau2
_DIFF_STEP_S: Final = 2e-3  # central differences for feed-forward: truncation ~1e-7, round-off ~1e-9
_LIMIT_MARGIN: Final = 0.99  # plan to 99 % of each limit: the check samples the path, the peak may fall between
_CHECK_SAMPLES: Final = 160  # samples per transition when checking the limits
_FORMATION_CHECK_S: Final = 60.0  # how long a formation's own motion is checked against the limits
_MAX_DURATION_S: Final = 3600.0
_BRAKING_PEAK_DECEL: Final = 8.0 / (3.0 * math.sqrt(3.0))  # max |d2x/dt2| * braking_s / v0 of the braking profile
_MIN_BRAKING_S: Final = 0.5
# The blended frame spins up at the formation's rate times s^3 (module docstring): the integral G of s^3, and G(1).
_SPIN_UP_INTEGRAL: Final = (Polynomial([0.0, 0.0, 0.0, 10.0, -15.0, 6.0]) ** 3).integ()
_SPIN_UP_MEAN: Final = float(_SPIN_UP_INTEGRAL(1.0))  # 26/77


class FormationError(ValueError):
    """A formation that cannot be flown as commanded (too many drones, limits it violates by itself, bad input)."""


class FieldError(ValueError):
    """One field of a spec or a request that cannot be: ``field`` names it and ``problem`` says why, so that each
    front-end can word it in its own terms (a CLI flag, a mission file's ``steps[2].alt_m``); str() is ``text``, or
    ``field: problem``."""

    def __init__(self, field: str, problem: str, text: str | None = None) -> None:
        super().__init__(text if text is not None else f"{field}: {problem}")
        self.field = field
        self.problem = problem


class SpecFieldError(FieldError, FormationError):
    """A spec's field that cannot be flown: ``Spec.field problem``."""

    def __init__(self, owner: object, field: str, problem: str, *, joint: str = " ") -> None:
        super().__init__(field, problem, f"{type(owner).__name__}.{field}{joint}{problem}")


# --------------------------------------------------------------------------------------------------- geometry


@runtime_checkable
class Formation(Protocol):
    """Slots in the swarm frame as a function of formation time (seconds since the formation was commanded)."""

    def slots_ned_m(self, times_s: FloatArray, drone_count: int) -> FloatArray:
        """Slot positions, shape (len(times_s), slot_count, 3) with slot_count >= drone_count.

        Raises FormationError when the formation has fewer slots than drones.
        """
        ...

    def frame(self, times_s: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The rigid frame the slots move with: centre (len, 3) NED metres and yaw (len,) radians, unwrapped."""
        ...


def slots_at(formation: Formation, t_s: float, drone_count: int) -> FloatArray:
    """Slot positions (slot_count, 3) at one formation time."""
    return formation.slots_ned_m(np.array([float(t_s)]), drone_count)[0]


def not_a_sysid(value: object) -> str | None:
    """Why a value is not a MAVLink system id (a whole number in 1..255: 0 addresses every system), or None: the one
    check of a sysid a request or a spec is given, whichever front-end gave it."""
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 255:
        return f"must be a sysid in 1..255, got {value!r}"
    return None


def check_finite(owner: object, **values: float) -> None:
    """Refuse a spec field that is not a finite number (one line naming spec and field)."""
    for name, value in values.items():
        if not math.isfinite(value):
            raise SpecFieldError(owner, name, f"must be finite, got {value}")


def check_positive(owner: object, **values: float) -> None:
    """Refuse a spec field that is not strictly positive (one line naming spec and field)."""
    for name, value in values.items():
        if not value > 0.0:
            raise SpecFieldError(owner, name, f"must be positive, got {value}")


def _check_centre(owner: object, centre: tuple[float, float]) -> None:
    if len(centre) != 2 or not all(math.isfinite(v) for v in centre):
        raise SpecFieldError(owner, "centre_ne_m", f"must be (north, east), got {centre}")


def _place(body_frd_m: FloatArray, times_s: FloatArray, centre: FloatArray, yaw: FloatArray) -> FloatArray:
    """Body (forward, right, down) slot offsets (K or 1, m, 3) -> swarm NED (K, m, 3) around a moving centre."""
    k = times_s.shape[0]
    body = np.broadcast_to(body_frd_m, (k, *body_frd_m.shape[-2:]))
    return centre[:, None, :] + rotate_yaw(body, yaw)


def _static_frame(
    times_s: FloatArray, centre_ne_m: tuple[float, float], alt_m: float, yaw_rad: float
) -> tuple[FloatArray, FloatArray]:
    k = np.asarray(times_s).shape[0]
    centre = np.tile(np.array([centre_ne_m[0], centre_ne_m[1], -alt_m]), (k, 1))
    return centre, np.full(k, yaw_rad)


def _need_slots(owner: object, capacity: int, drone_count: int) -> None:
    if drone_count < 1:
        raise FormationError(f"drone_count must be at least 1, got {drone_count}")
    if drone_count > capacity:
        raise FormationError(f"{type(owner).__name__} has {capacity} slots, cannot hold {drone_count} drones")


@dataclass(frozen=True, slots=True, kw_only=True)
class GridSpec:
    """``rows`` x ``cols`` slots ``spacing_m`` apart, centred on ``centre_ne_m`` at ``alt_m`` above the origin.

    Rows run across the heading (row 0 at the front), columns along it; ``heading_rad`` is the direction the grid
    faces (0 = north). With fewer drones than slots, the assignment picks the slots closest to the drones.
    """

    rows: int
    cols: int
    spacing_m: float
    alt_m: float
    heading_rad: float = 0.0
    centre_ne_m: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        if self.rows < 1 or self.cols < 1:
            raise FormationError(f"GridSpec needs at least one row and column, got {self.rows} x {self.cols}")
        check_finite(self, spacing_m=self.spacing_m, alt_m=self.alt_m, heading_rad=self.heading_rad)
        check_positive(self, spacing_m=self.spacing_m)
        _check_centre(self, self.centre_ne_m)

    def body_frd_m(self) -> FloatArray:
        row, col = np.divmod(np.arange(self.rows * self.cols), self.cols)
        forward = ((self.rows - 1) / 2.0 - row) * self.spacing_m
        right = (col - (self.cols - 1) / 2.0) * self.spacing_m
        return np.stack([forward, right, np.zeros_like(forward)], axis=-1)

    def slots_ned_m(self, times_s: FloatArray, drone_count: int) -> FloatArray:
        _need_slots(self, self.rows * self.cols, drone_count)
        centre, yaw = self.frame(times_s)
        return _place(self.body_frd_m()[None], np.asarray(times_s), centre, yaw)

    def frame(self, times_s: FloatArray) -> tuple[FloatArray, FloatArray]:
        return _static_frame(times_s, self.centre_ne_m, self.alt_m, self.heading_rad)


@dataclass(frozen=True, slots=True, kw_only=True)
class CircleSpec:
    """One slot per drone, evenly spaced on a circle that rotates at ``angular_rate_radps`` (positive clockwise
    seen from above, i.e. north towards east).

    Slot i sits at angle ``phase_rad + 2 pi i / n + rate t`` from north and at altitude
    ``alt_m + alt_osc_amp_m sin(alt_osc_rate_radps t + i alt_osc_phase_step_rad)`` (the demo's
    ``alt + 0.5 sin(t + i)`` is amplitude 0.5, rate 1, phase step 1).
    """

    radius_m: float
    alt_m: float
    angular_rate_radps: float = 0.0
    alt_osc_amp_m: float = 0.0
    alt_osc_rate_radps: float = 1.0
    alt_osc_phase_step_rad: float = 1.0
    phase_rad: float = 0.0
    centre_ne_m: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        check_finite(
            self,
            radius_m=self.radius_m,
            alt_m=self.alt_m,
            angular_rate_radps=self.angular_rate_radps,
            alt_osc_amp_m=self.alt_osc_amp_m,
            alt_osc_rate_radps=self.alt_osc_rate_radps,
            alt_osc_phase_step_rad=self.alt_osc_phase_step_rad,
            phase_rad=self.phase_rad,
        )
        check_positive(self, radius_m=self.radius_m)
        if self.alt_osc_amp_m < 0.0:
            raise FormationError(f"CircleSpec.alt_osc_amp_m must not be negative, got {self.alt_osc_amp_m}")
        _check_centre(self, self.centre_ne_m)

    def slots_ned_m(self, times_s: FloatArray, drone_count: int) -> FloatArray:
        _need_slots(self, drone_count, drone_count)
        t = np.asarray(times_s, dtype=np.float64)
        index = np.arange(drone_count)
        angle = 2.0 * math.pi * index / drone_count
        body = np.stack([self.radius_m * np.cos(angle), self.radius_m * np.sin(angle), np.zeros(drone_count)], -1)
        body = np.broadcast_to(body, (t.shape[0], drone_count, 3)).copy()
        osc = np.sin(self.alt_osc_rate_radps * t[:, None] + self.alt_osc_phase_step_rad * index[None, :])
        body[..., 2] = -self.alt_osc_amp_m * osc
        centre, yaw = self.frame(t)
        return _place(body, t, centre, yaw)

    def frame(self, times_s: FloatArray) -> tuple[FloatArray, FloatArray]:
        t = np.asarray(times_s, dtype=np.float64)
        centre, _ = _static_frame(t, self.centre_ne_m, self.alt_m, 0.0)
        return centre, self.phase_rad + self.angular_rate_radps * t

    def slot_speed_mps(self) -> float:
        """Peak speed of a slot: the rim speed combined with the fastest climb of the altitude oscillation."""
        rim = self.radius_m * abs(self.angular_rate_radps)
        climb = self.alt_osc_amp_m * abs(self.alt_osc_rate_radps)
        return math.hypot(rim, climb)


@dataclass(frozen=True, slots=True, kw_only=True)
class LineSpec:
    """One slot per drone on a line through ``centre_ne_m`` along ``heading_rad`` (slot 0 at the front)."""

    spacing_m: float
    alt_m: float
    heading_rad: float = 0.0
    centre_ne_m: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        check_finite(self, spacing_m=self.spacing_m, alt_m=self.alt_m, heading_rad=self.heading_rad)
        check_positive(self, spacing_m=self.spacing_m)
        _check_centre(self, self.centre_ne_m)

    def slots_ned_m(self, times_s: FloatArray, drone_count: int) -> FloatArray:
        _need_slots(self, drone_count, drone_count)
        forward = ((drone_count - 1) / 2.0 - np.arange(drone_count)) * self.spacing_m
        body = np.stack([forward, np.zeros(drone_count), np.zeros(drone_count)], -1)
        centre, yaw = self.frame(times_s)
        return _place(body[None], np.asarray(times_s), centre, yaw)

    def frame(self, times_s: FloatArray) -> tuple[FloatArray, FloatArray]:
        return _static_frame(times_s, self.centre_ne_m, self.alt_m, self.heading_rad)


@dataclass(frozen=True, slots=True, kw_only=True)
class VSpec:
    """A V pointing along ``heading_rad``: slot 0 at the apex on ``centre_ne_m``, then alternately right and left
    along two arms that trail back at +-``angle_rad`` / 2 from the rear axis; ``spacing_m`` between neighbours on
    an arm. The two drones k-th along their arms are ``2 k spacing_m sin(angle / 2)`` apart, so angles below 60 deg
    bring the first pair closer than ``spacing_m``.
    """

    spacing_m: float
    alt_m: float
    angle_rad: float = math.pi / 2.0
    heading_rad: float = 0.0
    centre_ne_m: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        check_finite(
            self, spacing_m=self.spacing_m, alt_m=self.alt_m, angle_rad=self.angle_rad, heading_rad=self.heading_rad
        )
        check_positive(self, spacing_m=self.spacing_m)
        if not 0.0 < self.angle_rad <= math.pi:
            raise FormationError(f"VSpec.angle_rad must be in (0, pi], got {self.angle_rad}")
        _check_centre(self, self.centre_ne_m)

    def slots_ned_m(self, times_s: FloatArray, drone_count: int) -> FloatArray:
        _need_slots(self, drone_count, drone_count)
        k = np.arange(drone_count)
        rank = (k + 1) // 2  # position along the arm
        side = np.where(k % 2 == 1, 1.0, -1.0)  # odd slots on the right arm
        half = self.angle_rad / 2.0
        forward = -rank * self.spacing_m * math.cos(half)
        right = np.where(k == 0, 0.0, side * rank * self.spacing_m * math.sin(half))
        body = np.stack([forward, right, np.zeros(drone_count)], -1)
        centre, yaw = self.frame(times_s)
        return _place(body[None], np.asarray(times_s), centre, yaw)

    def frame(self, times_s: FloatArray) -> tuple[FloatArray, FloatArray]:
        return _static_frame(times_s, self.centre_ne_m, self.alt_m, self.heading_rad)


def rotate_yaw(vectors: FloatArray, yaw_rad: FloatArray) -> FloatArray:
    """Rotate (K, n, 3) vectors about the down axis by yaw (K,) (north towards east for positive yaw)."""
    c = np.cos(yaw_rad)[:, None]
    s = np.sin(yaw_rad)[:, None]
    out = np.empty(np.broadcast_shapes(vectors.shape, (yaw_rad.shape[0], 1, 3)))
    out[..., 0] = c * vectors[..., 0] - s * vectors[..., 1]
    out[..., 1] = s * vectors[..., 0] + c * vectors[..., 1]
    out[..., 2] = vectors[..., 2]
    return out


def min_pairwise_distance_m(positions_ned_m: npt.ArrayLike) -> float:
    """Smallest distance between any two drones at any sample; positions shaped (samples, drones, 3)."""
    p = np.asarray(positions_ned_m, dtype=np.float64)
    if p.ndim == 2:
        p = p[None]
    n = p.shape[1]
    if n < 2:
        return math.inf
    i, j = np.triu_indices(n, k=1)
    return float(np.sqrt(np.min(np.sum((p[:, i, :] - p[:, j, :]) ** 2, axis=-1))))


# ------------------------------------------------------------------------------------------------- the engine


@dataclass(frozen=True, slots=True, kw_only=True)
class TransitionLimits:
    """Limits every drone's planned motion respects, transitions and moving formations alike."""

    max_speed_mps: float = 1.5
    max_accel_mps2: float = 1.0
    min_duration_s: float = 1.0  # even a transition of nothing takes this long (no step in the setpoint)

    def __post_init__(self) -> None:
        check_positive(self, max_speed_mps=self.max_speed_mps, max_accel_mps2=self.max_accel_mps2)
        check_finite(self, min_duration_s=self.min_duration_s)
        check_positive(self, min_duration_s=self.min_duration_s)


class YawMode(enum.Enum):
    HOLD = "hold"  # yaw NaN: each drone keeps its heading (PX4: yaw ignored -> hold)
    FORMATION = "formation"  # face the formation's heading (a rotating circle turns the drones with it)


@dataclass(frozen=True, slots=True, kw_only=True)
class Setpoint:
    """One drone's offboard setpoint in the swarm frame."""

    pos_ned_m: Vec3
    vel_ned_mps: Vec3
    acc_ned_mps2: Vec3
    yaw_rad: float  # NaN: not commanded


@dataclass(frozen=True, slots=True, kw_only=True)
class Transition:
    """What a command planned: which slot each drone flies to and when all of them get there."""

    start_s: float
    arrival_s: float
    slot_of_drone: Mapping[int, int] = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        return self.arrival_s - self.start_s


class _BrakingStart:
    """Where a transition starts: each drone's position and velocity, braking smoothly to rest.

    A drone already moving (a rotating circle, an unfinished transition) keeps its velocity at the instant of the
    command and decelerates along a straight line with ``dx/dt = v0 (1 - x^2)^2`` (x = time / braking time), so
    position and velocity stay continuous and the deceleration is zero at both ends. The braking time makes the
    deceleration use at most half the acceleration limit, leaving the rest to the transition itself. Before the
    command the drone is extrapolated at constant velocity (only finite differences at the command instant look
    there).
    """

    def __init__(self, points_ned_m: FloatArray, vels_ned_mps: FloatArray, start_s: float, braking_s: float) -> None:
        self._points = points_ned_m
        self._vels = vels_ned_mps
        self._start_s = start_s
        self._braking_s = braking_s

    @property
    def braking_s(self) -> float:
        return self._braking_s

    def positions(self, times_s: FloatArray) -> FloatArray:
        x = (times_s - self._start_s) / self._braking_s
        xc = np.clip(x, 0.0, 1.0)
        travelled = np.where(x < 0.0, x, xc - 2.0 * xc**3 / 3.0 + xc**5 / 5.0) * self._braking_s
        return np.asarray(self._points[None] + travelled[:, None, None] * self._vels[None], dtype=np.float64)

    def rest_points(self) -> FloatArray:
        """Where every drone comes to rest: the configuration the assignment plans from."""
        return np.asarray(self._points + (8.0 / 15.0) * self._braking_s * self._vels, dtype=np.float64)


class _SlotTrack:
    """Drones in their slots of a formation commanded at ``start_s``."""

    def __init__(self, formation: Formation, start_s: float, slot_index: IntArray) -> None:
        self.formation = formation
        self.start_s = start_s
        self.slot_index = slot_index

    def positions(self, times_s: FloatArray) -> FloatArray:
        slots = self.formation.slots_ned_m(times_s - self.start_s, self.slot_index.shape[0])
        return slots[:, self.slot_index, :]

    def frame(self, times_s: FloatArray) -> tuple[FloatArray, FloatArray]:
        return self.formation.frame(times_s - self.start_s)


def _quintic(tau: FloatArray) -> FloatArray:
    t = np.clip(tau, 0.0, 1.0)
    return np.asarray(t * t * t * (10.0 + t * (-15.0 + 6.0 * t)), dtype=np.float64)


class _Plan:
    """One transition from a braking start into a formation's slots; after arrival, the slots themselves.

    The start frame is fixed (centred on the rest configuration, yaw 0); the target frame is the formation's,
    offset by ``-kappa`` so that the blended yaw starts at 0 and spins up to the formation's rate (module docstring).
    ``kappa`` depends on the duration, so every duration gets its own plan.
    """

    def __init__(self, start: _BrakingStart, target: _SlotTrack, start_s: float, duration_s: float) -> None:
        self.start = start
        self.target = target
        self.start_s = start_s
        self.duration_s = duration_s
        self.arrival_s = start_s + duration_s
        self.rate_radps, spin = _arrival_spin(target.formation, duration_s)
        _, arrival_yaw = target.formation.frame(np.array([duration_s]))
        self.kappa_rad = float(arrival_yaw[0]) - spin
        self._start_centre = start.rest_points().mean(axis=0)

    def positions(self, times_s: FloatArray) -> FloatArray:
        times_s = np.asarray(times_s, dtype=np.float64)
        after = times_s >= self.arrival_s
        if np.all(after):
            return self.target.positions(times_s)
        out = np.empty((times_s.shape[0], self.target.slot_index.shape[0], 3))
        if np.any(after):
            out[after] = self.target.positions(times_s[after])
        out[~after] = self._blend(times_s[~after])
        return out

    def _blend(self, times_s: FloatArray) -> FloatArray:
        tau = (times_s - self.start_s) / self.duration_s
        s = _quintic(tau)
        start_body = self.start.positions(times_s) - self._start_centre
        goal_centre, goal_yaw = self.target.frame(times_s)
        goal_yaw = goal_yaw - self.kappa_rad
        goal_body = rotate_yaw(self.target.positions(times_s) - goal_centre[:, None, :], -goal_yaw)
        centre = (1.0 - s)[:, None] * self._start_centre + s[:, None] * goal_centre
        body = (1.0 - s)[:, None, None] * start_body + s[:, None, None] * goal_body
        # s (psi - kappa) alone would overshoot a steady rate by ~17 % mid-way; this makes the yaw rate omega s^3.
        t = np.clip(tau, 0.0, 1.0)
        spin_up = np.asarray(_SPIN_UP_INTEGRAL(t), dtype=np.float64) - s * (t - 1.0 + _SPIN_UP_MEAN)
        return centre[:, None, :] + rotate_yaw(body, s * goal_yaw + self.rate_radps * self.duration_s * spin_up)


def _arrival_spin(formation: Formation, duration_s: float) -> tuple[float, float]:
    """The formation's yaw rate at ``duration_s`` and the net turn of the blended frame spun up to it in that time."""
    _, yaw = formation.frame(np.array([duration_s - _DIFF_STEP_S, duration_s + _DIFF_STEP_S]))
    rate = float(yaw[1] - yaw[0]) / (2.0 * _DIFF_STEP_S)
    return rate, _SPIN_UP_MEAN * duration_s * rate


def _as_points(positions: Mapping[int, Sequence[float] | npt.ArrayLike], ids: Sequence[int]) -> FloatArray:
    pts = np.array([np.asarray(positions[i], dtype=np.float64).reshape(-1) for i in ids], dtype=np.float64)
    if pts.shape != (len(ids), 3) or not np.all(np.isfinite(pts)):
        raise FormationError("current positions must be finite (north, east, down) triples")
    return pts


class FormationEngine:
    """Assigns drones to formation slots and produces their setpoints each tick (pure; the caller passes time).

    ``command`` plans a transition from where the drones are. A drone that is following the current plan (its
    position within ``resume_tolerance_m`` of its setpoint) starts from its setpoint and setpoint velocity, so a
    formation can be changed while moving without a jump; any other drone starts at rest where it is.
    """

    def __init__(
        self,
        limits: TransitionLimits | None = None,
        *,
        yaw_mode: YawMode = YawMode.HOLD,
        resume_tolerance_m: float = 1.0,
    ) -> None:
        self._limits = limits if limits is not None else TransitionLimits()
        self._yaw_mode = yaw_mode
        self._resume_tolerance_m = resume_tolerance_m
        self._plan: _Plan | None = None
        self._ids: tuple[int, ...] = ()
        self._transition: Transition | None = None

    @property
    def limits(self) -> TransitionLimits:
        return self._limits

    @property
    def drone_ids(self) -> tuple[int, ...]:
        """Drones in the current plan, in the order of the arrays ``sample_ned_m`` returns."""
        return self._ids

    @property
    def transition(self) -> Transition | None:
        return self._transition

    @property
    def formation(self) -> Formation | None:
        return None if self._plan is None else self._plan.target.formation

    # ---------------------------------------------------------------------------------------------- commands

    def command(
        self, formation: Formation, now_s: float, current_positions: Mapping[int, Sequence[float] | npt.ArrayLike]
    ) -> Transition:
        """Assign the drones in ``current_positions`` (swarm NED) to the formation's slots and plan the transition."""
        if not math.isfinite(now_s):
            raise FormationError(f"now_s must be finite, got {now_s}")
        ids = tuple(sorted(current_positions))
        if not ids:
            raise FormationError("no drones to place in the formation")
        points = _as_points(current_positions, ids)
        slots_at(formation, 0.0, len(ids))  # refuses a formation with too few slots before any planning
        self._check_formation_motion(formation, len(ids))

        start = self._braking_start(now_s, ids, points)
        rest = start.rest_points()

        def assign(duration_s: float) -> IntArray:
            # Against the arrival slots turned back by the blended frame's net turn (it spins up from rest).
            _, spin = _arrival_spin(formation, duration_s)
            at = np.array([duration_s])
            goal_centre = formation.frame(at)[0][0]
            arrival = formation.slots_ned_m(at, len(ids))[0] - goal_centre
            # Absolute positions, not centred ones: with spare slots the translation decides which slots are used.
            goals = goal_centre + rotate_yaw(arrival[None], np.array([-spin]))[0]
            return np.array(assign_min_squared_distance(rest, goals), dtype=np.int64)

        def plan(duration_s: float) -> _Plan:
            return _Plan(start, _SlotTrack(formation, now_s, assign(duration_s)), now_s, duration_s)

        self._plan = self._shortest_feasible(plan, max(self._limits.min_duration_s, start.braking_s))
        self._ids = ids
        self._transition = Transition(
            start_s=now_s,
            arrival_s=self._plan.arrival_s,
            slot_of_drone={drone: int(slot) for drone, slot in zip(ids, self._plan.target.slot_index, strict=True)},
        )
        return self._transition

    def _braking_start(self, now_s: float, ids: tuple[int, ...], points: FloatArray) -> _BrakingStart:
        """Start from the setpoint (with its velocity) for drones on the current plan, at rest otherwise."""
        start_points = points.copy()
        vels = np.zeros_like(points)
        if self._plan is not None:
            h = _DIFF_STEP_S
            planned = self._plan.positions(np.array([now_s - h, now_s, now_s + h]))
            old_index = {drone: k for k, drone in enumerate(self._ids)}
            for k, drone in enumerate(ids):
                j = old_index.get(drone)
                if j is not None and math.hypot(*(planned[1, j] - points[k])) <= self._resume_tolerance_m:
                    start_points[k] = planned[1, j]
                    vels[k] = (planned[2, j] - planned[0, j]) / (2.0 * h)
        peak_speed = float(np.max(np.linalg.norm(vels, axis=1)))
        braking_s = max(_MIN_BRAKING_S, _BRAKING_PEAK_DECEL * peak_speed / (0.5 * self._limits.max_accel_mps2))
        return _BrakingStart(start_points, vels, now_s, braking_s)

    def _check_formation_motion(self, formation: Formation, drone_count: int) -> None:
        """A formation whose slots alone move faster than the limits cannot be tracked: refuse it up front."""
        step = 0.05
        times = np.arange(0.0, _FORMATION_CHECK_S + step / 2, step)
        speed, accel = _peak_speed_accel(formation.slots_ned_m(times, drone_count), step)
        lim = self._limits
        if speed > _LIMIT_MARGIN * lim.max_speed_mps or accel > _LIMIT_MARGIN * lim.max_accel_mps2:
            raise FormationError(
                f"formation slots move at up to {speed:.2f} m/s and {accel:.2f} m/s^2, above the limits "
                f"{lim.max_speed_mps:.2f} m/s and {lim.max_accel_mps2:.2f} m/s^2"
            )

    def _shortest_feasible(self, plan: Callable[[float], _Plan], shortest_s: float) -> _Plan:
        """The plan of the shortest duration >= ``shortest_s`` that stays within the limits.

        Every candidate duration is planned on its own: with moving slots the frame's net turn, hence the
        assignment, depends on the duration, and the separation bound needs the assignment made for the duration
        actually flown.
        """
        lim = self._limits
        v_max = _LIMIT_MARGIN * lim.max_speed_mps
        a_max = _LIMIT_MARGIN * lim.max_accel_mps2
        # Straight-line lower bound of the quintic profile for the farthest drone (exact for still formations).
        candidate = plan(shortest_s)
        goal = candidate.target.positions(np.array([candidate.arrival_s]))[0]
        reach_m = float(np.max(np.linalg.norm(goal - candidate.start.rest_points(), axis=1)))
        low = max(shortest_s, _QUINTIC_PEAK_RATE * reach_m / v_max, math.sqrt(_QUINTIC_PEAK_ACCEL * reach_m / a_max))

        def feasible(duration_s: float) -> _Plan | None:
            p = plan(duration_s)
            step = duration_s / _CHECK_SAMPLES
            times = np.asarray(p.start_s + step * np.arange(0, _CHECK_SAMPLES + 2), dtype=np.float64)
            speed, accel = _peak_speed_accel(p.positions(times), step)
            return p if speed <= v_max and accel <= a_max else None

        best = feasible(low)
        if best is not None:
            return best
        infeasible, duration = low, low * 1.25
        while (best := feasible(duration)) is None:
            infeasible, duration = duration, duration * 1.25
            if duration > _MAX_DURATION_S:
                raise FormationError("no transition within the speed and acceleration limits")
        for _ in range(10):
            middle = 0.5 * (infeasible + duration)
            found = feasible(middle)
            if found is not None:
                best, duration = found, middle
            else:
                infeasible = middle
        return best

    # ------------------------------------------------------------------------------------------------ outputs

    def sample_ned_m(self, times_s: npt.ArrayLike) -> FloatArray:
        """Planned positions (len(times), drones, 3), drones in ``drone_ids`` order."""
        if self._plan is None:
            return np.zeros((np.asarray(times_s).reshape(-1).shape[0], 0, 3))
        t = np.maximum(np.asarray(times_s, dtype=np.float64).reshape(-1), self._plan.start_s)
        return self._plan.positions(t)

    def setpoints(self, now_s: float) -> dict[int, Setpoint]:
        """Every planned drone's setpoint at ``now_s`` (empty before the first command)."""
        plan = self._plan
        if plan is None:
            return {}
        h = _DIFF_STEP_S
        t = max(now_s, plan.start_s)
        p = plan.positions(np.array([t - h, t, t + h]))
        vel = (p[2] - p[0]) / (2.0 * h)
        acc = (p[2] - 2.0 * p[1] + p[0]) / (h * h)
        yaw = math.nan
        if self._yaw_mode is YawMode.FORMATION:
            _, formation_yaw = plan.target.formation.frame(np.array([t - plan.start_s]))
            yaw = wrap_pi(float(formation_yaw[0]))
        return {
            drone: Setpoint(pos_ned_m=_vec(p[1, k]), vel_ned_mps=_vec(vel[k]), acc_ned_mps2=_vec(acc[k]), yaw_rad=yaw)
            for k, drone in enumerate(self._ids)
        }

    def targets(self, now_s: float) -> dict[int, Vec3]:
        """Each drone's formation slot at ``now_s`` (where it is heading; equal to the setpoint once settled)."""
        if self._plan is None:
            return {}
        slots = self._plan.target.positions(np.array([max(now_s, self._plan.start_s)]))[0]
        return {drone: _vec(slots[k]) for k, drone in enumerate(self._ids)}

    def error_rms(self, now_s: float, positions: Mapping[int, Sequence[float] | npt.ArrayLike]) -> float:
        """Root-mean-square distance (m) of the given drones from their formation slots; NaN if none is planned."""
        targets = self.targets(now_s)
        common = [d for d in sorted(positions) if d in targets]
        if not common:
            return math.nan
        pts = _as_points(positions, common)
        goal = np.array([targets[d] for d in common])
        return float(np.sqrt(np.mean(np.sum((pts - goal) ** 2, axis=1))))

    def settled(self, now_s: float) -> bool:
        """True once the transition is over (every setpoint is on its slot); False with nothing commanded."""
        return self._plan is not None and now_s >= self._plan.arrival_s

    def planned_min_separation_m(self, *, step_s: float = 0.02, after_arrival_s: float = 0.0) -> float:
        """Smallest distance between any two planned drones from the command to arrival (+ ``after_arrival_s``)."""
        if self._plan is None:
            return math.inf
        end = self._plan.arrival_s + after_arrival_s
        count = max(2, math.ceil((end - self._plan.start_s) / step_s) + 1)
        return min_pairwise_distance_m(self._plan.positions(np.linspace(self._plan.start_s, end, count)))


def _peak_speed_accel(positions: FloatArray, step_s: float) -> tuple[float, float]:
    """Peak speed and acceleration over all drones of positions sampled every ``step_s`` (central differences)."""
    if positions.shape[0] < 3:
        return 0.0, 0.0
    vel = (positions[2:] - positions[:-2]) / (2.0 * step_s)
    acc = (positions[2:] - 2.0 * positions[1:-1] + positions[:-2]) / (step_s * step_s)
    return float(np.max(np.linalg.norm(vel, axis=-1))), float(np.max(np.linalg.norm(acc, axis=-1)))


def _vec(values: FloatArray) -> Vec3:
    return (float(values[0]), float(values[1]), float(values[2]))
