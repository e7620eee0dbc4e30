"""Ground-station core without processes: the fleet view from telemetry, the control channel, spawn layouts."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink

from gcs.fleet.harness import grid_layout, line_layout
from gcs.fleet.telemetry import Fleet
from gcs.supervisor.control import ControlClient, ControlError, ControlServer

pytestmark = pytest.mark.timeout(30)


def decoded(msg: Any, sysid: int, compid: int = 1) -> Any:
    """A message as it arrives off the wire (packed by the drone, parsed by the ground station)."""
    encoder = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    parser = mavlink.MAVLink(None)
    return parser.parse_char(msg.pack(encoder))


def heartbeat(custom_mode: int, armed: bool) -> Any:
    base = 1 | (128 if armed else 0)
    return mavlink.MAVLink_heartbeat_message(2, 12, base, custom_mode, 4 if armed else 3, 3)


def test_fleet_tracks_mode_arming_position_home_and_liveness() -> None:
    fleet = Fleet()
    # GIVEN nothing until the first heartbeat: other messages from an unknown system are ignored
    fleet.handle(decoded(mavlink.MAVLink_global_position_int_message(0, 1, 2, 3, 4, 0, 0, 0, 0), 7), 0.0)
    assert fleet.drones == {}
    fleet.handle(decoded(heartbeat(393216, True), 7), 1.0)
    fleet.handle(decoded(mavlink.MAVLink_global_position_int_message(0, 473977420, 85455940, 491000, 3000,
                                                                     100, -50, 0, 9000), 7), 1.1)  # fmt: skip
    fleet.handle(decoded(mavlink.MAVLink_home_position_message(473977420, 85455940, 488000, 0.1, 0.2, 0.3,
                                                               [1, 0, 0, 0], 0, 0, 0), 7), 1.2)  # fmt: skip
    view = fleet.drones[7]
    assert view.mode == "OFFBOARD" and view.armed
    assert view.relative_alt_m == pytest.approx(3.0) and view.vel_ned_mps == pytest.approx((1.0, -0.5, 0.0))
    assert view.home == pytest.approx((47.397742, 8.545594, 488.0))
    assert view.home_local_ned_m == pytest.approx((0.1, 0.2, 0.3))
    # WHEN nothing is heard from it for more than 3 s THEN it is lost (any message of its autopilot counts, as in
    # QGroundControl: the last was HOME_POSITION at 1.2 s); a message from another component changes nothing, nor
    # does RADIO_STATUS, which a radio sends of itself
    fleet.handle(decoded(heartbeat(65536, False), 7, compid=190), 2.0)
    fleet.handle(decoded(mavlink.MAVLink_radio_status_message(200, 180, 50, 40, 30, 0, 0), 7), 2.5)
    assert fleet.drones[7].armed and fleet.lost(4.3) == [7] and fleet.lost(4.1) == []


def test_control_channel_answers_requests_and_reports_errors(tmp_path: Path) -> None:
    path = tmp_path / "supervisor.json"
    server = ControlServer(lambda req: {"ok": True, "echo": req["cmd"]}, path)
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():
            server.poll()
            stop.wait(0.01)

    thread = threading.Thread(target=serve)
    thread.start()
    try:
        client = ControlClient(path)
        assert client.request({"cmd": "status"}) == {"ok": True, "echo": "status"}
        assert client.request({"nocmd": 1})["ok"] is False  # a malformed request gets an error, not a hang
        # A second supervisor refuses to start while the first answers
        with pytest.raises(ControlError, match="already running"):
            ControlServer(lambda req: {"ok": True}, path)
    finally:
        stop.set()
        thread.join()
        server.close()
    assert not path.exists()
    with pytest.raises(ControlError, match="no swarm is running"):
        ControlClient(path).request({"cmd": "status"})


def test_a_stale_state_file_from_a_dead_supervisor_is_taken_over(tmp_path: Path) -> None:
    path = tmp_path / "supervisor.json"
    path.write_text('{"port": 9, "pid": 999999}')
    server = ControlServer(lambda req: {"ok": True}, path)
    server.close()


@pytest.mark.parametrize("n", [1, 2, 4, 9, 10, 50])
def test_spawn_layouts_are_centred_and_spaced(n: int) -> None:
    for layout in (grid_layout(n, 2.0), line_layout(n, 2.0)):
        assert len(layout) == n
        north = sum(p[0] for p in layout) / n
        east = sum(p[1] for p in layout) / n
        assert abs(east) < 1.0 + 1e-9 and abs(north) < 1.0 + 1e-9
        gaps = [((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2) ** 0.5 for i, a in enumerate(layout) for b in layout[i + 1 :]]
        assert not gaps or min(gaps) == pytest.approx(2.0)
