"""The shared world's geometry a drone reads at its camera and contact rates (sitl/world/shared.py is the shell: the
table, its layout, falling bodies, static obstacles).

Every other valid body's offset from one drone, in its local NED frame, from the table's geodetic positions: the same
operations in the same order as the numpy they replaced (degrees to radians by one product with pi/180, then the
Earth's radius, then the cosine of the drone's latitude), so offsets keep their bits. And the bodies a drone touches,
from the same offsets, in one call where the shell's numpy took seven.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from sitl.kernels import kernel

RAD_PER_DEG = math.pi / 180.0  # numpy's deg2rad and CPython's math.radians multiply by this
# ``columns``: the table's column of each figure (the layout is sitl/world/shared.py's).
C_VALID = 0
C_LAT = 1
C_LON = 2
C_ALT = 3
C_ENDED = 4
C_RADIUS = 5


@kernel("int64(float64[:, ::1], int64, int64[::1], float64, int64[::1], float64[:, ::1])")
def others_offsets(
    bodies: npt.NDArray[np.float64],
    instance: int,
    columns: npt.NDArray[np.int64],
    earth_radius_m: float,
    ids: npt.NDArray[np.int64],
    offsets: npt.NDArray[np.float64],
) -> int:
    """The instances (``ids``) and NED offsets from drone ``instance`` of every other valid body, in table order;
    returns how many, or -1 when one of them has ended (its body falls: the shell works out where it is now)."""
    valid, ended = columns[C_VALID], columns[C_ENDED]
    lat_c, lon_c, alt_c = columns[C_LAT], columns[C_LON], columns[C_ALT]
    me_lat = bodies[instance, lat_c]
    me_lon = bodies[instance, lon_c]
    me_alt = bodies[instance, alt_c]
    cos_lat = math.cos(me_lat * RAD_PER_DEG)
    n = 0
    for i in range(bodies.shape[0]):
        if i == instance or bodies[i, valid] != 1.0:
            continue
        if bodies[i, ended] != 0.0:
            return -1
        ids[n] = i
        offsets[n, 0] = (bodies[i, lat_c] - me_lat) * RAD_PER_DEG * earth_radius_m
        offsets[n, 1] = (bodies[i, lon_c] - me_lon) * RAD_PER_DEG * earth_radius_m * cos_lat
        offsets[n, 2] = me_alt - bodies[i, alt_c]
        n += 1
    return n


@kernel("float64(float64, float64, float64)")
def centre_distance_m(north: float, east: float, down: float) -> float:
    """The length of an offset, its squares added in one fixed order: numpy's einsum, which the contact check used,
    adds them in an order that depends on the CPU's vector width ((n^2 + d^2) + e^2 on this project's machines); a
    kernel keeps the one order everywhere."""
    return math.sqrt((north * north + down * down) + east * east)


@kernel(
    "int64(float64[:, ::1], int64, int64[::1], float64, float64, int64[::1], float64[:, ::1], int64[::1], float64[::1])"
)
def touching(
    bodies: npt.NDArray[np.float64],
    instance: int,
    columns: npt.NDArray[np.int64],
    earth_radius_m: float,
    own_radius_m: float,
    ids: npt.NDArray[np.int64],
    offsets: npt.NDArray[np.float64],
    hit_ids: npt.NDArray[np.int64],
    hit_distances_m: npt.NDArray[np.float64],
) -> int:
    """The other valid bodies closer to drone ``instance`` than both radii together (``hit_ids``, their centre
    distances in ``hit_distances_m``), in table order, from the offsets ``others_offsets`` gives (``ids`` and
    ``offsets``: its scratch); returns how many, or -1 when one of them has ended (the shell works out where it has
    fallen to)."""
    n = others_offsets(bodies, instance, columns, earth_radius_m, ids, offsets)
    if n < 0:
        return -1
    radius = columns[C_RADIUS]
    hits = 0
    for k in range(n):
        distance = centre_distance_m(offsets[k, 0], offsets[k, 1], offsets[k, 2])
        if distance < bodies[ids[k], radius] + own_radius_m:
            hit_ids[hits] = ids[k]
            hit_distances_m[hits] = distance
            hits += 1
    return hits
