"""A vehicle the simulation does not run, attached to a flying swarm (``swarm fly --attach``): an intruder played by a
plain pymavlink script crosses a rotating circle of six simulated drones, then stops on the circle and falls silent.
Nothing of it reaches the simulated world except through MAVLink.

One flight, many checks: the attach is said; the drones, told of the intruder as traffic (ADSB_VEHICLE: a body that
does not avoid in turn) and seeing it with their cameras, keep clear of it while it crosses, and after it went silent
(its body stays where it was last known, they are told of it there, and their keep-out grows with its age); its
loss is said once; the flight log holds its messages. Bad attaches are one line and exit code 2, before any drone
starts. The other links and roles: tests/integration/test_attach_links.py and test_attach_member.py.

Policy: loopback only (--no-forward); leased instances (tests/integration/instances.py); the intruder on a port the
system picked; paced at 1x (an attached vehicle keeps wall time); every process stopped by PID; time limits.
"""

from __future__ import annotations

import json
import math
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from pymavlink import mavutil

from gcs.flight.geodesy import DEFAULT_ORIGIN, GeoPoint, NedFrame
from tests.integration.instances import Leases
from tests.integration.scripted_vehicle import (
    ScriptedVehicle,
    UdpLink,
    back_and_forth,
)

pytestmark = [pytest.mark.sim_only]  # the long flights: acceptance, with the machine to themselves (wall_clock)

SWARM = [sys.executable, "-m", "gcs.cli"]
INTRUDER_SYSID = 250  # a sysid no drone of the suite has (tests/integration/instances.py)
MIN_CLEARANCE_M = 1.0  # centre to centre; two bodies touch at 0.7 m
CROSSING = back_and_forth((-9.0, 0.5), (9.0, 0.5), 3.0, 1.0)  # across the circle at its altitude, 1 m/s
ENTER_S = 14.0  # it waits outside until the circle has formed (the drones do not avoid while they take off)...
PARK_S = ENTER_S + 23.0  # ...crosses, and on its way back stops on the circle (north 4 m)...
SILENT_S = PARK_S + 3.0  # ...and falls silent there, the circle still turning through it
AGED_S = 12.0  # its last report this old, the drones' keep-out around it is 3 m wider (AVOID_STALE_MAX)...
AGED_CLEARANCE_M = 3.5  # ...and they keep at least this far from it (4.3 m measured)
MISSION = """
name = "circle_with_intruder"
[swarm]
drones = 6
spacing_m = 2.5

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "formation"
shape = "circle"
radius_m = 4.0
alt_m = 3.0
angular_rate_radps = 0.3
hold_s = 45.0

[[steps]]
action = "land"
"""


def crossing_then_parked(t_s: float) -> tuple[float, float, float]:
    return CROSSING(min(max(t_s - ENTER_S, 0.0), PARK_S - ENTER_S))


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


@dataclass
class Flown:
    result: subprocess.CompletedProcess[str]
    metrics: dict[str, Any]
    tlog: Path
    port: int


@pytest.fixture(scope="module")
def flown(tmp_path_factory: pytest.TempPathFactory, module_instances: Leases) -> Iterator[Flown]:
    tmp = tmp_path_factory.mktemp("attach")
    mission = tmp / "circle_with_intruder.toml"
    mission.write_text(MISSION)
    port = free_udp_port()
    intruder = ScriptedVehicle(
        sysid=INTRUDER_SYSID, link=UdpLink(port), origin=DEFAULT_ORIGIN, path=crossing_then_parked
    )
    intruder.start()
    silence = _silence_at(intruder, SILENT_S)
    try:
        result = subprocess.run(
            [*SWARM, "fly", str(mission), "--first-instance", str(module_instances(6)), "--attach",
             f"intruder=udpin:127.0.0.1:{port}", "--report", str(tmp / "report"), "--no-view", "--no-forward"],
            capture_output=True, text=True, timeout=240,
        )  # fmt: skip
    finally:
        silence.cancel()
        intruder.stop()
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    yield Flown(result, json.loads((tmp / "report" / "metrics.json").read_text()), tmp / "report" / "flight.tlog", port)


def _silence_at(vehicle: ScriptedVehicle, after_s: float) -> threading.Timer:
    timer = threading.Timer(after_s, vehicle.silent.set)
    timer.start()
    return timer


