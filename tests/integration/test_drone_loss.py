"""Losing a drone in flight, as a user does it: real ``swarm`` and ``sitl`` processes in lockstep on loopback.

Policy: leased instances (tests/integration/instances.py); every process found by PID and gone at the end; readiness
and progress read from the supervisor's output and ``swarm status``, never slept for.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import math
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from gcs.composition import SITL
from gcs.fleet.harness import SpawnPlan
from gcs.fleet.swarm import Swarm
from gcs.supervisor.control import ControlClient, ControlError, state_file
from gcs.supervisor.station import format_status
from sitl.dynamics.geodesy import ned_from_geo
from sitl.dynamics.plant import DEFAULT_HOME, GeoPoint
from sitl.harness.harness import HOSTED_KILL_CAUSE
from tests.integration.instances import Leases
from tests.integration.report_page import check_report_page
from tests.integration.test_swarm import alive, children_of, wait_dead

pytestmark = [pytest.mark.sim_only]

SWARM = [sys.executable, "-m", "gcs.cli"]
RADIUS_M = 3.0
ON_CIRCLE_M = 0.3  # every drone this close to the circle...
PENTAGON_SIDE_M = 2.0 * RADIUS_M * math.sin(math.pi / 5.0)  # ...and its neighbours about this far (3.53 m)
# Five drones left on the slots of a circle of six have neighbours 3.0 m apart (the hexagon's side): the check
# takes the midpoint, so it tells the two apart with 0.26 m to spare either way.
FIVE_APART_M = 0.5 * (PENTAGON_SIDE_M + RADIUS_M)


class Supervisor:
    """``swarm up`` in the background, its output collected line by line."""

    def __init__(self, args: list[str], env: dict[str, str]) -> None:
        self.env = env
        self.proc = subprocess.Popen([*SWARM, "up", *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, env=env)  # fmt: skip
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        self.wait_for(lambda: any("drones up" in ln for ln in self.lines), 60, "the drones to come up")
        direct = children_of(self.proc.pid)
        factories = [p for p in direct if b"sitl.harness.zygote" in Path(f"/proc/{p}/cmdline").read_bytes()]
        self.drones = [d for f in factories for d in children_of(f)]
        self.children = [*direct, *self.drones]

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def wait_for(self, condition: Callable[[], bool], timeout_s: float, what: str) -> None:
        end = time.monotonic() + timeout_s
        while not condition():
            assert self.proc.poll() is None, "swarm up ended:\n" + "\n".join(self.lines)
            if time.monotonic() > end:
                table = self.cli("status")
                raise AssertionError(
                    "\n".join([f"timed out waiting for {what}:", *self.lines[-30:], table.stdout, table.stderr])
                )
            time.sleep(0.2)

    def cli(self, *args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([*SWARM, *args], capture_output=True, text=True, env=self.env, timeout=60)

    def command(self, *args: str) -> None:
        """A swarm command whose outcome the test then waits for. On a busy machine a lockstep swarm can take more
        wall time to arm or switch mode than the client waits (30 s); the supervisor still carries the command
        out, and the test checks that it did."""
        result = self.cli(*args)
        assert result.returncode == 0 or "did not answer (timed out)" in result.stderr, result

    def status(self, *, by_command: bool = False) -> dict[int, list[str]]:
        """Every drone's row as ``swarm status`` prints it: read in this process through the control channel the
        command uses (a test polls it several times a second, and a ``swarm status`` process a poll cost a core's
        worth of interpreter starts beside the flight), or with ``by_command`` from the command itself."""
        if by_command:
            result = self.cli("status")
            while "did not answer (timed out)" in result.stderr:  # busy with a command (see ``command``)
                result = self.cli("status")
            assert result.returncode == 0, result.stderr
            table = result.stdout
        else:
            while True:
                try:
                    response = ControlClient(state_file(self.env)).request({"cmd": "status"})
                    break
                except ControlError as exc:
                    assert "did not answer (timed out)" in str(exc), exc  # busy with a command (see ``command``)
            assert response.get("ok"), response
            table = format_status(response["drones"])
        return {int(row.split()[0]): row.split() for row in table.strip().splitlines()[1:]}

    def stop(self) -> None:
        """SIGKILL: the drones end with their supervisor (test_swarm.py shows it), without a landing to wait for."""
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        for pid in self.children:
            with contextlib.suppress(ProcessLookupError):
                if alive(pid):
                    os.kill(pid, signal.SIGKILL)
        self._reader.join(timeout=5)


@pytest.fixture
def supervisors(tmp_path: Path) -> Iterator[Callable[[list[str]], Supervisor]]:
    env = {**os.environ, "SWARM_STATE_DIR": str(tmp_path / "state")}
    started: list[Supervisor] = []

    def start(args: list[str]) -> Supervisor:
        started.append(Supervisor(args, env))
        return started[-1]

    yield start
    for s in started:
        s.stop()
        assert wait_dead(s.children, 10) == []


def horizontal(row: list[str]) -> tuple[float, float]:
    """North/east of the swarm origin from a status row's lat/lon."""
    north, east, _ = ned_from_geo(GeoPoint(lat_deg=float(row[3]), lon_deg=float(row[4]), alt_amsl_m=0.0),
                                  DEFAULT_HOME)  # fmt: skip
    return north, east


