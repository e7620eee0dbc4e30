"""The ground station as a user runs it: real ``swarm`` and ``sitl`` processes on loopback.

Policy: loopback only; leased instances (tests/integration/instances.py); every process is found by PID (the
supervisor's children from /proc) and must be gone at the end; readiness is read from the supervisor's own output,
never slept for.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink

from tests.integration.instances import Leases

pytestmark = [pytest.mark.sim_only, pytest.mark.timeout(120)]

SWARM = [sys.executable, "-m", "gcs.cli"]


@pytest.fixture
def state_env(tmp_path: Path) -> dict[str, str]:
    return {**os.environ, "SWARM_STATE_DIR": str(tmp_path / "state")}


def children_of(pid: int) -> list[int]:
    try:
        text = Path(f"/proc/{pid}/task/{pid}/children").read_text()
    except OSError:
        return []
    return [int(p) for p in text.split()]


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # A zombie is dead for our purpose only once reaped; a zombie child of a dead parent is reaped by init.
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except OSError:
        return False


def wait_dead(pids: list[int], timeout_s: float) -> list[int]:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        left = [p for p in pids if alive(p)]
        if not left:
            return []
        time.sleep(0.1)
    return [p for p in pids if alive(p)]


class RunningSwarm:
    def __init__(self, n: int, first_instance: int, env: dict[str, str]) -> None:
        self.env = env
        self.proc = subprocess.Popen(
            [*SWARM, "up", "-n", str(n), "--speed", "4", "--first-instance", str(first_instance), "--no-forward"],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=env,
        )
        self.output: list[str] = []
        assert self.proc.stdout is not None
        for line in self.proc.stdout:  # the supervisor says when every drone has sent its first HEARTBEAT
            self.output.append(line)
            if "drones up" in line:
                break
        else:
            raise AssertionError("swarm up ended before the drones were up: " + "".join(self.output))
        # Every descendant must go at the end (multiprocessing's shared-memory tracker among them); the drones are
        # the children of the drone factory (sitl.harness.zygote), which forks them.
        direct = children_of(self.proc.pid)
        factories = [p for p in direct if b"sitl.harness.zygote" in Path(f"/proc/{p}/cmdline").read_bytes()]
        self.drones = [d for f in factories for d in children_of(f)]
        self.children = [*direct, *self.drones]

    def cli(self, *args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([*SWARM, *args], capture_output=True, text=True, env=self.env, timeout=60)

    def kill_all(self) -> None:
        for pid in [self.proc.pid, *self.children]:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        self.proc.wait()


@pytest.fixture
def swarm_factory(state_env: dict[str, str]) -> Iterator[type[RunningSwarm]]:
    started: list[RunningSwarm] = []

    class Factory(RunningSwarm):
        def __init__(self, n: int, first_instance: int) -> None:
            super().__init__(n, first_instance, state_env)
            started.append(self)

    yield Factory
    for s in started:
        if s.proc.poll() is None or any(alive(p) for p in s.children):
            s.kill_all()


def status_rows(swarm: RunningSwarm) -> list[list[str]]:
    result = swarm.cli("status")
    assert result.returncode == 0, result.stderr
    return [line.split() for line in result.stdout.strip().splitlines()[1:]]


def wait_for_modes(swarm: RunningSwarm, mode: str, timeout_s: float) -> bool:
    """Whether every drone reports ``mode`` within ``timeout_s`` of wall time (the supervisor runs at 4x)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if all(r[1] == mode for r in status_rows(swarm)):
            return True
        time.sleep(0.3)
    return False


