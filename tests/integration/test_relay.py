"""The neighbour relay with real processes: a drone's neighbour table follows another drone's movement.

A test participant joins the swarm the way any MAVLink vehicle would (HEARTBEATs from component 1 to the ground
station's port) and keeps the same NeighbourTable the drones keep, fed by what the relay forwards.
Loopback only; leased instances (tests/integration/instances.py).
"""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink

from gcs.bench.probe import PROBE_SYSIDS, RelayProbe
from sitl.dynamics.plant import DEFAULT_HOME
from sitl.protocol.neighbours import Neighbour, NeighbourTable
from tests.integration.instances import Leases

pytestmark = [pytest.mark.sim_only, pytest.mark.timeout(120)]

OBSERVER_SYSID = 250  # the participant: a sysid no drone of the suite has (tests/integration/instances.py)
SPEED = 2.0


def test_relayed_positions_follow_a_drone_and_arrive_promptly(tmp_path: Path, instances: Leases) -> None:
    first = instances(2)
    both = {first + 1, first + 2}  # the drones' sysids
    env = {**os.environ, "SWARM_STATE_DIR": str(tmp_path / "state")}
    cmd = [sys.executable, "-m", "gcs.cli"]
    args = ["up", "-n", "2", "--speed", str(SPEED), "--first-instance", str(first), "--no-forward"]
    up = subprocess.Popen([*cmd, *args],
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)  # fmt: skip
    relay_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        assert up.stdout is not None
        port = None
        for line in up.stdout:
            match = re.search(r"MAVLink on udp 127\.0\.0\.1:(\d+)", line)
            if match:
                port = int(match.group(1))
                break
        assert port is not None, "swarm up did not report its MAVLink port"
        relay_sock.bind(("127.0.0.1", 0))
        relay_sock.settimeout(0.05)
        me = mavlink.MAVLink(None, srcSystem=OBSERVER_SYSID, srcComponent=1)
        parser = mavlink.MAVLink(None)
        table = NeighbourTable(OBSERVER_SYSID)
        heights: list[float] = []
        t0 = time.monotonic()
        next_heartbeat = 0.0
        took_off = False

        def pump_until(condition: Callable[[], bool], timeout_s: float) -> bool:
            """Keep the participant alive and its table fed until the condition holds (or the timeout passes)."""
            nonlocal next_heartbeat
            end = time.monotonic() + timeout_s
            while time.monotonic() < end:
                if condition():
                    return True
                now = time.monotonic()
                if now >= next_heartbeat:  # join the swarm as a vehicle would
                    hb = mavlink.MAVLink_heartbeat_message(2, 12, 1, 0, 3, 3)
                    relay_sock.sendto(hb.pack(me), ("127.0.0.1", port))
                    next_heartbeat = now + 0.5
                try:
                    data = relay_sock.recv(65535)
                except TimeoutError:
                    continue
                for msg in parser.parse_buffer(data) or []:
                    if msg.get_type() != "GLOBAL_POSITION_INT":
                        continue
                    table.handle(msg, time.monotonic() - t0)
                    if msg.get_srcSystem() == first + 1:
                        heights.append(msg.relative_alt * 1e-3)
            return condition()

        def neighbours() -> dict[int, Neighbour]:
            return {n.sysid: n for n in table.entries(time.monotonic() - t0)}

        # GIVEN a running swarm WHEN the participant has joined THEN both drones appear in its table, fresh
        assert pump_until(lambda: set(neighbours()) == both, 10.0), neighbours()
        now = time.monotonic() - t0
        assert all(n.age_s(now) < 0.5 for n in neighbours().values())
        ground = neighbours()[first + 1].alt_amsl_m
        # WHEN the drones take off to 3 m THEN the table follows: the neighbour's altitude rises by about 3 m
        result = subprocess.run([*cmd, "takeoff", "--alt", "3"], capture_output=True, text=True, env=env, timeout=60)
        assert result.returncode == 0, result.stderr
        took_off = True

        def risen_m() -> float:
            # While `takeoff` ran nobody read the socket, so the entry may have aged out until the next report
            drone = neighbours().get(first + 1)
            return float("-inf") if drone is None else drone.alt_amsl_m - ground

        assert pump_until(lambda: risen_m() > 2.6, 20.0), risen_m()
        pump_until(lambda: False, 2.0)  # it holds there: the table keeps following, it does not run away
        assert 2.6 < risen_m() < 3.4, risen_m()
        assert max(heights) > 2.6 and min(heights) < 0.5
        # WHEN a probe joins as two more vehicles THEN every report of one reaches the other through the relay,
        # and the drones hear the probe too (a router forwards every system's position to every other)
        probe = RelayProbe(port, (DEFAULT_HOME.lat_deg, DEFAULT_HOME.lon_deg, DEFAULT_HOME.alt_amsl_m))
        try:
            stats = probe.run_for(3.0)
        finally:
            probe.close()
        assert stats.sent >= 25 and stats.received >= stats.sent - 1, stats  # the first may precede B joining
        assert 0.0 < stats.median_ms <= stats.p95_ms <= stats.max_ms, stats
        assert pump_until(lambda: PROBE_SYSIDS[0] in neighbours(), 2.0), neighbours()
    finally:
        relay_sock.close()
        if up.poll() is None:
            if took_off:
                subprocess.run([*cmd, "land"], capture_output=True, env=env, timeout=60)
            subprocess.run([*cmd, "down"], capture_output=True, env=env, timeout=60)
            try:
                up.wait(timeout=60)
            except subprocess.TimeoutExpired:
                up.kill()
                up.wait()
