"""What the ground station needs from a simulation, declared on the ground station's side.

A ground station flying real drones knows them only over MAVLink. Flying simulated ones it needs a little more:
someone who starts them where the plan says, tells it which have ended and why, crashes one on request (fault
injection) and, in lockstep, lets their common simulated time run on. ``SimulationHarness`` is that face, and the
ground station sees nothing else of the simulation: no processes or PIDs to signal, no shared-memory rows, no
drone code. The simulation side implements it (sitl/harness/, ``SitlHarness``); the composition root
(gcs/composition.py) is the only ground-station module that knows both and hands a harness to ``Swarm``. The
import-linter contract in pyproject.toml keeps it so (docs/architecture.md).

Everything crossing the face is a plain value: sysids, simulated seconds, one-line texts, geodetic tuples
``(lat_deg, lon_deg, alt_m)``, numpy arrays of figures. The plan that says what to start (``SpawnPlan``) is the
ground station's: where the swarm stands (origin, layout, spacing), how it runs (paced or lockstep), which
instances; the composition root turns it into the simulation's own launch plan.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Protocol

import numpy as np
import numpy.typing as npt

from gcs.fleet.links import LinkPlan, MeshPlan
from gcs.flight.geodesy import DEFAULT_ORIGIN, GeoPoint
from gcs.mavlink.transport import GCS_SYSID

FloatArray = npt.NDArray[np.float64]

# A swarm's drones are sysids 1..254 (instances 0..253): 255 is the ground station's own
# (gcs.mavlink.transport.GCS_SYSID), as QGroundControl's. The simulation gives each of them ports of its own
# (docs/mavlink.md); tests/unit/test_ports.py holds this and the simulation's limit to the same number.
MAX_DRONES = 254
LAST_INSTANCE = MAX_DRONES - 1


def grid_layout(n: int, spacing_m: float) -> list[tuple[float, float]]:
    """North/east spawn offsets on a square-ish grid centred on the origin, row by row."""
    cols = max(1, math.ceil(math.sqrt(n)))
    rows = math.ceil(n / cols)
    out = []
    for i in range(n):
        r, c = divmod(i, cols)
        out.append(((r - (rows - 1) / 2) * spacing_m, (c - (cols - 1) / 2) * spacing_m))
    return out


def line_layout(n: int, spacing_m: float) -> list[tuple[float, float]]:
    return [(0.0, (i - (n - 1) / 2) * spacing_m) for i in range(n)]


LAYOUTS: dict[str, Callable[[int, float], list[tuple[float, float]]]] = {"grid": grid_layout, "line": line_layout}


MAX_QUANTUM = 400  # lockstep: physics steps every drone may run between waits (2 s of simulated time)
MAX_WIND_MPS = 20.0  # steady wind or gust intensity a plan may ask for (beyond what a small quadrotor flies in)
MAX_SPAWN_JITTER_M = 10.0  # how far a spawn point may be moved from its layout's


@dataclass(frozen=True, slots=True, kw_only=True)
class SpawnPlan:
    """The swarm to start: how many drones, where they stand, how they run."""

    n_drones: int
    spacing_m: float = 2.0
    layout: str = "grid"
    origin: GeoPoint = DEFAULT_ORIGIN
    speed_factor: float = 1.0  # with lockstep: 0 = as fast as the CPU allows, else a pace for the common clock
    lockstep: bool = False
    lockstep_quantum: int = 1  # physics steps every drone runs between waits (the skew bound)
    first_instance: int = 0  # drone i (0-based, spawn order) is instance first_instance + i, sysid instance + 1
    airframe: str | None = None
    seed: int = 0
    log_dir: Path | None = None  # each drone's output goes to a log file here (a temporary directory if None)
    camera_drones: frozenset[int] = frozenset()  # drones (1..n, in spawn order) whose camera frames are saved...
    camera_dir: Path | None = None  # ...as PNG under camera_dir/drone-<instance>/
    # How many drones one simulation process runs: 1 (each drone its own process, as PX4 SITL), K, or "auto" (one
    # process per usable CPU). A hosted drone is the same vehicle on the wire; hosting saves the CPU every process
    # pays for its wake-ups (docs/architecture.md, "Drone hosts").
    drones_per_process: int | Literal["auto"] = 1
    # MAVLink 2 signing: the key file every drone and the ground station sign with (one key for the swarm); the
    # drones then require signed messages (MAV_SIGN_CFG = 2). None: no signing.
    signing_key_file: Path | None = None
    # The link model's settings per link class, the same for every drone (each draws its own: docs/links.md).
    links: LinkPlan = field(default_factory=LinkPlan)
    # The drone-to-drone mesh radio of every drone (docs/links.md "Mesh"); None: no mesh.
    mesh: MeshPlan | None = None
    # An onboard behaviour every drone runs from BHV_EN = 1 on (path/to/file.py:ClassName, absolute; docs/onboard.md)
    behaviour: str | None = None
    # The ground station's own system id: 255 (QGroundControl's) unless one beside it uses that (--gcs-sysid)
    gcs_sysid: int = GCS_SYSID
    # The weather every drone flies in: a steady wind (NED m/s, the way it blows) and gusts (RMS m/s, each drone's own
    # seeded draw)
    wind_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gust_mps: float = 0.0
    # Each drone's spawn point moved by up to this far north and east from its layout's, seeded by ``seed`` (design
    # principle 9: no two seeds line the drones up the same)
    spawn_jitter_m: float = 0.0

    def offsets_ne_m(self) -> list[tuple[float, float]]:
        """Each drone's spawn position, north/east metres from the origin in the swarm frame (spawn order)."""
        layout = LAYOUTS[self.layout](self.n_drones, self.spacing_m)
        if self.spawn_jitter_m <= 0.0:
            return layout
        shifts = np.random.default_rng(self.seed).uniform(-self.spawn_jitter_m, self.spawn_jitter_m, (len(layout), 2))
        return [(n + float(dn), e + float(de)) for (n, e), (dn, de) in zip(layout, shifts, strict=True)]


