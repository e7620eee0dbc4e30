"""The parameter table: every tunable of a drone declared once, with its range, unit and meaning.

Declarations live with the code that uses them (controllers, autopilot, avoidance) and are collected into one
``ParamStore`` per drone, which the MAVLink parameter service serves. Names follow PX4 where PX4 has the same
parameter and are at most 16 characters (the MAVLink PARAM_VALUE ``param_id`` field).

Stages never read the store inside their math: the wrapper that owns a stage copies values into the stage's
frozen config when a parameter changes (``ParamStore.version`` tells it when), so a gain set in flight takes effect
at the next control step.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from enum import Enum

MAX_NAME_LEN = 16


class ParamType(Enum):
    FLOAT = "float"  # MAVLink REAL32
    INT = "int"  # MAVLink INT32, sent PX4-style: the int's bytes reinterpreted as the float field


@dataclass(frozen=True, slots=True, kw_only=True)
class ParamDef:
    name: str
    default: float
    min: float
    max: float
    unit: str
    description: str
    type: ParamType = ParamType.FLOAT

    def __post_init__(self) -> None:
        if not self.name or len(self.name) > MAX_NAME_LEN or not self.name.isascii():
            raise ValueError(f"parameter name {self.name!r} must be 1-{MAX_NAME_LEN} ASCII characters")
        if not (self.min <= self.default <= self.max):
            raise ValueError(f"parameter {self.name}: default {self.default} outside [{self.min}, {self.max}]")
        if self.type is ParamType.INT and not all(float(v).is_integer() for v in (self.default, self.min, self.max)):
            raise ValueError(f"parameter {self.name}: INT parameter with non-integer bounds or default")


class ParamError(ValueError):
    """A set request that was refused; the store is unchanged."""


class ParamStore:
    """Current values of a set of declared parameters, in declaration order (which is the MAVLink index)."""

    def __init__(self, defs: Iterable[ParamDef]) -> None:
        self._defs: dict[str, ParamDef] = {}
        for d in defs:
            if d.name in self._defs:
                raise ValueError(f"parameter {d.name} declared twice")
            self._defs[d.name] = d
        self._names = list(self._defs)
        self._values = {d.name: float(d.default) for d in self._defs.values()}
        self.version = 0

    def __len__(self) -> int:
        return len(self._names)

    def __contains__(self, name: object) -> bool:
        return name in self._defs

    def __getitem__(self, name: str) -> float:
        return self._values[name]

    @property
    def names(self) -> list[str]:
        return list(self._names)

    def definition(self, name: str) -> ParamDef:
        return self._defs[name]

    def index_of(self, name: str) -> int:
        return self._names.index(name)

    def name_at(self, index: int) -> str:
        return self._names[index]

    def set(self, name: str, value: float) -> float:
        """Set a value after validation; returns the stored value. Raises ParamError and changes nothing if refused."""
        d = self._defs.get(name)
        if d is None:
            raise ParamError(f"unknown parameter {name!r}")
        if not math.isfinite(value):
            raise ParamError(f"{name}: value {value!r} is not finite")
        if d.type is ParamType.INT and not float(value).is_integer():
            raise ParamError(f"{name}: integer parameter cannot take {value!r}")
        if not (d.min <= value <= d.max):
            raise ParamError(f"{name}: {value:g} outside [{d.min:g}, {d.max:g}] {d.unit}".rstrip())
        stored = float(value)
        if self._values[name] != stored:
            self._values[name] = stored
            self.version += 1
        return stored
