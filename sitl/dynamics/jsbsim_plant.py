"""The JSBSim flight model of one multirotor behind the Plant interface.

This is the only module that imports jsbsim. It generates the aircraft definition from the airframe data file
(sitl/dynamics/jsbsim_model.py), loads it, places the vehicle at home and steps it at a fixed rate, converting
JSBSim's English units and geodetic position into the SI, NED and FRD quantities of ``PlantState``.

Position convention: ``pos_ned_m`` is the centre of gravity relative to home, whose down = 0 is the ground
(see sitl/dynamics/geodesy.py). A vehicle resting on the ground therefore reports down = -``rest_height_m``:
the gear height less the static compression of the contact springs (-0.116 m for the F450).

Per-step cost matters (a swarm of dozens of drones shares two cores), so every property is bound once to a
property node and read with ``get_double_value``, which is several times cheaper than ``fdm[name]``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import tempfile
import threading
from collections.abc import Sequence
from pathlib import Path

import jsbsim
import numpy as np
import numpy.typing as npt

from sitl.dynamics.airframe import Airframe
from sitl.dynamics.geodesy import LocalFrame
from sitl.dynamics.jsbsim_model import (
    M_PER_FT,
    N_PER_LBF,
    contact_count,
    contact_wow_property,
    model_name,
    motor_cmd_property,
    rotor_speed_property,
    write_model,
)
from sitl.dynamics.plant import DEFAULT_HOME, PHYSICS_RATE_HZ, GeoPoint, PlantState
from sitl.mathutil import GRAVITY_MPS2, Quat, Vec3, fast_constructor

_log = logging.getLogger(__name__)

_FT_PER_M = 1.0 / M_PER_FT

_new_geo = fast_constructor(GeoPoint)


class PlantError(RuntimeError):
    """JSBSim refused the generated model or its initial conditions, or stopped stepping."""


class _LogBridge(jsbsim.FGLogger):
    """Routes JSBSim's own messages to ``logging``: warnings and errors kept, start-up chatter dropped."""

    def __init__(self) -> None:
        super().__init__()
        self._level = int(jsbsim.LogLevel.INFO)
        self._parts: list[str] = []

    def set_level(self, level: jsbsim.LogLevel) -> None:
        self._level = int(level)
        self._parts.clear()

    def file_location(self, filename: str, line: int) -> None:
        pass

    def message(self, message: str) -> None:
        if self._level >= jsbsim.LogLevel.WARN:
            self._parts.append(message)

    def format(self, format: jsbsim.LogFormat) -> None:
        pass

    def flush(self) -> None:
        text = "".join(self._parts).strip()
        self._parts.clear()
        if not text:
            return
        if self._level >= jsbsim.LogLevel.ERROR:
            _log.error("JSBSim: %s", text)
        else:
            _log.warning("JSBSim: %s", text)


# JSBSim keeps its logger per thread; install ours once in every thread that builds a plant.
_thread_state = threading.local()


def _install_log_bridge() -> None:
    if getattr(_thread_state, "bridge", None) is None:
        _thread_state.bridge = _LogBridge()
        jsbsim.set_logger(_thread_state.bridge)


def _clamp_cmd(value: float) -> float:
    # NaN fails every comparison, so it lands on 0 (motor stopped) like a negative command.
    value = float(value)
    if value > 1.0:
        return 1.0
    if value > 0.0:
        return value
    return 0.0


