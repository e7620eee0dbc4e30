"""A falsification campaign's passes (gcs/falsify/campaign.py): draw, search side by side, shrink each failure on its
own budget, resume. The flights here are a stand-in's: a rule over the scenario that writes what ``swarm fly`` writes
(run.json, metrics.json), so that the search's own logic is checked in milliseconds on every point it has; the real
flights are tests/integration/test_falsify.py's.

The rule: two drones touch at 9 s, in the swap, when both fly with their avoidance off (AVOID_ENABLE = 0), unless the
gusts exceed 0.8 m/s (then nothing breaks); a link fault before 5 s on drone 3 makes the flight fail before it breaks
anything."""

from __future__ import annotations

import json
import tempfile
import threading
import time
import tomllib
from collections.abc import Callable
from itertools import combinations
from pathlib import Path

import pytest

from gcs.falsify.campaign import CAMPAIGN_FILE, Campaign, CampaignResult
from gcs.falsify.space import FalsifyError, FaultAt, ParamChange, Scenario
from gcs.fleet.clock import FLIGHT_VERSION
from gcs.sweep.runs import RUN_FILE, Flight, RunResult

pytestmark = [pytest.mark.unit, pytest.mark.timeout(120)]

MISSION = """
name = "crossing"
[swarm]
drones = 4

[[invariants]]
kind = "contact"

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "swap"

[[steps]]
action = "land"

[falsify]
params = { AVOID_ENABLE = [0], MPC_XY_VEL_MAX = [3.0] }
gust_mps = [0.0, 1.0]
max_perturbations = 4

[falsify.faults]
kinds = ["link"]
at_s = [2.0, 12.0]
for_s = [1.0, 5.0]
"""
FIRST_SYSID = 31
PAIRS = 2  # distinct failures the tests' search finds at least
STEPS_S = ((0.0, 5.0), (5.0, 20.0), (20.0, 30.0))  # takeoff, swap, land


class StandIn:
    """Flies a flight by the rule in the module docstring; counts flights, and how many fly at once at most."""

    def __init__(self, delay_s: float = 0.0) -> None:
        self.delay_s = delay_s
        self.flown: list[Scenario] = []
        self.most_at_once = 0
        self._now = 0
        self._lock = threading.Lock()

    def __call__(self, flights: list[Flight], finished: Callable[[RunResult], None], stop: threading.Event) -> None:
        threads = [threading.Thread(target=self._fly, args=(f, finished, stop)) for f in flights]
        for t in threads:
            t.start()
        for t in threads:
            t.join()

    def close(self) -> None:
        pass

    def _fly(self, flight: Flight, finished: Callable[[RunResult], None], stop: threading.Event) -> None:
        with self._lock:
            self._now += 1
            self.most_at_once = max(self.most_at_once, self._now)
        try:
            if stop.wait(self.delay_s):
                return
            scenario = Scenario.from_json(json.loads((flight.folder / "scenario.json").read_text()))
            with self._lock:
                self.flown.append(scenario)
            violations, ok = rule(scenario)
            report = flight.folder / "report"
            report.mkdir(parents=True, exist_ok=True)
            sysids = list(range(FIRST_SYSID, FIRST_SYSID + (scenario.drones or 4)))
            steps = [{"index": i, "start_s": start, "end_s": end} for i, (start, end) in enumerate(STEPS_S)]
            # a step the drones fail (two in contact never finish their swap) is not in the report
            steps = steps[:1] if violations else steps[: scenario.steps]
            metrics = {"sysids": sysids, "violations": violations, "steps": steps}
            (report / "metrics.json").write_text(json.dumps(metrics))
            result = RunResult(index=flight.run.index, name="standin", setting=(), seed=flight.run.seed, ok=ok,
                               wall_s=0.0, metrics={}, error=None if ok else "swarm fly exited with 1: link",
                               command=())  # fmt: skip
            (flight.folder / RUN_FILE).write_text(json.dumps(result.to_json()))
            finished(result)
        finally:
            with self._lock:
                self._now -= 1


