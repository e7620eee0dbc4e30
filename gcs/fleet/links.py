"""Link impairment settings as the ground station takes them: from ``swarm up``/``swarm fly`` options and from a
mission's ``[swarm.links]`` table, validated here, before anything is spawned.

The simulation applies them (its link model; docs/links.md). The ground station never imports the simulation; the
keys, ranges and one-line messages both sides read alike are swarmcommon/links.py.

Three link classes: ``gcs`` (the ground station and a drone, both ways), ``api`` (a client such as MAVSDK and a
drone's API link), ``neighbour`` (neighbour positions relayed to a drone, and the drone-to-drone mesh). Here too:
which way neighbours' positions travel (``NeighbourPlan``: the relay, the mesh, or both) and the mesh radio's
range and path loss (``MeshPlan``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Final

from gcs.fleet.relay import DEFAULT_RELAY_SCOPE, RelayScope
from swarmcommon.links import (
    DEFAULT_MESH_EXPONENT,
    DEFAULT_MESH_RANGE_M,
    LINK_CLASSES,
    LINK_KEYS,
    MESH_KEYS,
    mesh_value_problem,
    parse_value,
    settings_problem,
    value_problem,
)


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkSettings:
    """One link class's impairment; the defaults are a perfect link (the meanings: docs/links.md)."""

    loss: float = 0.0  # probability that a frame is lost while the channel is good
    burst_good_s: float = 0.0  # Gilbert-Elliott mean good time; 0 and 0: no bursts
    burst_bad_s: float = 0.0  # Gilbert-Elliott mean bad time (the mean outage)
    burst_loss: float = 1.0  # probability that a frame is lost while the channel is bad
    latency_ms: float = 0.0
    jitter_ms: float = 0.0
    bandwidth_bps: float | None = None  # None: no cap

    def __post_init__(self) -> None:
        problem = settings_problem(self.values())
        if problem is not None:
            raise ValueError(problem)

    def values(self) -> dict[str, float]:
        """The settings that are set (a cap given), by key in ``LINK_KEYS`` order."""
        out: dict[str, float] = {}
        for key in LINK_KEYS:
            value = getattr(self, key)
            if value is not None:
                out[key] = value
        return out

    def given(self) -> dict[str, float]:
        """The settings that differ from a perfect link's."""
        return {k: v for k, v in self.values().items() if v != getattr(PERFECT, k)}

    @property
    def is_perfect(self) -> bool:
        return (
            self.loss == 0
            and not (self.burst_bad_s > 0 and self.burst_loss > 0)
            and self.latency_ms == 0
            and self.jitter_ms == 0
            and self.bandwidth_bps is None
        )

    def describe(self) -> str:
        given = self.given()
        return ",".join(f"{k}={v:g}" for k, v in given.items()) if given else "perfect"


PERFECT: Final = LinkSettings()


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkPlan:
    """The settings of every link class for a swarm (every drone gets the same; their draws differ by seed)."""

    gcs: LinkSettings = field(default=PERFECT)
    api: LinkSettings = field(default=PERFECT)
    neighbour: LinkSettings = field(default=PERFECT)

    def of(self, link_class: str) -> LinkSettings:
        if link_class not in LINK_CLASSES:
            raise ValueError(f"link class must be {', '.join(LINK_CLASSES)}, got {link_class!r}")
        settings: LinkSettings = getattr(self, link_class)
        return settings

    @property
    def is_perfect(self) -> bool:
        return all(self.of(c).is_perfect for c in LINK_CLASSES)

    def overridden(self, values: Mapping[str, float]) -> LinkPlan:
        """These settings for every class, the others kept (the CLI's options over a mission's table).

        ValueError with one line (naming the class) when a class's result is no link."""
        out: dict[str, LinkSettings] = {}
        for link_class in LINK_CLASSES:
            merged = {**self.of(link_class).values(), **values}
            problem = settings_problem(merged)
            if problem is not None:
                raise ValueError(f"{link_class}: {problem}")
            out[link_class] = replace(PERFECT, **merged)
        return LinkPlan(**out)

    def describe(self) -> str:
        """One line: each class's settings (``perfect`` when nothing is impaired)."""
        if self.is_perfect:
            return "perfect"
        return "; ".join(f"{c} {self.of(c).describe()}" for c in LINK_CLASSES)