class JsbsimPlant:
    """A multirotor simulated by JSBSim, stepped at a fixed ``dt_s`` with normalised motor commands.

    ``initial_pos_ned_m`` is the initial centre-of-gravity position relative to home; a down coordinate lower
    than resting on the ground (for example the default (0, 0, 0)) places the vehicle at rest on the ground.
    ``initial_motor_cmds`` starts the rotors already spinning at the speeds those commands settle to, so a
    vehicle can begin in steady flight; by default the motors are stopped.
    """

    def __init__(
        self,
        airframe: Airframe,
        home: GeoPoint = DEFAULT_HOME,
        dt_s: float = 1.0 / PHYSICS_RATE_HZ,
        initial_pos_ned_m: Sequence[float] = (0.0, 0.0, 0.0),
        initial_yaw_rad: float = 0.0,
        *,
        initial_motor_cmds: Sequence[float] | None = None,
    ) -> None:
        if not (math.isfinite(dt_s) and 0.0 < dt_s <= 0.05):
            raise ValueError(f"dt_s must be in (0, 0.05] s, got {dt_s!r}")
        if len(initial_pos_ned_m) != 3 or not all(math.isfinite(float(v)) for v in initial_pos_ned_m):
            raise ValueError(f"initial_pos_ned_m must be three finite numbers, got {initial_pos_ned_m!r}")
        if not math.isfinite(initial_yaw_rad):
            raise ValueError(f"initial_yaw_rad must be finite, got {initial_yaw_rad!r}")
        self._airframe = airframe
        self._home = home
        self._frame = LocalFrame(home)
        self._dt_s = float(dt_s)
        self._n_rotors = len(airframe.rotors)
        self._sf_scale = N_PER_LBF / airframe.mass_kg  # lbf -> specific force in m/s^2
        # The contact springs compress under the weight, shared equally by one contact per rotor.
        self._rest_height_m = airframe.gear_height_m - airframe.mass_kg * GRAVITY_MPS2 / (
            self._n_rotors * airframe.gear_spring_n_per_m
        )
        self._wind_ned_mps = np.zeros(3)
        self._steps = 0
        # Rotors that have failed (0-based, an injected motor failure): whatever the mixer commands, the motor gets
        # nothing, so the rotor spins down through its lag and gives no thrust and no torque.
        self.failed_motors: frozenset[int] = frozenset()

        _install_log_bridge()
        self._fdm = self._load(airframe)
        self._fdm.set_dt(self._dt_s)
        pm = self._fdm.get_property_manager()

        def node(name: str) -> jsbsim.FGPropertyNode:
            found = pm.get_node(name)
            if found is None:
                raise PlantError(f"JSBSim model {model_name(airframe)!r} has no property {name!r}")
            return found

        self._cmd_setters = tuple(node(motor_cmd_property(i)).set_double_value for i in range(self._n_rotors))
        speed_nodes = tuple(node(rotor_speed_property(i)) for i in range(self._n_rotors))
        self._speed_getters = tuple(n.get_double_value for n in speed_nodes)
        self._speed_setters = tuple(n.set_double_value for n in speed_nodes)
        self._wow_getters = tuple(
            node(contact_wow_property(i)).get_double_value for i in range(contact_count(airframe))
        )
        self._get_lat = node("position/lat-geod-rad").get_double_value
        self._get_lon = node("position/long-gc-rad").get_double_value
        self._get_alt = node("position/geod-alt-ft").get_double_value
        self._vel_getters = tuple(node(f"velocities/{c}-fps").get_double_value for c in ("v-north", "v-east", "v-down"))
        self._euler_getters = tuple(node(f"attitude/{c}-rad").get_double_value for c in ("phi", "theta", "psi"))
        self._rate_getters = tuple(node(f"velocities/{c}-rad_sec").get_double_value for c in ("p", "q", "r"))
        self._force_getters = tuple(node(f"forces/fb{c}-total-lbs").get_double_value for c in ("x", "y", "z"))
        self._wind_setters = tuple(node(f"atmosphere/wind-{c}-fps").set_double_value for c in ("north", "east", "down"))

        self._initialise(initial_pos_ned_m, initial_yaw_rad, initial_motor_cmds)
        # The properties a state's record is built from, in the order ``_record`` unpacks them.
        self._raw_getters = (
            self._get_lat, self._get_lon, self._get_alt, *self._vel_getters, *self._euler_getters,
            *self._rate_getters, *self._force_getters,
        )  # fmt: skip
        self._state = self._read_state()

    @staticmethod
    def _load(airframe: Airframe) -> jsbsim.FGFDMExec:
        # JSBSim reads the model only while loading, so the generated files can go right after.
        with tempfile.TemporaryDirectory(prefix="sitl-jsbsim-") as root:
            write_model(airframe, Path(root))
            fdm = jsbsim.FGFDMExec(root)
            fdm.set_debug_level(0)
            if not fdm.load_model(model_name(airframe)):
                raise PlantError(f"JSBSim could not load the model generated from {airframe.source_path}")
        fdm.disable_output()
        return fdm

    def _initialise(self, pos_ned_m: Sequence[float], yaw_rad: float, motor_cmds: Sequence[float] | None) -> None:
        fdm = self._fdm
        north, east, down = (float(v) for v in pos_ned_m)
        down = min(down, -self._rest_height_m)
        start = self._frame.geo_from_ned((north, east, down))
        # Turbulence is the caller's business (set_wind with gusts), never JSBSim's random model.
        fdm["atmosphere/turb-type"] = 0
        fdm["ic/terrain-elevation-ft"] = self._home.alt_amsl_m * _FT_PER_M
        fdm["ic/lat-geod-deg"] = start.lat_deg
        fdm["ic/long-gc-deg"] = start.lon_deg
        fdm["ic/h-agl-ft"] = -down * _FT_PER_M
        for name in ("ic/u-fps", "ic/v-fps", "ic/w-fps", "ic/p-rad_sec", "ic/q-rad_sec", "ic/r-rad_sec"):
            fdm[name] = 0.0
        fdm["ic/phi-rad"] = 0.0
        fdm["ic/theta-rad"] = 0.0
        fdm["ic/psi-true-rad"] = yaw_rad % (2.0 * math.pi)
        cmds = motor_cmds if motor_cmds is not None else (0.0,) * self._n_rotors
        self._write_cmds(cmds)
        # The motor lag's state is the rotor-speed property, and JSBSim holds it while initialising.
        for set_speed, cmd in zip(self._speed_setters, cmds, strict=True):
            set_speed(_clamp_cmd(cmd) * self._airframe.motor_max_speed_radps)
        if not fdm.run_ic():
            raise PlantError("JSBSim rejected the initial conditions")

    @property
    def dt_s(self) -> float:
        return self._dt_s

    @property
    def airframe(self) -> Airframe:
        return self._airframe

    @property
    def home(self) -> GeoPoint:
        return self._home

    @property
    def rest_height_m(self) -> float:
        """Height of the centre of gravity above the ground when resting on the gear."""
        return self._rest_height_m

    @property
    def wind_ned_mps(self) -> Vec3:
        return self._wind_ned_mps.copy()

    def state(self) -> PlantState:
        return self._state

    def step(self, motor_cmds: tuple[float, ...] | list[float]) -> PlantState:
        self._write_cmds(motor_cmds)
        if not self._fdm.run():
            raise PlantError(f"JSBSim stopped at t={self._steps * self._dt_s:.4f} s")
        self._steps += 1
        self._state = self._read_state()
        return self._state

    def set_wind(self, wind_ned_mps: Vec3) -> None:
        wind = np.asarray(wind_ned_mps, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(wind)):
            raise ValueError(f"wind must be finite, got {wind_ned_mps!r}")
        self._wind_ned_mps = wind.copy()
        for setter, value in zip(self._wind_setters, wind, strict=True):
            setter(float(value) * _FT_PER_M)

    def _write_cmds(self, motor_cmds: Sequence[float]) -> None:
        if len(motor_cmds) != self._n_rotors:
            raise ValueError(f"expected {self._n_rotors} motor commands, got {len(motor_cmds)}")
        for setter, value in zip(self._cmd_setters, motor_cmds, strict=False):  # lengths checked above
            value = float(value)  # _clamp_cmd inline: this runs every physics step
            setter(1.0 if value > 1.0 else (value if value > 0.0 else 0.0))
        for index in self.failed_motors:
            self._cmd_setters[index](0.0)

    def _any_contact(self) -> bool:
        # A plain loop: three times cheaper than any() over a generator, and this runs every step.
        for weight_on_wheels in self._wow_getters:  # noqa: SIM110
            if weight_on_wheels() > 0.5:
                return True
        return False

    def imu_inputs(self) -> npt.NDArray[np.float64]:
        """The body rates and the specific force of the latest step in one row (rates, then specific force), the two
        vectors an IMU samples: what the kernel of a step between ticks takes (sitl/kernels/between_ticks.py),
        without building the state's record."""
        return self._state.imu_inputs()

    def _read_state(self) -> _SteppedState:
        # Every property the record needs is read now, while JSBSim holds this step: the record itself (numpy
        # vectors, the quaternion, the geodetic conversion) is built from these floats only if a reader asks.
        raw = tuple([g() for g in self._raw_getters])
        speeds = tuple([g() for g in self._speed_getters])
        state = _new_stepped(_SteppedState)
        _set_time(state, self._steps * self._dt_s)
        _set_on_ground(state, self._any_contact())
        _set_speeds(state, speeds)
        _set_raw(state, raw)
        _set_plant(state, self)
        # None marks a vector not built yet (a test of an unset slot would raise, and raising costs a microsecond).
        _set_pos(state, None)
        _set_geo(state, None)
        _set_vel(state, None)
        _set_att(state, None)
        _set_rates(state, None)
        _set_sf(state, None)
        return state

    def _quaternion(self, phi: float, theta: float, psi: float) -> Quat:
        """ZYX Euler angles to the project's w >= 0 quaternion, written out as the plant always computed it."""
        half_roll, half_pitch, half_yaw = 0.5 * phi, 0.5 * theta, 0.5 * psi
        cr, sr = math.cos(half_roll), math.sin(half_roll)
        cp, sp = math.cos(half_pitch), math.sin(half_pitch)
        cy, sy = math.cos(half_yaw), math.sin(half_yaw)
        qw = cr * cp * cy + sr * sp * sy
        qx = sr * cp * cy - cr * sp * sy
        qy = cr * sp * cy + sr * cp * sy
        qz = cr * cp * sy - sr * sp * cy
        if qw < 0.0:  # JSBSim reports yaw in [0, 2 pi); keep the project's w >= 0 form
            qw, qx, qy, qz = -qw, -qx, -qy, -qz
        return np.array((qw, qx, qy, qz))