def _positions(tlog: Path) -> tuple[dict[int, list[tuple[float, tuple[float, ...]]]], list[tuple[float, Any]]]:
    """Every GLOBAL_POSITION_INT of the flight log: the drones' (time, lat, lon, alt) by sysid, and the intruder's
    messages with their times."""
    log = mavutil.mavlink_connection(str(tlog))
    drones: dict[int, list[tuple[float, tuple[float, ...]]]] = {}
    intruder: list[tuple[float, Any]] = []
    try:
        while (msg := log.recv_match(type="GLOBAL_POSITION_INT")) is not None:
            t = float(msg._timestamp)
            if msg.get_srcSystem() == INTRUDER_SYSID:
                intruder.append((t, msg))
            else:
                drones.setdefault(msg.get_srcSystem(), []).append((t, (msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3)))
    finally:
        log.close()
    return drones, intruder


FRAME = NedFrame(DEFAULT_ORIGIN)


def _ned(lat: float, lon: float, alt: float) -> tuple[float, float, float]:
    return FRAME.ned_from_geo(GeoPoint(lat_deg=lat, lon_deg=lon, alt_amsl_m=alt))


def _intruder_at(intruder: list[tuple[float, Any]], t: float) -> tuple[float, float, float] | None:
    """The intruder's own last report at or before ``t``, carried on at its velocity (its truth, as it flies it),
    NED from the origin."""
    before = [m for ti, m in intruder if ti <= t]
    if not before:
        return None
    m = before[-1]
    dt = t - float(m._timestamp)
    n, e, d = _ned(m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3)
    return n + m.vx * 0.01 * dt, e + m.vy * 0.01 * dt, d + m.vz * 0.01 * dt


@pytest.mark.acceptance  # a long flight paced at 1x beside a vehicle that keeps wall time...
@pytest.mark.wall_clock  # ...so with the machine to itself (tests/wall_clock.py)
@pytest.mark.timeout(300)
def test_the_attach_and_the_intruders_silence_are_each_said_once(flown: Flown) -> None:
    out = flown.result.stdout
    assert f"swarm: attached intruder sysid {INTRUDER_SYSID} on udpin:127.0.0.1:{flown.port}" in out
    lost = [line for line in out.splitlines() if f"attached vehicle {INTRUDER_SYSID} lost at t=" in line]
    assert len(lost) == 1 and "its body stays where it was last known" in lost[0], out[-3000:]


@pytest.mark.acceptance  # a long flight paced at 1x beside a vehicle that keeps wall time...
@pytest.mark.wall_clock  # ...so with the machine to itself (tests/wall_clock.py)
@pytest.mark.timeout(300)
def test_the_drones_keep_clear_of_the_intruder_as_it_crosses_and_farther_as_what_they_know_of_it_ages(
    flown: Flown,
) -> None:
    # GIVEN six drones on a rotating circle, told of the intruder as traffic, and an intruder
    # crossing the circle, then parked on it and silent
    drones, intruder = _positions(flown.tlog)
    assert len(drones) == 6 and len(intruder) > 100
    # THEN nobody touched anything
    assert flown.metrics["collisions"] == 0, flown.metrics["collision_events"]
    # AND every drone kept at least MIN_CLEARANCE_M from the intruder at every report, while it flew and after its
    # last report (its body stays: the drones still had to go round it)
    last_report_s = intruder[-1][0]
    closest = math.inf
    closest_silent = math.inf
    closest_aged = math.inf  # AGED_S and more after its last report
    for track in drones.values():
        for t, here in track:
            there = _intruder_at(intruder, t)
            if there is None:
                continue
            d = math.dist(_ned(*here), there)
            closest = min(closest, d)
            if t > last_report_s:
                closest_silent = min(closest_silent, d)
            if t > last_report_s + AGED_S:
                closest_aged = min(closest_aged, d)
    assert closest >= MIN_CLEARANCE_M, closest
    assert math.isfinite(closest_silent) and closest_silent >= MIN_CLEARANCE_M, closest_silent
    # AND once silent it is reported where it was last known, its age growing, and the drones' keep-out around it
    # grows with that age (AVOID_STALE_RATE 0.25 m/s, at most AVOID_STALE_MAX 3 m more): 12 s on, they stay beyond
    # AGED_CLEARANCE_M (with the cameras alone they came within 1.45 m)
    assert math.isfinite(closest_aged) and closest_aged >= AGED_CLEARANCE_M, closest_aged
    # AND the report says the same from its own samples: the intruder's closest approach, to within the resampling
    attached = flown.metrics["attached"][str(INTRUDER_SYSID)]
    assert attached["role"] == "intruder" and attached["link"] == f"udpin:127.0.0.1:{flown.port}"
    assert attached["min_separation_m"] >= MIN_CLEARANCE_M and attached["closest_drone"] in drones
    assert attached["min_separation_m"] == pytest.approx(closest, abs=0.15)
    # AND they did have to avoid it: the circle passes through where it crossed and where it stopped
    assert flown.metrics["avoidance_events"] >= 1
    assert closest < 2.5, closest


