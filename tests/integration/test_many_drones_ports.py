"""More than 40 drones at once, and no drone hears another's API traffic.

Under PX4 SITL's port numbers drone i + 40 streams its API link to 14540 + i + 40 = 14580 + i, the API port of drone
i. Here 42 consecutive instances fly together (hosted, one process per CPU, on the ground: nothing needs to take off),
the first two below 40: those two keep PX4's ports, and the last two, 40 above them, are where PX4's numbers would send
their streams into the first two's API sockets. Before the swarm starts, the test binds a client socket on every
drone's API remote port (sitl/process/ports.py): under PX4's numbers two of those are the first two drones' own API
ports, and those drones could not start. Each client must then hear its own drone and no other, and a broadcast request
to a drone's API port must be answered by that drone alone.

Policy: loopback only, no ground-station forward (nothing goes to 14550); leased instances
(tests/integration/instances.py), clear of a user's drones 0-9 and of 14550 (instance 10's stream); every process is
stopped by PID and must be gone at the end.
"""

from __future__ import annotations

import contextlib
import os
import selectors
import signal
import socket
import subprocess
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl.process.ports import PX4_INSTANCES, instance_ports
from tests.integration.instances import Leases
from tests.integration.test_swarm import SWARM, alive, children_of, wait_dead

pytestmark = [pytest.mark.sim_only, pytest.mark.timeout(900)]
LEASE_TIMEOUT_S = 600.0  # its block lies where sweeps and falsification campaigns take theirs: it may wait for them

LOOPBACK = "127.0.0.1"
DRONES = 42
UP_TIMEOUT_S = 150.0
LISTEN_S = 3.0


def bind_clients(instances: range) -> dict[int, socket.socket]:
    clients: dict[int, socket.socket] = {}
    try:
        for i in instances:
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            clients[i] = sock
            try:
                sock.bind((LOOPBACK, instance_ports(i).api_remote))
            except OSError as exc:
                pytest.fail(f"drone {i}'s API remote port {instance_ports(i).api_remote} is taken: {exc}")
            sock.setblocking(False)
    except BaseException:
        for sock in clients.values():
            sock.close()
        raise
    return clients


def listen(clients: dict[int, socket.socket], seconds: float, kind: str | None = None) -> dict[int, set[int]]:
    """The sysids each client heard (of messages of ``kind``, or all) in ``seconds``."""
    heard: dict[int, set[int]] = {i: set() for i in clients}
    parsers = {i: mavlink.MAVLink(None) for i in clients}
    for parser in parsers.values():
        parser.robust_parsing = True
    with selectors.DefaultSelector() as selector:
        for i, sock in clients.items():
            selector.register(sock, selectors.EVENT_READ, i)
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            for key, _ in selector.select(left):
                i = key.data
                with contextlib.suppress(BlockingIOError):
                    while True:
                        data = clients[i].recv(65535)
                        for msg in parsers[i].parse_buffer(data) or []:
                            if kind is None or msg.get_type() == kind:
                                heard[i].add(msg.get_srcSystem())
    return heard


def wait_for_line(log: Path, text: str, proc: subprocess.Popen[bytes], timeout_s: float) -> None:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if text in log.read_text(errors="replace"):
            return
        if proc.poll() is not None:
            pytest.fail(f"swarm up ended with {proc.returncode} before {text!r}: {log.read_text()[-3000:]}")
        time.sleep(0.2)
    pytest.fail(f"no {text!r} within {timeout_s:g} s: {log.read_text()[-3000:]}")


def test_more_than_40_drones_each_talk_only_to_their_own_api_clients(tmp_path: Path, instances: Leases) -> None:
    # a block holding the last instance but one under PX4's numbers: its first two drones keep PX4's ports, and its
    # last two are 40 above them
    first = instances(DRONES, containing=PX4_INSTANCES - 2, timeout_s=LEASE_TIMEOUT_S)
    block = range(first, first + DRONES)
    # PX4's numbers: the second of each pair would stream its API link onto the first's API port
    pairs = [(first, first + 40), (first + 1, first + 41)]
    assert block[1] < PX4_INSTANCES <= block[-1] and pairs[-1][1] == block[-1]
    for low, high in pairs:  # what PX4's numbers would do to these drones
        assert 14540 + high == 14580 + low == instance_ports(low).api_bind
    env = {**os.environ, "SWARM_STATE_DIR": str(tmp_path / "state")}
    log = tmp_path / "swarm-up.log"
    clients = bind_clients(block)
    proc: subprocess.Popen[bytes] | None = None
    children: list[int] = []
    code: int | None = None
    left: list[int] = []
    try:
        with log.open("wb") as out:
            proc = subprocess.Popen(
                [*SWARM, "up", "-n", str(DRONES), "--first-instance", str(first), "--drones-per-process",
                 "auto", "--no-forward", "--no-view"],
                stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env,
            )  # fmt: skip
        wait_for_line(log, "drones up", proc, UP_TIMEOUT_S)
        factories = [
            p for p in children_of(proc.pid) if b"sitl.harness.zygote" in Path(f"/proc/{p}/cmdline").read_bytes()
        ]
        children = [*children_of(proc.pid), *(host for f in factories for host in children_of(f))]
        # THEN every client hears its own drone, and nothing from any other
        heard = listen(clients, LISTEN_S)
        assert {i: s for i, s in heard.items() if s != {i + 1}} == {}
        # AND a request to a drone's API port, addressed to every system, is answered by that drone alone
        me = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        asked = {i: clients[i] for pair in pairs for i in pair}
        for i, sock in asked.items():
            request = mavlink.MAVLink_param_request_read_message(0, 0, b"MIS_TAKEOFF_ALT", -1)
            sock.sendto(request.pack(me), (LOOPBACK, instance_ports(i).api_bind))
        answers = listen(asked, 2.0, kind="PARAM_VALUE")
        assert answers == {i: {i + 1} for i in asked}
    finally:
        for sock in clients.values():
            sock.close()
        if proc is not None:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)  # as Ctrl-C: the supervisor stops every drone
            try:
                code = proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                code = None
            left = wait_dead(children, 20)
            for pid in [proc.pid, *left]:
                if alive(pid):
                    with contextlib.suppress(ProcessLookupError):
                        os.kill(pid, signal.SIGKILL)
            proc.wait()
    # AND the supervisor stopped cleanly, every drone process with it
    assert code == 0 and left == [], (code, left, log.read_text(errors="replace")[-3000:])
