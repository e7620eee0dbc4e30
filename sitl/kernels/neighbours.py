"""A drone's neighbour table as collision prevention reads it: every report within its timeout, converted to the
drone's local NED frame in one call (sitl/drone/awareness.py, at ``RELAY_PERIOD_S``).

The table (sitl/protocol/neighbours.py) keeps each report's figures as one row (``E_*``: geodetic position, velocity,
times, source), made once per report and per host when it is decoded; this kernel filters the rows by age, counts the
ages per source as the table's ``entries`` counts them, and writes collision prevention's rows (sitl/kernels/
avoidance.py ``N_*``). The conversion is sitl/dynamics/geodesy.py ``LocalFrame.ned_from_geodetic_rad`` written out with
the same operations in the same order, its degrees turned to radians by one product with pi/180 as ``math.radians``
does, so the rows keep the bits the Python conversion gave. With 24 neighbours the conversion one report at a time was
about 80 us a look, 4 % of a hosted drone and a quarter of its perception (bench/drone_parts.py ``hosted-offboard``).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from sitl.kernels import avoidance as ak
from sitl.kernels import kernel
from sitl.kernels.world import RAD_PER_DEG

# A report's row (``Neighbour.row``)
E_LAT = 0  # degrees
E_LON = 1  # degrees
E_ALT = 2  # metres AMSL
E_VEL = 3  # NED m/s, 3
E_SENT = 6  # the sender's own time (s)
E_RECEIVED = 7  # this drone's time when it arrived (s)
E_STALE = 8  # how old the sender's knowledge was (s)
E_COOPERATIVE = 9  # 1.0: a swarm neighbour; 0.0: traffic
E_SYSID = 10
E_SOURCE = 11  # the index of its way in sitl/protocol/neighbours.py ``SOURCES``
ENTRY_SIZE = 12
# The drone's frame (sitl/dynamics/geodesy.py ``LocalFrame.conversion``)
F_X0 = 0  # ECEF of home, 3
F_SIN_LAT0 = 3
F_COS_LAT0 = 4
F_SIN_LON0 = 5
F_COS_LON0 = 6
F_ALT0 = 7
F_A = 8  # the ellipsoid's semi-major axis (m)
F_E2 = 9  # its eccentricity squared
F_ONE_MINUS_E2 = 10
FRAME_SIZE = 11
# The ages a table counts per source where it is read (``ages[source]``)
A_AGE = 0  # sum of the times since arrival
A_SENT_AGE = 1  # sum of the times since sending
A_SAMPLES = 2
AGES_SIZE = 3


@kernel("int64(float64[:, ::1], float64, float64, float64[::1], boolean, float64[:, ::1], float64[:, ::1])")
def relay_rows(
    entries: npt.NDArray[np.float64],
    now_s: float,
    timeout_s: float,
    frame: npt.NDArray[np.float64],
    shared_clock: bool,
    ages: npt.NDArray[np.float64],
    out: npt.NDArray[np.float64],
) -> int:
    """Collision prevention's rows (``out``, ``N_*``) of the ``entries`` (in sysid order) no older than ``timeout_s``
    at ``now_s``, each stamped with its sender's time (``shared_clock``: lockstep, one clock) or its arrival, and
    their ages added to ``ages`` per source; returns how many."""
    x0 = frame[F_X0]
    y0 = frame[F_X0 + 1]
    z0 = frame[F_X0 + 2]
    sin_lat0 = frame[F_SIN_LAT0]
    cos_lat0 = frame[F_COS_LAT0]
    sin_lon0 = frame[F_SIN_LON0]
    cos_lon0 = frame[F_COS_LON0]
    alt0 = frame[F_ALT0]
    semi_major_m = frame[F_A]
    e2 = frame[F_E2]
    one_minus_e2 = frame[F_ONE_MINUS_E2]
    n = 0
    for i in range(entries.shape[0]):
        received_s = entries[i, E_RECEIVED]
        if not now_s - received_s <= timeout_s:
            continue
        sent_s = entries[i, E_SENT]
        source = int(entries[i, E_SOURCE])
        ages[source, A_AGE] += now_s - received_s
        ages[source, A_SENT_AGE] += now_s - sent_s
        ages[source, A_SAMPLES] += 1.0
        lat_rad = entries[i, E_LAT] * RAD_PER_DEG
        lon_rad = entries[i, E_LON] * RAD_PER_DEG
        sin_lat = math.sin(lat_rad)
        normal = semi_major_m / math.sqrt(1.0 - e2 * sin_lat * sin_lat)
        r = (normal + alt0) * math.cos(lat_rad)
        x = r * math.cos(lon_rad)
        y = r * math.sin(lon_rad)
        z = (normal * one_minus_e2 + alt0) * sin_lat
        dx = x - x0
        dy = y - y0
        dz = z - z0
        t = cos_lon0 * dx + sin_lon0 * dy
        out[n, ak.N_POS] = -sin_lat0 * t + cos_lat0 * dz
        out[n, ak.N_POS + 1] = -sin_lon0 * dx + cos_lon0 * dy
        out[n, ak.N_POS + 2] = alt0 - entries[i, E_ALT]
        out[n, ak.N_VEL] = entries[i, E_VEL]
        out[n, ak.N_VEL + 1] = entries[i, E_VEL + 1]
        out[n, ak.N_VEL + 2] = entries[i, E_VEL + 2]
        out[n, ak.N_RECEIVED] = sent_s if shared_clock else received_s
        out[n, ak.N_STALE] = entries[i, E_STALE]
        out[n, ak.N_COOPERATIVE] = entries[i, E_COOPERATIVE]
        out[n, ak.N_SYSID] = entries[i, E_SYSID]
        n += 1
    return n
