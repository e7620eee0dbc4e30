"""Losing a drone, on the ground station's side (pure parts): the survivors re-plan, a leader hands over, faults
and loss policies are read from mission files and the command line, and the report counts only drones still
flying."""

from __future__ import annotations

import math
import signal
from pathlib import Path

import numpy as np
import pytest

from gcs.cli import main as swarm_main
from gcs.fleet.faults import FAULT_NAMES, FAULTS, FaultError, fault_request
from gcs.fleet.liveness import crash_cause
from gcs.fleet.losses import WRECK_CLEARANCE_M, DroneLoss, LossPolicy, landing_clear_of, loss_line
from gcs.flight.behaviours import FollowSpec, LeaderFollower, SwarmState
from gcs.flight.formation import CircleSpec, FormationEngine, TransitionLimits, min_pairwise_distance_m
from gcs.missions.mission_file import FaultStep, MissionFileError, parse_mission
from gcs.record.metrics import compute_metrics
from gcs.record.recording import DroneSample, FlightRecording, StepRecord
from gcs.supervisor.station import failsafe_text, format_status
from gcs.view.report import summary_text
from sitl.harness import process_exit_cause

LIMITS = TransitionLimits(max_speed_mps=1.5, max_accel_mps2=1.0)


def _ring(n: int, radius_m: float, alt_m: float = 3.0) -> dict[int, tuple[float, float, float]]:
    return {
        k + 1: (radius_m * math.cos(2 * math.pi * k / n), radius_m * math.sin(2 * math.pi * k / n), -alt_m)
        for k in range(n)
    }


# ---- formations re-planned over the survivors -----------------------------------------------------------------------
def test_a_rotating_circle_of_6_that_loses_a_drone_re_forms_a_circle_of_5_without_close_approach() -> None:
    # GIVEN six drones settled on a circle of radius 4 m turning at 0.3 rad/s
    circle = CircleSpec(radius_m=4.0, alt_m=3.0, angular_rate_radps=0.3)
    engine = FormationEngine(LIMITS)
    transition = engine.command(circle, 0.0, _ring(6, 4.0))
    now = transition.arrival_s + 10.0
    flying = {d: sp.pos_ned_m for d, sp in engine.setpoints(now).items()}
    # WHEN drone 3 is lost and the same formation is commanded over the five others (as the streamer does)
    del flying[3]
    replanned = engine.command(circle, now, flying)
    # THEN the five end evenly spaced on the same circle (a regular pentagon: sides 2 R sin 36 deg = 4.70 m)...
    assert set(replanned.slot_of_drone) == {1, 2, 4, 5, 6}
    end = engine.sample_ned_m([replanned.arrival_s + 1.0])[0]
    radii = np.linalg.norm(end[:, :2], axis=1)
    assert np.allclose(radii, 4.0, atol=1e-6)
    assert min_pairwise_distance_m(end) == pytest.approx(2 * 4.0 * math.sin(math.pi / 5), abs=1e-6)
    # ...turning with the formation, and nobody came closer than the hexagon's side (4 m) / sqrt 2 on the way
    assert engine.planned_min_separation_m(after_arrival_s=5.0) > 4.0 / math.sqrt(2.0)
    # AND the transition starts where the survivors are, at their speed (no jump in any setpoint)
    start = engine.setpoints(now)
    for drone, pos in flying.items():
        assert np.linalg.norm(np.subtract(start[drone].pos_ned_m, pos)) < 1e-3