# The raw properties' places in a stepped state's row (``JsbsimPlant._raw_getters``): geodetic position (radians,
# radians, feet), NED velocity (ft/s), Euler angles, body rates, body forces (lbf).
_RAW_GEO = 0
_RAW_VEL = 3
_RAW_EULER = 6
_RAW_RATES = 9
_RAW_FORCES = 12


class _SteppedState(PlantState):
    """The plant's state after a step, as a ``PlantState`` whose vectors are built on first read.

    Most steps nobody reads the position, velocity or attitude (the world and the sensors read them a few tens of
    times a second, the IMU of a step between ticks reads rates and specific force through ``imu_inputs``), so
    building five numpy vectors, a quaternion and a ``GeoPoint`` at every step was a third of the plant's Python.
    The raw properties are read at the step (so a state read later, even after further steps, is the state of its
    own step), and each vector is built from them on its first read, with the conversions ``PlantState`` promises
    (SI, NED, FRD) in the arithmetic the plant always used, so the same bits; it is kept in ``PlantState``'s own slot,
    which this class's property shadows. Scalars (time, ground contact, rotor speeds) are set at the step.
    ``dataclasses.replace``, copies and pickles of it give a plain ``PlantState`` with the same fields."""

    __slots__ = ("_plant", "_raw")
    _plant: JsbsimPlant
    _raw: tuple[float, ...]  # the properties read at the step, in ``_raw_getters`` order

    def __new__(cls, **fields: object) -> PlantState:  # type: ignore[misc]
        # Only ``dataclasses.replace`` calls the class: it gets the plain record (the plant builds with ``object``).
        return PlantState(**fields)  # type: ignore[arg-type]

    def __reduce__(self) -> tuple[object, tuple[object, ...]]:
        return _plain_state, (tuple(getattr(self, f.name) for f in dataclasses.fields(PlantState)),)

    def __eq__(self, other: object) -> bool:
        return _plain_state(tuple(getattr(self, f.name) for f in dataclasses.fields(PlantState))) == other

    __hash__ = None  # type: ignore[assignment]

    def imu_inputs(self) -> npt.NDArray[np.float64]:
        raw = self._raw
        sf = self._plant._sf_scale
        return np.array((raw[_RAW_RATES], raw[_RAW_RATES + 1], raw[_RAW_RATES + 2],
                         raw[_RAW_FORCES] * sf, raw[_RAW_FORCES + 1] * sf, raw[_RAW_FORCES + 2] * sf))  # fmt: skip

    @property
    def pos_ned_m(self) -> Vec3:
        built = _get_pos(self)
        if built is not None:
            return built
        raw = self._raw
        lat, lon, alt_m = raw[_RAW_GEO], raw[_RAW_GEO + 1], raw[_RAW_GEO + 2] * M_PER_FT
        pos = np.array(self._plant._frame.ned_from_geodetic_rad(lat, lon, alt_m))
        _set_pos(self, pos)
        return pos

    @property
    def geo(self) -> GeoPoint:
        built = _get_geo(self)
        if built is not None:
            return built
        raw = self._raw
        lat, lon, alt_m = raw[_RAW_GEO], raw[_RAW_GEO + 1], raw[_RAW_GEO + 2] * M_PER_FT
        geo = _new_geo(lat_deg=math.degrees(lat), lon_deg=math.degrees(lon), alt_amsl_m=alt_m)
        _set_geo(self, geo)
        return geo

    @property
    def vel_ned_mps(self) -> Vec3:
        built = _get_vel(self)
        if built is not None:
            return built
        raw = self._raw
        vel = np.array((raw[_RAW_VEL] * M_PER_FT, raw[_RAW_VEL + 1] * M_PER_FT, raw[_RAW_VEL + 2] * M_PER_FT))
        _set_vel(self, vel)
        return vel

    @property
    def att_q_frd_to_ned(self) -> Quat:
        built = _get_att(self)
        if built is not None:
            return built
        raw = self._raw
        att = self._plant._quaternion(raw[_RAW_EULER], raw[_RAW_EULER + 1], raw[_RAW_EULER + 2])
        _set_att(self, att)
        return att

    @property
    def rates_frd_radps(self) -> Vec3:
        built = _get_rates(self)
        if built is not None:
            return built
        raw = self._raw
        rates = np.array((raw[_RAW_RATES], raw[_RAW_RATES + 1], raw[_RAW_RATES + 2]))
        _set_rates(self, rates)
        return rates

    @property
    def specific_force_frd_mps2(self) -> Vec3:
        built = _get_sf(self)
        if built is not None:
            return built
        raw = self._raw
        sf = self._plant._sf_scale
        force = np.array((raw[_RAW_FORCES] * sf, raw[_RAW_FORCES + 1] * sf, raw[_RAW_FORCES + 2] * sf))
        _set_sf(self, force)
        return force


