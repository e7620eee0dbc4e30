"""QGroundControl .plan files: the committed plan reads, round-trips, shifts and converts; every mistake is one line."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink

from gcs.flight.geodesy import GeoPoint, NedFrame
from gcs.missions.mission_file import MissionFileError, parse_mission
from gcs.missions.qgc_plan import (
    FenceItemsError,
    PlanFileError,
    fence_items,
    last_item_lands,
    load_plan,
    mission_items,
    parse_plan,
    plan_from_items,
    plan_text,
    shifted,
)

MISSIONS = Path(__file__).resolve().parents[2] / "missions"
BOX_PLAN = MISSIONS / "box.plan"
PATH = Path("survey.plan")
JUMP = {
    "autoContinue": True,
    "command": 177,
    "doJumpId": 6,
    "frame": 2,
    "params": [2, 1, 0, 0, 0, 0, 0],
    "type": "SimpleItem",
}  # back to the item with doJumpId 2, once


def box_document() -> dict[str, Any]:
    data: dict[str, Any] = json.loads(BOX_PLAN.read_text())
    return data


def test_the_committed_qgroundcontrol_plan_reads_as_drawn() -> None:
    plan = load_plan(BOX_PLAN)
    assert [i.command for i in plan.items] == [22, 16, 16, 16, 21]
    assert all(i.frame == mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT for i in plan.items)
    assert math.isnan(plan.items[0].params[3])  # null yaw: "not set"
    assert plan.planned_home == (47.397742, 8.545594, 488.0)
    assert len(plan.polygons) == 1 and plan.polygons[0].inclusion and len(plan.polygons[0].vertices_deg) == 4
    assert len(plan.circles) == 1 and not plan.circles[0].inclusion and plan.circles[0].radius_m == 2.0
    assert last_item_lands(plan)


def test_a_plan_written_and_read_again_is_the_same_plan() -> None:
    plan = load_plan(BOX_PLAN)
    again = parse_plan(plan_text(plan), PATH)
    assert plan_text(again) == plan_text(plan)
    assert list(map(repr, again.items)) == list(map(repr, plan.items))  # repr: NaN as "nan", equal to itself
    assert (again.polygons, again.circles, again.planned_home) == (plan.polygons, plan.circles, plan.planned_home)
    # AND what is written is QGroundControl's layout: the same document as the file QGroundControl saved
    assert json.loads(plan_text(plan)) == box_document()


def test_items_travel_as_mission_item_int_with_degE7_and_fence_vertices_carry_their_count() -> None:
    plan = load_plan(BOX_PLAN)
    items = mission_items(plan)
    assert [i.seq for i in items] == [0, 1, 2, 3, 4]
    assert (items[1].x, items[1].y, items[1].z) == (473977960, 85455940, 3.0)
    assert all(i.mission_type == 0 for i in items)
    fence = fence_items(plan)
    assert [(f.command, f.param1, f.frame, f.mission_type) for f in fence] == [(5001, 4.0, 0, 1)] * 4 + [
        (5004, 2.0, 0, 1)  # the exclusion circle: its radius in param1
    ]
    # AND a download of those items makes a plan that travels as the same items again (the export; coordinates are
    # kept to the wire's 1e-7 degrees, about 1 cm)
    back = plan_from_items(items, fence, home=plan.planned_home)
    assert list(map(repr, mission_items(back))) == list(map(repr, items))  # repr: NaN as "nan", equal to itself
    assert list(map(repr, fence_items(back))) == list(map(repr, fence))
    for ours, theirs in zip(back.items, plan.items, strict=True):
        assert ours.params[4:6] == pytest.approx(theirs.params[4:6], abs=0.6e-7)


def test_a_do_jump_names_its_target_by_doJumpId_in_the_file_and_by_sequence_number_on_the_wire() -> None:
    # GIVEN the plan with a DO_JUMP to doJumpId 2 (the first waypoint) inserted before its landing
    data = box_document()
    data["mission"]["items"].insert(4, JUMP)
    data["mission"]["items"][5]["doJumpId"] = 7
    plan = parse_plan(json.dumps(data), PATH)
    # THEN on the wire it jumps to seq 1 (PX4 counts from 0, with no home item), as QGroundControl uploads it
    jump = mission_items(plan)[4]
    assert (jump.command, jump.param1, jump.param2) == (177, 1.0, 1.0)
    # AND exported again it names doJumpId 2, the first waypoint's
    back = plan_from_items(mission_items(plan), home=plan.planned_home)
    assert back.items[4].params[0] == 2.0 and back.items[1].do_jump_id == 2


def test_a_shifted_copy_keeps_the_shape_and_moves_every_coordinate_by_the_offset() -> None:
    plan = load_plan(BOX_PLAN)
    moved = shifted(plan, 3.0, -4.5)
    frame = NedFrame(GeoPoint(lat_deg=plan.planned_home[0], lon_deg=plan.planned_home[1], alt_amsl_m=488.0))

    def ne(lat: float, lon: float) -> tuple[float, float]:
        n, e, _ = frame.ned_from_geo(GeoPoint(lat_deg=lat, lon_deg=lon, alt_amsl_m=488.0))
        return n, e

    for before, after in zip(plan.items, moved.items, strict=True):
        n0, e0 = ne(before.params[4], before.params[5])
        n1, e1 = ne(after.params[4], after.params[5])
        assert (n1 - n0, e1 - e0) == pytest.approx((3.0, -4.5), abs=1e-3)
        assert after.params[6] == before.params[6]  # altitudes stay relative to each drone's home
    for v0, v1 in zip(plan.polygons[0].vertices_deg, moved.polygons[0].vertices_deg, strict=True):
        n0, e0 = ne(*v0)
        n1, e1 = ne(*v1)
        assert (n1 - n0, e1 - e0) == pytest.approx((3.0, -4.5), abs=1e-3)
    assert ne(*moved.planned_home[:2]) == pytest.approx((3.0, -4.5), abs=1e-3)
    assert shifted(plan, 0.0, 0.0) is plan


def _mutated(change: Any) -> str:
    data = copy.deepcopy(box_document())
    change(data)
    return json.dumps(data)


def _set(path: list[Any], value: Any) -> Any:
    def change(data: Any) -> None:
        for key in path[:-1]:
            data = data[key]
        data[path[-1]] = value

    return change


def _delete(path: list[Any]) -> Any:
    def change(data: Any) -> None:
        for key in path[:-1]:
            data = data[key]
        del data[path[-1]]

    return change


SURVEY = {"type": "ComplexItem", "complexItemType": "survey", "version": 5, "TransectStyleComplexItem": {}}

MALFORMED = [
    ("not json", "{", "survey.plan:1: not valid JSON: Expecting property name enclosed in double quotes (column 2)"),
    ("not an object", "[]", "survey.plan: must be a JSON object, got a list"),
    ("file type", _mutated(_set(["fileType"], "Mission")),
     "survey.plan: fileType: must be \"Plan\" (a QGroundControl plan file), got 'Mission'"),
    ("file version", _mutated(_set(["version"], 2)),
     "survey.plan: version: must be 1 (the version QGroundControl writes), got 2"),
    ("no mission", _mutated(_delete(["mission"])), "survey.plan: missing key 'mission'"),
    ("mission version", _mutated(_set(["mission", "version"], 1)),
     "survey.plan: mission.version: must be 2 (the version QGroundControl writes), got 1"),
    ("no home", _mutated(_delete(["mission", "plannedHomePosition"])),
     "survey.plan: mission: missing key 'plannedHomePosition'"),
    ("home latitude", _mutated(_set(["mission", "plannedHomePosition"], [97.0, 8.5, 488])),
     "survey.plan: mission.plannedHomePosition: latitude must be within -90..90 degrees, got 97"),
    ("no items", _mutated(_set(["mission", "items"], {})),
     "survey.plan: mission.items: must be a list of mission items, got an object"),
    ("six params", _mutated(_set(["mission", "items", 3, "params"], [0, 0, 0, 0, 47.4, 8.5])),
     "survey.plan: mission.items[3].params: must be a list of 7 numbers or null, got 6 values"),
    ("text param", _mutated(_set(["mission", "items", 2, "params", 6], "3 m")),
     "survey.plan: mission.items[2].params[6]: must be a number or null, got '3 m'"),
    ("no command", _mutated(_delete(["mission", "items", 1, "command"])),
     "survey.plan: mission.items[1]: missing key 'command'"),
    ("command range", _mutated(_set(["mission", "items", 1, "command"], 70000)),
     "survey.plan: mission.items[1].command: must be a whole number 0..65535, got 70000"),
    ("frame type", _mutated(_set(["mission", "items", 1, "frame"], "relative")),
     "survey.plan: mission.items[1].frame: must be a whole number 0..255, got 'relative'"),
    ("auto continue", _mutated(_set(["mission", "items", 1, "autoContinue"], 1)),
     "survey.plan: mission.items[1].autoContinue: must be true or false, got 1"),
    ("item longitude", _mutated(_set(["mission", "items", 2, "params", 5], 185.0)),
     "survey.plan: mission.items[2].params: longitude must be within -180..180 degrees, got 185"),
    ("item type", _mutated(_set(["mission", "items", 0, "type"], "Waypoint")),
     "survey.plan: mission.items[0].type: must be SimpleItem or ComplexItem, got 'Waypoint'"),
    ("survey", _mutated(_set(["mission", "items", 2], SURVEY)),
     "survey.plan: mission.items[2]: complex item 'survey' is not supported: QGroundControl keeps only its outline "
     "in the file; convert it to waypoints in QGroundControl first"),
    ("jump", _mutated(lambda d: d["mission"]["items"].insert(4, {**JUMP, "params": [9, 1, 0, 0, 0, 0, 0]})),
     "survey.plan: mission.items[4].params[0]: DO_JUMP to doJumpId 9, which no item has"),
    ("cruise speed", _mutated(_set(["mission", "cruiseSpeed"], 0)),
     "survey.plan: mission.cruiseSpeed: must be a positive speed in m/s, got 0"),
    ("fence version", _mutated(_set(["geoFence", "version"], 1)),
     "survey.plan: geoFence.version: must be 2 (the version QGroundControl writes), got 1"),
    ("two vertices", _mutated(_set(["geoFence", "polygons", 0, "polygon"], [[47.3, 8.5], [47.4, 8.5]])),
     "survey.plan: geoFence.polygons[0].polygon: must be a list of at least 3 [latitude, longitude] vertices, "
     "got 2 vertices"),
    ("vertex", _mutated(_set(["geoFence", "polygons", 0, "polygon", 2], [47.3])),
     "survey.plan: geoFence.polygons[0].polygon[2]: must be [latitude, longitude] in degrees, got [47.3]"),
    ("inclusion", _mutated(_delete(["geoFence", "polygons", 0, "inclusion"])),
     "survey.plan: geoFence.polygons[0]: missing key 'inclusion'"),
    ("circle radius", _mutated(_set(["geoFence", "circles"], [
        {"circle": {"center": [47.39, 8.54], "radius": -5}, "inclusion": False, "version": 1}])),
     "survey.plan: geoFence.circles[0].circle.radius: must be a positive number of metres, got -5"),
    ("rally point", _mutated(_set(["rallyPoints", "points"], [[47.39, 8.54]])),
     "survey.plan: rallyPoints.points[0]: must be [latitude, longitude, altitude], got [47.39, 8.54]"),
]  # fmt: skip


@pytest.mark.parametrize(("text", "line"), [(t, line) for _, t, line in MALFORMED], ids=[n for n, _, _ in MALFORMED])
def test_every_mistake_is_one_line_naming_the_file_the_place_and_the_problem(text: str, line: str) -> None:
    with pytest.raises(PlanFileError) as raised:
        parse_plan(text, PATH)
    assert str(raised.value) == line
    assert "\n" not in str(raised.value)


def test_an_unreadable_file_is_one_line(tmp_path: Path) -> None:
    with pytest.raises(PlanFileError, match=r"^.*nowhere\.plan: cannot read: No such file or directory$"):
        load_plan(tmp_path / "nowhere.plan")


def test_an_incomplete_downloaded_fence_is_refused_with_its_place() -> None:
    fence = fence_items(load_plan(BOX_PLAN))[:3]  # a polygon of 4 vertices cut after 3
    with pytest.raises(FenceItemsError, match="fence item 0: a polygon of 4 vertices is incomplete"):
        plan_from_items([], fence, home=(0.0, 0.0, 0.0))


MISSION = """name = "p"
[swarm]
drones = 3
[[steps]]
action = "plan"
file = "{file}"
{extra}
"""


def test_a_plan_step_reads_its_plan_and_names_a_broken_one_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "m.toml"
    step = parse_mission(MISSION.format(file=BOX_PLAN, extra='drones = "1,3"\ntimeout_s = 60'), path).steps[0]
    assert step.drones == "1,3" and step.timeout_s == 60.0 and len(step.plan.items) == 5  # type: ignore[union-attr]
    broken = tmp_path / "broken.plan"
    broken.write_text(_mutated(_set(["mission", "items", 3, "params"], [0, 0])))
    with pytest.raises(MissionFileError) as raised:
        parse_mission(MISSION.format(file="broken.plan", extra=""), path)
    assert str(raised.value) == (
        f"{path}:6: steps[0].file: {broken}: mission.items[3].params: must be a list of 7 numbers or null, got 2 values"
    )
    fence_only = tmp_path / "fence.plan"
    fence_only.write_text(_mutated(_set(["mission", "items"], [])))
    assert parse_mission(MISSION.format(file="fence.plan", extra="start = false"), path).steps[0].plan.items == ()  # type: ignore[union-attr]
    with pytest.raises(
        MissionFileError, match=r"steps\[0\].file: .*fence.plan: the plan has no mission items to start"
    ):
        parse_mission(MISSION.format(file="fence.plan", extra=""), path)
    with pytest.raises(MissionFileError, match=r"m.toml:7: steps\[0\].drones: 4 is not one of 1..3"):
        parse_mission(MISSION.format(file=BOX_PLAN, extra='drones = "2-4"'), path)
    with pytest.raises(MissionFileError, match=r"steps\[0\].offsets: 1 offsets for 3 drones: give one each"):
        parse_mission(MISSION.format(file=BOX_PLAN, extra="offsets = [[1, 2]]"), path)
