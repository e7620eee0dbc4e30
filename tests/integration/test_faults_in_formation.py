"""Faults injected into one drone of a flying formation, through ``swarm fly`` missions: real ``swarm`` and ``sitl``
processes in lockstep on loopback, the outcome read from the flight report.

- A drone made silent by a link fault holds its position in the path of a rotating circle of 8: nobody hears it,
  nobody relays it, the ground station loses it; the others, with default parameters, see it with their cameras.
- A drone whose rotor fails falls out of a rotating circle: it breaks on the ground, the ground station records the
  loss, the others fly on without touching the falling body.
- A drone whose links go silent for a few seconds in a rotating circle is lost, then heard again: the ground station
  takes it back, the circle re-plans with it and it flies its slot again in OFFBOARD.

Policy: loopback only (--no-forward); leased instances (tests/integration/instances.py); a time limit on every run.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
from pathlib import Path
from typing import Any

import pytest
from pymavlink import mavutil

from tests.integration.instances import Leases
from tests.integration.mission_flight import SWARM

pytestmark = [pytest.mark.sim_only]

ALT_M = 3.0
SPACING_M = 3.0
# Nine drones spawn on a 3 x 3 grid centred on the origin (gcs/fleet/harness.py grid_layout): drone 9 at the north-east
# corner, (3, 3) m. A circle about the origin through that corner puts the silent drone on everybody's path.
SILENT_RADIUS_M = math.hypot(SPACING_M, SPACING_M)


def takeoff_of(drones: int) -> str:
    """A mission's swarm (on a grid SPACING_M apart) and its takeoff to ALT_M."""
    return (f'[swarm]\ndrones = {drones}\nlayout = "grid"\nspacing_m = {SPACING_M}\n\n'
            f'[[steps]]\naction = "takeoff"\nalt_m = {ALT_M}')  # fmt: skip


SILENT_MISSION = f"""
name = "silent_drone_in_the_circle"
description = "drone 9 goes silent (link fault) and holds; the other 8 turn a circle through where it hovers"

{takeoff_of(9)}

[[steps]]
action = "fault"
drone = 9
fault = "link"

[[steps]]
action = "hold"
duration_s = 5.0  # the ground station loses the silent drone (no HEARTBEAT for 3 s) before the circle is planned

[[steps]]
action = "formation"
shape = "circle"
radius_m = {SILENT_RADIUS_M:.3f}
alt_m = {ALT_M}
angular_rate_radps = 0.3
hold_s = 30.0

[[steps]]
action = "land"
"""

MOTOR_MISSION = f"""
name = "rotor_out_of_the_circle"
description = "a circle of 6 turning; drone 3 loses a rotor"

{takeoff_of(6)}

[[steps]]
action = "fault"
drone = 3
fault = "motor"
motor = 1
after_s = 12.0

[[steps]]
action = "formation"
shape = "circle"
radius_m = 4.0
alt_m = {ALT_M}
angular_rate_radps = 0.3
hold_s = 22.0

[[steps]]
action = "land"
"""


OUTAGE_MISSION = f"""
name = "outage_in_the_circle"
description = "a circle of 5 turning; drone 2's links go silent for 5 s, then come back"

{takeoff_of(5)}

[[steps]]
action = "fault"
drone = 2
fault = "link"
for_s = 5.0
after_s = 10.0

[[steps]]
action = "formation"
shape = "circle"
radius_m = 4.0
alt_m = {ALT_M}
angular_rate_radps = 0.2
hold_s = 30.0

[[steps]]
action = "land"
"""
OFFBOARD_CUSTOM_MODE = 6 << 16  # PX4's custom_mode for OFFBOARD (main mode 6)


def fly(tmp_path: Path, mission_text: str, first_instance: int) -> tuple[dict[str, Any], str]:
    """Fly the mission in lockstep; the report's metrics and the supervisor's output."""
    mission = tmp_path / "mission.toml"
    mission.write_text(mission_text)
    report = tmp_path / "report"
    result = subprocess.run(
        [*SWARM, "fly", str(mission), "--lockstep", "--quantum", "8", "--first-instance", str(first_instance),
         "--report", str(report), "--no-forward"],
        capture_output=True, text=True, timeout=400,
    )  # fmt: skip
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    metrics: dict[str, Any] = json.loads((report / "metrics.json").read_text())
    return metrics, result.stdout


