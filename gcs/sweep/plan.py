"""What a sweep flies (pure): the cross product of seeds and settings, each run named, and the command that flies it.

A *setting* is one value for every swept option (drone parameters given with ``--param NAME=v1,v2``, the link loss
given with ``--link-loss p1,p2``); a *run* is one setting flown with one seed. Runs are numbered in a fixed order
(settings in the order of the product, seeds ascending within each), named by their setting and seed
(``AVOID_MIN_DIST=1.5+link_loss=0.2/seed-0017``), and each is a full ``swarm fly --lockstep`` of the mission:
lockstep makes a run a function of its mission, seed and setting alone, wherever and whenever it is flown.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from gcs.fleet.clock import FLIGHT_VERSION

MAX_RUNS: Final = 100_000
MAX_SEED: Final = 2**31 - 1
PARAM_NAME = re.compile(r"[A-Z][A-Z0-9_]{0,15}")  # PX4 parameter names: 16 characters at most
LINK_LOSS: Final = "link_loss"  # the name of the link-loss axis in settings, tables and files


class SweepError(ValueError):
    """A sweep that cannot be flown as given (one line for the user)."""


@dataclass(frozen=True, slots=True)
class Axis:
    """One swept option and its values, in the order given."""

    name: str  # a drone parameter's name, or LINK_LOSS
    values: tuple[float, ...]


@dataclass(frozen=True, slots=True)
class Run:
    index: int
    setting: tuple[tuple[str, float], ...]  # (axis name, value) for every axis, in axis order
    seed: int

    @property
    def setting_key(self) -> str:
        return setting_key(self.setting)

    @property
    def name(self) -> str:
        return f"{self.setting_key}/seed-{self.seed:04d}"


def setting_key(setting: Sequence[tuple[str, float]]) -> str:
    """A setting as a folder name: ``AVOID_MIN_DIST=1.5+link_loss=0.2`` (``default`` when nothing is swept)."""
    return "+".join(f"{name}={_number(value)}" for name, value in setting) or "default"


def _number(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else repr(float(value))


def parse_seeds(text: str) -> tuple[int, ...]:
    """``1-200``, ``1,5,9`` or ``1-10,20-30``: the seeds in ascending order, each once."""
    seeds: set[int] = set()
    for part in text.split(","):
        first, dash, last = part.strip().partition("-")
        try:
            lo, hi = int(first), int(last) if dash else int(first)
        except ValueError:
            raise SweepError(f"--seeds: {part.strip()!r} is not a seed or a range like 1-200") from None
        if not 0 <= lo <= hi <= MAX_SEED:
            raise SweepError(f"--seeds: {part.strip()!r} must be a range from low to high within 0..{MAX_SEED}")
        if hi - lo >= MAX_RUNS:
            raise SweepError(f"--seeds: {part.strip()!r} is more than {MAX_RUNS} seeds")
        seeds.update(range(lo, hi + 1))
    return tuple(sorted(seeds))


def parse_values(text: str, what: str) -> tuple[float, ...]:
    """``1.2,1.5,1.8`` or ``1.2:1.8:0.3`` (start:stop:step, both ends included): the values, each once, in order."""
    if ":" in text:
        try:
            start, stop, step = (float(v) for v in text.split(":"))
        except ValueError:
            raise SweepError(f"{what}: {text!r} is not START:STOP:STEP") from None
        if not all(math.isfinite(v) for v in (start, stop, step)) or step <= 0 or stop < start:
            raise SweepError(f"{what}: {text!r} needs START <= STOP and a positive STEP")
        count = math.floor((stop - start) / step + 1e-9) + 1
        if count > MAX_RUNS:
            raise SweepError(f"{what}: {text!r} is more than {MAX_RUNS} values")
        values = [round(start + k * step, 12) for k in range(count)]
    else:
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            raise SweepError(f"{what}: {text!r} is not a comma-separated list of numbers") from None
        if not values or not all(math.isfinite(v) for v in values):
            raise SweepError(f"{what}: {text!r} must list finite numbers")
    unique = tuple(dict.fromkeys(values))
    if len(unique) != len(values):
        raise SweepError(f"{what}: {text!r} lists a value twice")
    return unique


def parse_param(text: str) -> Axis:
    """``NAME=v1,v2`` (or ``NAME=start:stop:step``) into an axis."""
    name, equals, values = text.partition("=")
    name = name.strip()
    if not equals or not PARAM_NAME.fullmatch(name):
        raise SweepError(f"--param: {text!r} must be NAME=v1,v2,... with a parameter name such as AVOID_MIN_DIST")
    return Axis(name, parse_values(values, f"--param {name}"))


def link_loss_axis(text: str) -> Axis:
    values = parse_values(text, "--link-loss")
    if any(not 0.0 <= v < 1.0 for v in values):
        raise SweepError(f"--link-loss: {text!r}: every probability must be in [0, 1)")
    return Axis(LINK_LOSS, values)


@dataclass(frozen=True, slots=True)
class SweepPlan:
    """Everything that decides a sweep's runs and their results; saved as sweep.json in its output folder."""

    mission: Path
    mission_sha256: str
    n_drones: int
    seeds: tuple[int, ...]
    axes: tuple[Axis, ...]
    fly_args: tuple[str, ...] = ()  # further ``swarm fly`` options given to every run (the same for all)

    def __post_init__(self) -> None:
        names = [a.name for a in self.axes]
        if len(set(names)) != len(names):
            raise SweepError(f"{sorted({n for n in names if names.count(n) > 1})[0]} is swept twice")
        if not self.seeds:
            raise SweepError("--seeds: no seed")
        if self.n_runs > MAX_RUNS:
            raise SweepError(f"{self.n_runs} runs: a sweep is at most {MAX_RUNS}")

    @property
    def n_settings(self) -> int:
        return math.prod(len(a.values) for a in self.axes)

    @property
    def n_runs(self) -> int:
        return self.n_settings * len(self.seeds)

    def settings(self) -> list[tuple[tuple[str, float], ...]]:
        return [tuple(zip((a.name for a in self.axes), combo, strict=True))
                for combo in itertools.product(*(a.values for a in self.axes))]  # fmt: skip

    def runs(self) -> list[Run]:
        out: list[Run] = []
        for setting in self.settings():
            for seed in self.seeds:
                out.append(Run(index=len(out), setting=setting, seed=seed))
        return out

    def to_json(self) -> dict[str, Any]:
        return {
            "mission": str(self.mission),
            "mission_sha256": self.mission_sha256,
            "n_drones": self.n_drones,
            "seeds": list(self.seeds),
            "axes": [{"name": a.name, "values": list(a.values)} for a in self.axes],
            "fly_args": list(self.fly_args),
            "flight_version": FLIGHT_VERSION,  # what the runs' flights are a function of (``other_flights``)
        }

    def same_runs_as(self, saved: dict[str, Any]) -> bool:
        """Whether a saved sweep.json describes the same runs (the mission's content, not its path, counts)."""
        mine = self.to_json()
        return all(mine[k] == saved.get(k) for k in ("mission_sha256", "n_drones", "seeds", "axes", "fly_args"))


