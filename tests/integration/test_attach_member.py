"""Members: vehicles the simulation does not run, flown in the swarm's formations as a ground station flies them
(docs/external.md). One flight of six simulated drones with four members, each on a link of its own:

- a ``sitl`` started on its own (no shared world: nothing of it reaches the simulated world except through MAVLink),
  a PX4 as far as the ground station can tell, armed and taken off by the swarm (``arm = true``), flown in OFFBOARD;
- a scripted ArduPilot Copter (tests/integration/scripted_vehicle.py ``ScriptedCopter``), armed and taken off in
  GUIDED, flown with SET_POSITION_TARGET_GLOBAL_INT, with a keep-in of 8 m that the second formation's slots leave;
- a second scripted copter that the swarm may not arm, standing on the field: it is never commanded;
- a third, armed and flown by the swarm until its pilot takes it over (LOITER) and climbs it out of the way: it is
  released, never asked back, and the others re-plan without it.

They take off with the drones, fly a rotating circle of eight, then a wider circle (which the copter's keep-in does
not hold: it is put in Hold and released, the others re-plan without it), and when the drones land the members
are put in Hold, never landed or disarmed.

Policy: loopback only (--no-forward); leased instances (tests/integration/instances.py); the members' links on ports
the system picked; paced at 1x (an attached vehicle keeps wall time); every process stopped by PID; time limits.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from gcs.fleet.attachments import MODE_SETTLE_S
from gcs.flight.geodesy import DEFAULT_ORIGIN, GeoPoint, NedFrame
from tests.integration.instances import Leases
from tests.integration.report_page import check_report_page
from tests.integration.scripted_vehicle import ARDUCOPTER_GUIDED, ARDUCOPTER_LOITER, ScriptedCopter, UdpLink
from tests.integration.sitl_process import SitlDrone, start_drone, stop_drone
from tests.integration.test_attach import free_udp_port

pytestmark = [pytest.mark.sim_only]  # the long flights: acceptance, with the machine to themselves (wall_clock)

SWARM = [sys.executable, "-m", "gcs.cli"]
COPTER_SYSID = 251  # sysids no drone of the suite has (tests/integration/instances.py)
GROUNDED_SYSID = 252
PILOTED_SYSID = 253
TAKEOVER_AFTER_SETPOINTS = 60  # the piloted copter's pilot takes it over 6 s into its formation flight
COPTER_KEEP_IN_M = 8.0
SLOT_RMS_M = 0.3  # the bound on a member's distance to its slot once the circle has settled
FRAME = NedFrame(DEFAULT_ORIGIN)
SITL_HOME_NE_M = (-7.0, -7.0)  # where the members stand before takeoff: clear of the drones' grid
COPTER_HOME_NE_M = (5.0, 5.0)  # inside its keep-in
GROUNDED_NE_M = (14.0, -14.0)
PILOTED_HOME_NE_M = (-5.0, 5.0)
MISSION = """
name = "circle_with_members"
[swarm]
drones = 6
spacing_m = 2.5

[[swarm.attach]]
url = "udpin:127.0.0.1:{sitl_port}"
arm = true

[[swarm.attach]]
url = "udpin:127.0.0.1:{copter_port}"
arm = true
keep_in_m = {keep_in}

[[swarm.attach]]
url = "udpin:127.0.0.1:{grounded_port}"

[[swarm.attach]]
url = "udpin:127.0.0.1:{piloted_port}"
arm = true

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "formation"
shape = "circle"
radius_m = 4.5
alt_m = 3.0
angular_rate_radps = 0.3
hold_s = 25.0

[[steps]]
action = "formation"
shape = "circle"
radius_m = 10.0
alt_m = 3.0
hold_s = 12.0