def on_circle(rows: dict[int, list[str]], sysids: list[int]) -> bool:
    """Every drone in OFFBOARD within ON_CIRCLE_M of the circle and, for five, spread as a pentagon (no two closer
    than FIVE_APART_M: five left on a circle of six's slots fail this)."""
    if any(rows[s][1] != "OFFBOARD" for s in sysids):
        return False
    points = [horizontal(rows[s]) for s in sysids]
    if any(abs(math.hypot(n, e) - RADIUS_M) > ON_CIRCLE_M for n, e in points):
        return False
    if len(sysids) == 6:
        return True
    gaps = [math.dist(a, b) for a, b in itertools.combinations(points, 2)]
    return min(gaps) > FIVE_APART_M


@pytest.mark.timeout(600)  # about 70 s on 2 quiet cores; the waits are long only for a machine shared with others
@pytest.mark.parametrize(
    ("per_process", "cause"),
    [("1", "process killed by SIGKILL"), ("3", HOSTED_KILL_CAUSE)],
    ids=["process-per-drone", "hosted"],
)
def test_kill_9_of_one_drone_of_a_rotating_circle_of_6_leaves_a_circle_of_5_and_one_line(
    supervisors: Callable[[list[str]], Supervisor], tmp_path: Path, instances: Leases, per_process: str, cause: str
) -> None:
    # GIVEN six drones in lockstep flying a rotating circle (each in its own process, or three to a process), the
    # session recorded for a report
    report = tmp_path / "report"
    first = instances(6)
    swarm = supervisors(["-n", "6", "--lockstep", "--first-instance", str(first), "--no-forward", "--report",
                         str(report), "--drones-per-process", per_process])  # fmt: skip
    sysids = list(range(first + 1, first + 7))
    victim = first + 3  # the third drone
    absent = first  # a sysid the swarm does not have: the instance just below its block's
    assert len(swarm.drones) == 6 // int(per_process)  # processes
    swarm.command("takeoff", "--alt", "3")
    swarm.wait_for(lambda: all(float(r[5]) > 2.7 for r in swarm.status().values()), 240, "the takeoff")
    swarm.command("formation", "circle", "--radius", str(RADIUS_M), "--rate", "0.3", "--alt", "3")
    swarm.wait_for(lambda: on_circle(swarm.status(), sysids), 240, "the circle of 6")
    # WHEN the third drone is killed: its process with SIGKILL (by PID, through the supervisor), or inside its host
    result = swarm.cli("kill", str(victim))
    assert result.returncode == 0 and "killed" in result.stdout, result
    survivors = [s for s in sysids if s != victim]
    # THEN the five others re-form a circle of five
    swarm.wait_for(lambda: on_circle(swarm.status(), survivors), 240, "the circle of 5")
    # AND the status shows the dead drone LOST with its cause, not armed
    row = " ".join(swarm.status(by_command=True)[victim])  # the command itself, once
    assert row.startswith(f"{victim} LOST") and cause in row, row
    # AND the supervisor said so once, on one line, and nobody collided
    lost = [ln for ln in swarm.lines if "lost" in ln]
    assert len(lost) == 1 and re.fullmatch(rf"drone {victim} lost at t=\d+\.\d s: {cause}", lost[0]), lost
    assert not [ln for ln in swarm.lines if "link back" in ln or "exited" in ln], swarm.lines
    assert not [ln for ln in swarm.lines if "Collision" in ln], swarm.lines
    assert any("formation re-planned over 5 drones" in ln for ln in swarm.lines), swarm.lines
    # AND a fault for a drone the swarm does not have, or for the lost one, is one line (exit 2: bad input)
    unknown = swarm.cli("fault", str(absent), "motor")
    assert unknown.returncode == 2 and unknown.stderr == (
        f"swarm: error: no drone with sysid {absent} (sysids {first + 1}..{first + 6})\n"
    ), unknown
    again = swarm.cli("kill", str(victim))
    assert again.returncode == 1 and again.stderr.startswith(f"swarm: error: drone {victim} is already lost ("), again
    assert len(again.stderr.splitlines()) == 1
    # AND once the swarm is down, the report lists the loss and the fault, with no collision
    swarm.command("down")
    assert swarm.proc.wait(timeout=120) == 0, swarm.lines
    metrics = json.loads((report / "metrics.json").read_text())
    assert [(x["sysid"], x["cause"]) for x in metrics["losses"]] == [(victim, cause)]
    assert [(f["sysid"], f["fault"]) for f in metrics["faults"]] == [(victim, "crash")]
    assert [s["name"] for s in metrics["steps"]] == ["takeoff", "circle"]
    # (nobody hit the falling body while the swarm flew, nor its wreck when ``down`` landed the others: a survivor
    # above or beside it side-steps before it descends; and where it came down is reported)
    assert metrics["collision_events"] == [], metrics["collision_events"]
    down = metrics["losses"][0]["down_ne_m"]
    assert down is not None and abs(math.hypot(*down) - RADIUS_M) < 1.0, down  # below its place on the circle