def test_a_lost_follower_leaves_the_others_on_their_slots_and_a_lost_leader_hands_over_to_the_next() -> None:
    # GIVEN four drones on a line, drone 1 leading towards (20, 0) then (20, 20)
    spec = FollowSpec(waypoints_ne_m=((20.0, 0.0), (20.0, 20.0)), alt_m=3.0, leader_sysid=1)
    pos = np.array([[0.0, 0.0, -3.0], [0.0, 3.0, -3.0], [0.0, 6.0, -3.0], [0.0, 9.0, -3.0]])
    state = SwarmState(sysids=(1, 2, 3, 4), pos_ned_m=pos, vel_ned_mps=np.zeros((4, 3)))
    behaviour = LeaderFollower(spec, 0.0, state, LIMITS)
    # WHEN follower 4 is lost
    same = behaviour.without(4, 1.0, SwarmState(sysids=(1, 2, 3), pos_ned_m=pos[:3], vel_ned_mps=np.zeros((3, 3))),
                             LIMITS)  # fmt: skip
    # THEN the flight goes on with the same leader, without setpoints for drone 4
    assert same is behaviour and same.leader == 1 and same.followers == (2, 3)
    assert 4 not in same.setpoints(2.0, state)
    # WHEN the leader is lost once its reference passed the first waypoint
    t = behaviour.depart_s + behaviour.path.duration_s * 0.75
    rest = SwarmState(sysids=(2, 3), pos_ned_m=np.array([[20.0, 3.0, -3.0], [20.0, 6.0, -3.0]]),
                      vel_ned_mps=np.zeros((2, 3)))  # fmt: skip
    handed = behaviour.without(1, t, rest, LIMITS)
    # THEN the next follower leads, through the waypoint not yet reached only, and the other follows it
    assert handed.leader == 2 and handed.followers == (3,)
    assert handed.spec.waypoints_ne_m == ((20.0, 20.0),)
    assert set(handed.setpoints(t + 0.1, rest)) == {2, 3}


def test_the_last_waypoint_always_remains_for_a_new_leader() -> None:
    spec = FollowSpec(waypoints_ne_m=((10.0, 0.0),), alt_m=3.0, leader_sysid=1)
    pos = np.array([[0.0, 0.0, -3.0], [0.0, 3.0, -3.0]])
    behaviour = LeaderFollower(spec, 0.0, SwarmState(sysids=(1, 2), pos_ned_m=pos, vel_ned_mps=np.zeros((2, 3))),
                               LIMITS)  # fmt: skip
    assert behaviour.path.remaining_waypoints(spec.waypoints_ne_m, 1e6) == ((10.0, 0.0),)


# ---- losses and faults as words -------------------------------------------------------------------------------------
def test_a_loss_is_one_line_naming_the_signal_or_exit_code() -> None:
    assert process_exit_cause(-signal.SIGKILL) == "process killed by SIGKILL"
    assert process_exit_cause(1) == "process exited with code 1"
    loss = DroneLoss(sysid=3, time_s=22.43, cause=process_exit_cause(-9))
    assert loss_line(loss) == "drone 3 lost at t=22.4 s: process killed by SIGKILL"


def test_faults_map_to_px4_failure_units_and_types() -> None:
    assert (FAULTS["motor"].unit, FAULTS["motor"].failure_type) == (101, 1)
    assert (FAULTS["gps-glitch"].unit, FAULTS["gps-glitch"].failure_type) == (4, 4)
    assert (FAULTS["battery-critical"].unit, FAULTS["battery-critical"].battery_level) == (100, 2)
    assert (FAULTS["link"].unit, FAULTS["link"].failure_type) == (105, 1)
    assert fault_request("motor", 3).instance == 3
    assert fault_request("motor").instance == 1
    assert fault_request("gps").instance == 0
    with pytest.raises(FaultError, match="unknown fault 'engine'"):
        fault_request("engine")
    with pytest.raises(FaultError, match="only to the motor fault"):
        fault_request("gps", 2)
    with pytest.raises(FaultError, match=r"motor must be a whole number in 0\.\.8"):
        fault_request("motor", 9)
    # a link fault for a time: INJECT_FAILURE param4, the simulator's own (0, PX4's unused value: for good)
    assert (fault_request("link", for_s=6).duration_param, fault_request("link").duration_param) == (6.0, 0.0)
    assert fault_request("link", for_s=6.5).describe() == "link for 6.5 s"
    with pytest.raises(FaultError, match="a duration applies only to the link fault, not to 'gps'"):
        fault_request("gps", for_s=3.0)
    for bad in (0.0, -2.0, math.inf, math.nan, True, "6"):
        with pytest.raises(FaultError, match="link fault's duration must be a number of seconds"):
            fault_request("link", for_s=bad)