[[steps]]
action = "land"
"""


@dataclass
class Flown:
    result: subprocess.CompletedProcess[str]
    metrics: dict[str, Any]
    tlog: Path
    sitl_sysid: int
    copter: ScriptedCopter
    grounded: ScriptedCopter
    piloted: ScriptedCopter


def _home(north_east: tuple[float, float]) -> str:
    geo = FRAME.geo_from_ned((north_east[0], north_east[1], 0.0))
    return f"{geo.lat_deg:.9f},{geo.lon_deg:.9f},{geo.alt_amsl_m:.3f}"


@pytest.fixture(scope="module")
def flown(tmp_path_factory: pytest.TempPathFactory, module_instances: Leases) -> Iterator[Flown]:
    tmp = tmp_path_factory.mktemp("members")
    first = module_instances(6)
    member_instance = module_instances(1)
    sitl_port, copter_port, grounded_port, piloted_port = (free_udp_port() for _ in range(4))
    mission = tmp / "circle_with_members.toml"
    mission.write_text(MISSION.format(sitl_port=sitl_port, copter_port=copter_port, grounded_port=grounded_port,
                                      piloted_port=piloted_port, keep_in=COPTER_KEEP_IN_M))  # fmt: skip
    member: SitlDrone = start_drone(
        instance=member_instance, speed_factor=1.0, seed=7, log_dir=tmp,
        extra_args=("--gcs-remote", f"127.0.0.1:{sitl_port}", "--home", _home(SITL_HOME_NE_M)),
    )  # fmt: skip
    copter = ScriptedCopter(COPTER_SYSID, UdpLink(copter_port), DEFAULT_ORIGIN, COPTER_HOME_NE_M).start()
    grounded = ScriptedCopter(GROUNDED_SYSID, UdpLink(grounded_port), DEFAULT_ORIGIN, GROUNDED_NE_M).start()
    piloted = ScriptedCopter(PILOTED_SYSID, UdpLink(piloted_port), DEFAULT_ORIGIN, PILOTED_HOME_NE_M,
                             takeover_after_setpoints=TAKEOVER_AFTER_SETPOINTS).start()  # fmt: skip
    try:
        result = subprocess.run(
            [*SWARM, "fly", str(mission), "--first-instance", str(first), "--report", str(tmp / "report"),
             "--no-view", "--no-forward"],
            capture_output=True, text=True, timeout=280,
        )  # fmt: skip
    finally:
        copter.stop()
        grounded.stop()
        piloted.stop()
        stop_drone(member)
    (tmp / "stdout.txt").write_text(result.stdout + result.stderr)  # the whole flight's lines, for a failure's reader
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-3000:]
    metrics = json.loads((tmp / "report" / "metrics.json").read_text())
    yield Flown(result, metrics, tmp / "report" / "flight.tlog", member.sysid, copter, grounded, piloted)


def _setpoint_ned(msg: Any) -> tuple[float, float, float]:
    return FRAME.ned_from_geo(GeoPoint(lat_deg=msg.lat_int * 1e-7, lon_deg=msg.lon_int * 1e-7, alt_amsl_m=msg.alt))


def _heartbeats(tlog: Path, sysid: int) -> list[Any]:
    log = mavutil.mavlink_connection(str(tlog))
    out = []
    try:
        while (msg := log.recv_match(type="HEARTBEAT")) is not None:
            if msg.get_srcSystem() == sysid and msg.get_srcComponent() == 1:
                out.append(msg)
    finally:
        log.close()
    return out


@pytest.mark.acceptance  # a long flight paced at 1x beside a vehicle that keeps wall time...
@pytest.mark.wall_clock  # ...so with the machine to itself (tests/wall_clock.py)
@pytest.mark.timeout(300)
def test_the_px4_member_flies_its_slot_and_is_left_holding_armed(flown: Flown) -> None:
    out = flown.result.stdout
    assert f"attached member sysid {flown.sitl_sysid} on udpin:127.0.0.1:" in out
    # it held its slot of the rotating circle, and nobody touched anything
    assert flown.metrics["collisions"] == 0, flown.metrics["collision_events"]
    member = flown.metrics["attached"][str(flown.sitl_sysid)]
    assert member["role"] == "member"
    assert member["slot_rms_m"] is not None and member["slot_rms_m"] <= SLOT_RMS_M, member
    assert member["min_separation_m"] >= 1.0, member
    # it flew OFFBOARD, and the swarm left it in Hold (AUTO.LOITER), armed: never landed or disarmed by the swarm
    beats = _heartbeats(flown.tlog, flown.sitl_sysid)
    modes = [mavutil.interpret_px4_mode(b.base_mode, b.custom_mode) for b in beats]
    assert "OFFBOARD" in modes, modes
    assert modes[-1] == "LOITER" and beats[-1].base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED, modes[-5:]


@pytest.mark.acceptance  # a long flight paced at 1x beside a vehicle that keeps wall time...
@pytest.mark.wall_clock  # ...so with the machine to itself (tests/wall_clock.py)
@pytest.mark.timeout(300)
def test_the_ardupilot_member_is_armed_in_guided_flown_by_global_setpoints_and_released_at_its_keep_in(
    flown: Flown,
) -> None:
    copter = flown.copter
    out = flown.result.stdout
    # armed and taken off as ArduCopter takes off: GUIDED, arm, NAV_TAKEOFF to 3 m above its home (= the origin's
    # altitude)
    modes = [int(r.msg.param2) for r in copter.commands(mavlink.MAV_CMD_DO_SET_MODE)]
    assert modes[0] == ARDUCOPTER_GUIDED and modes[-1] == ARDUCOPTER_LOITER, modes
    arms = copter.commands(mavlink.MAV_CMD_COMPONENT_ARM_DISARM)
    assert arms and all(r.msg.param1 == 1.0 for r in arms), "the swarm never disarms a member"
    (takeoff,) = copter.commands(mavlink.MAV_CMD_NAV_TAKEOFF)
    assert takeoff.msg.param7 == pytest.approx(3.0)
    # flown with setpoints at most 10 a second, never outside its keep-in
    setpoints = copter.setpoints()
    assert len(setpoints) > 100
    span_s = setpoints[-1].time_s - setpoints[0].time_s
    assert len(setpoints) <= 10.5 * span_s + 1, (len(setpoints), span_s)
    farthest = max(math.hypot(*_setpoint_ned(r.msg)[:2]) for r in setpoints)
    assert farthest <= COPTER_KEEP_IN_M, farthest
    # the wide circle's slot left the keep-in: not sent; the copter was put in LOITER and released, once
    released = [line for line in out.splitlines() if f"member {COPTER_SYSID} released:" in line]
    assert len(released) == 1 and f"outside the keep-in of {COPTER_KEEP_IN_M:g} m" in released[0], out[-3000:]
    assert "asked to hold where it is" in released[0]
    assert copter.mode == ARDUCOPTER_LOITER and copter.armed
    after = [r for r in setpoints if r.time_s > copter.commands(mavlink.MAV_CMD_DO_SET_MODE)[-1].time_s]
    assert not after, "no setpoint after the member was released"
    # while it flew the circle it held its slot as well
    member = flown.metrics["attached"][str(COPTER_SYSID)]
    assert member["slot_rms_m"] is not None and member["slot_rms_m"] <= SLOT_RMS_M, member


@pytest.mark.acceptance  # a long flight paced at 1x beside a vehicle that keeps wall time...
@pytest.mark.wall_clock  # ...so with the machine to itself (tests/wall_clock.py)
@pytest.mark.timeout(300)
def test_the_report_page_replays_the_members_beside_the_drones(flown: Flown) -> None:
    check_report_page(
        flown.tlog.parent, flown.metrics, external=(flown.sitl_sysid, COPTER_SYSID, GROUNDED_SYSID, PILOTED_SYSID)
    )


@pytest.mark.acceptance  # a long flight paced at 1x beside a vehicle that keeps wall time...
@pytest.mark.wall_clock  # ...so with the machine to itself (tests/wall_clock.py)
@pytest.mark.timeout(300)
def test_a_member_the_swarm_may_not_arm_is_never_commanded_and_said_to_be_left_out(flown: Flown) -> None:
    assert not flown.grounded.received, [r.msg.get_type() for r in flown.grounded.received]
    assert not flown.grounded.armed
    assert f"member {GROUNDED_SYSID} is not flying" in flown.result.stdout


FIELD = GeoPoint(lat_deg=DEFAULT_ORIGIN.lat_deg + 0.027, lon_deg=DEFAULT_ORIGIN.lon_deg,
                 alt_amsl_m=DEFAULT_ORIGIN.alt_amsl_m + 25.0)  # fmt: skip  # 3 km north, on a hill 25 m higher
SHORT_FLIGHT = """
name = "hop"
[swarm]
drones = 2
spacing_m = 3.0

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "land"
"""


@pytest.mark.timeout(180)
def test_the_swarms_origin_is_put_at_an_attached_vehicles_home(tmp_path: Path, instances: Leases) -> None:
    # GIVEN a copter standing on a field 3 km from the default origin, 25 m higher (too far for an attach there)
    port = free_udp_port()
    mission = tmp_path / "hop.toml"
    mission.write_text(SHORT_FLIGHT)
    copter = ScriptedCopter(COPTER_SYSID, UdpLink(port), FIELD, (6.0, 0.0)).start()
    try:
        # WHEN a swarm flies with its origin at that copter's home
        result = subprocess.run(
            [*SWARM, "fly", str(mission), "--first-instance", str(instances(2)), "--origin", "attached", "--attach",
             f"intruder=udpin:127.0.0.1:{port}", "--report", str(tmp_path / "report"), "--no-view", "--no-forward"],
            capture_output=True, text=True, timeout=150,
        )  # fmt: skip
    finally:
        copter.stop()
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-2000:]
    # THEN the origin is the home it gave when asked (its HOME_POSITION, 6 m north of the field's centre)
    home = NedFrame(FIELD).geo_from_ned((6.0, 0.0, 0.0))
    said = f"swarm: origin at attached vehicle {COPTER_SYSID}'s home ({home.lat_deg:.7f}, {home.lon_deg:.7f}, "
    assert said in result.stdout, result.stdout[:2000]
    assert copter.commands(mavlink.MAV_CMD_REQUEST_MESSAGE), "its home was asked for"
    # AND the drones flew there, heights above that home: within metres of it, 3 m above it at the top
    log = mavutil.mavlink_connection(str(tmp_path / "report" / "flight.tlog"))
    frame = NedFrame(home)
    heights = []
    try:
        while (msg := log.recv_match(type="GLOBAL_POSITION_INT")) is not None:
            if msg.get_srcSystem() != COPTER_SYSID:
                north, east, down = frame.ned_from_geo(
                    GeoPoint(lat_deg=msg.lat * 1e-7, lon_deg=msg.lon * 1e-7, alt_amsl_m=msg.alt * 1e-3)
                )
                assert math.hypot(north, east) < 10.0
                heights.append(-down)
    finally:
        log.close()
    assert heights and max(heights) == pytest.approx(3.0, abs=0.4)


@pytest.mark.acceptance  # a long flight paced at 1x beside a vehicle that keeps wall time...
@pytest.mark.wall_clock  # ...so with the machine to itself (tests/wall_clock.py)
@pytest.mark.timeout(300)
def test_a_member_its_pilot_takes_over_is_released_and_never_asked_back(flown: Flown) -> None:
    piloted = flown.piloted
    assert piloted.taken_over_s is not None, "it flew its setpoints long enough for its pilot to take it over"
    released = [line for line in flown.result.stdout.splitlines() if f"member {PILOTED_SYSID} released:" in line]
    assert len(released) == 1 and "it is in LOITER, not GUIDED as asked" in released[0], released
    assert "asked to hold" not in released[0]  # its pilot has it: nothing is asked of it
    # nothing asked of it after the takeover, and its setpoints stopped once the swarm saw the new mode (its next
    # HEARTBEAT, within a second, and MODE_SETTLE_S after the last request)
    after = [r for r in piloted.received if r.time_s > piloted.taken_over_s]
    assert not [r for r in after if r.msg.get_type() != "SET_POSITION_TARGET_GLOBAL_INT"], after
    assert not after or after[-1].time_s - piloted.taken_over_s < 1.0 + MODE_SETTLE_S + 0.5
    assert piloted.mode == ARDUCOPTER_LOITER and piloted.armed
