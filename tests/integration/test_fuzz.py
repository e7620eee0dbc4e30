"""Fuzzing in flight: a hovering ``sitl`` drone takes seeded hostile MAVLink (bench/fuzz.py) and stays up.

Every message of the common dialect with NaN, infinities, integer extremes, denormals, random and unterminated
strings and every target, plus MAVLink 1, signed, glued, truncated, split and corrupted frames and random bytes, go to
the drone's API port while it hovers. With nothing addressed to it that it would act on, it must hold its hover within
0.5 m; with commands to it as well, it may land or disarm but must not crash, log a traceback or stop answering.

Each drone uses a leased instance (tests/integration/instances.py) on ports 14580+k, 14540+k, 18570+k for the first k
in 320-339 whose three are free (set explicitly: 14860-14919 and 18890-18909, none of them any instance's own,
sitl/process/ports.py), so it never meets the drones of other suites. bench/fuzz.py starts and stops each drone by PID
itself.
"""

from __future__ import annotations

from collections.abc import Iterator
from multiprocessing import resource_tracker
from pathlib import Path

import pytest

from bench.fuzz import (
    API_BIND_BASE_PORT,
    API_REMOTE_BASE_PORT,
    GCS_BIND_BASE_PORT,
    HOVER_TOLERANCE_M,
    KIND_WEIGHTS,
    MAX_HEARTBEAT_GAP_S,
    FuzzConfig,
    FuzzReport,
    run,
)
from tests.integration.instances import Leases
from tests.integration.sitl_process import udp_port_is_free

pytestmark = [pytest.mark.sim_only]

FIRST_PORT_BASE, SLOTS = 320, 20
FRAMES_HOVERING = 20_000
FRAMES_COMMANDED = 5_000
RATE_HZ = 2_000.0  # the bench's default: the drone parses them and still flies in real time on a loaded machine
SEED = 20261125


@pytest.fixture(scope="module", autouse=True)
def shared_memory_tracker() -> Iterator[None]:
    """The fuzzer's shared world (where it reads the drone's true position) starts Python's shared-memory tracker, a
    child process that lives as long as the interpreter; started before the leak check's snapshot, it is not taken
    for a leftover drone."""
    resource_tracker.ensure_running()
    yield


def _free_port_base() -> int:
    """A port base of this suite's block whose three ports are free."""
    for k in range(SLOTS):
        base = FIRST_PORT_BASE + k
        ports = (API_BIND_BASE_PORT + base, API_REMOTE_BASE_PORT + base, GCS_BIND_BASE_PORT + base)
        if all(udp_port_is_free(p) for p in ports):
            return base
    raise AssertionError(f"no free ports for port bases {FIRST_PORT_BASE}..{FIRST_PORT_BASE + SLOTS - 1}")


def _fuzz(tmp_path: Path, instances: Leases, *, frames: int, commands_to_drone: bool) -> FuzzReport:
    instance, base = instances(), _free_port_base()
    config = FuzzConfig(
        frames=frames, seed=SEED, commands_to_drone=commands_to_drone, rate_hz=RATE_HZ, instance=instance,
        port_base=base, log_dir=tmp_path,
    )  # fmt: skip
    report = run(config)
    print(report.text())
    return report


def _assert_survived(report: FuzzReport) -> None:
    assert report.drone_alive, f"the drone ended (exit code {report.exit_code})"
    assert report.tracebacks == 0, report.traceback_excerpt
    assert report.param_round_trip, "PARAM_REQUEST_READ unanswered after the fuzzing"
    assert report.command_round_trip, "COMMAND_LONG unanswered after the fuzzing"
    assert report.nonfinite_positions == 0, "the drone's position became NaN or infinite"
    assert report.max_heartbeat_gap_s < MAX_HEARTBEAT_GAP_S  # no command may silence the heartbeat (as in PX4)


@pytest.mark.timeout(180)
@pytest.mark.acceptance  # the long flood; the suite keeps the commanded one below
def test_a_hovering_drone_holds_its_position_under_20000_hostile_frames_not_addressed_to_it(
    tmp_path: Path, instances: Leases
) -> None:
    # GIVEN a drone hovering in Hold WHEN 20,000 seeded hostile frames arrive, none of them something it would act on
    # that is addressed to it
    report = _fuzz(tmp_path, instances, frames=FRAMES_HOVERING, commands_to_drone=False)

    # THEN every kind of frame and every message of the dialect was sent
    assert report.frames_sent == FRAMES_HOVERING
    assert set(report.by_kind) == set(KIND_WEIGHTS)
    assert report.message_types_sent == report.message_types_in_dialect
    # AND the drone is alive, answered throughout and after, logged no traceback and kept its hover point
    _assert_survived(report)
    assert report.max_horizontal_drift_m <= HOVER_TOLERANCE_M
    assert report.max_vertical_drift_m <= HOVER_TOLERANCE_M
    assert report.final_armed, "the drone disarmed"
    assert report.passed, report.failures


@pytest.mark.timeout(150)
def test_a_drone_commanded_by_hostile_frames_survives_and_answers(tmp_path: Path, instances: Leases) -> None:
    # GIVEN a drone hovering in Hold WHEN 5,000 seeded hostile frames arrive, commands addressed to it among them
    report = _fuzz(tmp_path, instances, frames=FRAMES_COMMANDED, commands_to_drone=True)

    # THEN it may have done what it was told, but it is alive, answers and logged no traceback
    assert report.frames_sent == FRAMES_COMMANDED
    assert (
        report.by_message.get("COMMAND_LONG", 0) > 0 and report.by_message.get("SET_POSITION_TARGET_LOCAL_NED", 0) > 0
    )
    _assert_survived(report)
    assert report.passed, report.failures