def plan_from_tables(common: Mapping[str, float], per_class: Mapping[str, Mapping[str, float]]) -> LinkPlan:
    """A plan from a mission's ``[swarm.links]`` keys (every class) and its ``[swarm.links.CLASS]`` tables (that
    class, over the common keys). ValueError with one line naming the class when a class's result is no link; the
    keys and values are the caller's to have checked one by one (``value_problem``), to name their line."""
    out: dict[str, LinkSettings] = {}
    for link_class in LINK_CLASSES:
        merged = {**common, **per_class.get(link_class, {})}
        problem = settings_problem(merged)
        if problem is not None:
            raise ValueError(f"{link_class}: {problem}")
        out[link_class] = replace(PERFECT, **merged)
    return LinkPlan(**out)


# The swarm's --link-* options and the key each sets (every class at once).
LINK_OPTIONS: Final = {
    "--link-loss": "loss",
    "--link-latency-ms": "latency_ms",
    "--link-jitter-ms": "jitter_ms",
    "--link-burst-good-s": "burst_good_s",
    "--link-burst-bad-s": "burst_bad_s",
    "--link-burst-loss": "burst_loss",
    "--link-bandwidth-bps": "bandwidth_bps",
}


def parse_link_value(key: str, text: str) -> float:
    """One ``--link-*`` option's value; ValueError with the one line that says why it is no value for ``key``."""
    return parse_value(key, text, value_problem)


# ---- how neighbours' positions travel: the ground station's relay, the drone-to-drone mesh, or both -------------

NEIGHBOUR_MODES: Final = ("relay", "mesh", "both")


@dataclass(frozen=True, slots=True, kw_only=True)
class MeshPlan:
    """The drones' mesh radio (docs/links.md "Mesh"): heard up to ``range_m``, a report lost with probability
    ``(distance / range_m) ** exponent`` within it, and the neighbour link class's impairment on top."""

    range_m: float = DEFAULT_MESH_RANGE_M
    exponent: float = DEFAULT_MESH_EXPONENT

    def __post_init__(self) -> None:
        for key in MESH_KEYS:
            problem = mesh_value_problem(key, getattr(self, key))
            if problem is not None:
                raise ValueError(problem)


@dataclass(frozen=True, slots=True, kw_only=True)
class NeighbourPlan:
    """How the drones learn each other's positions: the supervisor's relay, the mesh (``mesh`` set), both, or
    neither (the cameras alone)."""

    relay: bool = True
    mesh: MeshPlan | None = None
    relay_scope: RelayScope = DEFAULT_RELAY_SCOPE  # which drones a position is relayed to (gcs/fleet/relay.py)

    @property
    def relayed(self) -> RelayScope | None:
        """The relay's scope, or None without a relay (what ``Swarm`` takes)."""
        return self.relay_scope if self.relay else None

    @property
    def mode(self) -> str:
        """``relay``, ``mesh``, ``both`` or ``none``."""
        if self.relay:
            return "both" if self.mesh is not None else "relay"
        return "mesh" if self.mesh is not None else "none"

    def describe(self) -> str:
        """One line for the flight report: ``relay``, ``mesh (range 15 m, path loss (d/range)^4)``, ..."""
        mesh = (
            f"mesh (range {self.mesh.range_m:g} m, path loss (d/range)^{self.mesh.exponent:g})"
            if self.mesh is not None
            else ""
        )
        relay = f"relay ({self.relay_scope.describe()})"
        return {"relay": relay, "mesh": mesh, "both": f"{relay} and {mesh}", "none": "none (cameras only)"}[self.mode]

    def with_mode(self, mode: str) -> NeighbourPlan:
        """This plan with the mode ``mode`` (one of NEIGHBOUR_MODES); a mesh keeps its settings, or takes the
        defaults. ValueError (one line) for another mode."""
        if mode not in NEIGHBOUR_MODES:
            raise ValueError(f"must be one of {', '.join(NEIGHBOUR_MODES)}, got {mode!r}")
        mesh = (self.mesh or MeshPlan()) if mode in ("mesh", "both") else None
        return NeighbourPlan(relay=mode in ("relay", "both"), mesh=mesh, relay_scope=self.relay_scope)


def parse_mesh_value(key: str, text: str) -> float:
    """One mesh option's value (``--mesh-range-m``); ValueError with the one line that says why it is no value."""
    return parse_value(key, text, mesh_value_problem)
