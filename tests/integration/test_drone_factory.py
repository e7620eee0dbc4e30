"""The drone factory: forked drones report their exit codes, take signals, and none outlives the factory.

Policy: three leased instances (tests/integration/instances.py); the drones run without MAVLink."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest

from sitl.harness.factory import DroneFactory
from tests.integration.instances import Leases

pytestmark = pytest.mark.timeout(60)


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except OSError:
        return False


def _await_line(path: Path, text: str, timeout_s: float = 20.0) -> None:
    """Wait until the drone has written ``text`` to its log (it prints its start-up line once it is running)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if path.exists() and text in path.read_text():
            return
        time.sleep(0.05)
    raise AssertionError(f"{text!r} not in {path} within {timeout_s} s")


def test_forked_drones_report_exit_codes_take_signals_and_stop_with_the_factory(
    tmp_path: Path, instances: Leases
) -> None:
    first = instances(3)
    factory = DroneFactory(tmp_path / "factory.log")
    try:
        # A bad argument: the drone's own one-line error and exit code 2, as from the command line
        bad = factory.spawn(["--instance", "999"], tmp_path / "bad.log", 0)
        assert bad.wait(20) == 2
        assert "--instance must be in 0..253" in (tmp_path / "bad.log").read_text()
        # A short unpaced flight ends by itself with 0
        short = factory.spawn(["--instance", str(first), "--no-mavlink", "--speed", "0", "--duration", "1"], None, 0)
        assert short.wait(20) == 0
        # A drone running until told: SIGTERM stops it cleanly (sitl exits 0 and says why)
        running = factory.spawn(["--instance", str(first + 1), "--no-mavlink"], tmp_path / "running.log", 5)
        _await_line(tmp_path / "running.log", f"sitl {first + 1}: airframe")
        assert running.poll() is None and _alive(running.pid)
        assert os.getpriority(os.PRIO_PROCESS, running.pid) == 5
        running.send_signal(signal.SIGTERM)
        assert running.wait(20) == 0
        assert "stopped by SIGTERM" in (tmp_path / "running.log").read_text()
        running.send_signal(signal.SIGTERM)  # reaped: a no-op, never a signal to a recycled PID
        # One left running when the factory closes is stopped by it
        left = factory.spawn(["--instance", str(first + 2), "--no-mavlink"], tmp_path / "left.log", 0)
        _await_line(tmp_path / "left.log", f"sitl {first + 2}: airframe")
    finally:
        factory.close()
    assert left.returncode is not None
    assert not _alive(left.pid)
    assert not _alive(factory.pid)