def rule(scenario: Scenario) -> tuple[list[dict[str, object]], bool]:
    if any(isinstance(p, FaultAt) and p.drone == 3 and p.at_s < 5.0 for p in scenario.perturbations):
        return [], False
    if (scenario.gust_mps or 0.0) > 0.8:
        return [], True
    off = sorted({p.drone for p in scenario.perturbations if isinstance(p, ParamChange) and p.name == "AVOID_ENABLE"})
    return [{"name": "contact", "time_s": 9.0, "sysids": [FIRST_SYSID + a - 1, FIRST_SYSID + b - 1],
             "detail": f"drones {a} and {b} touched"} for a, b in combinations(off, 2)], True  # fmt: skip


def campaign(tmp_path: Path, out: str = "out", **options: object) -> tuple[Campaign, StandIn]:
    mission = tmp_path / "crossing.toml"
    mission.write_text(MISSION)
    stand_in = StandIn(delay_s=float(options.pop("delay_s", 0.0)))  # type: ignore[arg-type]
    settings: dict[str, object] = {"budget": 40, "shrink_budget": 40, "say": lambda _: None, **options}
    return Campaign(mission, tmp_path / out, flyer=stand_in, **settings), stand_in  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def seed() -> int:
    """The first campaign seed whose search finds at least ``PAIRS`` distinct pairs. Which scenarios a seed draws is
    hypothesis's, and hypothesis also draws now and then from the constants it finds in the project's own modules, so
    that a change anywhere in the code may change them: the tests take a seed that finds what they check, rather
    than one written down."""
    with tempfile.TemporaryDirectory() as folder:
        for candidate in range(100):
            run, _ = campaign(Path(folder), f"seed-{candidate}", seed=candidate, shrink_budget=0)
            if len(run.run().failures) >= PAIRS:
                return candidate
    raise AssertionError(f"no campaign seed below 100 finds {PAIRS} pairs")


def summary(result: CampaignResult) -> list[tuple[object, ...]]:
    """Each failure: its identity, its first flight's index and scenario, its smallest scenario and shrink flights
    (a failure met while shrinking: its first flight is whichever pass met it first)."""
    return [(k, f.first.index if f.searched else None, f.first.scenario if f.searched else None, f.smallest.scenario,
             f.shrink_flights) for k, f in sorted(result.failures.items())]  # fmt: skip


def test_every_pair_found_is_shrunk_to_its_two_perturbations_and_flown_once_per_scenario(
    tmp_path: Path, seed: int
) -> None:
    # GIVEN a campaign over four drones where any two with their avoidance off touch
    run, stand_in = campaign(tmp_path, seed=seed)
    result = run.run()
    # THEN it found distinct failures, each named by its pair, each shrunk to exactly that pair's two perturbations
    searched = {k: f for k, f in result.failures.items() if f.searched}
    assert len(searched) >= PAIRS, summary(result)
    for (invariant, drones), failure in result.failures.items():
        assert invariant == "contact" and len(drones) == 2
        assert f"drones {drones[0]} and {drones[1]} touched" in failure.detail(failure.smallest)
    for (_, drones), failure in searched.items():
        assert 0 < failure.shrink_flights <= 40
        smallest = failure.smallest.scenario
        assert sorted(p.drone for p in smallest.perturbations) == list(drones), smallest
        assert all(isinstance(p, ParamChange) and p.name == "AVOID_ENABLE" for p in smallest.perturbations), smallest
        assert smallest.gust_mps == 0.0, smallest
        # AND cut to the steps up to the one it broke in, and to the first drones it needs
        assert smallest.steps == 2 and smallest.drones == (drones[1] if drones[1] < 4 else None), smallest
        minimal = tomllib.loads(failure.smallest.mission.read_text())
        assert minimal["swarm"]["drones"] == (smallest.drones or 4) and len(minimal["steps"]) == 2, minimal
    # AND no scenario was flown twice, the search at most its budget, and the totals add up
    identities = [json.dumps(s.to_json(), sort_keys=True) for s in stand_in.flown]
    assert len(identities) == len(set(identities)) == result.flights
    assert result.search_flights <= 40 and result.errors == sum(not rule(s)[1] for s in stand_in.flown)
    # AND the summary names each failure, its minimal file and how it was shrunk
    text = (tmp_path / "out" / "summary.txt").read_text()
    for failure in result.failures.values():
        assert run.minimal_file(failure).is_file() and str(run.minimal_file(failure)) in text
        # AND each minimal file says how to replay it, naming itself, and is otherwise the file that was flown
        minimal_text = run.minimal_file(failure).read_text()
        comments = [line for line in minimal_text.splitlines() if line.startswith("#")]
        assert comments[1] == f"# swarm fly {run.minimal_file(failure)} --lockstep", comments
        flown = failure.smallest.mission.read_text()
        assert minimal_text.split("\n", 2)[2] == flown.split("\n", 2)[2]
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["flights"] == result.flights


