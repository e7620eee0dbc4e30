"""Small rotation helpers shared by the plant, sensors, estimator and controllers, and ``fast_constructor`` for the
records they hand each other every physics step.

Conventions used everywhere in the project:
- World frame is local NED (north, east, down) anchored at home; body frame is FRD (forward, right, down).
- Quaternions are (w, x, y, z) numpy arrays rotating body-frame vectors into NED: v_ned = R(q) @ v_frd.
- Euler angles are ZYX (yaw, pitch, roll) in radians, as in PX4 and MAVLink ATTITUDE.

Flight code never calls BLAS or LAPACK (``@`` on arrays, ``np.dot``, ``np.linalg.norm`` of a vector, ``pinv``):
OpenBLAS picks its kernels by CPU, and their rounding differs, so a flight would differ in its last bits from one
machine to the next (a sweep's runs on a cluster of mixed CPUs, CI against a recorded flight). ``mat_mul`` and
``math.hypot`` stand in for them; numpy's elementwise arithmetic and reductions give the same bits on every CPU.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any, ParamSpec, TypeVar

import numpy as np
import numpy.typing as npt

Vec3 = npt.NDArray[np.float64]
Quat = npt.NDArray[np.float64]
Mat3 = npt.NDArray[np.float64]

GRAVITY_MPS2 = 9.80665

_P = ParamSpec("_P")
_T = TypeVar("_T")


def vec3(x: float, y: float, z: float) -> Vec3:
    return np.array((x, y, z), dtype=np.float64)


def mat_mul(a: npt.NDArray[Any], b: npt.NDArray[Any]) -> npt.NDArray[np.float64]:
    """``a @ b`` for 2-D ``a`` and ``b`` (a rotation, points times a rotation), without BLAS (module docstring): the
    same bits on every CPU."""
    return np.asarray((a[:, :, None] * b[None, :, :]).sum(axis=1), dtype=np.float64)


def quat_to_dcm(q: Quat) -> Mat3:
    """Rotation matrix body->NED for a unit quaternion (w, x, y, z)."""
    w, x, y, z = q
    return np.array(
        (
            (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
            (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
            (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
        )
    )


def dcm_to_quat(r: Mat3) -> Quat:
    """Unit quaternion (w, x, y, z, w >= 0) from a rotation matrix, numerically robust branch selection."""
    tr = r[0, 0] + r[1, 1] + r[2, 2]
    if tr > 0.0:
        s = math.sqrt(tr + 1.0) * 2.0
        q = (0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s)
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2.0
        q = ((r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s)
    elif r[1, 1] > r[2, 2]:
        s = math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2.0
        q = ((r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s)
    else:
        s = math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2.0
        q = ((r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s)
    out = np.array(q)
    out /= math.hypot(*out)
    return out if out[0] >= 0.0 else -out


def quat_mul(a: Quat, b: Quat) -> Quat:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array(
        (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        )
    )


def quat_from_euler(roll_rad: float, pitch_rad: float, yaw_rad: float) -> Quat:
    cr, sr = math.cos(roll_rad / 2), math.sin(roll_rad / 2)
    cp, sp = math.cos(pitch_rad / 2), math.sin(pitch_rad / 2)
    cy, sy = math.cos(yaw_rad / 2), math.sin(yaw_rad / 2)
    return np.array(
        (
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        )
    )


def quat_to_euler(q: Quat) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in radians, ZYX convention."""
    w, x, y, z = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def wrap_pi(angle_rad: float) -> float:
    """Wrap an angle to [-pi, pi)."""
    return (angle_rad + math.pi) % (2 * math.pi) - math.pi


def fast_constructor(cls: Callable[_P, _T]) -> Callable[_P, _T]:
    """A constructor for a frozen slots dataclass that is two to three times cheaper than calling the class.

    A frozen dataclass's generated ``__init__`` assigns every field through ``object.__setattr__``, about 0.1 us
    per field; for the records built at the physics rate (plant state, sensor readings, estimate, controller
    output: some fifty fields per step) that is a measurable share of the loop. The function returned here builds
    the same object by writing each slot through its descriptor: same class, same keyword-only signature and
    defaults (mypy checks calls against the class's own), equal to what the class would build, and just as
    immutable afterwards. Classes with ``__post_init__``, ``default_factory`` or ``init=False`` fields are refused,
    since skipping ``__init__`` would skip them.
    """
    if not (isinstance(cls, type) and dataclasses.is_dataclass(cls) and "__slots__" in cls.__dict__):
        raise TypeError(f"{cls!r} is not a slots dataclass")
    if hasattr(cls, "__post_init__"):
        raise TypeError(f"{cls.__name__} has __post_init__, which a fast constructor would skip")
    namespace: dict[str, Any] = {"_new": object.__new__, "_cls": cls}
    params: list[str] = []
    body: list[str] = []
    for f in dataclasses.fields(cls):
        if not f.init or f.default_factory is not dataclasses.MISSING:
            raise TypeError(f"{cls.__name__}.{f.name}: only plain fields (optionally with a default) are supported")
        namespace[f"_set_{f.name}"] = cls.__dict__[f.name].__set__
        if f.default is dataclasses.MISSING:
            params.append(f.name)
        else:
            namespace[f"_default_{f.name}"] = f.default
            params.append(f"{f.name}=_default_{f.name}")
        body.append(f"    _set_{f.name}(obj, {f.name})\n")
    source = f"def new_{cls.__name__}(*, {', '.join(params)}):\n    obj = _new(_cls)\n{''.join(body)}    return obj\n"
    exec(source, namespace)  # the technique dataclasses itself uses to generate __init__
    constructor: Callable[_P, _T] = namespace[f"new_{cls.__name__}"]
    return constructor