def _plain_state(values: tuple[object, ...]) -> PlantState:
    """A plain ``PlantState`` from its fields' values in declaration order (copies and pickles of a stepped state)."""
    return PlantState(**{f.name: v for f, v in zip(dataclasses.fields(PlantState), values, strict=True)})  # type: ignore[arg-type]


_new_stepped = object.__new__
_set_time = PlantState.__dict__["time_s"].__set__
_set_on_ground = PlantState.__dict__["on_ground"].__set__
_set_speeds = PlantState.__dict__["motor_speeds_radps"].__set__
_set_raw = _SteppedState.__dict__["_raw"].__set__
_set_plant = _SteppedState.__dict__["_plant"].__set__
# PlantState's own slots, shadowed by the stepped state's properties: where each vector is kept once built.
_get_pos, _set_pos = PlantState.__dict__["pos_ned_m"].__get__, PlantState.__dict__["pos_ned_m"].__set__
_get_geo, _set_geo = PlantState.__dict__["geo"].__get__, PlantState.__dict__["geo"].__set__
_get_vel, _set_vel = PlantState.__dict__["vel_ned_mps"].__get__, PlantState.__dict__["vel_ned_mps"].__set__
_get_att, _set_att = PlantState.__dict__["att_q_frd_to_ned"].__get__, PlantState.__dict__["att_q_frd_to_ned"].__set__
_get_rates = PlantState.__dict__["rates_frd_radps"].__get__
_set_rates = PlantState.__dict__["rates_frd_radps"].__set__
_get_sf = PlantState.__dict__["specific_force_frd_mps2"].__get__
_set_sf = PlantState.__dict__["specific_force_frd_mps2"].__set__
