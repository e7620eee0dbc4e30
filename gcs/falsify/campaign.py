"""``swarm falsify``: a search of a mission's space for flights that break its invariants, each distinct failure
shrunk to a minimal mission file (docs/falsify.md).

hypothesis generates and shrinks; every example it asks for is one lockstep flight of a plain mission file (the
scenario written into the mission: gcs/falsify/space.py), flown as a sweep flies its runs (gcs/sweep/runs.py: a
``swarm fly`` of its own, on instances nobody else holds). A flight that breaks an invariant raises an exception whose
type is its failure's identity (the invariant and the drones involved, by their numbers in the mission), so that
hypothesis tells distinct failures apart and shrinks each. The campaign seed fixes what hypothesis draws, and its
example database (in the campaign's folder) replays the failures found before first: a campaign run again resumes.

Budgets: ``budget`` flights to search (hypothesis's ``max_examples``: what it generates), and ``shrink_budget``
flights more for shrinking (and hypothesis's final replay of each failure): at most ``budget + shrink_budget``
flights in all. When they are spent, each failure keeps the smallest failing flight hypothesis had reached: the last
one of its identity, since hypothesis only tries a candidate smaller than the best so far.
"""

from __future__ import annotations

import hashlib
import json
import time
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from gcs.falsify.space import FalsifySpace, Scenario, mission_text, parse_space, scenario_mission, strategy
from gcs.sweep.plan import Run, SweepPlan
from gcs.sweep.runs import InstanceLocks, fly

SUMMARY_FILE: Final = "summary.json"
DEFAULT_SHRINK_BUDGET: Final = 40


@dataclass(frozen=True, slots=True, kw_only=True)
class Outcome:
    """One flight of the search."""

    index: int
    scenario: Scenario
    mission: Path  # the plain mission file flown
    report: Path
    # False: the flight failed before it broke any invariant (its error says why): no outcome about the invariants
    flown: bool
    failures: tuple[tuple[str, tuple[int, ...]], ...] = ()  # each broken invariant and its drones (1-based)
    details: tuple[str, ...] = ()  # what was seen, one line each
    error: str | None = None


@dataclass(slots=True)
class Failure:
    """One distinct failure: its first flight, and the smallest flight of it reached."""

    key: tuple[str, tuple[int, ...]]
    first: Outcome
    smallest: Outcome

    def name(self) -> str:
        invariant, drones = self.key
        return f"{invariant}-drones-{'-'.join(map(str, drones))}" if drones else invariant


@dataclass(slots=True)
class CampaignResult:
    flights: int = 0  # flights flown: the search's (at most ``budget``) and the shrinking's
    errors: int = 0  # flights that failed before breaking anything
    failures: dict[tuple[str, tuple[int, ...]], Failure] = field(default_factory=dict)
    stopped: str | None = None  # why it ended early (a time limit), if it did


class _ShrinkBudgetSpent(BaseException):
    """Ends hypothesis's shrinking (a BaseException: hypothesis does not take it for a failure of the flight)."""


class Broken(AssertionError):
    """A flight broke an invariant; each failure's identity is a subclass of its own (``_failure_type``)."""


_TYPES: dict[tuple[str, tuple[int, ...]], type[Broken]] = {}


def _failure_type(key: tuple[str, tuple[int, ...]]) -> type[Broken]:
    if key not in _TYPES:
        _TYPES[key] = type(f"Broken_{key[0]}_{'_'.join(map(str, key[1]))}", (Broken,), {})
    return _TYPES[key]