def parse_drones_per_process(text: str) -> int | Literal["auto"]:
    """``K`` (at least 1) or ``auto``, as ``--drones-per-process`` takes it; ValueError with one line otherwise."""
    if text == "auto":
        return "auto"
    try:
        value = int(text)
    except ValueError:
        raise ValueError(f"must be a number of drones or auto, got {text!r}") from None
    if value < 1:
        raise ValueError(f"must be at least 1 (or auto), got {text!r}")
    return value


class SpawnError(RuntimeError):
    """A drone did not come up; the message names it and says why, in one line."""


class SimulationHarness(Protocol):
    """The simulated swarm as the ground station may use it. Drones are named by sysid."""

    def launch(self, gcs_port: int) -> list[int]:
        """Start every drone of the plan, its ground-station link sending to UDP ``gcs_port`` on 127.0.0.1; returns
        their sysids in spawn order. Raises RuntimeError with a one-line message when a drone cannot be started."""
        ...

    def close(self) -> None:
        """Stop every drone (terminate, then kill after a grace period) and release everything; no orphans."""
        ...

    def ended(self) -> dict[int, str]:
        """Every drone that has ended (its flight software stopped: a process exit, a kill), by sysid, with one line
        saying how. Asking also lets the simulation act on an end it sees for the first time."""
        ...

    def end_report(self, sysid: int) -> str:
        """One line about an ended drone for the user who started it (names it, its exit, its last words)."""
        ...

    def kill(self, sysid: int) -> str | None:
        """Crash the drone's flight software: now, or in lockstep at the next gate, every drone standing there, so
        that a flight with a kill replays exactly; what was done in one line, or None if it had already ended."""
        ...

    def drone_time_s(self) -> float | None:
        """The slowest running drone's own simulated clock; None before every running drone has one."""
        ...

    def grounded_body_geo(self, sysid: int, time_s: float) -> tuple[float, float, float] | None:
        """Where a drone's body lies (lat_deg, lon_deg, alt_m) at ``time_s`` once it is on the ground, else None."""
        ...

    def add_obstacle(self, *, cylinder: bool, centre_geo: tuple[float, float, float], radius_m: float,
                     height_m: float) -> None:  # fmt: skip
        """Declare a static obstacle (a vertical cylinder standing on the ground, or a sphere) in the world."""
        ...

    def place_external_body(self, sysid: int, geo: tuple[float, float, float],
                            vel_ned_mps: tuple[float, float, float], radius_m: float | None) -> None:  # fmt: skip
        """Put the body of a vehicle the simulation does not run (an attached real drone, gcs/fleet/attach.py) where
        the ground station last knew it to be, moving at ``vel_ned_mps``: the drones' cameras see it, and a drone
        that touches it crashes. ``radius_m`` None: the size of the swarm's own drones. Called again to move it."""
        ...

    def remove_external_body(self, sysid: int) -> None:
        """Take an external vehicle's body out of the world (it was detached)."""
        ...

    def wake_fileno(self) -> int | None:
        """In lockstep, a descriptor that turns readable when the drones need the clock moved on; else None."""
        ...

    def lockstep_time_s(self) -> float:
        """In lockstep, the drones' common simulated time (0 before they start; frozen once closed)."""
        ...

    def advance_lockstep(self, lead_s: float) -> float | None:
        """In lockstep, let the drones run to ``lead_s`` past their common time; returns the common time it started
        from, or None while not every drone has joined (nobody starts before the rest). Called when every drone
        stands at the gate: the kills asked for since the last one land first (``kill``)."""
        ...

    def process_ids(self) -> dict[int, int]:
        """For measurement (CPU time and memory read from /proc, as ``top`` would): the PID running each drone."""
        ...

    def clock_columns(self) -> tuple[FloatArray, FloatArray]:
        """For measurement: each drone's published simulated time and lockstep step count (spawn order), one read."""
        ...

    def note_sent_to_drones(self, datagrams: Mapping[int, int]) -> None:
        """Lockstep delivery: the datagrams the ground station has sent so far to each drone (by sysid), said before
        it lets them run on; a drone reads them all before its next step (gcs/fleet/clock.py ``SwarmClock.frame``)."""
        ...

    def sent_by_drones(self) -> dict[int, int]:
        """Lockstep delivery: the datagrams each drone (by sysid) has sent the ground station so far, as of the
        common time; the ground station reads them all before it acts at that time."""
        ...

    def link_counters(self) -> dict[str, dict[str, float]]:
        """What the link model did to the swarm's traffic, summed over the drones, by channel (``"gcs up"``: the
        ground-station links towards the drones; ``down``: from them) with ``frames_offered``, ``frames_lost``,
        ``delayed`` and ``total_delay_s``; still answers after ``close``. Empty when every link is perfect and there
        is no mesh. With the drone-to-drone mesh, ``"neighbour mesh"``: the reports the drones heard of each other,
        with ``frames_delivered`` and the losses by cause (``lost_range``, ``lost_path``, ``lost_model``,
        ``lost_overrun``), and the neighbour tables' updates by source (``relay_updates``: on the ground-station link,
        ``link_updates``: on another MAVLink link, ``mesh_updates``)."""
        ...

    def cpu_parts_s(self) -> FloatArray:
        """For measurement: each drone's CPU seconds in physics, control, perception and MAVLink (n x 4)."""
        ...


