"""An onboard behaviour in a real ``sitl`` process, driven the way a ground station drives one: pymavlink arms and
takes off, PARAM_SET turns the behaviour on (BHV_EN = 1) and changes its own parameter, NAMED_VALUE_FLOAT sends it a
message, and the drone flies where the behaviour says; a broken behaviour file is one line and exit code 2.

Policy: loopback only; leased instances (tests/integration/instances.py), but for the two tests whose behaviour does
not load (it is checked before any drone starts); a time limit; processes are stopped by their PIDs.
"""

from __future__ import annotations

import json
import math
import struct
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from sitl.process.ports import instance_ports
from tests.integration.instances import Leases

pytestmark = [pytest.mark.sim_only]

BEHAVIOUR = '''
from sitl.onboard import OnboardSetpoint


class Beacon:
    """Flies to (BCN_N, east) at 3 m; east comes in a message from the ground station."""

    RATE_HZ = 10
    PARAMS = {"BCN_N": (2.0, -20.0, 20.0)}

    def __init__(self):
        self.east = 0.0

    def step(self, state):
        for message in state.messages:
            if message.name == "east":
                self.east = message.value
        return OnboardSetpoint(pos_ned_m=(state.params["BCN_N"], self.east, -3.0))
'''


def recv(conn: mavutil.mavfile, kind: str, ok: Callable[[Any], bool], timeout_s: float) -> Any:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        msg = conn.recv_match(type=kind, blocking=True, timeout=0.5)
        if msg is not None and ok(msg):
            return msg
    raise AssertionError(f"no {kind} as wanted within {timeout_s:g} s")


@contextmanager
def drone(behaviour: Path, instance: int) -> Iterator[subprocess.Popen[str]]:
    proc = subprocess.Popen([sys.executable, "-m", "sitl.cli", "--instance", str(instance), "--no-gcs",
                             "--behaviour", f"{behaviour}:Beacon"], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)  # fmt: skip
    try:
        yield proc
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def set_param(conn: mavutil.mavfile, name: str, value: float, *, integer: bool = False) -> None:
    """PARAM_SET as PX4 takes it (an INT32 parameter's value bytewise in the float), confirmed by its echo."""
    kind = mavlink.MAV_PARAM_TYPE_INT32 if integer else mavlink.MAV_PARAM_TYPE_REAL32
    wire = struct.unpack("<f", struct.pack("<i", int(value)))[0] if integer else value
    conn.mav.param_set_send(conn.target_system, 1, name.encode(), wire, kind)
    recv(conn, "PARAM_VALUE", lambda m: m.param_id == name and m.param_value == wire, 5.0)


@pytest.mark.timeout(180)
def test_a_ground_station_turns_a_behaviour_on_tunes_it_and_messages_it(tmp_path: Path, instances: Leases) -> None:
    path = tmp_path / "beacon.py"
    path.write_text(BEHAVIOUR)
    instance = instances(1)
    with drone(path, instance):
        conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{instance_ports(instance).api_remote}", source_system=255)
        try:
            conn.wait_heartbeat(timeout=30)
            # GIVEN the drone in the air, its behaviour's parameter listed among the drone's
            recv(conn, "SYS_STATUS", lambda m: m.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_PREARM_CHECK,
                 60.0)  # fmt: skip
            conn.arducopter_arm()
            ground = recv(conn, "GLOBAL_POSITION_INT", lambda m: True, 5.0)
            conn.mav.command_long_send(conn.target_system, 1, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0,
                                       (ground.alt - ground.relative_alt) * 1e-3 + 3.0)  # fmt: skip
            recv(conn, "GLOBAL_POSITION_INT", lambda m: m.relative_alt > 2.7e3, 40.0)
            set_param(conn, "BCN_N", 4.0)
            # WHEN BHV_EN is set to 1 and the behaviour is told where east is
            set_param(conn, "BHV_EN", 1, integer=True)
            conn.mav.named_value_float_send(0, b"east", 3.0)
            # THEN the drone announces it, goes OFFBOARD and flies to (4, 3)
            recv(conn, "STATUSTEXT", lambda m: m.text == "Behaviour Beacon started", 10.0)
            recv(
                conn, "HEARTBEAT", lambda m: m.get_srcSystem() == conn.target_system and m.custom_mode == 6 << 16, 10.0
            )
            there = recv(conn, "LOCAL_POSITION_NED", lambda m: math.hypot(m.x - 4.0, m.y - 3.0) < 0.3, 30.0)
            assert abs(there.z + 3.0) < 0.4, there
            # WHEN the ground station sets BHV_EN back to 0 THEN it stops and says so
            set_param(conn, "BHV_EN", 0, integer=True)
            recv(conn, "STATUSTEXT", lambda m: m.text == "Behaviour Beacon stopped (BHV_EN 0)", 10.0)
        finally:
            conn.close()


