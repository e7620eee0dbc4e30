"""The neighbour relay: each drone's position forwarded to the drones it matters to, as a MAVLink router would.

Each GLOBAL_POSITION_INT a drone sends is forwarded byte for byte (its own system id and sequence kept) to the other
live systems the ground station hears that its ``RelayScope`` chooses. A real router forwards everything (scope
``all``); N drones at 10 Hz then make 10 N (N - 1) datagrams a second, about 990 per drone per second at 100 drones,
most of them about drones too far away to matter. The default scope, ``reach``, forwards a report to every drone the
source could matter to: one within RELAY_REACH_M (the cameras' default range, so the table knows every body a camera
could see and fusion can pair them), or closing in fast enough to get there within RELAY_REACH_HORIZON_S (twice
collision prevention's default horizon: it ignores a body it cannot reach within AVOID_HORIZON, so nothing it would
avoid is left out, with a margin for a late report and a turn). ``within:R`` forwards within R metres; ``nearest:K``
to the K nearest, as RVO2's maxNeighbors bounds what each agent considers.

Who gets whose reports is worked out once per relay period for the whole fleet, in one pass over arrays (the
distances and closing speeds of every pair), not once per report: a report then costs a look-up of its row. A drone
whose position is not known yet gets, and is sent to, everyone. Drones keep the result in their neighbour table
(sitl/protocol/neighbours.py). Pure: the caller passes the fleet view and the time.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from typing import Final, Literal

import numpy as np
import numpy.typing as npt

from gcs.fleet.telemetry import Fleet

M_PER_DEG: Final = 6_371_000.0 * math.pi / 180.0

# The rate limit is a token bucket: a source earns one report per 0.9 of its interval (10 % slack for its own clock)
# and may bank up to RELAY_BURST. Reports a late pump reads together (a loaded machine delays the supervisor, not the
# drones) arrive closer than the interval although the source kept its rate; a plain minimum gap dropped the newer.
RELAY_BURST: Final = 2.0
RELAY_RATE_SLACK: Final = 0.9
RELAY_RATE_HZ: Final = 10.0

RELAY_REACH_M: Final = 15.0  # CAM_RANGE's default: every body a drone's cameras could see is in its table
RELAY_REACH_HORIZON_S: Final = 5.0  # twice AVOID_HORIZON's default (2.5 s)

ScopeKind = Literal["reach", "all", "within", "nearest"]
SCOPE_KINDS: Final[tuple[ScopeKind, ...]] = ("reach", "all", "within", "nearest")
SCOPE_SPELLINGS: Final = "reach, all, within:METRES or nearest:COUNT"

BoolMatrix = npt.NDArray[np.bool_]
FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class RelayScope:
    """Which drones a drone's position is relayed to (module docstring): ``reach`` (the default), ``all``,
    ``within`` ``radius_m`` metres, or the ``count`` nearest."""

    kind: ScopeKind = "reach"
    radius_m: float | None = None  # ``within`` only
    count: int | None = None  # ``nearest`` only

    def __post_init__(self) -> None:
        if self.kind not in SCOPE_KINDS:
            raise ValueError(f"must be {SCOPE_SPELLINGS}, got {self.kind!r}")
        if self.kind == "within" and not (
            self.radius_m is not None and math.isfinite(self.radius_m) and self.radius_m > 0
        ):
            raise ValueError(f"within: the radius must be a positive number of metres, got {self.radius_m}")
        if self.kind == "nearest" and not (isinstance(self.count, int) and self.count >= 1):
            raise ValueError(f"nearest: the count must be a whole number of drones >= 1, got {self.count}")
        if (self.radius_m is not None) != (self.kind == "within") or (self.count is not None) != (
            self.kind == "nearest"
        ):
            raise ValueError(f"{self.kind} takes {'a radius' if self.kind == 'within' else 'no radius'} and "
                             f"{'a count' if self.kind == 'nearest' else 'no count'}")  # fmt: skip

    @classmethod
    def parse(cls, text: str) -> RelayScope:
        """``reach``, ``all``, ``within:15`` or ``nearest:8``; ValueError with the one line that says why not."""
        kind, _, value = text.strip().partition(":")
        if kind in ("reach", "all") and not value:
            return cls(kind=kind)  # type: ignore[arg-type]
        try:
            if kind == "within" and value:
                return cls(kind="within", radius_m=float(value))
            if kind == "nearest" and value:
                return cls(kind="nearest", count=int(value))
        except ValueError as exc:
            if "must be" in str(exc):
                raise
            raise ValueError(f"{kind}: {value!r} is not a number") from None
        raise ValueError(f"must be {SCOPE_SPELLINGS}, got {text!r}")

    def text(self) -> str:
        """As ``parse`` takes it."""
        if self.kind == "within":
            return f"within:{self.radius_m:g}"
        if self.kind == "nearest":
            return f"nearest:{self.count}"
        return self.kind

    def describe(self) -> str:
        """For the flight report: how far a position travels."""
        if self.kind == "within":
            return f"to drones within {self.radius_m:g} m"
        if self.kind == "nearest":
            return f"to the {self.count} nearest drones"
        if self.kind == "all":
            return "to every drone"
        return f"to drones within {RELAY_REACH_M:g} m or closing to it within {RELAY_REACH_HORIZON_S:g} s"


DEFAULT_RELAY_SCOPE: Final = RelayScope()
RELAY_SCOPE_HELP: Final = (
    f"which drones the relay forwards a position to: reach (default: those within {RELAY_REACH_M:g} m, or closing "
    f"in to it within {RELAY_REACH_HORIZON_S:g} s), all, within:METRES or nearest:COUNT"
)


def scope_argument(text: str) -> RelayScope:
    """``--relay-scope``'s argparse type: a bad scope is argparse's own one-line error."""
    try:
        return RelayScope.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def relay_matrix(scope: RelayScope, pos_ned_m: FloatArray, vel_ned_mps: FloatArray) -> BoolMatrix:
    """``[i, j]``: drone j is sent drone i's reports, for drones at ``pos_ned_m`` moving at ``vel_ned_mps`` (N x 3;
    a row with a NaN: not known, sent to and sent everyone). Never a drone to itself. Plain IEEE arithmetic (no
    transcendental), so the same on every CPU: the relay's choices are part of a lockstep flight."""
    n = pos_ned_m.shape[0]
    everyone = ~np.eye(n, dtype=np.bool_)
    if scope.kind == "all" or n < 2:
        return everyone
    offset = pos_ned_m[np.newaxis, :, :] - pos_ned_m[:, np.newaxis, :]  # [i, j]: from i to j
    north, east, down = offset[..., 0], offset[..., 1], offset[..., 2]
    distance = np.sqrt(north * north + east * east + down * down)
    unknown = np.isnan(distance)
    if scope.kind == "within":
        matters = distance <= float(scope.radius_m or 0.0)
    elif scope.kind == "nearest":
        order = np.argsort(np.where(unknown | ~everyone, np.inf, distance), axis=1, kind="stable")
        matters = np.zeros((n, n), dtype=np.bool_)
        np.put_along_axis(matters, order[:, : scope.count], True, axis=1)
    else:
        relative = vel_ned_mps[np.newaxis, :, :] - vel_ned_mps[:, np.newaxis, :]
        towards = -(north * relative[..., 0] + east * relative[..., 1] + down * relative[..., 2])
        with np.errstate(invalid="ignore", divide="ignore"):
            closing = np.where(distance > 0.0, towards / distance, 0.0)
        closing = np.where(np.isnan(closing), 0.0, np.maximum(closing, 0.0))  # a speed not known: no closing in
        matters = distance - RELAY_REACH_HORIZON_S * closing <= RELAY_REACH_M
    return (matters | unknown) & everyone


