"""Attaching a vehicle the simulation does not run (gcs/fleet/attach.py, gcs/mavlink/urls.py): its URL in both
spellings, the attach spec, the mission table, where its body is put, and which sysids it may not have."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink

from gcs.api.types import LaunchOptions
from gcs.cli import main
from gcs.fleet.attach import (
    AttachedVehicle,
    AttachError,
    ExternalLink,
    TokenBucket,
    last_known_traffic,
    parse_attach,
    role_of,
    sysid_problem,
    traffic_report,
)
from gcs.fleet.attachments import keep_in_problem, on_the_wire
from gcs.flight.behaviours import FollowAttached, FollowAttachedSpec, LeaderReport, SwarmState
from gcs.flight.frames import SwarmFrame
from gcs.flight.geodesy import GeoPoint, NedFrame
from gcs.mavlink.modes import HOLD, OFFBOARD, mode_name, purpose_mode_name, purpose_params
from gcs.mavlink.urls import DEFAULT_BAUD, UrlError, parse_vehicle_url
from gcs.missions.mission_file import FollowAttachedStep, MissionFileError, load_mission
from sitl.avoidance.algorithm import AvoidanceConfig, Obstacle, avoid
from sitl.protocol.neighbours import NeighbourTable


@pytest.mark.parametrize(
    ("url", "device", "kind"),
    [
        ("udpin:0.0.0.0:14560", "udpin:0.0.0.0:14560", "udpin"),
        ("udpin://0.0.0.0:14560", "udpin:0.0.0.0:14560", "udpin"),
        ("udp://0.0.0.0:14560", "udpin:0.0.0.0:14560", "udpin"),
        ("udp:127.0.0.1:14550", "udpin:127.0.0.1:14550", "udpin"),
        ("udpout:10.0.0.2:14550", "udpout:10.0.0.2:14550", "udpout"),
        ("udpout://10.0.0.2:14550", "udpout:10.0.0.2:14550", "udpout"),
        ("tcp:192.168.4.1:5760", "tcp:192.168.4.1:5760", "tcp"),
        ("tcp://192.168.4.1:5760", "tcp:192.168.4.1:5760", "tcp"),
        ("tcpout://192.168.4.1:5760", "tcp:192.168.4.1:5760", "tcp"),
        ("tcpin://0.0.0.0:5760", "tcpin:0.0.0.0:5760", "tcpin"),
        ("/dev/ttyUSB0,57600", "/dev/ttyUSB0,57600", "serial"),
        ("/dev/ttyACM0", f"/dev/ttyACM0,{DEFAULT_BAUD}", "serial"),
        ("serial:///dev/ttyUSB0:921600", "/dev/ttyUSB0,921600", "serial"),
        ("serial:///dev/ttyUSB0", f"/dev/ttyUSB0,{DEFAULT_BAUD}", "serial"),
    ],
)
def test_both_spellings_of_a_vehicle_url_become_pymavlinks(url: str, device: str, kind: str) -> None:
    parsed = parse_vehicle_url(url)
    assert (parsed.device, parsed.kind) == (device, kind)


@pytest.mark.parametrize(
    "url",
    [
        "",
        "14560",
        "udpin:14560",
        "udpin://0.0.0.0",
        "udpin://0.0.0.0:0",
        "udpin:h:99999",
        "http://x:80",
        "serial://",
        "/dev/ttyUSB0,fast",
        "quic://h:1",
    ],
)
def test_anything_else_is_one_line_naming_both_spellings(url: str) -> None:
    with pytest.raises(UrlError) as caught:
        parse_vehicle_url(url)
    text = str(caught.value)
    assert "\n" not in text and repr(url) in text


def test_an_attach_names_its_role_or_takes_the_default_and_refuses_what_it_cannot_do() -> None:
    spec = parse_attach("intruder=udpin://0.0.0.0:14560")
    assert (spec.role, spec.url.device, spec.radius_m) == ("intruder", "udpin:0.0.0.0:14560", None)
    assert parse_attach("INTRUDER=tcp:h:5760", radius_m=0.5).radius_m == 0.5
    with pytest.raises(AttachError, match="no role 'pilot'"):
        parse_attach("pilot=udpin:0.0.0.0:14560")
    # member is the default; only a member is armed by the swarm, and its keep-in is above the floor
    for text in ("udpin:0.0.0.0:14560", "member=udpin:0.0.0.0:14560"):
        assert parse_attach(text).role == "member" and role_of(text) == "member"
        assert not parse_attach(text).arm and parse_attach(text, arm=True).arm
    with pytest.raises(AttachError, match="only a member is armed by the swarm, not a leader"):
        parse_attach("leader=udpin:0.0.0.0:14560", arm=True)
    assert parse_attach("udpin:0.0.0.0:14560", keep_in_m=30.0).keep_in_m == 30.0
    for bad in (0.5, math.nan, math.inf):
        with pytest.raises(AttachError, match="keep-in"):
            parse_attach("udpin:0.0.0.0:14560", keep_in_m=bad)
    with pytest.raises(AttachError, match="radius_m"):
        parse_attach("intruder=udpin:0.0.0.0:14560", radius_m=0.0)
    assert parse_attach("intruder=udpin:0.0.0.0:14560", max_distance_m=50.0).max_distance_m == 50.0
    with pytest.raises(AttachError, match="must be positive"):
        parse_attach("intruder=udpin:0.0.0.0:14560", max_distance_m=-1.0)
    with pytest.raises(AttachError, match="no vehicle URL"):
        parse_attach("intruder=nowhere")


def test_a_missions_attach_tables_are_read_and_a_bad_one_is_named_by_its_line(tmp_path: Path) -> None:
    head = (
        '[swarm]\ndrones = 2\n\n[[swarm.attach]]\nrole = "intruder"\nurl = "udpin:0.0.0.0:14560"\nradius_m = 0.4\n'
        "max_distance_m = 80\n"
    )
    steps = '\n[[steps]]\naction = "takeoff"\nalt_m = 3.0\n'
    good = tmp_path / "good.toml"
    good.write_text(head + steps)
    (spec,) = load_mission(good).swarm.attach
    assert (spec.role, spec.url.device, spec.radius_m, spec.max_distance_m) == (
        "intruder",
        "udpin:0.0.0.0:14560",
        0.4,
        80,
    )
    bad = tmp_path / "bad.toml"
    bad.write_text(head.replace("udpin:0.0.0.0:14560", "udpin:0.0.0.0") + steps)
    with pytest.raises(MissionFileError, match=r"bad.toml:6: swarm.attach\[0\].url"):
        load_mission(bad)
    odd = tmp_path / "odd.toml"
    odd.write_text(head.replace("radius_m = 0.4", "size = 1") + steps)
    with pytest.raises(MissionFileError, match="unknown field"):
        load_mission(odd)
    member = tmp_path / "member.toml"
    member.write_text(head.replace('role = "intruder"', "arm = true\nkeep_in_m = 30") + steps)
    (spec,) = load_mission(member).swarm.attach
    assert (spec.role, spec.arm, spec.keep_in_m) == ("member", True, 30.0)
    for wrong, said in (("arm = 1", "arm: must be true or false"), ("keep_in_m = -3", "keep_in_m")):
        bad.write_text(head.replace('role = "intruder"', wrong) + steps)
        with pytest.raises(MissionFileError, match=said):
            load_mission(bad)
    bad.write_text(head.replace("radius_m = 0.4", "arm = true") + steps)  # an intruder is never armed
    with pytest.raises(MissionFileError, match="only a member is armed by the swarm"):
        load_mission(bad)


def test_a_vehicles_body_is_carried_on_briefly_at_its_velocity_and_stays_put_once_lost() -> None:
    origin = GeoPoint(lat_deg=47.0, lon_deg=8.0, alt_amsl_m=500.0)
    spec = parse_attach("intruder=udpin:0.0.0.0:1")
    vehicle = AttachedVehicle(sysid=42, spec=spec, link=ExternalLink(spec=spec, source_system=255))
    assert vehicle.body_at(1.0) is None  # no position yet
    vehicle.position, vehicle.vel_ned_mps, vehicle.position_s = origin, (2.0, -1.0, -0.5), 10.0
    frame = NedFrame(origin)

    def ned(t_s: float) -> tuple[float, ...]:
        geo = vehicle.body_at(t_s)
        assert geo is not None
        return tuple(frame.ned_from_geo(geo))

    assert ned(10.0) == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)
    assert ned(10.5) == pytest.approx((1.0, -0.5, -0.25), abs=1e-3)
    assert ned(30.0) == pytest.approx((2.0, -1.0, -0.5), abs=1e-3)  # carried on for a second at most
    vehicle.lost = True
    assert ned(30.0) == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)  # where it was last known
    assert math.isfinite(ned(1e6)[0])


def test_a_vehicle_may_not_take_a_simulated_drones_sysid_nor_the_ground_stations_nor_one_attached() -> None:
    simulated, attached = dict.fromkeys((21, 22)), {30: object()}
    assert sysid_problem(40, simulated, attached, 255) is None
    assert "ground station's own" in (sysid_problem(255, simulated, attached, 255) or "")
    assert "simulated drone's" in (sysid_problem(22, simulated, attached, 255) or "")
    assert "attached already" in (sysid_problem(30, simulated, attached, 255) or "")


def test_an_intruders_position_reaches_the_drones_as_traffic_they_avoid_in_full() -> None:
    # GIVEN an intruder's GLOBAL_POSITION_INT (sysid 250, 1.5 m/s north-east, climbing 0.3 m/s)
    position = mavlink.MAVLink_global_position_int_message(1000, 473977420, 85455940, 491_000, 3_000, 106, 106, -30, 0)
    position.pack(mavlink.MAVLink(None, srcSystem=250, srcComponent=1))
    report = traffic_report(position)
    # WHEN the ground station relays it as traffic and a drone's neighbour table reads it
    frame = report.pack(mavlink.MAVLink(None, srcSystem=255, srcComponent=190))
    received = mavlink.MAVLink(None).parse_char(frame)
    table = NeighbourTable(own_sysid=21)
    table.handle(received, 10.0)
    # THEN the drone knows it as traffic, where it is and how it moves (to the centimetre per second)
    (entry,) = table.entries(10.0)
    assert (entry.sysid, entry.cooperative) == (250, False)
    assert (entry.lat_deg, entry.lon_deg, entry.alt_amsl_m) == pytest.approx((47.397742, 8.545594, 491.0))
    assert entry.vel_ned_mps == pytest.approx((1.06, 1.06, -0.30), abs=0.01)
    # AND a report saying nothing of where the vehicle is, or about the drone itself, is not taken
    blind = traffic_report(position)
    blind.flags = 0
    other = NeighbourTable(own_sysid=250)
    for table_, msg in ((NeighbourTable(own_sysid=21), blind), (other, report)):
        table_.handle(mavlink.MAVLink(None).parse_char(msg.pack(mavlink.MAVLink(None, srcSystem=255))), 10.0)
        assert table_.entries(10.0) == []
    # AND collision prevention takes the whole manoeuvre for traffic, half of it for a neighbour that avoids too
    head_on = dict(rel_pos_ned_m=(4.0, 0.0, 0.0), vel_ned_mps=(-1.0, 0.0, 0.0), vel_known=True)
    neighbour = avoid((1.0, 0.0, 0.0), (1.0, 0.0, 0.0), [Obstacle(**head_on, source="relay")], AvoidanceConfig())
    traffic = avoid((1.0, 0.0, 0.0), (1.0, 0.0, 0.0), [Obstacle(**head_on, source="traffic")], AvoidanceConfig())
    sideways = (abs(neighbour.vel_ned_mps[1]), abs(traffic.vel_ned_mps[1]))
    assert traffic.active and sideways[1] > 1.5 * sideways[0] > 0.0, (neighbour, traffic)


def test_a_silent_vehicle_reaches_the_drones_where_it_was_last_known_with_the_age_of_that_knowledge() -> None:
    where = GeoPoint(lat_deg=47.397742, lon_deg=8.545594, alt_amsl_m=491.0)
    table = NeighbourTable(own_sysid=21)
    for now_s, age_s in ((20.0, 5.4), (21.0, 6.5), (22.0, 400.0)):  # its tslc whole seconds, 255 at most
        report = last_known_traffic(250, where, age_s)
        table.handle(mavlink.MAVLink(None).parse_char(report.pack(mavlink.MAVLink(None, srcSystem=255))), now_s)
        (entry,) = table.entries(now_s)
        # each report replaces the last (its time, now less whole seconds, may step back by a fraction)
        assert (entry.cooperative, entry.stale_s, entry.received_s) == (False, min(255, math.floor(age_s)), now_s)
        assert entry.vel_ned_mps == (0.0, 0.0, 0.0)
        assert (entry.lat_deg, entry.lon_deg, entry.alt_amsl_m) == pytest.approx((47.397742, 8.545594, 491.0))


def test_the_python_api_takes_attaches_as_swarm_up_does_and_checks_them_before_anything_starts() -> None:
    assert LaunchOptions(drones=2, lockstep=False, attach=["intruder=udpin:0.0.0.0:14560"]).attach == [
        "intruder=udpin:0.0.0.0:14560"
    ]
    # arm_external arms the members, and only them (as --arm-external)
    both = ["udpin:0.0.0.0:14560", "leader=udpin:0.0.0.0:14561"]
    specs = LaunchOptions(drones=2, lockstep=False, attach=both, arm_external=True).attach_specs()
    assert [(s.role, s.arm) for s in specs] == [("member", True), ("leader", False)]
    assert not any(s.arm for s in LaunchOptions(drones=2, lockstep=False, attach=both).attach_specs())
    for options, said in (
        (dict(attach=["intruder=udpin:0.0.0.0:14560"]), "pass lockstep=False"),  # lockstep is the API's default
        (dict(lockstep=False, speed=2.0, attach=["intruder=udpin:0.0.0.0:14560"]), "runs paced at speed 1"),
        (dict(lockstep=False, attach="intruder=udpin:0.0.0.0:14560"), "takes a list"),
        (dict(lockstep=False, attach=["intruder=nowhere"]), "no vehicle URL"),
    ):
        with pytest.raises(ValueError, match=said):
            LaunchOptions(drones=2, **options)  # type: ignore[arg-type]


def test_a_sweep_of_a_mission_with_an_attached_vehicle_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    mission = tmp_path / "with_intruder.toml"
    mission.write_text(
        '[swarm]\ndrones = 2\n\n[[swarm.attach]]\nrole = "intruder"\nurl = "udpin:127.0.0.1:14560"\n\n'
        '[[steps]]\naction = "takeoff"\nalt_m = 3.0\n'
    )
    assert main(["sweep", str(mission), "--seeds", "1-2", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "a sweep's runs are lockstep flights of simulated drones alone" in err, err
    assert not (tmp_path / "out").exists()


def test_the_supervisors_own_sysid_is_settable_but_never_a_drones(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["up", "-n", "4", "--first-instance", "0", "--gcs-sysid", "3", "--no-view"]) == 2
    assert capsys.readouterr().err == "swarm: error: --gcs-sysid 3 is a drone's (sysids 1..4)\n"
    assert main(["up", "-n", "1", "--gcs-sysid", "256", "--no-view"]) == 2
    assert "must be a sysid in 1..255" in capsys.readouterr().err
    assert LaunchOptions(drones=2, gcs_sysid=200).gcs_sysid == 200
    with pytest.raises(ValueError, match=r"gcs_sysid must be in 1\.\.255 and no drone's, got 2"):
        LaunchOptions(drones=2, gcs_sysid=2)


def test_a_links_signing_key_comes_from_the_mission_beside_it_and_a_missing_one_is_one_line(tmp_path: Path) -> None:
    mission = tmp_path / "signed.toml"
    mission.write_text(
        '[swarm]\ndrones = 2\n\n[[swarm.attach]]\nrole = "intruder"\nurl = "udpin:127.0.0.1:1"\n'
        'signing_key = "keys/radio.key"\n\n[[steps]]\naction = "takeoff"\nalt_m = 3.0\n'
    )
    (spec,) = load_mission(mission).swarm.attach
    assert spec.signing_key_file == tmp_path / "keys" / "radio.key"
    with pytest.raises(AttachError, match="cannot read signing key file") as caught:
        ExternalLink(spec=spec, source_system=255).open()  # nothing opened: the key is read first
    assert "\n" not in str(caught.value)


def test_followers_of_an_attached_leader_take_the_nearest_offsets_turn_with_its_course_and_hold_when_it_is_silent() -> (
    None
):
    # GIVEN a leader at the origin flying east at 1 m/s, and two followers west of it, one north, one south
    report: list[LeaderReport | None] = [LeaderReport(pos_ned_m=(0.0, 0.0, -3.0), vel_ned_mps=(0.0, 1.0, 0.0))]
    state = SwarmState.from_mappings({21: (2.0, -3.0, -3.0), 22: (-2.0, -3.0, -3.0)},
                                     {21: (0.0, 0.0, 0.0), 22: (0.0, 0.0, 0.0)})  # fmt: skip
    law = FollowAttached(FollowAttachedSpec(alt_m=3.0, duration_s=10.0, spacing_m=2.0), lambda: report[0], 0.0, state)
    # WHEN asked for setpoints
    setpoints = law.setpoints(0.1, state)
    # THEN each follower is behind the leader in a V facing east, on its own side, moving with the leader
    north_21, east_21, down_21 = setpoints[21].pos_ned_m
    north_22, east_22, _ = setpoints[22].pos_ned_m
    assert east_21 < 0.0 and east_22 < 0.0 and north_21 > 0.0 > north_22 and down_21 == -3.0
    assert north_21 == pytest.approx(-north_22) and math.hypot(north_21, east_21) == pytest.approx(2.0)
    assert setpoints[21].vel_ned_mps == pytest.approx((0.0, 1.0, 0.0))
    # AND with the leader silent they hold their last slots
    report[0] = None
    held = law.setpoints(0.2, state)
    assert held[21].pos_ned_m == setpoints[21].pos_ned_m and held[21].vel_ned_mps == (0.0, 0.0, 0.0)


def test_a_mission_names_the_attached_leader_step_and_a_leader_role_is_taken(tmp_path: Path) -> None:
    assert parse_attach("leader=udpin:0.0.0.0:14560").role == "leader"
    mission = tmp_path / "follow.toml"
    text = ('[swarm]\ndrones = 3\n\n[[steps]]\naction = "takeoff"\nalt_m = 3.0\n\n[[steps]]\naction = '
            '"follow_attached"\nalt_m = 3.0\nduration_s = 30\nspacing_m = 3\n')  # fmt: skip
    mission.write_text(text)
    step = load_mission(mission).steps[1]
    assert isinstance(step, FollowAttachedStep) and (step.spec.duration_s, step.spec.spacing_m) == (30.0, 3.0)
    mission.write_text(text.replace("duration_s = 30\n", ""))
    with pytest.raises(MissionFileError, match="missing field 'duration_s'"):
        load_mission(mission)


def test_a_links_budget_gives_its_rate_on_average_and_its_burst_at_once() -> None:
    bucket = TokenBucket(rate_per_s=20.0, burst=20.0)
    assert sum(bucket.take(0.0) for _ in range(50)) == 20  # a full burst at the start, then nothing
    assert not bucket.take(0.01)
    taken = sum(bucket.take(1.0 + k * 0.001) for k in range(10_000))  # asked 1,000 times a second for 10 s
    assert 200 <= taken <= 221  # 20 a second, plus what had built up since the burst


def test_a_members_keep_in_is_a_cylinder_around_the_origin_above_its_floor() -> None:
    assert keep_in_problem((30.0, 40.0, -10.0), 100.0) is None
    assert "50.0 m from the origin, outside the keep-in of 40 m" in str(keep_in_problem((30.0, 40.0, -10.0), 40.0))
    assert "above the keep-in's 20 m" in str(keep_in_problem((0.0, 0.0, -25.0), 20.0))
    assert "below the keep-in's floor" in str(keep_in_problem((0.0, 0.0, -0.2), 20.0))
    assert keep_in_problem((math.nan, 0.0, -3.0), 20.0) == "not a finite point"


def test_the_keep_in_judges_a_setpoint_as_the_member_reads_it_in_1e7_degree_steps() -> None:
    frame = SwarmFrame(GeoPoint(lat_deg=47.397742, lon_deg=8.545594, alt_amsl_m=488.0))
    slots = [(7.9995 * math.cos(k * 0.01), 7.9995 * math.sin(k * 0.01), -3.0) for k in range(629)]
    read = [on_the_wire(frame, slot) for slot in slots]
    # every slot is inside an 8 m keep-in, but some reach the member outside it: those are the ones refused
    assert all(keep_in_problem(slot, 8.0) is None for slot in slots)
    outside = [ned for _, ned in read if keep_in_problem(ned, 8.0) is not None]
    assert outside and all(math.hypot(n, e) > 8.0 for n, e, _ in outside)
    for (lat_e7, lon_e7, alt_amsl_m), ned in read:  # and the point read back is the one on the wire
        back = frame.geo_from_ned(ned)
        assert (round(back.lat_deg * 1e7), round(back.lon_deg * 1e7)) == (lat_e7, lon_e7)
        assert alt_amsl_m == pytest.approx(491.0)


@pytest.mark.parametrize(
    ("autopilot", "purpose", "params", "name"),
    [
        (mavlink.MAV_AUTOPILOT_PX4, OFFBOARD, (1.0, 6.0, 0.0), "OFFBOARD"),
        (mavlink.MAV_AUTOPILOT_PX4, HOLD, (29.0, 4.0, 3.0), "AUTO.LOITER"),
        (mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, OFFBOARD, (1.0, 4.0, 0.0), "GUIDED"),
        (mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, HOLD, (1.0, 5.0, 0.0), "LOITER"),
    ],
)
def test_each_autopilot_is_asked_for_its_own_mode_and_read_back_under_its_name(
    autopilot: int, purpose: str, params: tuple[float, float, float], name: str
) -> None:
    """PX4 and ArduPilot Copter through pymavlink's mappings: what DO_SET_MODE asks, and how HEARTBEAT reads back."""
    assert purpose_params(purpose, autopilot) == params
    assert purpose_mode_name(purpose, autopilot) == name
    custom = int(params[1]) << 16 | int(params[2]) << 24 if autopilot == mavlink.MAV_AUTOPILOT_PX4 else int(params[1])
    assert mode_name(custom, autopilot, mavlink.MAV_TYPE_QUADROTOR) == name
    assert mode_name(99, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA) == "custom 99"
