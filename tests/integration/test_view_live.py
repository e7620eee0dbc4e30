"""The live view of a running swarm, opened in a real (headless) browser: every drone drawn where its telemetry says,
and a killed drone marked lost at once. Screenshots of the page go to docs/images/ when SWARM_DOCS_SCREENSHOTS is set.

The reference is independent of the page: a MAVLink client on the supervisor's forward port (as QGroundControl),
whose GLOBAL_POSITION_INT reports are converted into the swarm frame here (gcs/flight/geodesy.py).

Policy: loopback only; leased instances (tests/integration/instances.py); the view on a port the system picks;
paced lockstep at 1x, so the page watches in real time; a time limit; every process stopped by PID.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import signal
import socket
import subprocess
import time
from pathlib import Path

import pytest
from pymavlink import mavutil

from gcs.flight.frames import SwarmFrame
from gcs.flight.geodesy import DEFAULT_ORIGIN, GeoPoint
from tests.integration.browser import Browser
from tests.integration.instances import Leases
from tests.integration.test_swarm import SWARM, children_of, wait_dead

pytestmark = [pytest.mark.sim_only, pytest.mark.timeout(240)]

DOCS_IMAGES = Path(__file__).resolve().parents[2] / "docs" / "images"


@pytest.fixture
def state_env(tmp_path: Path) -> dict[str, str]:
    """The supervisor's control-channel state in the test's own folder (as tests/integration/test_swarm.py)."""
    return {**os.environ, "SWARM_STATE_DIR": str(tmp_path / "state")}


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def telemetry_track(
    link: mavutil.mavfile, seconds: float, *, drain: bool
) -> dict[int, list[tuple[float, float, float]]]:
    """Every GLOBAL_POSITION_INT of every drone heard within ``seconds``, in the swarm frame; with ``drain`` what
    queued up before is dropped first (old news)."""
    frame = SwarmFrame(DEFAULT_ORIGIN)
    out: dict[int, list[tuple[float, float, float]]] = {}
    while drain and link.recv_match(blocking=False) is not None:
        pass
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        msg = link.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=0.05)
        if msg is not None:
            out.setdefault(msg.get_srcSystem(), []).append(frame.ned_from_geo(
                GeoPoint(lat_deg=msg.lat * 1e-7, lon_deg=msg.lon * 1e-7, alt_amsl_m=msg.alt * 1e-3)
            ))  # fmt: skip
    return out


def test_the_live_view_draws_nine_drones_where_their_telemetry_says_and_a_killed_one_lost_at_once(
    state_env: dict[str, str], instances: Leases
) -> None:
    first = instances(9)
    forward = free_udp_port()
    link = mavutil.mavlink_connection(f"udpin:127.0.0.1:{forward}", source_system=250)
    # paced at 1x: the page is judged against telemetry heard in wall-time windows, and a kill against a wall-clock 2 s
    proc = subprocess.Popen([*SWARM, "up", "-n", "9", "--lockstep", "--speed", "1", "--drones-per-process", "auto",
                             "--first-instance", str(first), "--forward", f"127.0.0.1:{forward}",
                             "--view-port", "0"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=state_env)  # fmt: skip
    children: list[int] = []
    try:
        assert proc.stdout is not None
        url = None
        for line in proc.stdout:
            found = re.search(r"live view on (http://127\.0\.0\.1:\d+/)", line)
            url = found.group(1) if found else url
            if "drones up" in line:
                break
        assert url is not None
        children = [*children_of(proc.pid), *(d for c in children_of(proc.pid) for d in children_of(c))]

        def cli(*args: str) -> None:
            result = subprocess.run([*SWARM, *args], capture_output=True, text=True, env=state_env, timeout=60)
            assert result.returncode == 0, result.stderr

        # GIVEN nine drones flying a rotating circle
        cli("takeoff", "--alt", "3")
        cli("formation", "circle", "--radius", "4", "--rate", "0.2")
        with Browser() as browser:
            # WHEN the page is opened
            browser.open(url)
            browser.wait_for("window.swarmView && swarmView.frames() > 20 && "
                             "Object.keys(swarmView.drones()).length === 9", 60)  # fmt: skip
            # (once the circle has formed: every drone within 0.5 m of its slot, as the page shows them)
            browser.wait_for("swarmView.frame().drones.every((d) => d.slot_ned_m && Math.hypot("
                             "...d.pos_ned_m.map((v, k) => v - d.slot_ned_m[k])) < 0.5)", 60)  # fmt: skip
            # THEN each drone of the page's own scene is within 0.5 m of where its telemetry put it about then: the
            # page shows the newest position it was sent, so it is compared with the telemetry heard from half a
            # second before the page was read to 0.3 s after (the drones move at 0.8 m/s: comparing with one
            # sample taken after the read would measure the time between them, not the page)
            before = telemetry_track(link, 0.5, drain=True)
            scene = browser.evaluate("swarmView.drones()")
            after = telemetry_track(link, 0.3, drain=False)
            heard = {s: before.get(s, []) + after.get(s, []) for s in {*before, *after}}
            assert sorted(int(s) for s in scene) == sorted(heard) == list(range(first + 1, first + 10))
            gaps = {s: min(math.dist(scene[str(s)]["pos_ned_m"], p) for p in track) for s, track in heard.items()}
            assert max(gaps.values()) < 0.5, gaps
            assert browser.evaluate("swarmView.webgl()") is True  # drawn in 3D, not only on the map
            rows = browser.evaluate("document.querySelectorAll('#drones tbody tr').length")
            assert rows == 9
            # WHEN a drone is clicked THEN its details show what its camera sees, fetched over MAVLink image
            # transmission and kept fresh
            clicked = first + 2  # the second drone
            browser.evaluate(f"document.querySelector('#drones tbody tr[data-sysid=\"{clicked}\"]').click()")
            shot = browser.wait_for(
                f"swarmView.camera() && swarmView.camera().sysid === {clicked} && swarmView.camera()", 10
            )
            assert (shot["width"], shot["height"]) == (4 * 160, 120), shot  # the default rig's four cameras
            browser.wait_for(f"swarmView.camera().time_s > {shot['time_s']}", 10)
            if os.environ.get("SWARM_DOCS_SCREENSHOTS"):
                browser.screenshot(DOCS_IMAGES / "live-view.png")
            # WHEN a drone's process is killed THEN the page marks it lost within 2 s of the kill (the supervisor
            # has done it when `swarm kill` returns; the command's own start-up is not the page's latency)
            killed = first + 5  # the fifth drone's sysid
            cli("kill", str(killed))
            killed_at = time.monotonic()
            browser.wait_for(f"swarmView.drones()['{killed}'].state === 'lost'", 5.0)
            assert time.monotonic() - killed_at < 2.0
            assert browser.evaluate(f"swarmView.drones()['{killed}'].colour") == "#212121"
    finally:
        with contextlib.suppress(ProcessLookupError):
            proc.send_signal(signal.SIGINT)
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        assert wait_dead(children, 15) == []
        link.close()