class Simulation(Protocol):
    """The simulation before any swarm exists: its limits, airframe sizes, and a harness for each plan."""

    @property
    def max_instances(self) -> int:
        """Instances run 0..max_instances - 1."""
        ...

    @property
    def max_obstacles(self) -> int:
        """How many static obstacles a world holds."""
        ...

    @property
    def physics_rate_hz(self) -> float: ...

    def harness(self, plan: SpawnPlan) -> SimulationHarness:
        """A harness for the swarm of ``plan`` (nothing started until its ``launch``)."""
        ...

    def contact_distance_m(self, airframe: str | None) -> float:
        """Centre distance at which two drones of the airframe (None: the default) touch; ValueError (one line)
        when the airframe does not exist."""
        ...

    def bare_plant_cpu_ms_per_sim_s(self) -> float:
        """CPU ms per simulated second of the physics alone (the bench's machine-independent yardstick)."""
        ...

    def check_behaviour(self, spec: str) -> None:
        """Load an onboard behaviour as the drones will; ValueError with one line if it cannot be."""
        ...

    def drones_per_host(self, n_drones: int, drones_per_process: int | Literal["auto"]) -> list[int]:
        """How many drones each process would run for a swarm of ``n_drones`` with this setting, in spawn order."""
        ...

    def parameter_value(self, name: str, value: float) -> int | float:
        """``value`` as every drone takes parameter ``name``: an int for an integer parameter (sent as INT32), a
        float otherwise; ValueError with one line when it is no parameter of theirs, out of range or not of its
        type. Onboard behaviours' parameters are not in this table."""
        ...
