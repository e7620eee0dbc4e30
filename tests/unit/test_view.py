"""The live view without a simulation: frames from fleet views (gcs/view/scene.py), the server that serves the page
and streams frames to several clients at once (gcs/view/server.py), and bad view options as one line, exit code 2."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import math
import random
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from gcs.fleet.telemetry import DroneView
from gcs.view.feed import FramePacer
from gcs.view.scene import ObstacleShape, drone_state, frame
from gcs.view.server import DEFAULT_PORT, ViewError, ViewServer, serve_view

pytestmark = pytest.mark.timeout(60)


def view_of(sysid: int, **fields: Any) -> DroneView:
    return DroneView(sysid=sysid, first_heartbeat_s=0.0, last_heard_s=9.5, **fields)


def test_a_drones_state_is_the_first_that_applies_lost_failsafe_avoiding_armed() -> None:
    avoiding = view_of(1, armed=True, texts=[(1.0, 6, "Avoidance: braking for drone 2")])
    assert drone_state(avoiding, lost=False) == "avoiding"
    assert drone_state(avoiding, lost=True) == "lost"
    ended = view_of(1, armed=True, texts=[(1.0, 6, "Avoidance: braking"), (2.0, 6, "Avoidance ended: 1.9 m"),
                                          (3.0, 6, "Mode OFFBOARD")])  # fmt: skip
    assert drone_state(ended, lost=False) == "armed"
    assert drone_state(view_of(1, armed=True, system_status=5, texts=ended.texts[:1]), lost=False) == "failsafe"
    assert drone_state(view_of(1), lost=False) == "disarmed"


def test_a_frame_carries_every_drone_in_the_swarm_frame_and_is_plain_json() -> None:
    drones = {2: view_of(2, armed=True, mode="OFFBOARD", heading_deg=90.0, battery_remaining=0.5,
                         vel_ned_mps=(1.0, 0.0, math.nan)), 1: view_of(1)}  # fmt: skip
    out = frame(time_s=10.0, drones=drones, positions_ned_m={2: (1.23456, -2.0, -3.0)}, homes_ned_m={2: (0, 0, 0)},
                slots_ned_m={2: (1.2, -2.0, -3.0)}, lost=[], now_s=10.0, separation_m=None, min_separation_m=1.5,
                realtime_factor=None, obstacles=[ObstacleShape(kind="cylinder", north_m=1, east_m=2, radius_m=0.25,
                                                               height_m=8)])  # fmt: skip
    assert json.loads(json.dumps(out, allow_nan=False)) == out
    assert [d["sysid"] for d in out["drones"]] == [1, 2]
    one, two = out["drones"]
    assert one["pos_ned_m"] is None and one["state"] == "disarmed"
    assert two["pos_ned_m"] == [1.235, -2.0, -3.0] and two["alt_m"] == 3.0 and two["heading_deg"] == 90.0
    assert two["vel_ned_mps"] == [1.0, 0.0, None] and two["link_age_s"] == 0.5 and two["battery"] == 0.5
    assert out["obstacles"][0]["kind"] == "cylinder" and out["min_separation_m"] == 1.5


def test_an_attached_vehicle_is_drawn_as_external_and_as_lost_once_silent() -> None:
    drones = {30: view_of(30, armed=True), 250: view_of(250, armed=True)}
    common: dict[str, Any] = dict(time_s=1.0, drones=drones, positions_ned_m={250: (1.0, 2.0, -3.0)}, homes_ned_m={},
                                  slots_ned_m={}, now_s=10.0, separation_m=None, min_separation_m=None,
                                  realtime_factor=None, external=[250])  # fmt: skip
    flying = frame(lost=[], **common)["drones"]
    assert [(d["sysid"], d["state"]) for d in flying] == [(30, "armed"), (250, "external")]
    assert flying[1]["pos_ned_m"] == [1.0, 2.0, -3.0]
    assert [d["state"] for d in frame(lost=[250], **common)["drones"]] == ["armed", "lost"]


async def _watch(url: str, count: int) -> list[list[dict[str, Any]]]:
    """``count`` clients at once, each reading two frames."""
    async with aiohttp.ClientSession() as session:

        async def one() -> list[dict[str, Any]]:
            async with session.ws_connect(url.replace("http", "ws") + "ws") as ws:
                return [json.loads((await ws.receive(timeout=5)).data) for _ in range(2)]

        return await asyncio.gather(*(one() for _ in range(count)))


def test_the_server_serves_the_page_and_streams_the_newest_frame_to_every_tab() -> None:
    server = serve_view(0)
    try:
        server.publish({"time_s": 1.0, "drones": []})

        async def check() -> list[list[dict[str, Any]]]:
            async with aiohttp.ClientSession() as session:
                script = "text/javascript"
                pages = (("", "text/html"), ("static/live.js", script), ("static/draw.js", script),
                         ("static/vendor/three/three.core.js", script))  # fmt: skip
                for path, kind in pages:
                    async with session.get(server.url + path) as response:
                        assert response.status == 200 and response.content_type == kind
                for path in ("static/../server.py", "static/nothing.js", "static/vendor//three/LICENSE"):
                    async with session.get(server.url + path) as response:
                        assert response.status == 404, path
                async with session.get(server.url + "frame") as response:
                    assert await response.json() == {"time_s": 1.0, "drones": []}
            watching = asyncio.ensure_future(_watch(server.url, 3))
            await asyncio.sleep(0.5)
            server.publish({"time_s": 2.0, "drones": []})
            return await watching

        seen = asyncio.run(check())
        assert [[f["time_s"] for f in frames] for frames in seen] == [[1.0, 2.0]] * 3
    finally:
        server.stop()


def test_a_port_in_use_or_out_of_range_is_one_line_and_the_default_port_moves_on() -> None:
    taken = socket.socket()
    taken.bind(("127.0.0.1", 0))
    port = taken.getsockname()[1]
    try:
        with pytest.raises(ViewError, match=rf"^cannot serve the view on 127.0.0.1:{port}: Address already in use$"):
            ViewServer(port=port).start()
        with pytest.raises(ViewError, match=r"^view port must be 0..65535, got 70000$"):
            ViewServer(port=70000)
    finally:
        taken.close()
    # without a port asked for, a swarm whose default port is taken (another swarm's page) serves on another one
    default = socket.socket()
    with contextlib.suppress(OSError):  # taken already: as good for the check
        default.bind(("127.0.0.1", DEFAULT_PORT))
    try:
        server = serve_view(None)
        assert server.port != DEFAULT_PORT
        server.stop()
    finally:
        default.close()


@pytest.mark.parametrize(
    ("options", "line"),
    [
        (["--view-port", "70000"], "swarm: error: view port must be 0..65535, got 70000"),
        (["--view-port", "8080", "--no-view"], "swarm: error: --view-port and --no-view contradict each other"),
    ],
)
def test_swarm_fly_refuses_bad_view_options_with_one_line_and_exit_code_2(options: list[str], line: str) -> None:
    mission = Path(__file__).resolve().parents[2] / "missions" / "grid_to_circle.toml"
    result = subprocess.run([sys.executable, "-m", "gcs.cli", "fly", str(mission), "--no-forward", *options],
                            capture_output=True, text=True, timeout=50)  # fmt: skip
    assert result.returncode == 2 and result.stderr == line + "\n", result.stderr


def test_swarm_up_refuses_a_port_in_use_with_one_line_and_exit_code_2() -> None:
    taken = socket.socket()
    taken.bind(("127.0.0.1", 0))
    port = taken.getsockname()[1]
    try:
        result = subprocess.run([sys.executable, "-m", "gcs.cli", "up", "-n", "1", "--no-forward", "--view-port",
                                 str(port)], capture_output=True, text=True, timeout=50)  # fmt: skip
    finally:
        taken.close()
    assert result.returncode == 2
    assert result.stderr == f"swarm: error: cannot serve the view on 127.0.0.1:{port}: Address already in use\n"


def test_frames_keep_their_rate_on_a_jittered_tick_and_restart_after_a_pause() -> None:
    pacer = FramePacer(10.0)
    rng = random.Random(3)
    ticks = [k * 0.05 + rng.uniform(0.0, 0.01) for k in range(400)]  # the supervisor's 20 Hz, jittered: 20 s
    frames = [t for t in ticks if pacer.due(t)]
    assert len(frames) in (199, 200, 201)  # 10 a second, not the 6-7 of "a period since the last"
    gaps = [b - a for a, b in itertools.pairwise(frames)]
    assert min(gaps) > 0.03 and max(gaps) < 0.16  # one frame per tick at most, none skipped for long
    # after a pause (nobody watching), the first tick gives a frame and the grid starts from it
    assert pacer.due(100.0) and not pacer.due(100.05) and pacer.due(100.1)