@pytest.mark.timeout(300)
def test_loss_policy_hold_puts_the_survivor_in_hold_where_it_is(
    supervisors: Callable[[list[str]], Supervisor], instances: Leases
) -> None:
    # GIVEN two drones flying a line under loss policy hold
    first = instances(2)
    swarm = supervisors(["-n", "2", "--lockstep", "--first-instance", str(first), "--no-forward", "--loss-policy",
                         "hold"])  # fmt: skip
    swarm.command("takeoff", "--alt", "3")
    swarm.wait_for(lambda: all(float(r[5]) > 2.7 for r in swarm.status().values()), 120, "the takeoff")
    swarm.command("formation", "line", "--spacing", "4", "--alt", "3")
    swarm.wait_for(lambda: all(r[1] == "OFFBOARD" for r in swarm.status().values()), 120, "OFFBOARD")
    # WHEN the second drone's process is killed
    assert swarm.cli("kill", str(first + 2)).returncode == 0
    # THEN the survivor is switched to PX4 Hold (AUTO.LOITER) and stays up, and the supervisor says why
    swarm.wait_for(lambda: swarm.status()[first + 1][1] == "AUTO.LOITER", 120, "Hold")
    row = swarm.status()[first + 1]
    assert row[2] == "yes" and float(row[5]) > 2.5, row
    assert "swarm: loss policy hold: every drone holds where it is" in swarm.lines, swarm.lines


@pytest.mark.timeout(300)
def test_a_drone_heard_again_under_loss_policy_hold_is_held_too(
    supervisors: Callable[[list[str]], Supervisor], instances: Leases
) -> None:
    # GIVEN two drones flying a line under loss policy hold
    first = instances(2)
    survivor, silent = first + 1, first + 2  # sysids
    swarm = supervisors(["-n", "2", "--lockstep", "--first-instance", str(first), "--no-forward", "--loss-policy",
                         "hold"])  # fmt: skip
    swarm.command("takeoff", "--alt", "3")
    swarm.wait_for(lambda: all(float(r[5]) > 2.7 for r in swarm.status().values()), 120, "the takeoff")
    swarm.command("formation", "line", "--spacing", "4", "--alt", "3")
    swarm.wait_for(lambda: all(r[1] == "OFFBOARD" for r in swarm.status().values()), 120, "OFFBOARD")
    # WHEN the second drone's links go silent for 5 s
    result = swarm.cli("fault", str(silent), "link", "--for", "5")
    assert result.returncode == 0 and result.stdout == f"swarm: drone {silent}: accepted\n", result
    # THEN it is lost after 3 s of silence and the survivor holds, as the policy says
    swarm.wait_for(lambda: any(ln.startswith(f"drone {silent} lost at t=") for ln in swarm.lines), 120, "the loss")
    swarm.wait_for(lambda: swarm.status()[survivor][1] == "AUTO.LOITER", 120, "Hold")
    # AND once heard again it is told the same: both hold, in the air
    swarm.wait_for(lambda: any(ln.startswith(f"drone {silent} link regained at t=") for ln in swarm.lines), 120,
                   "the regain")  # fmt: skip
    said = f"swarm: loss policy hold: sysid {silent} "  # said once the drone acknowledged, after the regain line
    swarm.wait_for(lambda: any(ln.startswith(said) for ln in swarm.lines), 30, "what the policy does")
    assert f"{said}holds where it is too" in swarm.lines, swarm.lines
    swarm.wait_for(lambda: swarm.status()[silent][1] == "AUTO.LOITER", 120, "Hold")
    rows = swarm.status()
    assert all(rows[s][2] == "yes" and float(rows[s][5]) > 2.5 for s in (survivor, silent)), rows


