"""The neighbour relay: every drone's position forwarded to the other drones, as a MAVLink router would.

Each GLOBAL_POSITION_INT a drone sends is forwarded byte for byte (its own system id and sequence kept) to every
other live system the ground station hears, or only to those within ``radius_m`` of it. A real router forwards
everything; a radius keeps the traffic of large swarms in check (N drones at 10 Hz make 10 N (N - 1) datagrams a
second with no radius). Drones keep the result in their neighbour table (sitl/protocol/neighbours.py).
Pure: the caller passes the fleet view and the time.
"""

from __future__ import annotations

import math

from gcs.fleet.telemetry import DroneView, Fleet

M_PER_DEG = 6_371_000.0 * math.pi / 180.0


# The rate limit is a token bucket: a source earns one report per 0.9 of its interval (10 % slack for its own clock)
# and may bank up to RELAY_BURST. Reports a late pump reads together (a loaded machine delays the supervisor, not the
# drones) arrive closer than the interval although the source kept its rate; a plain minimum gap dropped the newer.
RELAY_BURST = 2.0
RELAY_RATE_SLACK = 0.9


class NeighbourRelay:
    def __init__(self, rate_hz: float = 10.0, radius_m: float | None = None) -> None:
        self.min_interval_s = 1.0 / rate_hz
        self.radius_m = radius_m
        self._last_s: dict[int, float] = {}
        self._credit: dict[int, float] = {}
        self.forwarded = 0

    def targets(self, source: int, now_s: float, fleet: Fleet) -> list[int]:
        """Systems that should receive this position report of ``source`` now (empty when rate-limited)."""
        last = self._last_s.get(source)
        earned = 1.0 if last is None else (now_s - last) / (self.min_interval_s * RELAY_RATE_SLACK)
        credit = min(RELAY_BURST, self._credit.get(source, 0.0) + earned)
        self._last_s[source] = now_s
        if credit < 1.0:
            self._credit[source] = credit
            return []
        self._credit[source] = credit - 1.0
        origin = fleet.drones.get(source)
        out = []
        for sysid, view in fleet.drones.items():
            if sysid == source or view.lost(now_s):
                continue
            if self.radius_m is not None and origin is not None and _distance_m(origin, view) > self.radius_m:
                continue
            out.append(sysid)
        self.forwarded += len(out)
        return out


def _distance_m(a: DroneView, b: DroneView) -> float:
    lat_a, lon_a, alt_a = a.lat_deg, a.lon_deg, a.alt_amsl_m
    lat_b, lon_b, alt_b = b.lat_deg, b.lon_deg, b.alt_amsl_m
    if not all(math.isfinite(v) for v in (lat_a, lon_a, alt_a, lat_b, lon_b, alt_b)):
        return 0.0  # position not known yet: relay rather than drop
    north = (lat_b - lat_a) * M_PER_DEG
    east = (lon_b - lon_a) * M_PER_DEG * math.cos(math.radians(lat_a))
    return math.sqrt(north * north + east * east + (alt_b - alt_a) ** 2)