def test_a_broken_behaviour_file_is_one_line_and_exit_code_2(tmp_path: Path) -> None:
    path = tmp_path / "beacon.py"
    path.write_text(BEHAVIOUR.replace("def step(self, state):", "def step(self, state)"))
    # (no drone starts: the behaviour is checked first, so the instance is never leased)
    result = subprocess.run([sys.executable, "-m", "sitl.cli", "--instance", "59", "--behaviour",
                             f"{path}:Beacon"], capture_output=True, text=True, timeout=60)  # fmt: skip
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].endswith("beacon.py:14: SyntaxError: expected ':'"), result.stderr


CLIMB = '''
from sitl.onboard import OnboardSetpoint


class Climb:
    """Holds its place and climbs to CLB_ALT."""

    RATE_HZ = 5
    PARAMS = {"CLB_ALT": (4.0, 1.0, 10.0)}

    def __init__(self):
        self.place = None

    def step(self, state):
        if self.place is None:
            self.place = state.pos_ned_m[:2]
        return OnboardSetpoint(pos_ned_m=(*self.place, -state.params["CLB_ALT"]))
'''
CLIMB_MISSION = """
name = "climb"
[swarm]
drones = 3
layout = "line"
spacing_m = 3.0
behaviour = "climb.py:Climb"
params = { CLB_ALT = 5.5 }

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "behaviour"
duration_s = 10.0

[[steps]]
action = "land"
"""


@pytest.mark.timeout(240)
def test_a_mission_runs_its_onboard_behaviour_on_every_drone_for_a_step(tmp_path: Path, instances: Leases) -> None:
    # GIVEN a mission whose drones carry a behaviour (in a file beside it) tuned by a mission parameter
    (tmp_path / "climb.py").write_text(CLIMB)
    (tmp_path / "climb.toml").write_text(CLIMB_MISSION)
    report = tmp_path / "report"
    first = instances(3)
    sysids = [first + 1, first + 2, first + 3]
    result = subprocess.run([sys.executable, "-m", "gcs.cli", "fly", str(tmp_path / "climb.toml"), "--lockstep",
                             "--first-instance", str(first), "--drones-per-process", "auto", "--report", str(report),
                             "--no-forward"], capture_output=True, text=True, timeout=220)  # fmt: skip
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    # THEN every drone started it, climbed to the mission's CLB_ALT under it, and was stopped and held at the step's end
    log = mavutil.mavlogfile(str(report / "flight.tlog"))
    texts: dict[int, list[str]] = {}
    top: dict[int, float] = {}
    while (msg := log.recv_match(type=["STATUSTEXT", "GLOBAL_POSITION_INT"])) is not None:
        sysid = msg.get_srcSystem()
        if msg.get_type() == "STATUSTEXT":
            texts.setdefault(sysid, []).append(msg.text)
        else:
            top[sysid] = max(top.get(sysid, 0.0), msg.relative_alt * 1e-3)
    assert sorted(top) == sysids, top
    for sysid in sysids:
        assert "Behaviour Climb started" in texts[sysid], texts[sysid]
        assert any(t.startswith("Behaviour Climb stopped") for t in texts[sysid]), texts[sysid]
        assert abs(top[sysid] - 5.5) < 0.3, top
    metrics = json.loads((report / "metrics.json").read_text())
    assert [s["kind"] for s in metrics["steps"]] == ["takeoff", "behaviour", "land"], metrics["steps"]
    assert metrics["collisions"] == 0


def test_a_mission_whose_behaviour_does_not_load_is_one_line_and_exit_code_2(tmp_path: Path) -> None:
    (tmp_path / "climb.py").write_text(CLIMB.replace("RATE_HZ = 5", "RATE_HZ = -5"))
    (tmp_path / "climb.toml").write_text(CLIMB_MISSION)
    # (no drone starts: the mission's behaviour is checked first, so its instances are never leased)
    result = subprocess.run([sys.executable, "-m", "gcs.cli", "fly", str(tmp_path / "climb.toml"), "--lockstep",
                             "--first-instance", "5", "--no-forward"],
                            capture_output=True, text=True, timeout=60)  # fmt: skip
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "climb.toml: swarm.behaviour:" in lines[0] and "RATE_HZ must be" in lines[0], lines
