"""Vehicles the simulation does not run, attached on every kind of link and in every role but the intruder's
(tests/integration/test_attach.py flies that one): TCP and a serial line (a pseudo-terminal) as UDP, shown in the
status, detached and attached again while ``swarm up`` runs, the supervisor under another sysid; a signed link; and
four drones following a leader that flies itself. Each vehicle is a pymavlink script (tests/integration/
scripted_vehicle.py): nothing of it reaches the simulated world except through MAVLink.

Policy: loopback only (--no-forward); leased instances (tests/integration/instances.py); the vehicles' ports picked by
the system; paced at 1x (an attached vehicle keeps wall time); every process stopped by PID; time limits.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink

from gcs.fleet.attachments import SHARE_RADIUS_M, SHARE_RATE_HZ
from gcs.flight.geodesy import DEFAULT_ORIGIN, GeoPoint
from tests.integration.instances import Leases
from tests.integration.mission_flight import fly_mission
from tests.integration.scripted_vehicle import (
    PtyLink,
    ScriptedVehicle,
    TcpServerLink,
    UdpLink,
    hover_then_circle,
)
from tests.integration.test_attach import CROSSING, FRAME, INTRUDER_SYSID, MIN_CLEARANCE_M, SWARM, free_udp_port

pytestmark = [pytest.mark.sim_only]  # lines, status and counts run beside the rest; the long flight: acceptance


@contextlib.contextmanager
def swarm_up_beside(vehicle: ScriptedVehicle, first: int, env: dict[str, str], *extra: str,
                    drones: int = 1) -> Iterator[tuple[subprocess.Popen[str], list[str]]]:  # fmt: skip
    """``swarm up`` with ``vehicle`` attached as an intruder: the supervisor and what it said until its drones were up
    (or until it ended); at the end it is killed if the test left it running, and the vehicle stops."""
    try:
        proc = subprocess.Popen([*SWARM, "up", "-n", str(drones), "--first-instance", str(first), "--attach",
                                 f"intruder={vehicle.link.url()}", "--no-forward", "--no-view", *extra],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)  # fmt: skip
        try:
            lines: list[str] = []
            assert proc.stdout is not None
            for line in proc.stdout:
                lines.append(line)
                if "drones up" in line:
                    break
            yield proc, lines
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    finally:
        vehicle.stop()


def _status_rows(env: dict[str, str]) -> dict[int, str]:
    status = subprocess.run([*SWARM, "status"], capture_output=True, text=True, env=env, timeout=30)
    assert status.returncode == 0, status
    return {int(r.split()[0]): r for r in status.stdout.splitlines()[1:]}


@pytest.mark.timeout(180)
@pytest.mark.parametrize("kind", ["tcp", "serial"])
def test_a_vehicle_on_tcp_or_a_serial_line_is_attached_shown_in_the_status_detached_and_attached_again(
    kind: str, tmp_path: Path, instances: Leases
) -> None:
    # GIVEN a vehicle hovering 5 m north-east of the origin, served on a TCP port (a Wi-Fi bridge, another SITL) or
    # on a serial line (a pseudo-terminal standing in for a telemetry radio's USB port)
    link = TcpServerLink() if kind == "tcp" else PtyLink()
    vehicle = ScriptedVehicle(sysid=INTRUDER_SYSID, link=link, origin=DEFAULT_ORIGIN,
                              path=lambda _t: (5.0, 5.0, -3.0)).start()  # fmt: skip
    env = {**os.environ, "SWARM_STATE_DIR": str(tmp_path / "state")}
    # WHEN a swarm is brought up with it attached (over TCP, the supervisor as sysid 240: a QGroundControl beside it
    # may use 255)
    sysid_args = ["--gcs-sysid", "240"] if kind == "tcp" else []
    with swarm_up_beside(vehicle, instances(1), env, *sysid_args) as (proc, lines):
        # THEN the attach is said, and the status lists it beside the simulated drone, where it is
        described = link.url()
        assert f"swarm: attached intruder sysid {INTRUDER_SYSID} on {described}\n" in lines, lines
        rows = _status_rows(env)
        assert len(rows) == 2 and INTRUDER_SYSID in rows, rows
        row = rows[INTRUDER_SYSID]
        assert f"external: intruder on {described}" in row, row
        lat, lon, alt = (float(v) for v in row.split("  external:")[0].split()[-5:-2])  # ... lat lon alt batt link
        north, east, _ = FRAME.ned_from_geo(GeoPoint(lat_deg=lat, lon_deg=lon, alt_amsl_m=DEFAULT_ORIGIN.alt_amsl_m))
        assert (north, east) == pytest.approx((5.0, 5.0), abs=0.05) and alt == pytest.approx(3.0, abs=0.01), row
        # AND the simulated drone takes its commands from that sysid (and answers it): it takes off
        takeoff = subprocess.run([*SWARM, "takeoff", "--alt", "2"], capture_output=True, text=True, env=env, timeout=60)
        assert takeoff.returncode == 0, takeoff
        # AND 'swarm detach' lets it go, 'swarm attach' takes it back while the swarm runs
        detached = subprocess.run([*SWARM, "detach", str(INTRUDER_SYSID)], capture_output=True, text=True, env=env,
                                  timeout=30)  # fmt: skip
        assert detached.stdout == f"swarm: detached sysid {INTRUDER_SYSID}\n", detached
        assert INTRUDER_SYSID not in _status_rows(env)
        again = subprocess.run([*SWARM, "attach", f"intruder={link.url()}"], capture_output=True, text=True, env=env,
                               timeout=60)  # fmt: skip
        assert again.stdout == f"swarm: attached intruder sysid {INTRUDER_SYSID} on {described}\n", again
        assert INTRUDER_SYSID in _status_rows(env)
        # AND an attach the swarm cannot take is one line and exit code 2, the swarm untouched
        twice = subprocess.run([*SWARM, "attach", f"intruder={link.url()}"], capture_output=True, text=True, env=env,
                               timeout=60)  # fmt: skip
        assert twice.returncode == 2 and twice.stderr.count("\n") == 1, twice
        nobody = subprocess.run([*SWARM, "detach", "77"], capture_output=True, text=True, env=env, timeout=30)
        assert nobody.returncode == 2 and "no attached vehicle with sysid 77" in nobody.stderr, nobody
        assert len(_status_rows(env)) == 2

        # AND 'swarm follow --attached' follows an attached leader: refused with one line while it is an intruder,
        # flown once it is attached again as the leader
        def follow() -> subprocess.CompletedProcess[str]:
            return subprocess.run([*SWARM, "follow", "--attached", "--alt", "2", "--spacing", "3"],
                                  capture_output=True, text=True, env=env, timeout=60)  # fmt: skip

        refused = follow()
        assert refused.returncode == 2 and "no attached leader" in refused.stderr, refused
        subprocess.run([*SWARM, "detach", str(INTRUDER_SYSID)], capture_output=True, text=True, env=env, timeout=30)
        led = subprocess.run([*SWARM, "attach", f"leader={link.url()}"], capture_output=True, text=True, env=env,
                             timeout=60)  # fmt: skip
        assert led.returncode == 0, led
        following = follow()
        assert following.stdout == f"swarm: following attached leader sysid {INTRUDER_SYSID}\n", following

        # AND 'swarm require' checks an invariant from now on (docs/invariants.md); a bad one is one line, exit code 2
        def require(*words: str) -> subprocess.CompletedProcess[str]:
            return subprocess.run([*SWARM, "require", *words], capture_output=True, text=True, env=env, timeout=30)

        taken = require("separation", "min_m=0.5", "name=apart", "drones=[1]")
        assert taken.stdout == "swarm: checking apart always\n", taken
        for words, said in ((("fence",), "missing field 'radius_m'"), (("separation", "min_m=1", "name=apart"),
                                                                        "'apart' is checked already")):  # fmt: skip
            refused = require(*words)
            assert refused.returncode == 2 and said in refused.stderr and refused.stderr.count("\n") == 1, refused
        # AND 'swarm down' ends it cleanly, the attached vehicle told nothing
        assert subprocess.run([*SWARM, "down"], capture_output=True, text=True, env=env, timeout=30).returncode == 0
        assert proc.wait(timeout=60) == 0


@pytest.mark.timeout(120)
def test_a_signed_link_takes_the_vehicle_that_signs_with_its_key_and_nothing_unsigned(
    tmp_path: Path, instances: Leases
) -> None:
    key = bytes(range(32))
    key_file = tmp_path / "vehicle.key"
    key_file.write_text(key.hex() + "\n")
    env = {**os.environ, "SWARM_STATE_DIR": str(tmp_path / "state")}
    first = instances(1)
    for signs, attached in ((True, True), (False, False)):
        link = UdpLink(free_udp_port())
        vehicle = ScriptedVehicle(sysid=INTRUDER_SYSID, link=link, origin=DEFAULT_ORIGIN, path=CROSSING,
                                  signing_key=key if signs else None).start()  # fmt: skip
        # GIVEN a link signed with the vehicle's key WHEN the vehicle signs (or does not)
        with swarm_up_beside(vehicle, first, env, "--attach-signing-key", str(key_file)) as (proc, lines):
            if attached:
                # THEN it is attached
                assert f"swarm: attached intruder sysid {INTRUDER_SYSID} on {link.url()}\n" in lines, lines
                # AND while the swarm runs, 'swarm attach --signing-key' takes it again after a detach with its key, and
                # not with another
                other_key = tmp_path / "other.key"
                other_key.write_text(bytes(range(1, 33)).hex() + "\n")
                again = ["attach", f"intruder={link.url()}", "--signing-key"]
                for command, code in ((["detach", str(INTRUDER_SYSID)], 0), ([*again, str(other_key)], 2),
                                      ([*again, str(key_file)], 0)):  # fmt: skip
                    done = subprocess.run([*SWARM, *command], capture_output=True, text=True, env=env, timeout=60)
                    assert done.returncode == code, done
                assert subprocess.run([*SWARM, "down"], capture_output=True, text=True, env=env,
                                      timeout=30).returncode == 0  # fmt: skip
                assert proc.wait(timeout=60) == 0
            else:
                # OR nothing it sends is heard: the attach fails with one line, exit code 2, before any drone starts
                assert proc.wait(timeout=60) == 2
                assert lines[-1] == f"swarm: error: --attach intruder={link.url()}: no vehicle HEARTBEAT within 10 s\n"


LEADER_MISSION = """
name = "follow_a_real_leader"
[swarm]
drones = 4
spacing_m = 2.5