class Campaign:
    def __init__(self, mission: Path, out: Path, *, budget: int, shrink_budget: int = DEFAULT_SHRINK_BUDGET,
                 seed: int = 0, time_s: float | None = None, say: Callable[[str], None] = print) -> None:  # fmt: skip
        """Search ``mission``'s ``[falsify]`` space into folder ``out`` (FalsifyError, one line, for a bad space)."""
        self.mission_path = mission
        self.raw: dict[str, Any] = tomllib.loads(mission.read_text())
        self.n_drones = int(self.raw["swarm"]["drones"])
        self.space: FalsifySpace = parse_space(self.raw.get("falsify", {}), drones=self.n_drones)
        self.out = out
        self.budget = budget
        self.shrink_budget = shrink_budget
        self.seed = seed
        self.deadline = None if time_s is None else time.monotonic() + time_s
        self.say = say
        self.result = CampaignResult()
        self._locks = InstanceLocks(self.n_drones)
        self._index = 0

    # ---- one flight ----------------------------------------------------------------------------------------------
    def fly(self, scenario: Scenario) -> Outcome:
        """Fly one scenario as a plain mission file in a folder of its own."""
        index = self._index
        self._index += 1
        run_dir = self.out / "runs" / f"{index:04d}"
        run_dir.mkdir(parents=True, exist_ok=True)
        path = run_dir / "mission.toml"
        path.write_text(mission_text(scenario_mission(self.raw, scenario), header=[
            f"{self.mission_path.name}, {scenario.describe()}",
            f"swarm fly {path.name} --lockstep",
        ]))  # fmt: skip
        seed = scenario.seed if scenario.seed is not None else int(self.raw["swarm"].get("seed", 0))
        plan = SweepPlan(mission=path, mission_sha256=hashlib.sha256(path.read_bytes()).hexdigest(),
                         n_drones=self.n_drones, seeds=(seed,), axes=())  # fmt: skip
        with self._locks.block() as block:
            result = fly(plan, Run(index=index, setting=(), seed=seed), run_dir, block.first, lock_fds=block.fds)
        report = run_dir / "report"
        try:  # a flight that broke an invariant and then failed a step (drones in contact never reach their goal)
            metrics = json.loads((report / "metrics.json").read_text())  # still wrote what broke first
        except (OSError, ValueError):
            metrics = None
        if metrics is None or not (result.ok or metrics.get("violations")):
            return Outcome(index=index, scenario=scenario, mission=path, report=report, flown=False, error=result.error)
        first_sysid = block.first + 1
        failures, details = [], []
        for v in metrics.get("violations", []):
            drones = tuple(sorted(s - first_sysid + 1 for s in v["sysids"] if first_sysid <= s < first_sysid
                                  + self.n_drones))  # fmt: skip
            failures.append((str(v["name"]), drones))
            details.append(f"{v['name']} at t={v['time_s']} s: {v['detail']}")
        return Outcome(index=index, scenario=scenario, mission=path, report=report, flown=True,
                       failures=tuple(failures), details=tuple(details))  # fmt: skip

    # ---- the search ----------------------------------------------------------------------------------------------
    def run(self) -> CampaignResult:
        """The search and the shrinking, in one run of hypothesis (module docstring); the summary written."""
        from hypothesis import Phase

        self._hypothesis((Phase.reuse, Phase.generate, Phase.shrink))
        self._write_summary()
        return self.result

    def _check(self, scenario: Scenario) -> None:
        """One example of hypothesis's: a flight; a failure raises its identity's exception."""
        result = self.result
        if result.flights >= self.budget + self.shrink_budget:
            raise _ShrinkBudgetSpent()
        if self.deadline is not None and time.monotonic() > self.deadline:
            result.stopped = "its time was up"
            raise _ShrinkBudgetSpent()
        outcome = self.fly(scenario)
        result.flights += 1
        if not outcome.flown:
            result.errors += 1
            self.say(f"falsify: flight {outcome.index} did not fly: {outcome.error}")
            return
        if not outcome.failures:
            return
        key = outcome.failures[0]  # the first broken invariant names the failure
        known = result.failures.get(key)
        if known is None:
            result.failures[key] = Failure(key=key, first=outcome, smallest=outcome)
            self.say(f"falsify: flight {outcome.index} broke {outcome.details[0]} ({scenario.describe()})")
        elif len(outcome.scenario.perturbations) <= len(known.smallest.scenario.perturbations):
            # shrinking only tries what hypothesis takes for smaller than its best so far (the search, which may go on
            # after a first failure, can draw a larger one of the same identity: not kept)
            known.smallest = outcome
        raise _failure_type(key)(outcome.details[0])

    def _hypothesis(self, phases: tuple[Any, ...]) -> None:
        """Run hypothesis over the space with these phases, its database the campaign's (what it saves as it finds
        failures is what the shrinking replays, and what a campaign run again resumes from)."""
        from hypothesis import HealthCheck, given, settings
        from hypothesis import seed as seeded
        from hypothesis.database import DirectoryBasedExampleDatabase

        test = seeded(self.seed)(settings(
            max_examples=self.budget, deadline=None, database=DirectoryBasedExampleDatabase(self.out / "hypothesis"),
            phases=phases, suppress_health_check=list(HealthCheck), report_multiple_bugs=True, print_blob=False,
        )(given(strategy(self.space))(self._check)))  # fmt: skip
        try:
            test()
        except _ShrinkBudgetSpent:
            pass
        except Broken:  # hypothesis re-raises the failure it found (they are the result)
            pass
        except ExceptionGroup as group:  # ...or every distinct one; anything else is a fault of the search itself
            rest = group.split(Broken)[1]
            if rest is not None:
                raise rest from None

    # ---- what it found -------------------------------------------------------------------------------------------
    def minimal_file(self, failure: Failure) -> Path:
        return self.out / "failures" / f"{failure.name()}.toml"

    def _write_summary(self) -> None:
        """Each failure's smallest mission file under failures/, and summary.json and summary.txt."""
        result = self.result
        (self.out / "failures").mkdir(parents=True, exist_ok=True)
        rows = []
        for failure in result.failures.values():
            smallest = failure.smallest
            self.minimal_file(failure).write_text(smallest.mission.read_text())
            rows.append({"invariant": failure.key[0], "drones": list(failure.key[1]),
                         "first_flight": failure.first.index, "smallest_flight": smallest.index,
                         "perturbations": len(smallest.scenario.perturbations),
                         "scenario": smallest.scenario.describe(), "detail": smallest.details[0],
                         "mission": str(self.minimal_file(failure)), "report": str(smallest.report)})  # fmt: skip
        summary = {"mission": str(self.mission_path), "seed": self.seed, "budget": self.budget,
                   "shrink_budget": self.shrink_budget, "flights": result.flights, "errors": result.errors,
                   "stopped": result.stopped, "failures": rows}  # fmt: skip
        (self.out / SUMMARY_FILE).write_text(json.dumps(summary, indent=1) + "\n")
        lines = [f"falsify {self.mission_path.name} (campaign seed {self.seed}): {result.flights} flights (search "
                 f"budget {self.budget}, shrink budget {self.shrink_budget}), {result.errors} that failed before "
                 "breaking anything" + (f"; stopped: {result.stopped}" if result.stopped else "")]  # fmt: skip
        lines.append(f"{len(rows)} distinct failure(s)" if rows else "no invariant broken")
        for row in rows:
            lines.append(f"  {row['invariant']} (drones {row['drones']}): {row['detail']}")
            lines.append(f"    smallest: {row['scenario']} ({row['perturbations']} perturbation(s))")
            lines.append(f"    replay: swarm fly {row['mission']} --lockstep   report: {row['report']}")
        (self.out / "summary.txt").write_text("\n".join(lines) + "\n")

    def emit_tests(self, folder: Path) -> list[Path]:
        """Each failure's smallest mission file beside a pytest regression test that flies it and fails while the
        invariant still breaks."""
        folder.mkdir(parents=True, exist_ok=True)
        written = []
        for failure in self.result.failures.values():
            name = failure.name().replace("-", "_")
            mission = folder / f"{name}.toml"
            mission.write_text(failure.smallest.mission.read_text())
            test = folder / f"test_{name}.py"
            test.write_text(REGRESSION_TEST.format(name=name, mission=mission.name, invariant=failure.key[0],
                                                   scenario=failure.smallest.scenario.describe()))  # fmt: skip
            written.append(test)
        return written


REGRESSION_TEST: Final = '''"""Found by swarm falsify: {invariant} broke with {scenario}.
Fails while it still breaks."""

import json
import subprocess
import sys
from pathlib import Path

import pytest


@pytest.mark.timeout(600)
def test_{name}(tmp_path: Path) -> None:
    mission = Path(__file__).with_name("{mission}")
    run = subprocess.run([sys.executable, "-m", "gcs.cli", "fly", str(mission), "--lockstep", "--no-view",
                          "--no-forward", "--report", str(tmp_path / "report")], capture_output=True, text=True)
    metrics = json.loads((tmp_path / "report" / "metrics.json").read_text())
    broken = [v for v in metrics["violations"] if v["name"] == "{invariant}"]
    assert not broken, f"{{broken[0]['detail']}} (report: {{tmp_path / 'report'}})"
    assert run.returncode == 0, run.stderr[-2000:]
'''
