"""The swarm frame and its conversions to geodetic coordinates and to each drone's own local frame.

Formations are defined in one **swarm frame**: local NED in metres around a geographic origin (latitude,
longitude, altitude AMSL) chosen for the flight. Every PX4-like drone, however, reports and accepts local positions
in **its own** local NED frame, anchored where it booted; drones spawned side by side have origins metres apart,
so a swarm-frame point has different local coordinates on every drone.

All conversions go through gcs/flight/geodesy.py, the ground station's own implementation of the local-frame definition
the drones use (orthographic projection onto the origin's tangent plane; down is the altitude difference), written
independently of the drone's code so that a projection bug cannot cancel out. Swarm NED -> geodetic -> drone NED
round-trips to well under a millimetre at swarm scales.

Which setpoint message: SET_POSITION_TARGET_LOCAL_NED in each drone's own local frame
--------------------------------------------------------------------------------------
The supervisor converts each drone's swarm-frame setpoint into that drone's local frame (``DroneFrame.to_local``,
``DroneFrame.vector_to_local``) and streams SET_POSITION_TARGET_LOCAL_NED (frame 1, LOCAL_NED) rather than
SET_POSITION_TARGET_GLOBAL_INT. Why:

- Precision. GLOBAL_INT carries latitude and longitude as degE7 integers: steps of 1.1 cm north and about 0.75 cm
  east at 47 deg latitude, so a smoothly moving target (a rotating circle) becomes a staircase that the position
  loop sees as jitter. LOCAL_NED carries float32 metres: resolution below 0.01 mm within 100 m of the origin.
- The same frame both ways. The drone's position feedback (LOCAL_POSITION_NED) is in its local frame too and is
  mapped back with ``DroneFrame.to_swarm``. Any error in the estimate of the drone's origin then shifts the
  command and the measurement alike, so it never shows up as a formation error or as a control offset.
- It is the path every offboard example (MAVSDK ``set_position_ned``, PX4 offboard guides) exercises.

The price is knowing each drone's local origin. PX4 reports it in GPS_GLOBAL_ORIGIN; HOME_POSITION also carries
both the geodetic home and home's local coordinates, from which ``origin_from_home`` recovers the origin exactly
(up to the message's degE7/millimetre quantisation: a constant offset below 6 mm, identical for command and
feedback). Velocity and acceleration feed-forward are rotated between the two tangent planes
(``vector_to_local``); the rotation is about d / R (1.6e-6 rad for 10 m) but costs nothing to apply.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt

from gcs.flight.arrays import mat_mul
from gcs.flight.geodesy import GeoPoint, NedFrame

Vec3 = tuple[float, float, float]
# Where the ground station has each drone fly at a mission time, swarm frame (the setpoint streamer's ``targets``):
# what the recorder, the live view and the invariants read of it, without holding the streamer that commands
Targets = Callable[[float], dict[int, Vec3]]

_ORIGIN_ITERATIONS = 4  # each fixed-point step shrinks the error by ~d / R; 4 is far below a micrometre


def _as_vec3(values: Sequence[float] | npt.ArrayLike, what: str) -> Vec3:
    if type(values) is tuple and len(values) == 3:  # the common case, every setpoint of every drone: no array
        x, y, z = float(values[0]), float(values[1]), float(values[2])
        if math.isfinite(x) and math.isfinite(y) and math.isfinite(z):
            return (x, y, z)
    arr = np.asarray(values, dtype=np.float64).reshape(-1)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} must be three finite numbers, got {values!r}")
    return (float(arr[0]), float(arr[1]), float(arr[2]))


def _ned_from_ecef_matrix(origin: GeoPoint) -> npt.NDArray[np.float64]:
    """Rotation taking ECEF vectors to the NED axes of the tangent plane at ``origin``."""
    lat = math.radians(origin.lat_deg)
    lon = math.radians(origin.lon_deg)
    sl, cl, so, co = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
    return np.array(
        (
            (-sl * co, -sl * so, cl),
            (-so, co, 0.0),
            (-cl * co, -cl * so, -sl),
        )
    )


Rows = tuple[Vec3, Vec3, Vec3]


def _rotate(rows: Rows, v: Vec3) -> Vec3:
    """``mat_mul(rows, v)`` to the bit, signed zeros included, in floats: numpy's sum along a row of three adds
    them to 0.0 one by one, as here. A setpoint's velocity and acceleration are rotated for every drone at every
    tick, and two small arrays a call cost more than the rotation."""
    x, y, z = v
    (a, b, c), (d, e, f), (g, h, i) = rows
    return (0.0 + a * x + b * y + c * z, 0.0 + d * x + e * y + f * z, 0.0 + g * x + h * y + i * z)


class SwarmFrame:
    """Local NED (metres) around the swarm's geographic origin: the frame formations are defined in."""

    __slots__ = ("_frame", "_origin")

    def __init__(self, origin: GeoPoint) -> None:
        self._origin = origin
        self._frame = NedFrame(origin)

    @property
    def origin(self) -> GeoPoint:
        return self._origin

    def ned_from_geo(self, point: GeoPoint) -> Vec3:
        """Swarm-frame NED metres of a geodetic point."""
        return self._frame.ned_from_geo(point)

    def geo_from_ned(self, pos_ned_m: Sequence[float] | npt.ArrayLike) -> GeoPoint:
        """Geodetic point of a swarm-frame NED position."""
        return self._frame.geo_from_ned(_as_vec3(pos_ned_m, "swarm NED position"))

    def drone_frame(self, drone_origin: GeoPoint) -> DroneFrame:
        """Conversions between this swarm frame and the local frame of a drone whose local origin is given."""
        return DroneFrame(self, drone_origin)