@pytest.mark.timeout(300)
def test_a_host_process_killed_from_outside_loses_its_drones_and_the_other_host_flies_on(
    supervisors: Callable[[list[str]], Supervisor], instances: Leases
) -> None:
    # GIVEN four drones in lockstep, two to a process, holding a line at 3 m
    first = instances(4)
    killed = (first + 1, first + 2)  # the sysids of the first host's drones
    flying = (first + 3, first + 4)  # and of the other host's
    swarm = supervisors(["-n", "4", "--lockstep", "--first-instance", str(first), "--no-forward", "--layout", "line",
                         "--spacing", "3", "--drones-per-process", "2"])  # fmt: skip
    assert len(swarm.drones) == 2  # two host processes
    swarm.command("takeoff", "--alt", "3")
    swarm.wait_for(lambda: all(float(r[5]) > 2.7 for r in swarm.status().values()), 120, "the takeoff")
    # WHEN the process hosting the first two drones is killed with SIGKILL from outside the swarm (as the OOM killer
    # would), not through the supervisor
    name = f"sitl-{first}-{first + 1}"
    host = next(pid for pid in swarm.drones if Path(f"/proc/{pid}/comm").read_text().strip() == name)
    os.kill(host, signal.SIGKILL)
    # THEN both its drones are lost, each said once with the host's end, and the other host's drones fly on
    swarm.wait_for(lambda: sum("lost" in ln for ln in swarm.lines) == 2, 60, "two losses")
    lost = sorted(ln for ln in swarm.lines if "lost" in ln)
    for line, sysid in zip(lost, killed, strict=True):
        assert re.fullmatch(rf"drone {sysid} lost at t=\d+\.\d s: its host process killed by SIGKILL", line), lost
    rows = swarm.status()
    assert rows[killed[0]][1] == rows[killed[1]][1] == "LOST", rows
    assert all(rows[s][2] == "yes" and float(rows[s][5]) > 2.5 for s in flying), rows
    swarm.command("land")
    swarm.wait_for(lambda: all(swarm.status()[s][2] == "no" for s in flying), 120, "the landing")


MISSION = """\
name = "lose_one"
[swarm]
drones = 4
spacing_m = 3.0

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "fault"
drone = 2
fault = "crash"
after_s = 6.0

[[steps]]
action = "formation"
shape = "circle"
radius_m = 3.0
alt_m = 3.0
hold_s = 20.0

[[steps]]
action = "land"
"""


@pytest.mark.timeout(300)
def test_a_mission_crash_fault_is_in_the_report_with_the_loss_and_metrics_over_the_survivors(
    tmp_path: Path, instances: Leases
) -> None:
    # GIVEN a mission that kills drone 2 six seconds into a circle of four
    mission = tmp_path / "lose_one.toml"
    mission.write_text(MISSION)
    report = tmp_path / "report"
    first = instances(4)
    victim = first + 2  # drone 2's sysid
    # WHEN flown in lockstep
    result = subprocess.run(
        [*SWARM, "fly", str(mission), "--report", str(report), "--lockstep", "--first-instance", str(first),
         "--no-forward"],
        capture_output=True, text=True, timeout=280,
    )  # fmt: skip
    # THEN the mission completes with the three survivors landing
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert len(re.findall(rf"^drone {victim} lost at t=", result.stdout, re.M)) == 1, result.stdout
    # AND the report lists the fault, the loss and where it came down, with no collision
    metrics = json.loads((report / "metrics.json").read_text())
    assert [f["fault"] for f in metrics["faults"]] == ["crash"]
    assert metrics["faults"][0]["sysid"] == victim and "killed with SIGKILL" in metrics["faults"][0]["result"]
    assert [(x["sysid"], x["cause"]) for x in metrics["losses"]] == [(victim, "process killed by SIGKILL")]
    assert metrics["collisions"] == 0, metrics["collision_events"]
    assert metrics["loss_policy"] == "continue"
    assert metrics["losses"][0]["down_ne_m"] is not None, metrics["losses"]  # where the falling body came down
    summary = (report / "summary.txt").read_text()
    assert "drones lost: 1 (loss policy: continue)" in summary
    # AND the flight log holds the ground station's commands beside the drones' answers (an injected fault's
    # COMMAND_LONG goes there the same way)
    log = mavutil.mavlink_connection(str(report / "flight.tlog"))
    commands = set()
    while (msg := log.recv_match(type="COMMAND_LONG")) is not None:
        commands.add((msg.get_srcSystem(), msg.command))
    assert (255, mavlink.MAV_CMD_COMPONENT_ARM_DISARM) in commands, commands
    # AND the circle step's formation error is that of the three still flying, settled on their circle of three
    circle = next(s for s in metrics["steps"] if s["name"] == "circle")
    assert circle["formation_rms_m"] is not None and circle["formation_rms_m"] < 0.3, circle
    # AND the report page replays the flight to the end with the same minimum separation, the killed drone drawn
    # lost, and the crash and the loss marked on its timeline
    check_report_page(report, metrics, lost=(victim,), marks=("fault", "loss"), screenshot_at_s=circle["start_s"] + 8.0)


