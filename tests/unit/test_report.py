"""The flight report's files, and .tlog files that standard MAVLink tools read back."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from gcs.record.metrics import compute_metrics
from gcs.record.recording import DroneSample, EventRecord, FlightRecording, StepRecord
from gcs.record.tlog import TlogWriter
from gcs.view.report import (
    ALTITUDE_FILE,
    METRICS_FILE,
    SEPARATION_FILE,
    SUMMARY_FILE,
    TRAJECTORIES_FILE,
    counted,
    summary_text,
    write_report,
)

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
REQUIRED_KEYS = {
    "mission",
    "n_drones",
    "duration_s",
    "min_separation_m",
    "min_separation_time_s",
    "collisions",
    "takeoff_time_s",
    "takeoff_time_per_drone_s",
    "steps",
    "distance_flown_m",
    "separation",
}
STEP_KEYS = {"name", "kind", "start_s", "end_s", "formation_rms_m", "time_to_formation_s", "max_error_m"}


def synthetic_flight(n_drones: int = 3, rate_hz: float = 10.0) -> FlightRecording:
    """Drones in a row take off to 3 m, fly to a circle, then land; each follows a first-order lag to its goal."""
    rec = FlightRecording(mission_name="circle_demo", n_drones=n_drones, collision_radius_m=0.35)
    rec.steps = [
        StepRecord(index=0, name="takeoff", kind="takeoff", start_s=1.0, end_s=8.0, target_alt_m=3.0),
        StepRecord(index=1, name="circle", kind="formation", start_s=8.0, end_s=20.0),
        StepRecord(index=2, name="land", kind="land", start_s=20.0, end_s=26.0),
    ]
    rec.events = [
        EventRecord(time_s=9.0, sysid=2, text="Avoidance: yielding to drone 1"),
        EventRecord(time_s=9.5, sysid=1, text="Collision with drone 2"),
    ]
    step_alpha = 1.0 - math.exp(-1.0 / rate_hz)  # 1 s time constant
    for i in range(n_drones):
        angle = 2.0 * math.pi * i / n_drones
        slot = (4.0 * math.cos(angle), 4.0 * math.sin(angle), -3.0)
        pos = [0.0, 2.0 * i, 0.0]
        for k in range(int(27 * rate_hz)):
            t = k / rate_hz
            target = slot if 8.0 <= t < 20.0 else None
            if t < 1.0:
                goal = pos
            elif t < 8.0:
                goal = [0.0, 2.0 * i, -3.0]
            elif t < 20.0:
                goal = list(slot)
            else:
                goal = [pos[0], pos[1], 0.0]
            pos = [p + (g - p) * step_alpha for p, g in zip(pos, goal, strict=True)]
            rec.samples.append(
                DroneSample(
                    time_s=t,
                    sysid=i + 1,
                    pos_ned_m=(pos[0], pos[1], pos[2]),
                    vel_ned_mps=(0.0, 0.0, 0.0),
                    armed=1.0 <= t < 25.0,
                    mode="OFFBOARD",
                    target_ned_m=target,
                )
            )
    return rec


def assert_png(path: Path) -> None:
    data = path.read_bytes()
    assert data.startswith(PNG_SIGNATURE), f"{path.name} is not a PNG"
    assert len(data) > 10_000, f"{path.name} looks empty ({len(data)} bytes)"


# --- flight report ----------------------------------------------------------------------------------------------


def test_report_writes_every_file_with_the_metrics_and_plots(tmp_path: Path) -> None:
    # GIVEN a recorded three-drone flight
    rec = synthetic_flight()

    # WHEN the report is written into a directory that does not exist yet
    out = write_report(rec, tmp_path / "report")

    # THEN metrics.json parses and holds the documented keys, for the flight and for every step
    assert out == tmp_path / "report"
    metrics = json.loads((out / METRICS_FILE).read_text())
    assert metrics.keys() >= REQUIRED_KEYS
    assert [s["name"] for s in metrics["steps"]] == ["takeoff", "circle", "land"]
    assert all(s.keys() >= STEP_KEYS for s in metrics["steps"])
    assert metrics["collisions"] == 1
    assert metrics["n_drones"] == 3
    assert metrics["takeoff_time_s"] is not None
    assert metrics["steps"][1]["time_to_formation_s"] is not None
    # AND the three plots are real, non-trivial PNGs
    for name in (TRAJECTORIES_FILE, ALTITUDE_FILE, SEPARATION_FILE):
        assert_png(out / name)
    # AND the summary names the mission, every step and the headline numbers
    summary = (out / SUMMARY_FILE).read_text()
    for text in ("circle_demo", "takeoff", "circle", "land", "min separation", "collisions: 1", "Collision with"):
        assert text in summary


def test_plots_on_failure_are_drawn_for_a_flight_that_broke_something_and_left_out_of_one_that_did_not(
    tmp_path: Path,
) -> None:
    plots = (TRAJECTORIES_FILE, ALTITUDE_FILE, SEPARATION_FILE)
    # GIVEN the same flight with a contact, and without it
    touched = synthetic_flight()
    clean = synthetic_flight()
    clean.events = [e for e in clean.events if not e.text.startswith("Collision")]
    # WHEN the reports are written with plots="failed" THEN the flight with a contact has its plots
    out = write_report(touched, tmp_path / "touched", plots="failed")
    assert all((out / name).read_bytes().startswith(PNG_SIGNATURE) for name in plots)
    # AND the clean one has every other file, the same metrics as with plots, and none left from an earlier report
    full = write_report(clean, tmp_path / "clean")
    metrics = (full / METRICS_FILE).read_bytes()
    out = write_report(clean, tmp_path / "clean", plots="failed")
    assert not any((out / name).exists() for name in plots)
    assert (out / METRICS_FILE).read_bytes() == metrics
    assert (out / SUMMARY_FILE).exists() and "<img" not in (out / "report.html").read_text()
    # AND a flight that did not finish has them, and "never" never draws them
    out = write_report(clean, tmp_path / "unfinished", plots="failed", failed=True)
    assert all((out / name).exists() for name in plots)
    out = write_report(touched, tmp_path / "never", plots="never", failed=True)
    assert not any((out / name).exists() for name in plots)


def test_metrics_json_is_identical_for_the_same_recording(tmp_path: Path) -> None:
    first = write_report(synthetic_flight(), tmp_path / "a") / METRICS_FILE
    second = write_report(synthetic_flight(), tmp_path / "b") / METRICS_FILE

    assert first.read_bytes() == second.read_bytes()


def test_report_of_an_empty_recording_still_has_every_file(tmp_path: Path) -> None:
    rec = FlightRecording(mission_name="aborted", n_drones=4, collision_radius_m=0.3)

    out = write_report(rec, tmp_path)

    metrics = json.loads((out / METRICS_FILE).read_text())
    assert metrics["min_separation_m"] is None
    assert metrics["steps"] == []
    for name in (TRAJECTORIES_FILE, ALTITUDE_FILE, SEPARATION_FILE):
        assert (out / name).read_bytes().startswith(PNG_SIGNATURE)
    assert "aborted" in (out / SUMMARY_FILE).read_text()


def test_counts_in_the_summary_agree_with_their_nouns() -> None:
    assert [counted(n, "drone") for n in (0, 1, 2)] == ["0 drones", "1 drone", "2 drones"]
    assert counted(1, "body", "bodies") == "1 body" and counted(3, "body", "bodies") == "3 bodies"
    # GIVEN a flight whose mesh carried one frame, one report to the neighbour tables
    rec = synthetic_flight()
    rec.link_counters = {"mesh": {"frames_offered": 1.0, "frames_delivered": 1.0, "lost_range": 0.0, "lost_path": 0.0,
                                  "lost_model": 0.0, "relay_updates": 0.0, "mesh_updates": 1.0}}  # fmt: skip
    # THEN its summary says so in the singular
    line = next(x for x in summary_text(compute_metrics(rec)).splitlines() if x.startswith("link model, mesh"))
    assert "0 of 1 frame lost" in line and "took 1 report from the mesh, 0 from the relay" in line, line


def test_report_of_a_large_swarm_is_written_without_a_legend_per_drone(tmp_path: Path) -> None:
    out = write_report(synthetic_flight(n_drones=16, rate_hz=5.0), tmp_path)

    assert len(json.loads((out / METRICS_FILE).read_text())["sysids"]) == 16
    assert_png(out / TRAJECTORIES_FILE)


# --- tlog -------------------------------------------------------------------------------------------------------

T0_US = 1_700_000_000_123_456  # 2023-11-14, an arbitrary unix time


def packets() -> list[tuple[bytes, int]]:
    """A heartbeat and a position from drone 3, with increasing sequence numbers and times."""
    encoder = mavlink.MAVLink(None, srcSystem=3, srcComponent=1)
    messages = [
        mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0x81, 6 << 16, mavlink.MAV_STATE_ACTIVE, 3
        ),
        mavlink.MAVLink_global_position_int_message(
            61_000, 473_977_420, 85_455_940, 510_250, 22_250, 150, -25, 50, 13_500
        ),
        mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0x81, 6 << 16, mavlink.MAV_STATE_ACTIVE, 3
        ),
    ]
    out = []
    for k, message in enumerate(messages):
        out.append((message.pack(encoder), T0_US + 250_000 * k))
        encoder.seq = (encoder.seq + 1) % 256  # pack() alone does not advance it
    return out


def write_tlog(path: Path) -> None:
    with TlogWriter(path) as tlog:
        for packet, time_us in packets():
            tlog.write(packet, time_us)


def test_pymavlink_reads_back_the_same_messages_and_timestamps(tmp_path: Path) -> None:
    # GIVEN a tlog of three packets
    path = tmp_path / "flight.tlog"
    write_tlog(path)

    # WHEN pymavlink opens it the way its log tools do
    log = mavutil.mavlink_connection(str(path))
    read = []
    while (message := log.recv_match()) is not None:
        read.append(message)

    # THEN it finds the same messages, from drone 3, in order, each with its record's time
    assert [m.get_type() for m in read] == ["HEARTBEAT", "GLOBAL_POSITION_INT", "HEARTBEAT"]
    assert [m.get_srcSystem() for m in read] == [3, 3, 3]
    assert [m.get_seq() for m in read] == [0, 1, 2]
    assert [m._timestamp for m in read] == pytest.approx([(T0_US + 250_000 * k) * 1e-6 for k in range(3)], abs=1e-6)
    position = read[1]
    assert (position.lat, position.lon, position.relative_alt) == (473_977_420, 85_455_940, 22_250)
    assert position.hdg == 13_500
    assert read[0].custom_mode == 6 << 16


def test_mavlogdump_prints_every_message_with_its_time(tmp_path: Path) -> None:
    # GIVEN a tlog of three packets
    path = tmp_path / "flight.tlog"
    write_tlog(path)
    mavlogdump = Path(sys.executable).parent / "mavlogdump.py"
    if not mavlogdump.exists():
        pytest.skip("mavlogdump.py is not installed next to this interpreter")
    env = {**os.environ, "TZ": "UTC"}

    # WHEN pymavlink's mavlogdump.py dumps it, as JSON and in its default text format
    def dump(*options: str) -> list[str]:
        result = subprocess.run(
            [sys.executable, str(mavlogdump), *options, str(path)],
            capture_output=True,
            text=True,
            timeout=60,
            env=env,
            check=True,
        )
        return [line for line in result.stdout.splitlines() if line.strip()]

    as_json = [json.loads(line) for line in dump("--format", "json")]
    as_text = dump()

    # THEN every message is there with its type, fields and timestamp
    assert [m["meta"]["type"] for m in as_json] == ["HEARTBEAT", "GLOBAL_POSITION_INT", "HEARTBEAT"]
    assert [m["meta"]["timestamp"] for m in as_json] == pytest.approx(
        [(T0_US + 250_000 * k) * 1e-6 for k in range(3)], abs=1e-6
    )
    assert as_json[1]["data"]["relative_alt"] == 22_250
    assert len(as_text) == 3
    assert as_text[0].startswith("2023-11-14 22:13:20.12: HEARTBEAT {")
    assert as_text[1].startswith("2023-11-14 22:13:20.37: GLOBAL_POSITION_INT {")


def test_tlog_rejects_what_is_not_a_packet_or_a_valid_time(tmp_path: Path) -> None:
    packet, _ = packets()[0]
    with TlogWriter(tmp_path / "x.tlog") as tlog:
        with pytest.raises(ValueError, match="not a MAVLink packet"):
            tlog.write(b"hello", T0_US)
        with pytest.raises(ValueError, match="out of range"):
            tlog.write(packet, -1)
        with pytest.raises(TypeError):
            tlog.write(packet, 1.7e15)  # type: ignore[arg-type]
        assert tlog.records_written == 0
    assert tlog.closed
    with pytest.raises(ValueError, match="closed"):
        tlog.write(packet, T0_US)
    assert (tmp_path / "x.tlog").read_bytes() == b""


def test_tlog_record_layout_is_big_endian_microseconds_then_the_packet(tmp_path: Path) -> None:
    packet, _ = packets()[0]
    path = tmp_path / "one.tlog"
    with TlogWriter(path) as tlog:
        tlog.write(packet, 0x0102030405060708)

    assert path.read_bytes() == bytes.fromhex("0102030405060708") + packet