[[swarm.attach]]
role = "leader"
url = "udpin:127.0.0.1:{port}"

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "follow_attached"
alt_m = 3.0
duration_s = 55.0

[[steps]]
action = "land"
"""


@pytest.mark.acceptance  # a long flight paced at 1x beside a vehicle that keeps wall time...
@pytest.mark.wall_clock  # ...so with the machine to itself (tests/wall_clock.py)
@pytest.mark.timeout(240)
def test_four_drones_follow_a_leader_that_flies_itself_in_a_v_and_keep_clear_of_it(
    tmp_path: Path, instances: Leases
) -> None:
    # GIVEN a leader the ground station never commands (a pymavlink script: 8 m north of the origin, then once the
    # drones are up a circle of 10 m radius at 1 m/s, a smooth turn as a pilot flies one) attached to a swarm of four
    port = free_udp_port()
    leader = ScriptedVehicle(sysid=INTRUDER_SYSID, link=UdpLink(port), origin=DEFAULT_ORIGIN,
                             path=hover_then_circle((18.0, 0.0), 10.0, 3.0, 1.0, wait_s=12.0)).start()  # fmt: skip
    mission = tmp_path / "follow_a_real_leader.toml"
    mission.write_text(LEADER_MISSION.format(port=port))
    try:
        metrics, result = fly_mission(mission, [], tmp_path, 200, instances)
    finally:
        leader.stop()
    # THEN the leader is attached, and the drones follow it in a V: in formation within 15 s of the step's start (they
    # join from the ground grid while it hovers; 11.7 s on an idle machine) and within 0.5 m RMS of their slots from
    # then on, as it flies its circle. The leader keeps wall time and the drones the simulated one: on a machine that
    # holds the drones below real time it outruns them, so the 15 s are of its time (18.8 s of theirs under the
    # suite's load, the drones at 0.74x)
    assert f"swarm: attached leader sysid {INTRUDER_SYSID} on udpin:127.0.0.1:{port}" in result.stdout
    step = next(s for s in metrics["steps"] if s["name"] == "follow attached")
    slowest = min(1.0, metrics["realtime_factor_min"])
    assert step["time_to_formation_s"] is not None and step["time_to_formation_s"] * slowest < 15.0, (step, slowest)
    assert step["formation_rms_m"] < 0.5, step
    # AND they flew round with it (the leader's 40-odd metres each at least), touching nothing, clear of the leader
    assert metrics["collisions"] == 0, metrics["collision_events"]
    assert min(metrics["distance_flown_m"].values()) > 35.0, metrics["distance_flown_m"]
    assert metrics["attached"][str(INTRUDER_SYSID)]["min_separation_m"] >= MIN_CLEARANCE_M


@pytest.mark.timeout(120)
@pytest.mark.parametrize("north_m", [5.0, 150.0], ids=["near", "far"])
def test_the_simulated_drones_reach_an_attached_vehicle_as_traffic_within_its_radius_and_budget(
    north_m: float, tmp_path: Path, instances: Leases
) -> None:
    # GIVEN a vehicle hovering near the swarm (5 m) or beyond the radius the ground station shares it (150 m)
    link = UdpLink(free_udp_port())
    vehicle = ScriptedVehicle(sysid=INTRUDER_SYSID, link=link, origin=DEFAULT_ORIGIN,
                              path=lambda _t: (north_m, 0.0, -3.0)).start()  # fmt: skip
    env = {**os.environ, "SWARM_STATE_DIR": str(tmp_path / "state")}
    first = instances(3)
    with swarm_up_beside(vehicle, first, env, drones=3) as (proc, _lines):
        link.read()  # what came before the drones were up
        # WHEN the swarm runs for 3 s
        time.sleep(3.0)
        traffic = [m for m in link.read() if m.get_type() == "ADSB_VEHICLE"]
        status = subprocess.run([*SWARM, "status"], capture_output=True, text=True, env=env, timeout=30).stdout
        assert subprocess.run([*SWARM, "down"], capture_output=True, text=True, env=env, timeout=30).returncode == 0
        assert proc.wait(timeout=60) == 0
    if north_m > SHARE_RADIUS_M:
        # THEN a vehicle beyond the radius is told nothing
        assert traffic == []
        return
    # THEN the nearby vehicle hears each simulated drone as traffic, at most SHARE_RATE_HZ, where its status says it is
    drones = {first + 1, first + 2, first + 3}
    assert {m.ICAO_address for m in traffic} == drones, traffic
    for sysid in drones:
        reports = [m for m in traffic if m.ICAO_address == sysid]
        assert 2 <= len(reports) <= 3.0 * SHARE_RATE_HZ + 1, (sysid, len(reports))
        row = next(r for r in status.splitlines()[1:] if int(r.split()[0]) == sysid).split()
        lat, lon = float(row[3]), float(row[4])
        last = reports[-1]
        assert last.callsign == f"SYS{sysid}" and last.emitter_type == mavlink.ADSB_EMITTER_TYPE_UAV
        assert (last.lat * 1e-7, last.lon * 1e-7) == pytest.approx((lat, lon), abs=1e-5)  # about a metre