# ---- mission files --------------------------------------------------------------------------------------------------
MISSION = """\
name = "t"
[swarm]
drones = 4
loss_policy = "land"

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "fault"
drone = 2
fault = "motor"
motor = 3
after_s = 5.0

[[steps]]
action = "fault"
drone = 4
fault = "crash"

[[steps]]
action = "fault"
drone = 3
fault = "link"
for_s = 6.0

[[steps]]
action = "land"
"""


def test_fault_steps_and_the_loss_policy_are_read() -> None:
    mission = parse_mission(MISSION, Path("m.toml"))
    assert mission.loss_policy is LossPolicy.LAND
    faults = [s for s in mission.steps if isinstance(s, FaultStep)]
    assert [(f.drone, f.fault.kind, f.fault.motor, f.after_s) for f in faults] == [
        (2, "motor", 3, 5.0),
        (4, "crash", 1, 0.0),
        (3, "link", 1, 0.0),
    ]
    assert faults[2].fault.for_s == 6.0


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        ("drone = 2", "drone = 7", "m.toml:12: steps[1].drone: must be one of the swarm's drones 1..4, got 7"),
        ('fault = "motor"', 'fault = "rotor"', "m.toml:13: steps[1].fault: unknown fault 'rotor'"),
        ("motor = 3", "motor = 12", "m.toml:14: steps[1].motor: motor must be a whole number in 0..8"),
        ("after_s = 5.0", "after_s = -1.0", "m.toml:15: steps[1].after_s: must be >= 0, got -1.0"),
        ("after_s = 5.0", 'after_s = "soon"', "m.toml:15: steps[1].after_s: must be a number, got 'soon'"),
        ("drone = 2\n", "", "steps[1]: missing field 'drone' for a fault step"),
        ("for_s = 6.0", "for_s = -6.0", "m.toml:26: steps[3].for_s: a link fault's duration must be a number"),
        ("motor = 3", "motor = 3\nfor_s = 2.0", "m.toml:15: steps[1].for_s: a duration applies only to the link"),
        ('loss_policy = "land"', 'loss_policy = "panic"', "m.toml:4: swarm.loss_policy: must be one of continue"),
    ],
)
def test_fault_step_mistakes_are_one_line_naming_file_line_and_field(old: str, new: str, expected: str) -> None:
    with pytest.raises(MissionFileError) as info:
        parse_mission(MISSION.replace(old, new, 1), Path("m.toml"))
    assert expected in str(info.value)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["fault", "3", "engine"], "argument KIND: invalid choice: 'engine'"),
        (["fault", "three", "motor"], "argument sysid: must be a drone's sysid"),
        (["fault", "3", "gps", "--motor", "2"], "a motor number applies only to the motor fault"),
        (["fault", "3", "motor", "--motor", "9"], "motor must be a whole number in 0..8"),
        (["fault", "3", "gps", "--for", "5"], "a duration applies only to the link fault, not to 'gps'"),
        (["fault", "3", "link", "--for", "0"], "link fault's duration must be a number of seconds in (0, 86400]"),
        (["fault", "3", "link", "--for", "soon"], "argument --for: invalid float value: 'soon'"),
        (["kill", "0"], "argument sysid: must be a sysid in 1..255"),
        (["up", "-n", "2", "--loss-policy", "panic"], "argument --loss-policy: invalid choice: 'panic'"),
    ],
)
def test_bad_fault_commands_give_one_line_and_exit_code_2_before_anything_is_sent(
    args: list[str], fragment: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setenv("SWARM_STATE_DIR", str(tmp_path))  # no supervisor: anything sent would fail with code 1
    assert swarm_main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("swarm: error: ") and fragment in err[0], err


# ---- the report -----------------------------------------------------------------------------------------------------
def test_the_report_lists_the_loss_and_counts_formation_metrics_over_the_drones_still_flying() -> None:
    # GIVEN two drones in a formation step; drone 2 is lost at t = 5 s and its last report stays far off its slot
    recording = FlightRecording(mission_name="t", n_drones=2, collision_radius_m=0.5)
    for k in range(101):
        t = 0.1 * k
        recording.samples.append(DroneSample(time_s=t, sysid=1, pos_ned_m=(0.0, 0.0, -3.0), vel_ned_mps=(0, 0, 0),
                                             armed=True, mode="OFFBOARD", target_ned_m=(0.0, 0.0, -3.0)))  # fmt: skip
        off = 0.0 if t < 5.0 else 3.0 * (t - 5.0)  # falling away after the loss
        recording.samples.append(DroneSample(time_s=t, sysid=2, pos_ned_m=(0.0, 4.0, -3.0 + off),
                                             vel_ned_mps=(0, 0, 0), armed=True, mode="OFFBOARD",
                                             target_ned_m=(0.0, 4.0, -3.0)))  # fmt: skip
    recording.steps.append(StepRecord(index=0, name="circle", kind="formation", start_s=0.0, end_s=10.0))
    recording.losses.append(DroneLoss(sysid=2, time_s=5.0, cause="process killed by SIGKILL", down_ne_m=(0.1, 4.2)))
    # WHEN the metrics are computed
    metrics = compute_metrics(recording)
    # THEN drone 2's fall does not count as formation error, and the loss is in the summary and the JSON
    assert metrics.steps[0].max_error_m == pytest.approx(0.0, abs=1e-9)
    text = summary_text(metrics)
    assert "drones lost: 1 (loss policy: continue)" in text
    assert "drone 2: process killed by SIGKILL; down at 0.1 m N, 4.2 m E" in text
    assert metrics.to_dict()["losses"] == [
        {"sysid": 2, "time_s": 5.0, "cause": "process killed by SIGKILL", "down_ne_m": [0.1, 4.2]}
    ]


def test_a_silent_drone_heard_again_counts_out_of_the_formation_only_while_it_was_lost() -> None:
    # GIVEN two drones in a formation step; drone 2 is lost for silence from 4 s to 7 s, off its slot meanwhile
    recording = FlightRecording(mission_name="t", n_drones=2, collision_radius_m=0.5)
    for k in range(101):
        t = 0.1 * k
        off = 2.0 if 4.0 <= t < 7.0 else 0.0
        for sysid, east in ((1, 0.0), (2, 4.0)):
            recording.samples.append(DroneSample(time_s=t, sysid=sysid, pos_ned_m=(0.0, east + off * (sysid == 2),
                                                 -3.0), vel_ned_mps=(0, 0, 0), armed=True, mode="OFFBOARD",
                                                 target_ned_m=(0.0, east, -3.0)))  # fmt: skip
    recording.steps.append(StepRecord(index=0, name="circle", kind="formation", start_s=0.0, end_s=10.0))
    recording.regained.append(DroneLoss(sysid=2, time_s=4.0, cause="link lost (nothing heard for 3.0 s)",
                                        silent=True, regained_s=7.0))  # fmt: skip
    # WHEN the metrics are computed
    metrics = compute_metrics(recording)
    # THEN its time away is no formation error, it counts again once back, and the summary and JSON say so
    assert metrics.steps[0].max_error_m == pytest.approx(0.0, abs=1e-9)
    assert metrics.distance_flown_m[2] == pytest.approx(0.0, abs=1e-9)
    text = summary_text(metrics)
    assert "drones lost: 0, 1 more heard again (loss policy: continue)" in text
    assert "drone 2: link lost (nothing heard for 3.0 s); regained at 7.0 s" in text
    assert metrics.to_dict()["regained"] == [
        {"sysid": 2, "time_s": 4.0, "cause": "link lost (nothing heard for 3.0 s)", "down_ne_m": None,
         "regained_s": 7.0}
    ]  # fmt: skip


def test_a_crash_is_blamed_on_the_first_recent_warning_not_on_its_consequences() -> None:
    texts = [(1.0, 4, "Low battery: 30% remaining"), (20.0, 2, "Collision with drone 2 at 0.61 m"),
             (20.0, 2, "Motors stopped: crashed"), (20.5, 6, "Landing detected")]  # fmt: skip
    assert crash_cause(texts, 21.0) == "crashed: Collision with drone 2 at 0.61 m"
    assert crash_cause(texts[:1], 21.0) == "crashed"  # a warning long before is about something else


def test_status_shows_a_lost_drone_and_an_active_failsafe() -> None:
    rows = [
        {"sysid": 203, "mode": "LOST", "detail": "t=5.1 s: process killed by SIGKILL"},
        {"sysid": 204, "mode": "AUTO.LAND", "armed": True, "lat_deg": 47.0, "lon_deg": 8.0, "alt_m": 2.0,
         "battery": 0.1, "link_age_s": 0.2, "failsafe": failsafe_text(5, [(3.0, 2, "Critical battery level!")])},
        {"sysid": 205, "mode": "OFFBOARD", "armed": True, "lat_deg": 47.0, "lon_deg": 8.0, "alt_m": 3.0,
         "battery": 0.9, "link_age_s": 0.2, "failsafe": failsafe_text(4, [(3.0, 2, "Critical battery level!")])},
    ]  # fmt: skip
    lines = format_status(rows).splitlines()
    assert lines[1].split() == ["203", "LOST", "t=5.1", "s:", "process", "killed", "by", "SIGKILL"]
    assert lines[2].endswith("FAILSAFE: Critical battery level!")
    assert "FAILSAFE" not in lines[3]  # ACTIVE, no failsafe: an old warning is no failsafe


def test_swarm_fly_with_a_bad_fault_step_is_one_line_and_exit_code_2_before_anything_flies(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(MISSION.replace('fault = "crash"', 'fault = "meteor"'))
    assert swarm_main(["fly", str(path), "--report", str(tmp_path / "report")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    names = ", ".join(FAULT_NAMES)
    assert err == [f"swarm: error: {path}:20: steps[2].fault: unknown fault 'meteor' (faults: {names})"]
    assert not (tmp_path / "report").exists()


def test_swarm_up_report_with_an_unknown_airframe_is_one_line_and_exit_code_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["up", "-n", "1", "--report", str(tmp_path / "r"), "--airframe", "no_such_frame", "--no-forward"]
    assert swarm_main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("swarm: error: ") and "no_such_frame" in err[0], err


def test_swarm_fly_with_an_unknown_airframe_is_one_line_and_exit_code_2_before_anything_flies(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "m.toml"
    path.write_text(MISSION)
    args = ["fly", str(path), "--report", str(tmp_path / "report"), "--airframe", "no_such_frame", "--no-forward"]
    assert swarm_main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("swarm: error: ") and "no such airframe file" in err[0], err
    assert not (tmp_path / "report").exists()


def test_a_survivor_lands_clear_of_every_wreck_and_straight_down_when_nothing_is_near() -> None:
    # GIVEN a wreck at the origin
    wrecks = [(0.0, 0.0)]
    # THEN a drone 3 m away lands where it is
    assert landing_clear_of((3.0, 0.0), wrecks) is None
    # AND one 0.5 m east of it moves straight away to the clearance, one right above it goes north
    assert landing_clear_of((0.0, 0.5), wrecks) == pytest.approx((0.0, WRECK_CLEARANCE_M))
    assert landing_clear_of((0.0, 0.0), wrecks) == pytest.approx((WRECK_CLEARANCE_M, 0.0))
    # AND between two wrecks 2 m apart, the point found is clear of both
    two = [(0.0, 0.0), (0.0, 2.0)]
    spot = landing_clear_of((0.0, 0.9), two)
    assert spot is not None
    assert all(math.hypot(spot[0] - n, spot[1] - e) >= WRECK_CLEARANCE_M - 1e-9 for n, e in two), spot