def test_cli_commands_fly_a_running_swarm_and_down_stops_every_process(
    swarm_factory: type[RunningSwarm], instances: Leases
) -> None:
    # GIVEN a running 2-drone swarm
    first = instances(2)
    swarm = swarm_factory(2, first)
    assert len(swarm.drones) == 2
    rows = status_rows(swarm)
    assert [r[0] for r in rows] == [str(first + 1), str(first + 2)] and all(r[2] == "no" for r in rows)
    # WHEN it takes off to 2 m
    result = swarm.cli("takeoff", "--alt", "2")
    assert result.returncode == 0, result.stderr
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        rows = status_rows(swarm)
        if all(r[2] == "yes" and float(r[5]) > 1.8 for r in rows):
            break
        time.sleep(0.3)
    # THEN both are armed and up
    assert all(r[2] == "yes" and float(r[5]) > 1.8 for r in rows), rows
    # WHEN they fly a line, then pause (a verb added by following docs/architecture.md's recipe)
    assert swarm.cli("formation", "line", "--alt", "2").returncode == 0
    assert wait_for_modes(swarm, "OFFBOARD", 10), status_rows(swarm)
    result = swarm.cli("pause")
    assert result.returncode == 0 and "Hold" in result.stdout, result
    # THEN both hold where they are in PX4 Hold
    assert wait_for_modes(swarm, "AUTO.LOITER", 10), status_rows(swarm)
    # WHEN they land
    assert swarm.cli("land").returncode == 0
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and not all(r[2] == "no" for r in status_rows(swarm)):
        time.sleep(0.3)
    assert all(r[2] == "no" for r in status_rows(swarm))
    # AND the swarm is brought down
    assert swarm.cli("down").returncode == 0
    assert swarm.proc.wait(timeout=30) == 0
    assert wait_dead(swarm.children, 5) == []
    assert swarm.cli("status").returncode == 1


def shm_mappings(pid: int) -> list[str]:
    """The shared-memory segments process ``pid`` maps, as /proc shows them ("... (deleted)" once unlinked)."""
    lines = Path(f"/proc/{pid}/maps").read_text().splitlines()
    return sorted({line.split(None, 5)[5] for line in lines if "/dev/shm/psm_" in line})


def test_killing_the_supervisor_with_sigkill_leaves_no_drone_process(
    swarm_factory: type[RunningSwarm], instances: Leases
) -> None:
    swarm = swarm_factory(3, instances(3))
    assert len(swarm.drones) == 3
    # AND the shared world's name has already left /dev/shm (only the mappings hold the memory), so nothing can
    # outlive the kill there either
    deadline = time.monotonic() + 5
    while not (segments := shm_mappings(swarm.proc.pid)) or not all(s.endswith("(deleted)") for s in segments):
        assert time.monotonic() < deadline, f"the world segment still has its name: {segments}"
        time.sleep(0.1)
    swarm.proc.send_signal(signal.SIGKILL)
    swarm.proc.wait()
    assert wait_dead(swarm.children, 10) == []


def test_sigterm_to_the_supervisor_stops_every_drone(swarm_factory: type[RunningSwarm], instances: Leases) -> None:
    swarm = swarm_factory(2, instances(2))
    swarm.proc.send_signal(signal.SIGTERM)
    assert swarm.proc.wait(timeout=30) == 0
    assert wait_dead(swarm.children, 5) == []


