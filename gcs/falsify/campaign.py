"""``swarm falsify``: a search of a mission's space for flights that break its invariants, each distinct failure
shrunk to a minimal mission file (docs/falsify.md).

hypothesis generates and shrinks; every example it asks for is one lockstep flight of a plain mission file (the
scenario written into the mission: gcs/falsify/space.py), flown by a sweep's flyer (gcs/sweep: side by side on this
machine, on instances nobody else holds, or on a Ray cluster). A campaign goes in three passes:

1. **Draw.** hypothesis, seeded with the campaign seed, generates the search's ``budget`` scenarios and flies none:
   its generation does not depend on outcomes until a first failure, so every pass below that uses the same seed
   and budget draws the same scenarios in the same order.
2. **Search.** The drawn scenarios are flown side by side, each in runs/NNNN/ (its mission file, scenario.json, the
   sweep's run.json and the report). Every flight is kept and never flown twice: a campaign run again flies only
   what it has not flown (it resumes), and the passes below take what was flown from there.
3. **Shrink.** Each distinct failure (its invariant and the drones involved) is shrunk by a hypothesis run of its
   own, with the same seed and budget: its generation replays the drawn scenarios, flown already, up to that
   failure's first flight, and stops there (``report_multiple_bugs=False``); its shrinking flies what it asks for,
   and only a flight that breaks that invariant with those drones counts as failing. Each failure has a shrink
   budget of its own, and failures are shrunk side by side, ``jobs`` at a time (hypothesis is thread-safe from
   6.136). hypothesis stops shrinking after 5 minutes of its own; a campaign's budgets and time limit bound it
   instead (``MAX_SHRINKING_SECONDS``, which hypothesis documents as the one to change).

A failure keeps the smallest failing flight hypothesis reached: the last one of its identity, since hypothesis only
tries a candidate smaller than its best so far, and replays the best once more at the end.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
import hashlib
import json
import threading
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from gcs.falsify.space import (
    FalsifyError,
    FalsifySpace,
    Scenario,
    mission_text,
    parse_space,
    scenario_mission,
    strategy,
)
from gcs.fleet.clock import FLIGHT_VERSION
from gcs.sweep.plan import Run, SweepPlan, other_flights
from gcs.sweep.runs import Flight, RunResult, completed
from gcs.sweep.sweep import Flyer

SUMMARY_FILE: Final = "summary.json"
SCENARIO_FILE: Final = "scenario.json"
MISSION_FILE: Final = "mission.toml"  # a flight's plain mission file, in its folder
CAMPAIGN_FILE: Final = "campaign.json"  # the mission a campaign folder's flights are of
DEFAULT_SHRINK_BUDGET: Final = 40
NO_SHRINK_TIME_LIMIT_S: Final = 10**9  # hypothesis's own 5-minute limit on shrinking, lifted while a campaign runs

Key = tuple[str, tuple[int, ...]]  # a failure's identity: the invariant's name and the drones involved (1-based)


@dataclass(frozen=True, slots=True, kw_only=True)
class Outcome:
    """One flight of the campaign."""

    index: int
    scenario: Scenario
    mission: Path  # the plain mission file flown
    report: Path
    # False: the flight failed before it broke any invariant (its error says why): no outcome about the invariants
    flown: bool
    failures: tuple[Key, ...] = ()  # each broken invariant and its drones
    details: tuple[str, ...] = ()  # what was seen, one line each
    times_s: tuple[float, ...] = ()  # when each broke, mission time
    steps_s: tuple[tuple[int, float, float], ...] = ()  # each mission step flown: its index, start and end
    error: str | None = None


@dataclass(slots=True)
class Failure:
    """One distinct failure: its first flight, and the smallest flight of it reached."""

    key: Key
    first: Outcome
    smallest: Outcome
    shrink_flights: int = 0  # flights its shrinking flew (its own budget)
    searched: bool = True  # False: met while another failure was shrunk (its search pass never draws it: not shrunk)

    def name(self) -> str:
        invariant, drones = self.key
        return f"{invariant}-drones-{'-'.join(map(str, drones))}" if drones else invariant

    def detail(self, outcome: Outcome) -> str:
        return outcome.details[outcome.failures.index(self.key)]


@dataclass(slots=True)
class CampaignResult:
    search_flights: int = 0  # flights of the drawn scenarios flown by this run of the campaign
    reused: int = 0  # drawn scenarios flown by an earlier run of the campaign (resumed)
    errors: int = 0  # flights that failed before breaking anything
    failures: dict[Key, Failure] = field(default_factory=dict)
    stopped: str | None = None  # why it ended early (a time limit), if it did

    @property
    def flights(self) -> int:
        """Flights flown by this run of the campaign: the search's and every failure's shrinking."""
        return self.search_flights + sum(f.shrink_flights for f in self.failures.values())


class _Spent(BaseException):
    """Ends a hypothesis run: a failure's shrink budget is spent, or the campaign was stopped (a BaseException:
    hypothesis does not take it for a failure of the flight)."""


class Broken(AssertionError):
    """A flight broke the invariant a shrinking pass is about."""


def _identity(scenario: Scenario) -> str:
    return json.dumps(scenario.to_json(), sort_keys=True)


class Campaign:
    def __init__(self, mission: Path, out: Path, *, budget: int, flyer: Flyer, jobs: int = 1,
                 shrink_budget: int = DEFAULT_SHRINK_BUDGET, seed: int = 0, time_s: float | None = None,
                 fly_args: tuple[str, ...] = (), say: Callable[[str], None] = print) -> None:  # fmt: skip
        """Search ``mission``'s ``[falsify]`` space into folder ``out`` (FalsifyError, one line, for a bad space),
        flying with ``flyer``; ``jobs``: failures shrunk side by side; ``fly_args``: swarm fly's options for every
        flight, none that changes what it flies (a minimal file replays with ``swarm fly FILE --lockstep``)."""
        self.mission_path = mission
        self.raw: dict[str, Any] = tomllib.loads(mission.read_text())
        self.n_drones = int(self.raw["swarm"]["drones"])
        self.space: FalsifySpace = parse_space(self.raw.get("falsify", {}), drones=self.n_drones)
        self.out = out
        self.budget = budget
        self.shrink_budget = shrink_budget
        self.seed = seed
        self.time_s = time_s
        self.flyer = flyer
        self.fly_args = fly_args
        self.jobs = max(1, jobs)
        self.say = say
        self.result = CampaignResult()
        self.stop = threading.Event()  # set: flights under way stop, and nothing more is flown
        self._lock = threading.Lock()  # the flights kept, the next index, the result
        self._flown: dict[str, Outcome] = {}
        self._flying: dict[str, threading.Event] = {}  # scenarios a shrinking pass is flying now
        self._said: set[Key] = set()  # failures said as their first flight came
        self._next_index = 0

    # ---- flights -------------------------------------------------------------------------------------------------
    def _load(self) -> None:
        """The flights an earlier run of this campaign completed (runs/NNNN/ with scenario.json and run.json);
        FalsifyError for a folder that holds a campaign over another mission (its flights would be another's), or
        one whose flights were flown by code that flies differently (``other_flights``: a failure found there might
        not fail now, and the search would skip what it takes for flown)."""
        sha256 = hashlib.sha256(self.mission_path.read_bytes()).hexdigest()
        path = self.out / CAMPAIGN_FILE
        try:
            record = json.loads(path.read_text())
            held = record.get("mission_sha256")
        except (OSError, ValueError, AttributeError):
            record, held = {}, None
        if path.exists() and held != sha256:
            raise FalsifyError(f"{self.out} holds a campaign over another mission ({path}): give another --out, or "
                               "remove it")  # fmt: skip
        if path.exists() and (why := other_flights(record, self.out)) is not None:
            raise FalsifyError(why)
        self.out.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({"mission": str(self.mission_path), "mission_sha256": sha256,
                                    "flight_version": FLIGHT_VERSION}, indent=1) + "\n")  # fmt: skip
        for folder in sorted((self.out / "runs").glob("[0-9]" * 4)):
            self._next_index = max(self._next_index, int(folder.name) + 1)
            result = completed(folder)
            try:
                scenario = Scenario.from_json(json.loads((folder / SCENARIO_FILE).read_text()))
            except (OSError, ValueError, KeyError, TypeError, IndexError):
                continue
            # kept only if it flew the file this campaign would write now (not one written by another version)
            with contextlib.suppress(OSError):
                if result is not None and (folder / MISSION_FILE).read_text() == self._text(scenario):
                    self._flown[_identity(scenario)] = self._outcome(scenario, folder, result)

    def _text(self, scenario: Scenario, path: Path | str = MISSION_FILE) -> str:
        """The plain mission file of a scenario, its comment saying how to replay it as the file ``path``."""
        mission = scenario_mission(self.raw, scenario, self.mission_path.parent.resolve())
        return mission_text(mission, header=[f"{self.mission_path.name}, {scenario.describe()}",
                                             f"swarm fly {path} --lockstep"])  # fmt: skip

    def _flight(self, scenario: Scenario) -> Flight:
        """The scenario as a plain mission file in a folder of its own, ready to fly."""
        with self._lock:
            index = self._next_index
            self._next_index += 1
        folder = self.out / "runs" / f"{index:04d}"
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / MISSION_FILE
        path.write_text(self._text(scenario))
        (folder / SCENARIO_FILE).write_text(json.dumps(scenario.to_json(), indent=1) + "\n")
        seed = scenario.seed if scenario.seed is not None else int(self.raw["swarm"].get("seed", 0))
        plan = SweepPlan(mission=path, mission_sha256=hashlib.sha256(path.read_bytes()).hexdigest(),
                         n_drones=scenario.drones or self.n_drones, seeds=(seed,), axes=(),
                         fly_args=self.fly_args)  # fmt: skip
        return Flight(plan, Run(index=index, setting=(), seed=seed), folder)

    def _outcome(self, scenario: Scenario, folder: Path, result: RunResult) -> Outcome:
        mission, report = folder / MISSION_FILE, folder / "report"
        try:  # a flight that broke an invariant and then failed a step (drones in contact never reach their goal)
            metrics = json.loads((report / "metrics.json").read_text())  # still wrote what broke first
        except (OSError, ValueError):
            metrics = None
        if metrics is None or not (result.ok or metrics.get("violations")):
            return Outcome(index=result.index, scenario=scenario, mission=mission, report=report, flown=False,
                           error=result.error)  # fmt: skip
        sysids = list(metrics["sysids"])  # the drones' in the mission's order: drone k is sysids[k - 1]
        violations = metrics.get("violations", [])
        return Outcome(
            index=result.index, scenario=scenario, mission=mission, report=report, flown=True,
            failures=tuple((str(v["name"]), tuple(sorted(sysids.index(s) + 1 for s in v["sysids"] if s in sysids)))
                           for v in violations),
            details=tuple(f"{v['name']} at t={v['time_s']} s: {v['detail']}" for v in violations),
            times_s=tuple(float(v["time_s"]) for v in violations),
            steps_s=tuple((int(st["index"]), float(st["start_s"]), float(st["end_s"]))
                          for st in metrics.get("steps", []) if None not in (st.get("start_s"), st.get("end_s"))),
        )  # fmt: skip

    def _fly(self, scenarios: list[Scenario]) -> list[Outcome]:
        """Fly scenarios side by side; their outcomes, kept (those stopped before they finished are not)."""
        flights = {f.run.index: (f, s) for f, s in ((self._flight(s), s) for s in scenarios)}
        outcomes: list[Outcome] = []

        def finished(result: RunResult) -> None:
            flight, scenario = flights[result.index]
            outcome = self._outcome(scenario, flight.folder, result)
            with self._lock:
                self._flown[_identity(scenario)] = outcome
                outcomes.append(outcome)
                self.result.errors += not outcome.flown
                new = [k for k in outcome.failures if k not in self._said]
                self._said.update(new)
            if not outcome.flown:
                self.say(f"falsify: flight {outcome.index} failed before it broke an invariant: {outcome.error}")
            for key in new:  # said as it comes: a search takes a while
                self.say(f"falsify: flight {outcome.index} broke {outcome.details[outcome.failures.index(key)]} "
                         f"({scenario.describe()})")  # fmt: skip

        self.flyer([f for f, _ in flights.values()], finished, self.stop)
        return outcomes

    def _kept(self, scenario: Scenario) -> Outcome | None:
        with self._lock:
            return self._flown.get(_identity(scenario))

    # ---- the passes ----------------------------------------------------------------------------------------------
    def run(self) -> CampaignResult:
        """Draw, search, shrink (module docstring); the summary written. Ctrl-C stops the flights under way, writes
        the summary of what was flown, and raises KeyboardInterrupt: the same command resumes."""
        from hypothesis.internal.conjecture import engine

        self._load()
        timer = None
        if self.time_s is not None:
            timer = threading.Timer(self.time_s, self._time_up)
            timer.daemon = True
            timer.start()
        lifted, engine.MAX_SHRINKING_SECONDS = engine.MAX_SHRINKING_SECONDS, NO_SHRINK_TIME_LIMIT_S
        try:
            self._search(self._draw())
            self._shrink_all()
            self._settle_met()
        except KeyboardInterrupt:
            self.stop.set()
            self.result.stopped = "interrupted"
            raise
        finally:
            engine.MAX_SHRINKING_SECONDS = lifted
            if timer is not None:
                timer.cancel()
            self._write_summary()
        return self.result

    def _time_up(self) -> None:
        self.result.stopped = "its time was up"
        self.stop.set()

    def _hypothesis(self, test: Callable[[Scenario], None], *, shrink: bool) -> Callable[[], None]:
        """``test`` as a hypothesis test over the space: seeded with the campaign seed, ``budget`` examples, no
        database (the flights kept are the campaign's memory); generation only, or generation and shrinking of the
        first failure."""
        from hypothesis import HealthCheck, Phase, given, settings
        from hypothesis import seed as seeded

        phases = (Phase.generate, Phase.shrink) if shrink else (Phase.generate,)
        return seeded(self.seed)(settings(
            max_examples=self.budget, deadline=None, database=None, phases=phases, report_multiple_bugs=False,
            suppress_health_check=list(HealthCheck), print_blob=False,
        )(given(strategy(self.space))(test)))  # fmt: skip

    def _draw(self) -> list[Scenario]:
        """The search's scenarios, in hypothesis's order, each once."""
        drawn: dict[str, Scenario] = {}

        def record(scenario: Scenario) -> None:
            drawn.setdefault(_identity(scenario), scenario)

        self._hypothesis(record, shrink=False)()
        return list(drawn.values())

    def _search(self, drawn: list[Scenario]) -> None:
        todo = [s for s in drawn if self._kept(s) is None]
        self.result.reused = len(drawn) - len(todo)
        if self.result.reused:
            self.say(f"falsify: {self.result.reused} of {len(drawn)} flights of the search flown before")
        self.result.search_flights = len(self._fly(todo))
        for scenario in drawn:  # each failure's first flight, in the order drawn
            if (outcome := self._kept(scenario)) is None:
                continue
            for key in outcome.failures:
                if key not in self.result.failures:
                    self.result.failures[key] = Failure(key=key, first=outcome, smallest=outcome)

    def _shrink_all(self) -> None:
        failures = [f for f in self.result.failures.values() if f.searched]
        if not failures or self.shrink_budget == 0 or self.stop.is_set():
            return
        with concurrent.futures.ThreadPoolExecutor(max_workers=self.jobs, thread_name_prefix="shrink") as pool:
            futures = [pool.submit(self._shrink, failure) for failure in failures]
            try:
                for future in concurrent.futures.as_completed(futures):
                    future.result()
            except BaseException:
                self.stop.set()
                raise

    def _settle_met(self) -> None:
        """A failure met while another was shrunk keeps the simplest flight of it: fewest perturbations, then by the
        scenario (not the first met: with passes side by side, which came first is a matter of timing)."""
        with self._lock:
            kept = list(self._flown.items())
        for failure in self.result.failures.values():
            if not failure.searched:
                failing = [
                    (len(o.scenario.perturbations), identity, o) for identity, o in kept if failure.key in o.failures
                ]
                failure.smallest = min(failing, key=lambda t: t[:2])[2]

    def _shrink(self, failure: Failure) -> None:
        """One failure's shrinking pass (module docstring, 3.)."""

        def check(scenario: Scenario) -> None:
            outcome = self._outcome_for(scenario, failure)
            if outcome is None:
                raise _Spent()
            with self._lock:  # another failure met on the way: kept, not shrunk (its own pass never draws it)
                for key in outcome.failures:
                    if key not in self.result.failures:
                        self.result.failures[key] = Failure(key=key, first=outcome, smallest=outcome, searched=False)
            if failure.key in outcome.failures:
                failure.smallest = outcome
                raise Broken(failure.detail(outcome))

        with contextlib.suppress(_Spent, Broken):
            self._hypothesis(check, shrink=True)()
        self._cut(failure)

    def _cut(self, failure: Failure) -> None:
        """What hypothesis cannot shrink, since its space does not vary it, tried on what is left of the failure's
        budget, each kept if the failure still breaks: the mission cut after the step it broke in, then the swarm
        cut to its first drones (those it involves and those perturbed at least; tried at that, half way to the
        mission's count, and one less)."""
        smallest = failure.smallest
        if failure.key not in smallest.failures:
            return
        broke_at_s = smallest.times_s[smallest.failures.index(failure.key)]
        # the step under way then: one that spans it, or the one after the last that ended (a step that failed,
        # as drones in contact fail theirs, is not in the report's steps)
        step = next((i for i, start, end in smallest.steps_s if start <= broke_at_s < end), None)
        if step is None and smallest.steps_s and broke_at_s >= smallest.steps_s[-1][2]:
            step = smallest.steps_s[-1][0] + 1
        if step is not None and step + 1 < len(self.raw["steps"]):
            self._try_cut(failure, dataclasses.replace(smallest.scenario, steps=step + 1))
        scenario = failure.smallest.scenario
        involved = max((*failure.key[1], *(p.drone for p in scenario.perturbations)), default=1)
        for n in sorted({n for n in (involved, (involved + self.n_drones) // 2, self.n_drones - 1)
                         if involved <= n < self.n_drones}):  # fmt: skip
            if self._try_cut(failure, dataclasses.replace(scenario, drones=n)):
                break

    def _try_cut(self, failure: Failure, scenario: Scenario) -> bool:
        outcome = self._outcome_for(scenario, failure)
        if outcome is None or failure.key not in outcome.failures:
            return False
        failure.smallest = outcome
        return True

    def _outcome_for(self, scenario: Scenario, failure: Failure) -> Outcome | None:
        """The scenario's outcome: kept, or being flown by another failure's pass (waited for), or flown now on
        ``failure``'s shrink budget; None when that budget is spent or the campaign stopped."""
        identity = _identity(scenario)
        with self._lock:
            if identity in self._flown:
                return self._flown[identity]
            flying = self._flying.get(identity)
            if flying is None:
                if failure.shrink_flights >= self.shrink_budget or self.stop.is_set():
                    return None
                failure.shrink_flights += 1
                self._flying[identity] = threading.Event()
        if flying is not None:
            flying.wait()
            return self._kept(scenario)
        try:
            flown = self._fly([scenario])
            return flown[0] if flown else None  # none: stopped while it flew
        finally:
            with self._lock:
                self._flying.pop(identity).set()

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
            self.minimal_file(failure).write_text(self._text(smallest.scenario, self.minimal_file(failure)))
            rows.append({"invariant": failure.key[0], "drones": list(failure.key[1]),
                         "first_flight": failure.first.index, "smallest_flight": smallest.index,
                         "searched": failure.searched, "shrink_flights": failure.shrink_flights,
                         "perturbations": len(smallest.scenario.perturbations),
                         "scenario": smallest.scenario.describe(), "detail": failure.detail(smallest),
                         "mission": str(self.minimal_file(failure)), "report": str(smallest.report)})  # fmt: skip
        summary = {"mission": str(self.mission_path), "seed": self.seed, "budget": self.budget,
                   "shrink_budget": self.shrink_budget, "flights": result.flights,
                   "search_flights": result.search_flights, "reused": result.reused, "errors": result.errors,
                   "stopped": result.stopped, "failures": rows}  # fmt: skip
        (self.out / SUMMARY_FILE).write_text(json.dumps(summary, indent=1) + "\n")
        reused = f", {result.reused} flown before" if result.reused else ""
        lines = [f"falsify {self.mission_path.name} (campaign seed {self.seed}): {result.flights} flights: "
                 f"{result.search_flights} to search (budget {self.budget}{reused}), "
                 f"{result.flights - result.search_flights} to shrink (budget {self.shrink_budget} per failure); "
                 f"{result.errors} that failed before breaking anything"
                 + (f"; stopped: {result.stopped}" if result.stopped else "")]  # fmt: skip
        lines.append(f"{len(rows)} distinct failure(s)" if rows else "no invariant broken")
        for row in rows:
            lines.append(f"  {row['invariant']} (drones {row['drones']}): {row['detail']}")
            how = (f"{row['shrink_flights']} flights to shrink" if row["searched"]
                   else "met while another failure was shrunk, not shrunk itself")  # fmt: skip
            lines.append(f"    smallest: {row['scenario']} ({row['perturbations']} perturbation(s); {how})")
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
            mission.write_text(self._text(failure.smallest.scenario, mission))
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
