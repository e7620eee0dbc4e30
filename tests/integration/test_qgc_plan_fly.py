"""A QGroundControl plan flown by real drones: ``swarm fly`` with a plan step, and ``swarm plan`` against ``swarm up``.

Policy: loopback only; leased instances (tests/integration/instances.py); lockstep with the drones hosted
(``--drones-per-process auto``) so the flights do not depend on machine load and stay short (15-30 s each on an idle
machine); a time limit on every test, generous for a loaded one; every process this file starts is stopped by PID
(``swarm down`` for the supervisor, SIGKILL by PID if it does not end) and must be gone at the end.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync
from pymavlink import mavutil

from gcs.fleet.harness import line_layout
from gcs.flight.geodesy import GeoPoint, NedFrame
from gcs.mavlink.mission_transfer import WireItem
from gcs.missions.qgc_plan import fence_items, load_plan, mission_items, plan_from_items, plan_text, shifted
from tests.integration.instances import Leases
from tests.integration.mavsdk_client import call_within, connect
from tests.integration.mission_flight import mission_drones
from tests.integration.sitl_process import start_drones, stop_drone

pytestmark = [pytest.mark.sim_only]

MISSIONS = Path(__file__).resolve().parents[2] / "missions"
BOX_PLAN = MISSIONS / "box.plan"
SWARM = [sys.executable, "-m", "gcs.cli"]
FAST = ["--lockstep", "--drones-per-process", "auto", "--no-forward"]
NAV_ACC_RAD_M = 1.0  # the drones' default waypoint acceptance radius (PX4's NAV_ACC_RAD)
LANDED_WITHIN_M = 0.5  # a land item at a point lands that close to it


def tracks(tlog: Path) -> tuple[dict[int, list[tuple[float, float, float]]], dict[int, list[int]], dict[int, bool]]:
    """Per sysid from a flight log: (lat, lon, relative alt) of every GLOBAL_POSITION_INT, the MISSION_ITEM_REACHED
    seqs in order, and whether its last HEARTBEAT said armed."""
    positions: dict[int, list[tuple[float, float, float]]] = {}
    reached: dict[int, list[int]] = {}
    armed: dict[int, bool] = {}
    log = mavutil.mavlink_connection(str(tlog))
    while (msg := log.recv_match(type=["GLOBAL_POSITION_INT", "MISSION_ITEM_REACHED", "HEARTBEAT"])) is not None:
        sysid = msg.get_srcSystem()
        if msg.get_srcComponent() != 1:
            continue
        kind = msg.get_type()
        if kind == "GLOBAL_POSITION_INT":
            positions.setdefault(sysid, []).append((msg.lat * 1e-7, msg.lon * 1e-7, msg.relative_alt * 1e-3))
        elif kind == "MISSION_ITEM_REACHED":
            seqs = reached.setdefault(sysid, [])
            if not seqs or seqs[-1] != msg.seq:
                seqs.append(msg.seq)
        else:
            armed[sysid] = bool(msg.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
    return positions, reached, armed


@pytest.mark.timeout(240)
def test_a_qgroundcontrol_plan_flies_as_a_copy_per_drone_and_every_drone_reaches_every_item_and_lands(
    tmp_path: Path, instances: Leases
) -> None:
    # GIVEN the committed QGroundControl plan (take off to 3 m, a 6 m box, land where it took off, inside a fence)
    # in a mission of three drones in a line 8 m apart, each to fly its copy moved by its spawn offset
    plan = load_plan(BOX_PLAN)
    report = tmp_path / "report"
    first = instances(mission_drones(MISSIONS / "qgc_box.toml"))
    sysids = (first + 1, first + 2, first + 3)
    # WHEN the mission is flown in lockstep
    started = time.monotonic()
    result = subprocess.run(
        [*SWARM, "fly", str(MISSIONS / "qgc_box.toml"), "--first-instance", str(first), "--report", str(report),
         *FAST],
        capture_output=True, text=True, timeout=220,
    )  # fmt: skip
    wall_s = time.monotonic() - started
    # THEN it succeeds, and the supervisor saw every drone reach every item
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert (
        f"box.plan: 5 items and 2 fence zone(s) uploaded to sysid {first + 1}, {first + 2}, {first + 3}"
        in result.stdout
    )
    assert "box.plan: every drone reached every item" in result.stdout
    metrics = json.loads((report / "metrics.json").read_text())
    assert metrics["collisions"] == 0
    # AND the report lists every drone's items reached, in order
    reported = {sysid: [r["seq"] for r in items] for sysid, items in metrics["mission_items_reached"].items()}
    assert reported == {str(sysid): [0, 1, 2, 3, 4] for sysid in sysids}
    # AND the flight log shows each drone reach items 0..4 in order, come within the acceptance radius of each of
    # its own copy's waypoints, land on its copy's landing point and disarm
    positions, reached, armed = tracks(report / "flight.tlog")
    frame = NedFrame(GeoPoint(lat_deg=plan.planned_home[0], lon_deg=plan.planned_home[1], alt_amsl_m=0.0))

    def ne(lat: float, lon: float) -> tuple[float, float]:
        north, east, _ = frame.ned_from_geo(GeoPoint(lat_deg=lat, lon_deg=lon, alt_amsl_m=0.0))
        return north, east

    for sysid, (north, east) in zip(sysids, line_layout(3, 8.0), strict=True):
        assert reached.get(sysid) == [0, 1, 2, 3, 4], f"sysid {sysid} reported {reached.get(sysid)}"
        copy = shifted(plan, north, east)
        track = [(*ne(lat, lon), alt) for lat, lon, alt in positions[sysid]]
        for seq in (1, 2, 3):
            wn, we = ne(*copy.items[seq].params[4:6])
            closest = min(math.dist((n, e, a), (wn, we, 3.0)) for n, e, a in track)
            assert closest <= NAV_ACC_RAD_M, f"sysid {sysid} passed item {seq} at {closest:.2f} m"
        ln, le = ne(*copy.items[4].params[4:6])
        last_n, last_e, last_alt = track[-1]
        assert math.dist((last_n, last_e), (ln, le)) < LANDED_WITHIN_M and last_alt < 0.3
        assert armed[sysid] is False
    print(f"qgc_box: {wall_s:.1f} s wall, plan step {metrics['steps'][0]['end_s'] - metrics['steps'][0]['start_s']:.1f}"
          f" s simulated, min separation {metrics['min_separation_m']:.2f} m")  # fmt: skip


SUBSET_MISSION = f"""name = "plan_for_one"
[swarm]
drones = 2
layout = "line"
spacing_m = 8.0
[[steps]]
action = "takeoff"
alt_m = 3.0
[[steps]]
action = "plan"
file = "{BOX_PLAN}"
drones = "2"
[[steps]]
action = "land"
"""


@pytest.mark.timeout(240)
def test_a_plan_for_some_drones_after_a_takeoff_leaves_the_others_holding_where_they_are(
    tmp_path: Path, instances: Leases
) -> None:
    # GIVEN two drones in the air (OFFBOARD, after the takeoff step), and the plan for the second only
    mission = tmp_path / "one.toml"
    mission.write_text(SUBSET_MISSION)
    report = tmp_path / "report"
    first = instances(2)
    holding, planned = first + 1, first + 2  # the first drone's sysid and the second's
    # WHEN the mission is flown
    result = subprocess.run(
        [*SWARM, "fly", str(mission), "--first-instance", str(first), "--report", str(report), *FAST],
        capture_output=True, text=True, timeout=220,
    )  # fmt: skip
    # THEN the second flies the whole plan, and the first hovers in Hold meanwhile: no failsafe, hardly a move
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    metrics = json.loads((report / "metrics.json").read_text())
    reached_items = {k: [r["seq"] for r in v] for k, v in metrics["mission_items_reached"].items()}
    assert reached_items == {str(planned): [0, 1, 2, 3, 4]}
    assert metrics["failsafes"] == [] and metrics["collisions"] == 0
    log = mavutil.mavlink_connection(str(report / "flight.tlog"))
    modes: set[str] = set()
    while (msg := log.recv_match(type="HEARTBEAT")) is not None:
        if msg.get_srcSystem() == holding and msg.get_srcComponent() == 1:
            modes.add(mavutil.interpret_px4_mode(msg.base_mode, msg.custom_mode))
    assert "LOITER" in modes and "MISSION" not in modes, modes
    positions, _, _ = tracks(report / "flight.tlog")
    start = positions[holding][len(positions[holding]) // 2]  # hovering, half way through the flight
    frame = NedFrame(GeoPoint(lat_deg=start[0], lon_deg=start[1], alt_amsl_m=0.0))
    drift = max(
        math.hypot(*frame.ned_from_geo(GeoPoint(lat_deg=lat, lon_deg=lon, alt_amsl_m=0.0))[:2])
        for lat, lon, alt in positions[holding]
        if alt > 2.5
    )
    assert drift < 0.5, f"drone 1 moved {drift:.2f} m while it should have held"


class RunningSwarm:
    """``swarm up`` in lockstep, its readiness read from its own output; stopped by ``swarm down``, or by PID."""

    def __init__(self, n: int, first_instance: int, env: dict[str, str]) -> None:
        self.env = env
        self.first_instance = first_instance
        self.proc = subprocess.Popen(
            [*SWARM, "up", "-n", str(n), "--layout", "line", "--spacing", "8", "--first-instance",
             str(first_instance), *FAST],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, start_new_session=True,
        )  # fmt: skip
        self.output: list[str] = []
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.output.append(line)
            if "drones up" in line:
                return
        raise AssertionError("swarm up ended before the drones were up: " + "".join(self.output))

    def cli(self, *args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([*SWARM, *args], capture_output=True, text=True, env=self.env, timeout=60)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.cli("down")
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:  # its whole session (drone factory, drones) by the group's PID
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()


@pytest.fixture
def running_swarm(tmp_path: Path, instances: Leases) -> Iterator[RunningSwarm]:
    swarm = RunningSwarm(2, instances(2), {**os.environ, "SWARM_STATE_DIR": str(tmp_path / "state")})
    try:
        yield swarm
    finally:
        swarm.stop()


@pytest.mark.timeout(240)
def test_swarm_plan_uploads_downloads_the_same_items_starts_and_refuses_a_broken_file(
    running_swarm: RunningSwarm, tmp_path: Path
) -> None:
    swarm = running_swarm
    first = swarm.first_instance
    # GIVEN a plan with a ComplexItem (a survey), which only QGroundControl can expand
    broken = tmp_path / "survey.plan"
    data = json.loads(BOX_PLAN.read_text())
    data["mission"]["items"][2] = {"type": "ComplexItem", "complexItemType": "survey", "version": 5}
    broken.write_text(json.dumps(data))
    # WHEN it is uploaded THEN one line names the file and the problem, exit code 2
    result = swarm.cli("plan", "upload", str(broken))
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        f"swarm: error: {broken}: mission.items[2]: complex item 'survey' is not supported: QGroundControl keeps "
        "only its outline in the file; convert it to waypoints in QGroundControl first"
    ]
    # WHEN the committed plan is uploaded to both drones
    result = swarm.cli("plan", "upload", str(BOX_PLAN), "--drones", "all")
    assert result.returncode == 0, result.stderr
    assert f"5 items and 2 fence zone(s) uploaded to sysid {first + 1}, {first + 2}" in result.stdout
    # THEN a download of the second gives back its copy's items: the plan moved by its spawn offset
    out = tmp_path / "back.plan"
    result = swarm.cli("plan", "download", str(first + 2), str(out))
    assert result.returncode == 0, result.stderr
    north, east = line_layout(2, 8.0)[1]
    expected = shifted(load_plan(BOX_PLAN), north, east)
    back = load_plan(out)
    assert list(map(repr, mission_items(back))) == list(map(repr, mission_items(expected)))
    assert list(map(repr, fence_items(back))) == list(map(repr, fence_items(expected)))
    # WHEN the mission is started on the ground
    result = swarm.cli("plan", "start")
    assert result.returncode == 0, result.stderr
    # THEN both take off, fly it, land and disarm (seen by the supervisor's status)
    flown: set[str] = set()
    progress: set[str] = set()  # what the status table said of the missions
    deadline = time.monotonic() + 150  # wall seconds: lockstep runs as fast as a loaded machine lets it
    while time.monotonic() < deadline:
        lines = swarm.cli("status").stdout.strip().splitlines()[1:]
        rows = [line.split() for line in lines]
        progress |= {line.split("mission: ")[1] for line in lines if "mission: " in line}
        flown |= {row[1] for row in rows}
        if "AUTO.MISSION" in flown and all(row[2] == "no" for row in rows):
            break
        time.sleep(0.5)
    assert "AUTO.MISSION" in flown and all(row[2] == "no" for row in rows), rows
    assert all(float(row[5]) < 0.3 for row in rows), rows
    # AND while they flew, the status table showed their progress through the mission (ending complete)
    assert any(p.endswith(" active") for p in progress) and "item 5/5 complete" in progress, progress
    # AND a drone that does not exist is a usage error (sysid ``first``: instance first - 1's, outside the swarm)
    assert swarm.cli("plan", "download", str(first), str(out)).returncode == 2


@pytest.mark.timeout(90)
async def test_mavsdk_reads_the_committed_plan_and_an_exported_one_into_the_items_we_upload(
    tmp_path: Path, instances: Leases
) -> None:
    # GIVEN one drone, for MAVSDK to have a system, and MAVSDK's own QGroundControl importer (an independent reader
    # of the format)
    drones = start_drones(instances=[instances(1)], speed_factor=4.0, seed=0, log_dir=tmp_path, hosted=False)
    try:
        async with connect(f"udpin://127.0.0.1:{drones[0].ports.api_remote}", drones[0].sysid) as drone:
            importer = MissionRawAsync(drone.system)
            plan = load_plan(BOX_PLAN)
            # WHEN MAVSDK imports the committed plan
            imported = await call_within(importer.import_qgroundcontrol_mission(str(BOX_PLAN)), 10.0, "import")
            # THEN it makes exactly the mission and fence items our reader makes (and uploads)
            assert _mavsdk_items(imported.mission_items) == _our_items(mission_items(plan))
            assert _mavsdk_items(imported.geofence_items) == _our_items(fence_items(plan))
            # AND a plan we write (an export) imports as the same items too
            exported = tmp_path / "exported.plan"
            exported.write_text(
                plan_text(plan_from_items(mission_items(plan), fence_items(plan), home=plan.planned_home))
            )
            again = await call_within(importer.import_qgroundcontrol_mission(str(exported)), 10.0, "import")
            assert _mavsdk_items(again.mission_items) == _our_items(mission_items(plan))
            assert _mavsdk_items(again.geofence_items) == _our_items(fence_items(plan))
    finally:
        for started in drones:
            stop_drone(started)


def _mavsdk_items(items: list[Any]) -> list[tuple[Any, ...]]:
    return [(i.seq, i.frame, i.command, i.autocontinue, *(_p(p) for p in (i.param1, i.param2, i.param3, i.param4)),
             i.x, i.y, round(i.z, 3), i.mission_type) for i in items]  # fmt: skip


def _our_items(items: list[WireItem]) -> list[tuple[Any, ...]]:
    return [(i.seq, i.frame, i.command, int(i.autocontinue), *(_p(p) for p in (i.param1, i.param2, i.param3, i.param4)),
             i.x, i.y, round(i.z, 3), i.mission_type) for i in items]  # fmt: skip


def _p(value: float) -> float | str:
    return "nan" if math.isnan(value) else round(value, 4)