def _fly_attach(
    tmp_path: Path, first: int, *attach: str, extra: tuple[str, ...] = ()
) -> subprocess.CompletedProcess[str]:
    mission = tmp_path / "circle_with_intruder.toml"
    mission.write_text(MISSION)
    args = [a for spec in attach for a in ("--attach", spec)]
    return subprocess.run([*SWARM, "fly", str(mission), "--first-instance", str(first), *args, *extra, "--report",
                           str(tmp_path / "report"), "--no-view", "--no-forward"],
                          capture_output=True, text=True, timeout=60)  # fmt: skip


@pytest.mark.timeout(120)
def test_bad_attaches_are_one_line_and_exit_2_before_any_drone_starts(tmp_path: Path, instances: Leases) -> None:
    first = instances(6)
    port = free_udp_port()
    cases = [
        (("pilot=udpin:127.0.0.1:1",), (), "no role 'pilot'"),
        (("member=udpin:127.0.0.1:1",), ("--attach-keep-in", "0.2"), "the keep-in must be more than 0.5 m"),
        (("intruder=udpin:127.0.0.1",), (), "is no vehicle URL"),
        ((f"intruder=udpin:127.0.0.1:{port}",), ("--lockstep",), "runs paced at speed 1"),
        ((f"intruder=udpin:127.0.0.1:{port}",), ("--speed", "2"), "runs paced at speed 1"),
        ((f"intruder=udpin:127.0.0.1:{port}",), (), "no vehicle HEARTBEAT within 10 s"),  # nobody there
    ]
    for attach, extra, said in cases:
        result = _fly_attach(tmp_path, first, *attach, extra=extra)
        assert result.returncode == 2, (attach, result.stdout[-2000:], result.stderr[-2000:])
        assert result.stderr.count("\n") == 1 and said in result.stderr, (attach, result.stderr)
        assert "spawning" not in result.stdout, result.stdout
    # A port someone holds
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as holder:
        holder.bind(("127.0.0.1", 0))
        taken = holder.getsockname()[1]
        result = _fly_attach(tmp_path, first, f"intruder=udpin:127.0.0.1:{taken}")
    assert result.returncode == 2 and "cannot open the link" in result.stderr, result.stderr


@pytest.mark.timeout(180)
def test_a_vehicle_with_a_simulated_drones_sysid_far_away_or_nowhere_is_refused_before_any_drone_starts(
    tmp_path: Path, instances: Leases
) -> None:
    first = instances(6)
    cases = [
        (dict(sysid=first + 2), f"sysid {first + 2} is a simulated drone's"),
        (dict(sysid=INTRUDER_SYSID, path=lambda _t: (600.0, 0.0, -3.0)),
         f"sysid {INTRUDER_SYSID} is 600 m from the swarm's origin (at most 500 m)"),
        (dict(sysid=INTRUDER_SYSID, reports_position=False), f"sysid {INTRUDER_SYSID} sent no GLOBAL_POSITION_INT"),
        (dict(sysid=240), "sysid 240 is the ground station's own"),  # with --gcs-sysid 240 (below)
    ]  # fmt: skip
    for overrides, said in cases:
        port = free_udp_port()
        settings: dict[str, Any] = {"link": UdpLink(port), "origin": DEFAULT_ORIGIN, "path": CROSSING, **overrides}
        vehicle = ScriptedVehicle(**settings).start()
        try:
            result = _fly_attach(tmp_path, first, f"intruder=udpin:127.0.0.1:{port}", extra=("--gcs-sysid", "240"))
        finally:
            vehicle.stop()
        assert result.returncode == 2, (said, result.stderr)
        assert said in result.stderr and result.stderr.count("\n") == 1, result.stderr
        assert "spawning" not in result.stdout