@pytest.mark.timeout(420)
def test_a_drone_silenced_by_a_link_fault_in_the_path_of_a_rotating_circle_of_8_is_avoided(
    tmp_path: Path, instances: Leases
) -> None:
    # GIVEN nine drones up, WHEN drone 9's links fail (it flies on, holding, but says nothing) and the other eight
    # turn a circle through the point where it hovers, with default parameters
    first = instances(9)
    metrics, out = fly(tmp_path, SILENT_MISSION, first)
    silent = first + 9  # drone 9's sysid
    # THEN the ground station lost it by its silence, once, and planned the circle over the eight others
    assert [(f["sysid"], f["fault"]) for f in metrics["faults"]] == [(silent, "link")], metrics["faults"]
    assert [x["sysid"] for x in metrics["losses"]] == [silent], metrics["losses"]
    assert metrics["losses"][0]["cause"].startswith("link lost"), metrics["losses"]
    assert len(re.findall(rf"^drone {silent} lost at t=", out, re.M)) == 1, out
    # AND nobody touched it (or anyone else): the cameras found what nobody relayed, and they did avoid it
    assert metrics["collisions"] == 0, metrics["collision_events"]
    assert metrics["avoidance_events"] >= 8, metrics["avoidance_events"]


@pytest.mark.timeout(420)
def test_a_rotor_failure_in_a_rotating_circle_brings_one_drone_down_and_the_others_fly_on(
    tmp_path: Path, instances: Leases
) -> None:
    # GIVEN a circle of six turning WHEN drone 3 loses rotor 1
    first = instances(6)
    metrics, out = fly(tmp_path, MOTOR_MISSION, first)
    victim = first + 3  # drone 3's sysid
    # THEN it falls and breaks on the ground (FLIGHT_TERMINATION): the ground station records one loss, a crash
    assert [(f["sysid"], f["fault"]) for f in metrics["faults"]] == [(victim, "motor 1 off")], metrics["faults"]
    assert [x["sysid"] for x in metrics["losses"]] == [victim], metrics["losses"]
    # (the cause is the drone's first recent warning: the injected failure that led to the impact)
    assert metrics["losses"][0]["cause"] == "crashed: Injected: motor off, instances 1", metrics["losses"]
    assert len(re.findall(rf"^drone {victim} lost at t=", out, re.M)) == 1, out
    assert metrics["losses"][0]["down_ne_m"] is not None, metrics["losses"]
    # AND no drone touched another (the falling body included): the only crash is the victim's own impact
    assert metrics["collisions"] == 0, metrics["collision_events"]
    # AND the five others flew on: their circle (counted over the drones still flying) held, and they landed
    steps = {s["name"]: s for s in metrics["steps"]}
    assert list(steps) == ["takeoff", "circle", "land"], metrics["steps"]
    assert steps["circle"]["start_s"] < metrics["losses"][0]["time_s"] < steps["circle"]["end_s"], metrics
    assert steps["circle"]["formation_rms_m"] < 0.5, steps["circle"]


@pytest.mark.timeout(420)
def test_a_drone_whose_links_come_back_after_an_outage_is_taken_back_into_the_rotating_circle(
    tmp_path: Path, instances: Leases
) -> None:
    # GIVEN a circle of five turning WHEN drone 2's links go silent for 5 s (the drone holds, then its link is back)
    first = instances(5)
    metrics, out = fly(tmp_path, OUTAGE_MISSION, first)
    drone = first + 2  # drone 2's sysid
    assert [(f["sysid"], f["fault"]) for f in metrics["faults"]] == [(drone, "link for 5 s")], metrics["faults"]
    # THEN the ground station lost it for its silence, heard it again 2-3 s later (5 s of silence, of which the
    # first 3 make a loss), and the report lists it as regained, not lost
    assert metrics["losses"] == [], metrics["losses"]
    [regained] = metrics["regained"]
    assert regained["sysid"] == drone and regained["cause"].startswith("link lost"), regained
    assert 1.5 < regained["regained_s"] - regained["time_s"] < 3.0, regained
    assert len(re.findall(rf"^drone {drone} link regained at t=", out, re.M)) == 1, out
    assert re.search(rf"formation re-planned over 5 drones, sysid {drone} back", out), out
    # AND it went back to OFFBOARD after its failsafe took it out of it (its own HEARTBEATs say so)
    log = mavutil.mavlogfile(str(tmp_path / "report" / "flight.tlog"))
    modes: list[int] = []
    while (msg := log.recv_match(type="HEARTBEAT")) is not None:
        if msg.get_srcSystem() == drone and msg.get_srcComponent() == 1 and (not modes or modes[-1] != msg.custom_mode):
            modes.append(msg.custom_mode)
    offboard = [k for k, mode in enumerate(modes) if mode == OFFBOARD_CUSTOM_MODE]
    assert len(offboard) == 2 and offboard[1] - offboard[0] >= 2, modes
    # AND the circle held with it, nobody touched anybody, and everybody landed
    circle = next(s for s in metrics["steps"] if s["kind"] == "formation")
    assert circle["formation_rms_m"] is not None and circle["formation_rms_m"] < 0.3, circle
    assert circle["start_s"] + circle["time_to_formation_s"] > regained["regained_s"], circle
    assert metrics["collisions"] == 0, metrics["collision_events"]
