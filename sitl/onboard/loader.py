"""Read an onboard behaviour from ``path/to/file.py:ClassName`` (or an installed module's, ``package.module:ClassName``,
as the shipped ``sitl.onboard.behaviours.flocking:Flocking``), checked before any drone flies it.

Every mistake is one line naming the file (and the line, when there is one) and the problem: a file that is not
there, a syntax error, an exception while the module runs, a missing class, a class without ``step``, a bad
``RATE_HZ`` or ``PARAMS`` table. A behaviour's parameters become the drone's MAVLink parameters, declared beside
``BHV_EN``, which starts and stops it.
"""

from __future__ import annotations

import importlib.util
import math
import re
import sys
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sitl.drone.param_table import build_param_store
from sitl.params import ParamDef, ParamType

ENABLE_PARAM = "BHV_EN"
MAX_RATE_HZ = 250.0  # the physics rate: a behaviour cannot step more often than the drone
_PARAM_NAME = re.compile(r"^[A-Z][A-Z0-9_]{0,15}$")  # MAVLink param_id: at most 16 characters
_DRONE_PARAMS = frozenset(build_param_store().names)  # a behaviour's parameters are its own, beside these


class BehaviourError(ValueError):
    """A behaviour that cannot be loaded; the message is one line: ``file.py:12: what is wrong``."""


@dataclass(frozen=True, slots=True)
class LoadedBehaviour:
    """A checked behaviour class and what the drone declares for it."""

    cls: type
    spec: str  # as given: path:ClassName or module:ClassName
    file: Path  # the file the class is in (an error in flight names it)
    name: str  # the class's name
    rate_hz: float
    params: tuple[ParamDef, ...]  # its own, then BHV_EN


def enable_param() -> ParamDef:
    return ParamDef(name=ENABLE_PARAM, default=0, min=0, max=1, unit="", type=ParamType.INT,
                    description="Onboard behaviour: 1 runs it (OFFBOARD, fed by it), 0 stops it")  # fmt: skip


def load_behaviour(spec: str) -> LoadedBehaviour:
    """The behaviour class of ``spec`` (``path/to/file.py:ClassName`` or ``package.module:ClassName``), checked;
    BehaviourError names the problem."""
    path_text, sep, class_name = spec.rpartition(":")
    if not sep or not path_text or not class_name.isidentifier():
        raise BehaviourError(f"{spec}: a behaviour is given as path/to/file.py:ClassName")
    if is_module_name(path_text):
        module = _import_module(path_text)
        path = Path(module.__file__ or path_text)
    else:
        path = Path(path_text)
        if not path.is_file():
            raise BehaviourError(f"{path}: no such file")
        module = _run_module(path)
    cls = getattr(module, class_name, None)
    if not isinstance(cls, type):
        raise BehaviourError(f"{path}: no class {class_name}")
    where = f"{path}:{class_name}"
    if not callable(getattr(cls, "step", None)):
        raise BehaviourError(f"{where}: the class has no step(state) method")
    rate = getattr(cls, "RATE_HZ", None)
    if isinstance(rate, bool) or not isinstance(rate, int | float) or not 0 < rate <= MAX_RATE_HZ:
        raise BehaviourError(f"{where}: RATE_HZ must be a number in (0, {MAX_RATE_HZ:g}], got {rate!r}")
    return LoadedBehaviour(cls=cls, spec=spec, file=path, name=class_name, rate_hz=float(rate),
                           params=(*_params(where, getattr(cls, "PARAMS", {})), enable_param()))  # fmt: skip


def is_module_name(text: str) -> bool:
    """``package.module`` (dotted identifiers, no ``.py``), as opposed to a file's path."""
    return not text.endswith(".py") and all(part.isidentifier() for part in text.split("."))


def _import_module(name: str) -> Any:
    """An installed module; an error in it is one line with its file and line."""
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as exc:
        if exc.name is not None and name.startswith(exc.name):
            raise BehaviourError(f"{name}: no such module") from None
        raise BehaviourError(f"{name}: {type(exc).__name__}: {exc}") from None
    except SyntaxError as exc:
        raise BehaviourError(f"{exc.filename}:{exc.lineno}: SyntaxError: {exc.msg}") from None
    except Exception as exc:
        frames = traceback.extract_tb(exc.__traceback__)
        where = f"{frames[-1].filename}:{frames[-1].lineno}" if frames else name
        raise BehaviourError(f"{where}: {type(exc).__name__}: {exc}") from None


def _run_module(path: Path) -> Any:
    """Import the file as a module of its own; an error in it is one line with its file and line."""
    name = f"onboard_behaviour_{abs(hash(path.resolve()))}"
    module_spec = importlib.util.spec_from_file_location(name, path)
    if module_spec is None or module_spec.loader is None:
        raise BehaviourError(f"{path}: not a Python file")
    module = importlib.util.module_from_spec(module_spec)
    try:
        module_spec.loader.exec_module(module)
    except SyntaxError as exc:
        raise BehaviourError(f"{path}:{exc.lineno}: SyntaxError: {exc.msg}") from None
    except Exception as exc:
        raise BehaviourError(f"{path}:{error_line(exc, path)}: {type(exc).__name__}: {exc}") from None
    sys.modules[name] = module
    return module


def error_line(exc: BaseException, path: Path) -> int | str:
    """The line of ``path`` where ``exc`` was raised (the innermost frame in that file), or '?'."""
    frames = [f for f in traceback.extract_tb(exc.__traceback__) if Path(f.filename).resolve() == path.resolve()]
    return frames[-1].lineno or "?" if frames else "?"


def _params(where: str, table: object) -> list[ParamDef]:
    if not isinstance(table, dict):
        raise BehaviourError(f"{where}: PARAMS must be a dict of NAME: (default, min, max), got {type(table).__name__}")
    out = []
    for name, value in table.items():
        if not isinstance(name, str) or not _PARAM_NAME.match(name) or name == ENABLE_PARAM or name in _DRONE_PARAMS:
            raise BehaviourError(f"{where}: parameter name {name!r} must be 1-16 characters A-Z, 0-9, _ and not "
                                 f"one of the drone's own")  # fmt: skip
        numbers = value if isinstance(value, tuple | list) else ()
        if len(numbers) != 3 or not all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                                        for v in numbers):  # fmt: skip
            raise BehaviourError(f"{where}: PARAMS[{name!r}] must be (default, min, max), got {value!r}")
        default, low, high = (float(v) for v in numbers)
        if not low <= default <= high:
            raise BehaviourError(f"{where}: PARAMS[{name!r}]: default {default:g} outside [{low:g}, {high:g}]")
        out.append(ParamDef(name=name, default=default, min=low, max=high, unit="",
                            description=f"Onboard behaviour {where.rpartition(':')[2]}"))  # fmt: skip
    return out