class NeighbourRelay:
    """The relay's choices: which drones get a source's report now (rate limit and scope)."""

    def __init__(self, rate_hz: float = RELAY_RATE_HZ, scope: RelayScope | None = None) -> None:
        self.min_interval_s = 1.0 / rate_hz
        self.scope = scope or DEFAULT_RELAY_SCOPE
        self._last_s: dict[int, float] = {}
        self._credit: dict[int, float] = {}
        self.forwarded = 0
        self._plan_s = -math.inf
        self._rows: dict[int, list[int]] = {}
        self._live: list[int] = []

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
        if now_s - self._plan_s >= self.min_interval_s or now_s < self._plan_s:
            self._plan(now_s, fleet)
        out = self._rows.get(source)
        if out is None:  # a system the plan has not placed (silent at the plan, or not a drone): to every live one
            out = [sysid for sysid in self._live if sysid != source]
        self.forwarded += len(out)
        return out

    def _plan(self, now_s: float, fleet: Fleet) -> None:
        """Every live source's targets, in one pass over the fleet's latest positions."""
        self._plan_s = now_s
        views = [view for view in fleet.drones.values() if not view.lost(now_s)]
        self._live = [view.sysid for view in views]
        if not views:
            self._rows = {}
            return
        lat0 = next((v.lat_deg for v in views if math.isfinite(v.lat_deg)), 0.0)
        lon0 = next((v.lon_deg for v in views if math.isfinite(v.lon_deg)), 0.0)
        east_per_deg = M_PER_DEG * math.cos(math.radians(lat0))
        pos = np.array([((v.lat_deg - lat0) * M_PER_DEG, (v.lon_deg - lon0) * east_per_deg, -v.alt_amsl_m)
                        for v in views], dtype=np.float64)  # fmt: skip
        vel = np.array([v.vel_ned_mps for v in views], dtype=np.float64)
        matrix = relay_matrix(self.scope, pos, vel)
        live = np.array(self._live)
        self._rows = {sysid: live[matrix[i]].tolist() for i, sysid in enumerate(self._live)}
