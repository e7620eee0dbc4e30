"""``swarm fly --signing-key`` end to end: the supervisor signs what it sends, its drones sign theirs and require
signed messages, the mission flies (it could not: every command and setpoint would be dropped otherwise), the
forward ground station receives the drones' frames with their signatures intact, and the report says signing was
on. A bad key file is one line and exit code 2, for ``swarm`` and for ``sitl``.

Policy: loopback only; leased instances (tests/integration/instances.py); a time limit on every test.
"""

from __future__ import annotations

import hashlib
import json
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from tests.integration.instances import Leases
from tests.integration.mission_flight import mission_drones

pytestmark = [pytest.mark.sim_only]

SWARM = [sys.executable, "-m", "gcs.cli"]
SITL = [sys.executable, "-m", "sitl.cli"]
PASSPHRASE = "swarm signing mission"
KEY = hashlib.sha256(PASSPHRASE.encode()).digest()

MISSION = """
name = "signed_hop"
description = "2 drones: take off, hold a line, land (signed)"

[swarm]
drones = 2
layout = "line"
spacing_m = 3.0

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "formation"
shape = "line"
spacing_m = 3.0
alt_m = 3.0
hold_s = 5.0

[[steps]]
action = "land"
"""


@pytest.mark.timeout(240)
def test_a_signed_lockstep_mission_flies_forwards_signed_frames_and_reports_signing_on(
    tmp_path: Path, instances: Leases
) -> None:
    # GIVEN a key file, a short mission and a ground station listening on the forward port
    key_file = tmp_path / "swarm.key"
    key_file.write_text(PASSPHRASE + "\n")
    mission = tmp_path / "signed_hop.toml"
    mission.write_text(MISSION)
    first = instances(mission_drones(mission))
    report = tmp_path / "report"
    ground_station = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ground_station.bind(("127.0.0.1", 0))
    ground_station.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    try:
        # WHEN the mission is flown in lockstep with the key
        result = subprocess.run(
            [*SWARM, "fly", str(mission), "--lockstep", "--first-instance", str(first),
             "--report", str(report), "--forward", f"127.0.0.1:{ground_station.getsockname()[1]}",
             "--signing-key", str(key_file)],
            capture_output=True, text=True, timeout=220,
        )  # fmt: skip
        forwarded = _drain(ground_station)
    finally:
        ground_station.close()
    # THEN it completes: the drones took the supervisor's signed commands and setpoints
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    metrics = json.loads((report / "metrics.json").read_text())
    assert metrics["collisions"] == 0 and len(metrics["sysids"]) == 2
    line = next(s for s in metrics["steps"] if s["name"] == "line")
    assert line["formation_rms_m"] is not None and line["formation_rms_m"] < 0.3
    # AND the report says signing was on, naming the key by its id only
    key_id = hashlib.sha256(KEY).hexdigest()[:8]
    assert metrics["signing"] == {"on": True, "key_id": key_id}
    assert f"MAVLink signing: on (key {key_id}" in (report / "summary.txt").read_text()
    assert KEY.hex() not in result.stdout + result.stderr
    # AND the forward ground station got the drones' frames as they sent them: signed, and valid under the key
    parser = mavlink.MAVLink(None)
    parser.signing.secret_key = KEY
    parser.signing.allow_unsigned_callback = lambda _mav, _msg_id: False
    for data in forwarded:
        parser.parse_buffer(data)
    assert parser.signing.goodsig_count > 100, parser.signing.goodsig_count
    assert parser.signing.reject_count == 0 and parser.signing.badsig_count == 0
    # AND the flight log holds the traffic without its signatures, as the signing specification asks of logs
    log = mavutil.mavlink_connection(str(report / "flight.tlog"))
    logged = 0
    while (msg := log.recv_msg()) is not None:
        assert not msg.get_header().incompat_flags & mavlink.MAVLINK_IFLAG_SIGNED, msg
        logged += 1
    log.close()
    assert logged > 100
    # AND every drone dropped nothing it should have taken (its log's closing line)
    logs = sorted(p for p in (report / "logs").glob("drone-*.log") if p.stem.removeprefix("drone-").isdigit())
    assert len(logs) == 2
    for log in logs:
        text = log.read_text()
        assert "MAVLink signing: key " + key_id in text, text[-2000:]
        assert "0 unsigned dropped, 0 bad signatures, 0 replays" in text, text[-2000:]


def _drain(sock: socket.socket) -> list[bytes]:
    sock.setblocking(False)
    out = []
    while True:
        try:
            out.append(sock.recv(65535))
        except BlockingIOError:
            return out


@pytest.mark.timeout(60)
@pytest.mark.parametrize(
    ("content", "reason"), [(None, "cannot read"), (b"", "empty"), (b"0" * 64, "all-zero"), (b"a\nb\n", "one line")]
)
def test_a_bad_key_file_is_one_line_and_exit_code_2(tmp_path: Path, content: bytes | None, reason: str) -> None:
    key_file = tmp_path / "swarm.key"
    if content is not None:
        key_file.write_bytes(content)
    for command in (  # the key file is read before anything starts: the instance is only an argument here
        [*SWARM, "up", "-n", "1", "--first-instance", "170", "--no-forward", "--signing-key"],
        [*SITL, "--instance", "170", "--signing-key"],
    ):
        result = subprocess.run([*command, str(key_file)], capture_output=True, text=True, timeout=50)
        assert result.returncode == 2, result.stdout + result.stderr
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and reason in lines[0] and "Traceback" not in result.stderr, result.stderr