ABORT_MISSION = """\
name = "abort_on_loss"
[swarm]
drones = 2
spacing_m = 4.0
loss_policy = "abort"
params = { RTL_RETURN_ALT = 5.0 }  # a short return: the default 30 m climb takes long for nothing here

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "fault"
drone = 1
fault = "crash"
after_s = 2.0

[[steps]]
action = "formation"
shape = "line"
spacing_m = 4.0
alt_m = 3.0
heading_deg = 90.0
hold_s = 60.0

[[steps]]
action = "land"
"""


@pytest.mark.timeout(240)
def test_loss_policy_abort_returns_the_survivor_to_launch_and_drops_the_rest_of_the_mission(
    tmp_path: Path, instances: Leases
) -> None:
    # GIVEN a mission whose first drone crashes two seconds into a minute-long formation, under loss policy abort
    mission = tmp_path / "abort.toml"
    mission.write_text(ABORT_MISSION)
    report = tmp_path / "report"
    first = instances(2)
    # WHEN flown in lockstep
    result = subprocess.run(
        [*SWARM, "fly", str(mission), "--report", str(report), "--lockstep", "--first-instance", str(first),
         "--no-forward"],
        capture_output=True, text=True, timeout=220,
    )  # fmt: skip
    # THEN the survivor returned to launch and landed, and the mission ended there instead of holding its formation
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert "loss policy abort: every drone returns to launch and lands" in result.stdout
    assert "remaining steps dropped" in result.stdout
    metrics = json.loads((report / "metrics.json").read_text())
    assert metrics["loss_policy"] == "abort"
    assert [x["sysid"] for x in metrics["losses"]] == [first + 1]  # the first drone
    assert [e["text"] for e in metrics["loss_policy_actions"]] == [
        "loss policy abort: every drone returns to launch and lands"
    ]
    assert metrics["duration_s"] < 50.0  # not the formation's 60 s


@pytest.mark.timeout(30)
def test_the_supervisor_sends_every_drone_a_gcs_heartbeat_once_a_second() -> None:
    """As QGroundControl does: a drone's datalink-loss failsafe (COM_DL_LOSS_T) counts from the last one."""
    # GIVEN a supervisor that has heard one drone (a real UDP socket speaking for sysid 7)
    plan = SpawnPlan(n_drones=1)
    swarm = Swarm(plan, SITL.harness(plan), relay=False)
    drone = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        drone.bind(("127.0.0.1", 0))
        drone.settimeout(0.0)
        encoder = mavlink.MAVLink(None, srcSystem=7, srcComponent=1)
        beat = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0, 0, 3, 3)
        drone.sendto(beat.pack(encoder), ("127.0.0.1", swarm.link.port))
        # WHEN it runs for 3.5 s
        swarm.pump.run_for(3.5)
        # THEN the drone got a HEARTBEAT from a ground station each second (at 0, 1, 2 and 3 s)
        parser = mavlink.MAVLink(None)
        received: list[Any] = []
        with contextlib.suppress(BlockingIOError):
            while True:
                received += parser.parse_buffer(drone.recv(65535)) or []
        beats = [m for m in received if m.get_type() == "HEARTBEAT"]
        assert len(beats) == 4, received
        assert all(m.type == mavlink.MAV_TYPE_GCS and m.autopilot == mavlink.MAV_AUTOPILOT_INVALID for m in beats)
        assert all((m.get_srcSystem(), m.get_srcComponent()) == (255, 190) for m in beats)
    finally:
        drone.close()
        swarm.shutdown()
