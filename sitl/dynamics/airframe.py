"""Airframe data: the physical constants of one multirotor, read from ``airframes/<name>.toml``.

One file is the single source of truth for geometry, mass, inertia and rotor coefficients. The JSBSim model is
generated from it (sitl/dynamics/jsbsim_model.py) and the control allocation computes its mixer from the same
numbers, so the controller and the flight model can never disagree about the vehicle.

All figures are SI. Rotor positions are in the body FRD frame relative to the centre of gravity.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

AIRFRAMES_DIR = Path(__file__).resolve().parent.parent.parent / "airframes"
DEFAULT_AIRFRAME = "quad_x_f450"


class AirframeError(ValueError):
    """A missing or malformed airframe file. The message names the file and the problem in one line."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Rotor:
    pos_frd_m: tuple[float, float, float]
    # +1: spins counter-clockwise seen from above, so its drag torque on the body is +yaw (nose right, FRD z down).
    # -1: clockwise, drag torque is -yaw.
    spin_dir: int


@dataclass(frozen=True, slots=True, kw_only=True)
class Airframe:
    name: str
    source_path: Path
    mass_kg: float
    inertia_diag_kg_m2: tuple[float, float, float]
    rotors: tuple[Rotor, ...]
    thrust_coeff_n_per_radps2: float  # thrust = k_t * omega^2
    torque_coeff_nm_per_radps2: float  # rotor drag torque = k_q * omega^2
    motor_max_speed_radps: float
    motor_time_constant_s: float  # first-order lag of rotor speed to command
    drag_coeff_frd_n_per_mps2: tuple[float, float, float]  # quadratic body drag per axis: F = -c * v|v|
    collision_radius_m: float
    gear_height_m: float  # distance from CG down to the contact points
    gear_spring_n_per_m: float
    gear_damping_n_per_mps: float

    @property
    def max_thrust_per_rotor_n(self) -> float:
        return self.thrust_coeff_n_per_radps2 * self.motor_max_speed_radps**2

    @property
    def hover_thrust_fraction(self) -> float:
        """Collective thrust needed to hover as a fraction of the maximum (PX4's MPC_THR_HOVER analogue)."""
        return self.mass_kg * 9.80665 / (self.max_thrust_per_rotor_n * len(self.rotors))


def _require(table: dict[str, Any], key: str, where: str, path: Path) -> Any:
    if key not in table:
        raise AirframeError(f"{path}: missing field '{where}{key}'")
    return table[key]


def _positive(table: dict[str, Any], key: str, where: str, path: Path) -> float:
    value = _require(table, key, where, path)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
        raise AirframeError(f"{path}: field '{where}{key}' must be a positive number, got {value!r}")
    return float(value)


def _vector(table: dict[str, Any], key: str, where: str, path: Path, *, positive: bool) -> tuple[float, ...]:
    value = _require(table, key, where, path)
    ok = isinstance(value, list) and len(value) == 3
    ok = ok and all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in value)
    if ok and positive:
        ok = all(v > 0 for v in value)
    if not ok:
        kind = "three positive numbers" if positive else "three numbers"
        raise AirframeError(f"{path}: field '{where}{key}' must be a list of {kind}, got {value!r}")
    return tuple(float(v) for v in value)


def parse_airframe(data: dict[str, Any], path: Path) -> Airframe:
    """Validate a decoded TOML document into an Airframe, raising AirframeError for the first problem found."""
    body = _require(data, "body", "", path)
    rotor_common = _require(data, "rotor", "", path)
    gear = _require(data, "gear", "", path)
    for name, table in (("body", body), ("rotor", rotor_common), ("gear", gear)):
        if not isinstance(table, dict):
            raise AirframeError(f"{path}: '{name}' must be a table")
    rotor_list = _require(data, "rotors", "", path)
    if not isinstance(rotor_list, list) or len(rotor_list) < 3:
        raise AirframeError(f"{path}: 'rotors' must be an array of at least 3 [[rotors]] tables")
    rotors = []
    for i, entry in enumerate(rotor_list):
        where = f"rotors[{i}]."
        if not isinstance(entry, dict):
            raise AirframeError(f"{path}: '{where[:-1]}' must be a table")
        pos = _vector(entry, "pos_frd_m", where, path, positive=False)
        spin = _require(entry, "spin", where, path)
        if spin not in ("ccw", "cw"):
            raise AirframeError(f'{path}: field \'{where}spin\' must be "ccw" or "cw", got {spin!r}')
        rotors.append(Rotor(pos_frd_m=(pos[0], pos[1], pos[2]), spin_dir=1 if spin == "ccw" else -1))
    inertia = _vector(body, "inertia_diag_kg_m2", "body.", path, positive=True)
    drag = _vector(body, "drag_coeff_frd_n_per_mps2", "body.", path, positive=True)
    name = data.get("name", path.stem)
    if not isinstance(name, str) or not name:
        raise AirframeError(f"{path}: field 'name' must be a non-empty string")
    airframe = Airframe(
        name=name,
        source_path=path,
        mass_kg=_positive(body, "mass_kg", "body.", path),
        inertia_diag_kg_m2=(inertia[0], inertia[1], inertia[2]),
        rotors=tuple(rotors),
        thrust_coeff_n_per_radps2=_positive(rotor_common, "thrust_coeff_n_per_radps2", "rotor.", path),
        torque_coeff_nm_per_radps2=_positive(rotor_common, "torque_coeff_nm_per_radps2", "rotor.", path),
        motor_max_speed_radps=_positive(rotor_common, "max_speed_radps", "rotor.", path),
        motor_time_constant_s=_positive(rotor_common, "time_constant_s", "rotor.", path),
        drag_coeff_frd_n_per_mps2=(drag[0], drag[1], drag[2]),
        collision_radius_m=_positive(body, "collision_radius_m", "body.", path),
        gear_height_m=_positive(gear, "height_m", "gear.", path),
        gear_spring_n_per_m=_positive(gear, "spring_n_per_m", "gear.", path),
        gear_damping_n_per_mps=_positive(gear, "damping_n_per_mps", "gear.", path),
    )
    if airframe.hover_thrust_fraction >= 0.9:
        raise AirframeError(
            f"{path}: rotors cannot lift the vehicle with margin (hover needs "
            f"{airframe.hover_thrust_fraction:.0%} of maximum thrust; must be below 90%)"
        )
    return airframe


def resolve_airframe_path(name_or_path: str) -> Path:
    """An airframe is named (``quad_x_f450`` -> airframes/quad_x_f450.toml) or given as a path to a .toml file."""
    candidate = Path(name_or_path)
    if candidate.suffix == ".toml" or candidate.parent != Path("."):
        return candidate
    return AIRFRAMES_DIR / f"{name_or_path}.toml"


def available_airframes() -> list[str]:
    return sorted(p.stem for p in AIRFRAMES_DIR.glob("*.toml"))


def load_airframe(name_or_path: str = DEFAULT_AIRFRAME) -> Airframe:
    path = resolve_airframe_path(name_or_path)
    if not path.is_file():
        known = ", ".join(available_airframes()) or "none"
        raise AirframeError(f"{path}: no such airframe file (known airframes: {known})")
    try:
        with path.open("rb") as handle:
            data = tomllib.load(handle)
    except tomllib.TOMLDecodeError as exc:
        raise AirframeError(f"{path}: not valid TOML: {exc}") from None
    except OSError as exc:
        raise AirframeError(f"{path}: cannot read: {exc.strerror}") from None
    return parse_airframe(data, path)