def test_sigterm_while_the_drones_start_ends_the_start_up_at_once(state_env: dict[str, str], instances: Leases) -> None:
    """A start-up that cannot finish (here: the drone factory is held stopped) must not hold a SIGTERM or Ctrl-C
    back until it times out; the supervisor stops what it started and says so."""
    proc = subprocess.Popen(
        [*SWARM, "up", "-n", "2", "--first-instance", str(instances(2)), "--no-forward"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=state_env,
    )  # fmt: skip
    factory = None
    try:
        end = time.monotonic() + 30
        while factory is None and time.monotonic() < end and proc.poll() is None:
            found = [
                p for p in children_of(proc.pid) if b"sitl.harness.zygote" in Path(f"/proc/{p}/cmdline").read_bytes()
            ]
            factory = found[0] if found else None
            time.sleep(0.005)
        assert factory is not None, "no drone factory started"
        os.kill(factory, signal.SIGSTOP)  # still importing the drone code: the supervisor waits for its word
        proc.send_signal(signal.SIGTERM)
        os.kill(factory, signal.SIGCONT)
        out, err = proc.communicate(timeout=20)
        assert proc.returncode == 130, (out, err)
        assert "drones up" not in out
        assert "interrupted while starting" in err and "Traceback" not in err, err
        assert wait_dead([factory], 10) == []
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        if factory is not None and alive(factory):
            os.kill(factory, signal.SIGKILL)


def test_a_swarm_that_cannot_keep_the_requested_speed_is_warned_about_once(
    state_env: dict[str, str], instances: Leases
) -> None:
    """Paced drones that cannot keep up give the lag up, so the supervisor's wall-clock timing would run ahead of
    them unnoticed; 200x real time is beyond any machine this suite runs on."""
    proc = subprocess.Popen(
        [*SWARM, "up", "-n", "2", "--speed", "200", "--first-instance", str(instances(2)), "--no-forward"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=state_env,
    )  # fmt: skip
    lines: list[str] = []
    try:
        assert proc.stdout is not None
        for line in proc.stdout:  # the warning comes once a 5 s window has been measured
            lines.append(line)
            if "warning" in line:
                break
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=60)
        lines += out.splitlines(keepends=True)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    warnings = [ln for ln in lines if "warning" in ln]
    assert len(warnings) == 1, "".join(lines)
    rate = float(re.search(r"run at ([0-9.]+)x real time", warnings[0]).group(1))  # type: ignore[union-attr]
    assert 0 < rate < 0.9 * 200, warnings[0]
    assert "requested 200x" in warnings[0] and "--lockstep" in warnings[0]
    assert proc.returncode == 0, "".join(lines)


def test_a_drone_that_cannot_start_is_named_in_one_line(state_env: dict[str, str], instances: Leases) -> None:
    first = instances(2)
    result = subprocess.run(
        [*SWARM, "up", "-n", "2", "--first-instance", str(first), "--airframe", "no_such_frame"],
        capture_output=True, text=True, env=state_env, timeout=60,
    )  # fmt: skip
    assert result.returncode == 1
    errors = [ln for ln in result.stdout.splitlines() + result.stderr.splitlines() if "error" in ln]
    assert len(errors) == 1, result
    # Both drones fail the same way; whichever exits first is the one named.
    drone, sysid = f"({first}|{first + 1})", f"({first + 1}|{first + 2})"
    assert re.search(rf"drone {drone} \(sysid {sysid}\) exited with code 2", errors[0]), errors[0]
    assert "no_such_frame" in errors[0] and "Traceback" not in result.stderr


@pytest.mark.parametrize(
    ("args", "code", "fragment"),
    [
        (("status",), 1, "no swarm is running"),
        (("up", "-n", "0"), 2, "-n must be in 1..254"),
        (("up", "-n", "255"), 2, "-n must be in 1..254, got 255"),
        (("up", "-n", "4", "--first-instance", "251"), 2, "every sysid (instance + 1) must lie in 1..254"),
        (("up", "-n", "2", "--speed", "fast"), 2, "--speed"),
        (("fly-away",), 2, "invalid choice"),
    ],
)
def test_bad_commands_give_one_line(state_env: dict[str, str], args: tuple[str, ...], code: int, fragment: str) -> None:
    result = subprocess.run([*SWARM, *args], capture_output=True, text=True, env=state_env, timeout=30)
    assert result.returncode == code
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and fragment in lines[0], result.stderr


def test_a_ground_station_on_the_forward_port_sees_every_drone_and_can_command_one(
    state_env: dict[str, str], instances: Leases
) -> None:
    first = instances(2)
    # GIVEN a "QGroundControl" socket and a swarm forwarding to it
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.settimeout(0.2)
    port = gcs.getsockname()[1]
    up = subprocess.Popen([*SWARM, "up", "-n", "2", "--first-instance", str(first), "--forward", f"127.0.0.1:{port}"],
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=state_env)  # fmt: skip
    try:
        assert up.stdout is not None
        assert any("drones up" in line for line in up.stdout)
        parser = mavlink.MAVLink(None)
        me = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)

        def receive(kind: str, seconds: float) -> list[tuple[Any, tuple[str, int]]]:
            out = []
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                try:
                    data, addr = gcs.recvfrom(65535)
                except TimeoutError:
                    continue
                out += [(m, addr) for m in parser.parse_buffer(data) or [] if m.get_type() == kind]
            return out

        # WHEN it listens THEN it hears both drones' heartbeats
        beats = receive("HEARTBEAT", 2.5)
        assert {m.get_srcSystem() for m, _ in beats} == {first + 1, first + 2}
        # WHEN it asks the second drone for a parameter THEN only that drone answers, through the supervisor
        request = mavlink.MAVLink_param_request_read_message(first + 2, 1, b"MIS_TAKEOFF_ALT", -1)
        gcs.sendto(request.pack(me), beats[0][1])
        answers = receive("PARAM_VALUE", 2.0)
        assert answers and {m.get_srcSystem() for m, _ in answers} == {first + 2}
        assert answers[0][0].param_value == pytest.approx(2.5)
    finally:
        gcs.close()
        subprocess.run([*SWARM, "down"], capture_output=True, env=state_env, timeout=60)
        up.wait(timeout=60)
