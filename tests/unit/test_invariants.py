"""Invariants (gcs/invariants): each property on instants made to hold and made to fail, the forms over a sequence
of instants, and every bad declaration refused with one line naming its field."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from gcs.invariants.monitor import Monitor
from gcs.invariants.spec import InvariantError, build_invariant, components, unique_names
from gcs.invariants.state import LOSS, STEP, TickState

pytestmark = [pytest.mark.unit, pytest.mark.timeout(10)]

SYSIDS = [21, 22, 23, 24]


def tick(t: float, **fields: Any) -> TickState:
    positions = fields.pop("positions", {21: (0.0, 0.0, -3.0), 22: (3.0, 0.0, -3.0), 23: (0.0, 3.0, -3.0)})
    fields.setdefault("airborne", frozenset(positions))
    return TickState(time_s=t, positions_ned_m=positions, **fields)


def first(fields: dict[str, Any], *states: TickState, tmp: Path = Path(".")) -> Any:
    """The first violation of one invariant over the instants, or None."""
    monitor = Monitor([build_invariant(fields, base=tmp, drone_count=4)], SYSIDS)
    for state in states:
        monitor.check(state)
    return next(iter(monitor.first.values()), None)


def test_separation_between_airborne_drones_and_to_attached_vehicles() -> None:
    spec = {"kind": "separation", "min_m": 1.0}
    assert first(spec, tick(0.0)) is None
    near = tick(1.0, positions={21: (0.0, 0.0, -3.0), 22: (0.6, 0.0, -3.0), 23: (9.0, 0.0, -3.0)})
    violation = first(spec, tick(0.0), near)
    assert (violation.time_s, violation.sysids) == (1.0, (21, 22)) and "0.60 m apart" in violation.detail
    # a drone on the ground is not counted; an attached vehicle is
    grounded = tick(1.0, positions=near.positions_ned_m, airborne=frozenset({21, 23}))
    assert first(spec, grounded) is None
    beside = tick(2.0, attached_ned_m={250: (0.0, 3.5, -3.0)})
    assert first(spec, beside).sysids == (23, 250)
    # only the drones named: drone 1 (sysid 21) and drone 3 (sysid 23)
    assert first({**spec, "drones": [1, 3]}, near) is None
    # a contact is a separation of the distance it reports, though the positions at the ticks are far apart
    touched = tick(5.2, contacts=((22, "Collision with drone 23 at 0.64 m"),))
    violation = first(spec, tick(5.1), touched)
    assert (violation.time_s, violation.sysids) == (5.2, (22, 23)) and "0.64 m apart" in violation.detail
    assert first({**spec, "min_m": 0.6}, touched) is None
    # (with no distance given, the bodies touched: any separation is broken)
    assert first({**spec, "min_m": 0.1}, tick(5.2, contacts=((22, "Collision with drone 23"),))) is not None
    assert first(spec, tick(5.2, contacts=((22, "Collision with obstacle 1 at 0.30 m"),))) is None


def test_contact_and_failsafe_come_from_what_the_drones_report() -> None:
    assert first({"kind": "contact"}, tick(0.0)) is None
    violation = first({"kind": "contact"}, tick(0.0), tick(4.2, contacts=((22, "Collision with drone 23"),)))
    # both bodies are involved: the drone that reported it and the one its report names
    assert (violation.time_s, violation.sysids) == (4.2, (22, 23)) and "Collision with drone 23" in violation.detail
    failsafe = ((23, "Failsafe: battery critical"),)
    assert first({"kind": "no_failsafe"}, tick(3.0, failsafes=failsafe)).sysids == (23,)
    # unless a fault was injected into that drone
    assert first({"kind": "no_failsafe"}, tick(3.0, failsafes=failsafe, faulted=frozenset({23}))) is None


def test_altitude_band_fence_and_formation_error() -> None:
    high = tick(1.0, positions={21: (0.0, 0.0, -3.0), 22: (3.0, 0.0, -12.0)})
    assert first({"kind": "altitude", "min_m": 1.0, "max_m": 10.0}, tick(0.0)) is None
    assert first({"kind": "altitude", "min_m": 1.0, "max_m": 10.0}, high).sysids == (22,)
    far = tick(1.0, positions={21: (30.0, 40.0, -3.0), 22: (3.0, 0.0, -3.0)})
    assert first({"kind": "fence", "radius_m": 50.0}, far) is None
    farther = {21: (30.0, 30.0, -3.0), 22: (40.0, 40.0, -3.0)}
    violation = first({"kind": "fence", "radius_m": 50.0}, tick(0.0), tick(1.0, positions=farther))
    assert violation.sysids == (22,) and "56.57 m" in violation.detail
    slots = {21: (0.0, 0.0, -3.0), 22: (3.0, 0.6, -3.0)}
    assert first({"kind": "formation", "max_m": 0.7}, tick(0.0, slots_ned_m=slots)) is None
    assert first({"kind": "formation", "max_m": 0.5}, tick(0.0, slots_ned_m=slots)).sysids == (22,)


def test_connectivity_is_a_graph_search_over_the_airborne_drones() -> None:
    chain = {21: (0.0, 0.0, -3.0), 22: (4.0, 0.0, -3.0), 23: (8.0, 0.0, -3.0), 24: (20.0, 0.0, -3.0)}
    assert components(chain, 5.0) == [[21, 22, 23], [24]]
    assert components(chain, 12.0) == [[21, 22, 23, 24]]
    violation = first({"kind": "connected", "range_m": 5.0}, tick(0.0, positions=chain))
    assert violation.sysids == (24,) and "2 groups" in violation.detail
    assert first({"kind": "connected", "range_m": 12.0}, tick(0.0, positions=chain)) is None
    # a drone on the ground leaves the graph
    assert first({"kind": "connected", "range_m": 5.0},
                 tick(0.0, positions=chain, airborne=frozenset({21, 22, 23}))) is None  # fmt: skip


def test_answered_commands() -> None:
    assert first({"kind": "answered", "within_s": 3.0}, tick(0.0, unanswered_s={21: 2.5})) is None
    assert first({"kind": "answered", "within_s": 3.0}, tick(0.0, unanswered_s={21: 3.5})).sysids == (21,)


def test_a_users_predicate_is_imported_from_its_file_and_its_failures_are_violations(tmp_path: Path) -> None:
    (tmp_path / "checks.py").write_text(
        "def low(state):\n"
        "    worst = max((-p[2] for p in state.positions_ned_m.values()), default=0.0)\n"
        "    return True if worst < 5.0 else f'highest drone {worst:.1f} m'\n"
        "def broken(state):\n"
        "    raise KeyError('x')\n"
    )
    spec = {"kind": "predicate", "function": "checks.py:low"}
    assert first(spec, tick(0.0), tmp=tmp_path) is None
    violation = first(spec, tick(1.0, positions={21: (0.0, 0.0, -6.0)}), tmp=tmp_path)
    assert violation.detail.endswith("checks.py:low: highest drone 6.0 m")
    raised = first({"kind": "predicate", "function": "checks.py:broken"}, tick(0.0), tmp=tmp_path)
    assert "raised KeyError" in raised.detail


def test_always_after_a_grace_and_eventually_within_a_window() -> None:
    # a formation's error only from 5 s after each step began
    spec = {"kind": "formation", "max_m": 0.5, "after": STEP, "grace_s": 5.0}
    off = {21: (2.0, 0.0, -3.0)}
    early = [tick(0.0, events=frozenset({STEP}), slots_ned_m=off), tick(4.9, slots_ned_m=off)]
    assert first(spec, *early) is None
    late = first(spec, *early, tick(5.0, slots_ned_m=off))
    assert late.time_s == 5.0
    # re-formed within 3 s of a loss: holds if some tick within the window holds; fails at the window's end otherwise
    spec = {"kind": "formation", "max_m": 0.5, "form": "eventually", "after": LOSS, "within_s": 3.0}
    loss = tick(10.0, events=frozenset({LOSS}), slots_ned_m=off)
    assert first(spec, tick(0.0, slots_ned_m=off), loss, tick(12.0), tick(13.5, slots_ned_m=off)) is None
    violation = first(spec, loss, tick(12.0, slots_ned_m=off), tick(13.0, slots_ned_m=off))
    assert violation.time_s == 13.0 and "not within 3 s of the loss at t=10.0 s" in violation.detail
    # no event, no window
    assert first(spec, tick(0.0, slots_ned_m=off), tick(20.0, slots_ned_m=off)) is None


def test_only_the_first_violation_of_each_invariant_is_kept() -> None:
    monitor = Monitor([build_invariant({"kind": "contact"}, base=Path("."), drone_count=4)], SYSIDS)
    assert len(monitor.check(tick(1.0, contacts=((21, "Collision with drone 22"),)))) == 1
    assert monitor.check(tick(2.0, contacts=((23, "Collision with drone 24"),))) == []
    assert monitor.first["contact"].time_s == 1.0


@pytest.mark.parametrize(
    ("fields", "said"),
    [
        ({"kind": "closeness"}, "kind: must be one of"),
        ({"kind": "separation"}, "missing field 'min_m'"),
        ({"kind": "separation", "min_m": -1}, "min_m: must be positive"),
        ({"kind": "separation", "min_m": "far"}, "min_m: must be a number"),
        ({"kind": "separation", "min_m": 1, "radius_m": 2}, "radius_m: not a field of a separation invariant"),
        ({"kind": "altitude", "min_m": 5, "max_m": 2}, "min_m: must be below max_m"),
        ({"kind": "contact", "drones": [7]}, r"drones: no drone 7 \(the swarm's drones are 1\.\.4\)"),
        ({"kind": "contact", "drones": []}, "drones: must be a list"),
        ({"kind": "contact", "form": "sometimes"}, "form: must be one of always, eventually"),
        ({"kind": "contact", "form": "eventually"}, "missing field 'within_s'"),
        ({"kind": "contact", "form": "eventually", "within_s": 0}, "within_s: must be positive"),
        ({"kind": "contact", "after": "landing"}, "after: must be one of start, loss, fault, step"),
        ({"kind": "contact", "grace_s": -2}, "grace_s: must be zero or more"),
        ({"kind": "predicate", "function": "nowhere.py:f"}, "function: no file"),
        ({"kind": "predicate", "function": "checks"}, "function: must be file.py:function"),
    ],
)
def test_a_bad_invariant_is_one_line_naming_its_field(fields: dict[str, Any], said: str, tmp_path: Path) -> None:
    with pytest.raises(InvariantError, match=said) as caught:
        build_invariant(fields, base=tmp_path, drone_count=4)
    assert "\n" not in str(caught.value)


def test_a_predicate_that_cannot_be_imported_or_found_is_one_line(tmp_path: Path) -> None:
    (tmp_path / "bad.py").write_text("import nothing_of_that_name\n")
    (tmp_path / "ok.py").write_text("x = 1\n")
    with pytest.raises(InvariantError, match="cannot be imported: ModuleNotFoundError"):
        build_invariant({"kind": "predicate", "function": "bad.py:f"}, base=tmp_path, drone_count=1)
    with pytest.raises(InvariantError, match="has no function 'f'"):
        build_invariant({"kind": "predicate", "function": "ok.py:f"}, base=tmp_path, drone_count=1)
    twice = [build_invariant({"kind": "contact"}, base=tmp_path, drone_count=1)] * 2
    with pytest.raises(InvariantError, match="two invariants named 'contact'"):
        unique_names(twice)


def test_a_missions_invariants_are_read_and_a_bad_one_is_named_by_its_file_line_and_field(tmp_path: Path) -> None:
    from gcs.missions.mission_file import MissionFileError, load_mission

    head = '[swarm]\ndrones = 3\n\n[[steps]]\naction = "takeoff"\nalt_m = 3.0\n\n'
    good = tmp_path / "good.toml"
    formed = 'name = "formed"\nkind = "formation"\nmax_m = 0.5\nform = "eventually"\nafter = "loss"\nwithin_s = 10\n'
    good.write_text(head + '[[invariants]]\nkind = "separation"\nmin_m = 1.0\n\n[[invariants]]\n' + formed)
    invariants = load_mission(good).invariants
    assert [i.describe() for i in invariants] == ["separation always", "formed within 10 s of each loss"]
    for text, said in (
        ('[[invariants]]\nkind = "separation"\nmin_m = -1\n', r"bad.toml:10: invariants\[0\]\.min_m: must be positive"),
        ('[[invariants]]\nkind = "fence"\n', r"bad.toml:8: invariants\[0\]: missing field 'radius_m'"),
        ('[[invariants]]\nkind = "contact"\ndrones = [4]\n', r"invariants\[0\]\.drones: no drone 4"),
        ('[[invariants]]\nkind = "contact"\n[[invariants]]\nkind = "contact"\n', "two invariants named 'contact'"),
    ):
        bad = tmp_path / "bad.toml"
        bad.write_text(head + text)
        with pytest.raises(MissionFileError, match=said):
            load_mission(bad)