def file_sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def fly_command(plan: SweepPlan, run: Run, *, first_instance: int, report: Path) -> list[str]:
    """The ``swarm fly`` arguments (after ``swarm``) that fly ``run``: a user can paste them to fly it again."""
    # the plots only where something broke: they cost a short flight as much as its flying (gcs/view/report.py)
    args = ["fly", str(plan.mission), "--lockstep", "--seed", str(run.seed), "--report", str(report), "--plots",
            "failed", "--first-instance", str(first_instance), "--no-forward", "--no-view", *plan.fly_args]  # fmt: skip
    for name, value in run.setting:
        args += ["--link-loss", _number(value)] if name == LINK_LOSS else ["--param", f"{name}={_number(value)}"]
    return args


def describe(plan: SweepPlan) -> str:
    axes = ", ".join(f"{a.name} in {{{', '.join(_number(v) for v in a.values)}}}" for a in plan.axes) or "no setting"
    return (f"{plan.n_runs} runs: {plan.n_settings} setting(s) ({axes}) x {len(plan.seeds)} seed(s) "
            f"of {plan.mission.name} ({plan.n_drones} drones)")  # fmt: skip


def other_flights(saved: dict[str, Any], folder: Path) -> str | None:
    """Why a campaign's folder (a sweep's, a falsification's) must not be resumed by this code, in one line: its
    record (``saved``: its sweep.json or campaign.json) says its flights were flown by code that flies differently
    (gcs/fleet/clock.py ``FLIGHT_VERSION``; none recorded: before version 2). Its runs would be mixed with runs that
    the same seeds no longer fly, and the statistics, a failure's minimal file or a "flown already" would be about
    flights nobody can fly again. None when it may be resumed."""
    held = saved.get("flight_version")
    if held == FLIGHT_VERSION:
        return None
    version = f"flight version {held}" if held is not None else "a flight version before 2"
    return (f"{folder} holds flights flown by code that flies differently ({version}; this code flies version "
            f"{FLIGHT_VERSION}): give another --out, or remove it")  # fmt: skip


def saved_plan(path: Path) -> dict[str, Any] | None:
    try:
        data: dict[str, Any] = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data