class DroneFrame:
    """One drone's local NED frame (anchored at its own origin) seen from the swarm frame."""

    __slots__ = ("_local", "_local_from_swarm", "_origin", "_swarm", "_swarm_from_local")

    def __init__(self, swarm: SwarmFrame, drone_origin: GeoPoint) -> None:
        self._swarm = swarm
        self._origin = drone_origin
        self._local = NedFrame(drone_origin)
        rotation = mat_mul(_ned_from_ecef_matrix(drone_origin), _ned_from_ecef_matrix(swarm.origin).T)
        self._local_from_swarm = _rows(rotation)
        self._swarm_from_local = _rows(rotation.T)

    @property
    def origin(self) -> GeoPoint:
        """Geodetic point of the drone's local (0, 0, 0)."""
        return self._origin

    @property
    def swarm(self) -> SwarmFrame:
        return self._swarm

    def to_local(self, swarm_ned_m: Sequence[float] | npt.ArrayLike) -> Vec3:
        """A swarm-frame position in the drone's local NED frame (what SET_POSITION_TARGET_LOCAL_NED carries)."""
        return self._local.ned_from_geo(self._swarm.geo_from_ned(swarm_ned_m))

    def to_swarm(self, local_ned_m: Sequence[float] | npt.ArrayLike) -> Vec3:
        """A position in the drone's local NED frame (LOCAL_POSITION_NED) in the swarm frame."""
        geo = self._local.geo_from_ned(_as_vec3(local_ned_m, "local NED position"))
        return self._swarm.ned_from_geo(geo)

    def vector_to_local(self, swarm_vec: Sequence[float] | npt.ArrayLike) -> Vec3:
        """A free vector (velocity, acceleration) from swarm NED axes to the drone's NED axes."""
        return _rotate(self._local_from_swarm, _as_vec3(swarm_vec, "swarm NED vector"))

    def vector_to_swarm(self, local_vec: Sequence[float] | npt.ArrayLike) -> Vec3:
        """A free vector from the drone's NED axes to swarm NED axes."""
        return _rotate(self._swarm_from_local, _as_vec3(local_vec, "local NED vector"))


def _rows(matrix: npt.NDArray[np.float64]) -> Rows:
    (a, b, c), (d, e, f), (g, h, i) = matrix.tolist()
    return ((a, b, c), (d, e, f), (g, h, i))


def origin_from_home(home: GeoPoint, home_local_ned_m: Sequence[float] | npt.ArrayLike) -> GeoPoint:
    """A drone's local origin from its HOME_POSITION: home's geodetic position and home's local coordinates.

    The origin is the point O with ``NedFrame(O).ned_from_geo(home) == home_local_ned_m``. Stepping back from home
    by the local offset lands within about d^2 / R of it (the two tangent planes differ); a few fixed-point
    corrections remove that.
    """
    target = np.asarray(_as_vec3(home_local_ned_m, "home local NED position"))
    origin = NedFrame(home).geo_from_ned(tuple(-target))
    for _ in range(_ORIGIN_ITERATIONS):
        frame = NedFrame(origin)
        residual = target - np.asarray(frame.ned_from_geo(home))
        if float(np.max(np.abs(residual))) < 1e-9:
            break
        # Home sits `residual` short of where it should be in the origin's frame: move the origin the other way.
        origin = frame.geo_from_ned(tuple(-residual))
    return origin
