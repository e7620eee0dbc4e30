"""``swarm fly`` end to end with real processes: a 4-drone mission, its report, and mission-file errors.

Policy: loopback only; leased instances (tests/integration/instances.py); a time limit on every test. That no
process outlives the supervisor is tested in test_swarm.py.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink import mavutil

from gcs.fleet.clock import LOCKSTEP_STALL_S
from tests.integration.instances import Leases
from tests.integration.mission_flight import mission_drones
from tests.integration.test_swarm import children_of

pytestmark = [pytest.mark.sim_only]

MISSIONS = Path(__file__).resolve().parents[2] / "missions"
SWARM = [sys.executable, "-m", "gcs.cli"]


@pytest.mark.timeout(240)
@pytest.mark.parametrize("per_process", ["1", "2"], ids=["process-per-drone", "hosted"])
def test_four_drone_mission_flies_end_to_end_and_writes_a_report(
    tmp_path: Path, instances: Leases, per_process: str
) -> None:
    # GIVEN the 4-drone mission (each drone in its own process, or two to a process)
    report = tmp_path / "report"
    first = instances(mission_drones(MISSIONS / "square_four.toml"))
    # WHEN it is flown in lockstep, as fast as the machine goes: what it flies then does not depend on the machine's
    # load (free-running at 3x, the supervisor and four drones need some 1.3 of this machine's two cores, and with the
    # other test worker busy the drones fell behind the mission's clock and missed their takeoff and formation times)
    result = subprocess.run(
        [*SWARM, "fly", str(MISSIONS / "square_four.toml"), "--lockstep",
         "--first-instance", str(first), "--report", str(report), "--no-forward", "--drones-per-process", per_process],
        capture_output=True, text=True, timeout=220,
    )  # fmt: skip
    # THEN it succeeds and the report holds what the issue asks for
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    metrics = json.loads((report / "metrics.json").read_text())
    assert metrics["n_drones"] == 4 and len(metrics["sysids"]) == 4
    assert metrics["collisions"] == 0
    assert metrics["min_separation_m"] > 1.0
    assert metrics["takeoff_time_s"] is not None and metrics["takeoff_time_s"] <= 5.0
    circle = next(s for s in metrics["steps"] if s["name"] == "circle")
    assert circle["time_to_formation_s"] is not None
    assert circle["formation_rms_m"] < 0.3
    for png in ("trajectories.png", "altitude.png", "separation.png"):
        assert (report / png).stat().st_size > 10_000
    # AND the MAVLink log is readable by pymavlink, with every drone in it
    log = mavutil.mavlink_connection(str(report / "flight.tlog"))
    systems = set()
    while (msg := log.recv_match(type="HEARTBEAT")) is not None:
        systems.add(msg.get_srcSystem())
    assert systems == {first + 1, first + 2, first + 3, first + 4}
    assert "Flight report: square_four" in result.stdout


@pytest.mark.timeout(30)
def test_a_mission_file_mistake_is_one_line_with_field_and_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text((MISSIONS / "square_four.toml").read_text().replace("radius_m = 2.5", "radius_m = -2.5"))
    result = subprocess.run([*SWARM, "fly", str(bad)], capture_output=True, text=True, timeout=20)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert f"{bad}:" in lines[0] and "steps[2].radius_m: must be a positive number" in lines[0]


@pytest.mark.timeout(60)
@pytest.mark.parametrize(
    ("args", "line"),
    [
        (["--param", "NOT_A_PARAM=1"], "--param: NOT_A_PARAM is not a parameter of the simulated drones"),
        (["--param", "AVOID_ENABLE=0.5"], "--param: AVOID_ENABLE: integer parameter cannot take 0.5"),
        (["--param", "AVOID_MIN_DIST"], "is not NAME=VALUE"),
    ],
)
def test_a_bad_drone_parameter_is_one_line_before_anything_flies(tmp_path: Path, args: list[str], line: str) -> None:
    """On the command line or in the mission's [swarm] params: checked against the drones' own table at once,
    instead of a PARAM_SET nobody answers once the swarm is up."""
    result = subprocess.run([*SWARM, "fly", str(MISSIONS / "square_four.toml"), "--no-view", *args],
                            capture_output=True, text=True, timeout=30)  # fmt: skip
    assert result.returncode == 2 and result.stderr.count("\n") == 1 and line in result.stderr, result.stderr
    mission = tmp_path / "typo.toml"
    mission.write_text(
        (MISSIONS / "square_four.toml").read_text().replace("[swarm]\n", "[swarm]\nparams = { AVOID_MIN_DIS = 2 }\n")
    )
    result = subprocess.run([*SWARM, "fly", str(mission), "--no-view"], capture_output=True, text=True, timeout=30)
    assert result.returncode == 2 and f"{mission}: swarm.params: AVOID_MIN_DIS is not a parameter" in result.stderr


@pytest.mark.timeout(180)
def test_drones_commanded_into_each_other_collide_crash_and_are_counted_once(tmp_path: Path, instances: Leases) -> None:
    # GIVEN two drones without onboard avoidance told to fly a line with 0.3 m spacing: closer than two collision
    # radii (0.7 m)
    mission = tmp_path / "crash.toml"
    mission.write_text(
        'name = "crash"\n[swarm]\ndrones = 2\nlayout = "line"\nspacing_m = 3.0\nparams = { AVOID_ENABLE = 0 }\n'
        '[[steps]]\naction = "takeoff"\nalt_m = 3.0\n'
        '[[steps]]\naction = "formation"\nshape = "line"\nspacing_m = 0.3\nalt_m = 3.0\nhold_s = 8.0\n'
        '[[steps]]\naction = "land"\n'
    )
    report = tmp_path / "report"
    first = instances(mission_drones(mission))
    # WHEN the mission is flown
    result = subprocess.run(
        [*SWARM, "fly", str(mission), "--speed", "3", "--first-instance", str(first), "--report", str(report),
         "--no-forward"],
        capture_output=True, text=True, timeout=160,
    )  # fmt: skip
    # THEN both crash (a STATUSTEXT says so) and the report counts one collision
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    metrics = json.loads((report / "metrics.json").read_text())
    assert metrics["collisions"] == 1, metrics["collision_events"]
    assert "Collision with drone" in result.stdout


@pytest.mark.timeout(120)
def test_a_lockstep_flight_whose_drones_join_late_flies_whole_and_its_low_takeoff_is_timed_to_the_altitude_flown(
    tmp_path: Path, instances: Leases
) -> None:
    # GIVEN a lockstep mission whose drone factory is held back, before it has started any drone, for longer than the
    # supervisor waits on a simulation that does not advance (as on a machine's first run, where the factory compiles
    # the drones' kernels for some 25 s before any drone exists), and whose takeoff asks for less than the drones'
    # MIS_TAKEOFF_ALT (2.5 m)
    mission = tmp_path / "hop.toml"
    mission.write_text('name = "hop"\n[swarm]\ndrones = 2\n[[steps]]\naction = "takeoff"\nalt_m = 2.0\n'
                       '[[steps]]\naction = "hold"\nduration_s = 3.0\n[[steps]]\naction = "land"\n')  # fmt: skip
    proc = subprocess.Popen([*SWARM, "fly", str(mission), "--lockstep", "--first-instance", str(instances(2)),
                             "--report", str(tmp_path / "report"), "--no-forward", "--no-view"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    factory = None
    try:
        deadline = time.monotonic() + 30
        while factory is None and time.monotonic() < deadline and proc.poll() is None:
            factory = next((p for p in children_of(proc.pid)
                            if b"sitl.harness.zygote" in Path(f"/proc/{p}/cmdline").read_bytes()), None)  # fmt: skip
            time.sleep(0.005)
        assert factory is not None, "no drone factory started"
        os.kill(factory, signal.SIGSTOP)
        assert children_of(factory) == [], "the factory had started drones already"
        time.sleep(LOCKSTEP_STALL_S + 3)
        os.kill(factory, signal.SIGCONT)
        # WHEN the drones then start and join
        out, err = proc.communicate(timeout=90)
    finally:
        if factory is not None and proc.poll() is None:
            os.kill(factory, signal.SIGCONT)
        if proc.poll() is None:
            proc.terminate()
            proc.wait(30)
    # THEN the flight flies from the time they joined, whole, instead of being called stalled
    assert proc.returncode == 0, out[-3000:] + err[-3000:]
    assert "below the drones' MIS_TAKEOFF_ALT (2.5 m), they climb to 2.5 m" in out
    # AND the report times the takeoff to the altitude the drones climbed to, as the takeoff step waited for it
    metrics = json.loads((tmp_path / "report" / "metrics.json").read_text())
    assert metrics["n_drones"] == 2
    assert metrics["steps"][0]["target_alt_m"] == 2.5
    assert metrics["takeoff_time_s"] is not None