def test_each_failure_has_its_own_shrink_budget(tmp_path: Path, seed: int) -> None:
    run, _ = campaign(tmp_path, shrink_budget=2, seed=seed)
    result = run.run()
    assert len(result.failures) >= PAIRS
    assert all(f.shrink_flights <= 2 for f in result.failures.values())
    assert result.flights - result.search_flights == sum(f.shrink_flights for f in result.failures.values())


def test_side_by_side_it_finds_and_shrinks_exactly_what_it_does_one_at_a_time(tmp_path: Path, seed: int) -> None:
    alone, _ = campaign(tmp_path, "alone", jobs=1, seed=seed)
    together, stand_in = campaign(tmp_path, "together", jobs=3, delay_s=0.02, seed=seed)
    # (each failure's shrink flights may differ: a scenario two passes ask for is flown once, for whichever asks first)
    assert [row[:-1] for row in summary(alone.run())] == [row[:-1] for row in summary(together.run())]
    assert stand_in.most_at_once >= 3  # the search flew its flights side by side


def test_run_again_it_flies_nothing_it_flew_before_and_finds_the_same(tmp_path: Path, seed: int) -> None:
    first, _ = campaign(tmp_path, seed=seed)
    found = summary(first.run())
    again, stand_in = campaign(tmp_path, seed=seed)
    result = again.run()
    assert stand_in.flown == [] and result.flights == 0 and result.reused > 0
    assert summary(result) == [(*rest, 0) for *rest, _ in found]
    # AND a flight whose file is not the one this campaign writes now (another version wrote it) is flown again
    kept = tmp_path / "out" / "runs" / "0000" / "mission.toml"
    kept.write_text(kept.read_text().replace("[swarm]", "[swarm]\nspacing_m = 2.0"))
    third, stand_in = campaign(tmp_path, seed=seed)
    third.run()
    assert len(stand_in.flown) == 1


def test_a_time_limit_stops_it_and_the_summary_says_so(tmp_path: Path, seed: int) -> None:
    run, _ = campaign(tmp_path, time_s=0.3, delay_s=0.1, jobs=1, seed=seed)
    started = time.monotonic()
    result = run.run()
    assert time.monotonic() - started < 10
    assert result.stopped == "its time was up"
    assert "stopped: its time was up" in (tmp_path / "out" / "summary.txt").read_text()


def test_a_folder_holding_a_campaign_over_another_mission_is_refused_before_anything_flies(
    tmp_path: Path, seed: int
) -> None:
    first, _ = campaign(tmp_path, budget=3, shrink_budget=0, seed=seed)
    first.run()
    (tmp_path / "crossing.toml").write_text(MISSION.replace('action = "land"', 'action = "hold"\nduration_s = 1.0'))
    other = Campaign(tmp_path / "crossing.toml", tmp_path / "out", budget=3, flyer=StandIn(), say=lambda _: None)
    with pytest.raises(FalsifyError, match="holds a campaign over another mission") as caught:
        other.run()
    assert "\n" not in str(caught.value)


def test_a_campaign_flown_by_code_that_flies_differently_is_refused_before_anything_flies(
    tmp_path: Path, seed: int
) -> None:
    # GIVEN a campaign's folder whose record says its flights were flown by another version of the flights
    first, _ = campaign(tmp_path, budget=3, shrink_budget=0, seed=seed)
    first.run()
    path = tmp_path / "out" / CAMPAIGN_FILE
    record = json.loads(path.read_text())
    assert record["flight_version"] == FLIGHT_VERSION
    path.write_text(json.dumps({**record, "flight_version": FLIGHT_VERSION - 1}))
    # WHEN the same campaign is run there again THEN it is refused in one line, and nothing flies
    again, stand_in = campaign(tmp_path, budget=3, shrink_budget=0, seed=seed)
    with pytest.raises(FalsifyError, match="holds flights flown by code that flies differently") as caught:
        again.run()
    assert "\n" not in str(caught.value) and not stand_in.flown
