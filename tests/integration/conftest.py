"""Integration tests: real ``sitl`` processes on the wire with unchanged MAVSDK and pymavlink clients.

Policy:
- Loopback only. Drones this suite starts bind 127.0.0.1 and stream to 127.0.0.1; clients bind 127.0.0.1.
- Instances are leased (tests/integration/instances.py, the ``instances`` fixture): blocks no other process on
  the machine holds (pytest-xdist workers, sweeps), at or above ``--sitl-instance-base`` (default 20), never
  instances 0-9 nor one whose ports a user's drones 0-9 or a ground station on 14550 use, and only while their UDP
  ports are free, so a user's own simulator is untouched. No test file names an instance number of its own.
- A drone is ready when its first HEARTBEAT arrived; nothing sleeps and hopes.
- Every process started here is stopped by PID (SIGTERM, then SIGKILL) and reaped; after each test no child
  process and no extra thread (MAVSDK's native ones included) may remain.
- Every test has a time limit (pytest-timeout, 120 s by default in pyproject.toml, tighter per test).
- ``pytest tests/integration --vehicle udpin://0.0.0.0:14540`` flies the flight tests against that vehicle
  instead (a PX4 SITL, or a ``sitl`` started by hand); nothing is spawned and ``sim_only`` tests are skipped.

Coroutine test functions are run here with ``asyncio.run`` (one event loop per test), so no asyncio plugin is
needed.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import inspect
import os
import threading
import time
import zlib
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.integration.instances import DEFAULT_LOWEST_INSTANCE, Leases, leases
from tests.integration.sitl_process import (
    InstanceAllocator,
    SitlDrone,
    SpawnDrones,
    WorldDrone,
    drone_in_world,
    start_drones,
    stop_drone,
)
from tests.integration.vehicle_link import VehicleLink, VehicleUrlError, pymavlink_url

DEFAULT_SPEED_FACTOR = 4.0
INSTANCES_PER_WORKER = 10
LEAK_SETTLE_S = 5.0
SEED_SPAN = 10_000


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("sitl integration")
    group.addoption(
        "--vehicle",
        metavar="URL",
        default=None,
        help="fly the flight tests against this vehicle (MAVSDK URL, e.g. udpin://0.0.0.0:14540) instead of "
        "spawning sitl; sim_only tests are skipped",
    )
    group.addoption(
        "--vehicle-speed",
        type=float,
        default=1.0,
        metavar="F",
        help="speed factor of the --vehicle simulator, to scale wall-clock waits (default 1)",
    )
    group.addoption(
        "--sitl-speed",
        type=float,
        default=DEFAULT_SPEED_FACTOR,
        metavar="F",
        help=f"speed factor of spawned sitl drones (default {DEFAULT_SPEED_FACTOR:g})",
    )
    group.addoption(
        "--sitl-instance-base",
        type=int,
        default=DEFAULT_LOWEST_INSTANCE,
        metavar="I",
        help=f"lowest sitl instance number this run may lease (default {DEFAULT_LOWEST_INSTANCE}; its ports: "
        "sitl/process/ports.py)",
    )
    group.addoption(
        "--sitl-seed-offset",
        type=int,
        default=0,
        metavar="K",
        help="added to each test's drone seed (default 0: the test's own, from its node ID), to fly the tests with "
        "other noise",
    )


def pytest_configure(config: pytest.Config) -> None:
    url = config.getoption("--vehicle")
    if url is not None:
        try:
            pymavlink_url(url)
        except VehicleUrlError as exc:
            raise pytest.UsageError(str(exc)) from None
    speed = config.getoption("--sitl-speed")
    if not (0 < speed <= 20):
        raise pytest.UsageError(f"--sitl-speed must be in (0, 20], got {speed}")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if config.getoption("--vehicle") is None:
        return
    skip = pytest.mark.skip(reason="sim_only: needs a drone this suite starts itself (--vehicle given)")
    for item in items:
        if "sim_only" in item.keywords:
            item.add_marker(skip)


@pytest.hookimpl(tryfirst=True)
def pytest_pyfunc_call(pyfuncitem: pytest.Function) -> bool | None:
    """Run ``async def`` tests to completion in a fresh event loop."""
    if not inspect.iscoroutinefunction(pyfuncitem.obj):
        return None
    kwargs = {name: pyfuncitem.funcargs[name] for name in pyfuncitem._fixtureinfo.argnames}
    asyncio.run(pyfuncitem.obj(**kwargs))
    return True


@pytest.fixture(scope="session")
def instance_allocator(pytestconfig: pytest.Config) -> Iterator[InstanceAllocator]:
    """This process's block of INSTANCES_PER_WORKER instances for drones spawned one or two at a time, leased for
    the session from the top of the range (tests/integration/instances.py says why)."""
    with leases(pytestconfig.getoption("--sitl-instance-base")) as take:
        yield InstanceAllocator(take(INSTANCES_PER_WORKER, from_top=True), INSTANCES_PER_WORKER)


@pytest.fixture
def instances(pytestconfig: pytest.Config) -> Iterator[Leases]:
    """``instances(count)``: the first of ``count`` consecutive instances leased to this test alone (a ``swarm``
    command's ``--first-instance``), given back when the test ends."""
    with leases(pytestconfig.getoption("--sitl-instance-base")) as take:
        yield take


@pytest.fixture(scope="module")
def module_instances(pytestconfig: pytest.Config) -> Iterator[Leases]:
    """``instances`` for a module's shared flights: leased until the module's last test ends."""
    with leases(pytestconfig.getoption("--sitl-instance-base")) as take:
        yield take


@pytest.fixture
def drone_seed(request: pytest.FixtureRequest) -> int:
    """The base seed of the drones a test spawns: from the test's node ID, so that a test flies the same flight
    whichever instances it is given (their numbers depend on what else runs at the time); ``--sitl-seed-offset``
    moves every test's seed at once."""
    offset = int(request.config.getoption("--sitl-seed-offset"))
    return (zlib.crc32(request.node.nodeid.encode()) + offset) % SEED_SPAN


@pytest.fixture
def world_drone(tmp_path: Path, instance_allocator: InstanceAllocator, drone_seed: int) -> WorldDrone:
    """``world_drone(speed_factor=..., log_lines=...)``: a drone of this test in a fresh shared world
    (``sitl_process.drone_in_world``), seeded with ``drone_seed``."""
    return functools.partial(drone_in_world, tmp_path, instance_allocator, seed=drone_seed)


@pytest.fixture
def spawn_drones(
    request: pytest.FixtureRequest, instance_allocator: InstanceAllocator, tmp_path: Path, drone_seed: int
) -> Iterator[SpawnDrones]:
    """Factory: ``spawn_drones(n)`` starts n ready drones on adjacent free instances. At teardown every one is
    stopped and reaped (each independently of the others) and its log is printed, which pytest shows for failed
    tests."""
    if request.config.getoption("--vehicle") is not None:
        pytest.skip("spawning sitl is disabled when --vehicle is given")
    default_speed = request.config.getoption("--sitl-speed")

    def stop(drone: SitlDrone) -> None:
        try:
            exit_code = stop_drone(drone)
        finally:
            instance_allocator.give_back(drone.ports.instance)
        print(f"--- sitl instance {drone.ports.instance} (exit code {exit_code}) ---\n{drone.process.log_tail()}")

    with contextlib.ExitStack() as stoppers:

        def spawn(count: int = 1, *, speed_factor: float = default_speed, hosted: bool = False) -> list[SitlDrone]:
            instances = instance_allocator.take(count)
            drones: list[SitlDrone] = []
            try:
                drones = start_drones(
                    instances=instances, speed_factor=speed_factor, seed=drone_seed, log_dir=tmp_path, hosted=hosted
                )
                for drone in drones:
                    stoppers.callback(stop, drone)
            finally:
                for instance in instances[len(drones) :]:
                    instance_allocator.give_back(instance)
            return drones

        yield spawn


HOST_NEIGHBOURS = 2  # a hosted vehicle shares its process with this many other drones, which stand idle


@pytest.fixture(params=["process", "hosted"])
def vehicle(request: pytest.FixtureRequest) -> VehicleLink:
    """The vehicle a flight test flies: ``--vehicle`` if given, else a fresh drone of our own, once in its own
    process and once hosted with HOST_NEIGHBOURS other drones in one ``sitl --instances`` process (a client must
    not be able to tell the two apart)."""
    url = request.config.getoption("--vehicle")
    if url is not None:
        if request.param == "hosted":
            pytest.skip("an external vehicle is flown once")
        return VehicleLink.external(url, request.config.getoption("--vehicle-speed"))
    spawn: SpawnDrones = request.getfixturevalue("spawn_drones")
    if request.param == "hosted":
        return VehicleLink.of(spawn(1 + HOST_NEIGHBOURS, hosted=True)[0])
    return VehicleLink.of(spawn()[0])


def child_pids() -> set[int]:
    """This process's children (started from any thread), but Python's shared-memory resource tracker: a process
    that creates shared memory (an in-process swarm session, gcs/api) starts one, and it lives until that process
    ends, whatever the session does."""
    me = os.getpid()
    children: set[int] = set()
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            stat = Path(entry.path, "stat").read_text()
        except OSError:
            continue
        # the command name (field 2) may contain spaces; the parent PID is the 2nd field after its ")"
        if int(stat.rpartition(")")[2].split()[1]) == me:
            with contextlib.suppress(OSError):
                if b"multiprocessing.resource_tracker" not in Path(entry.path, "cmdline").read_bytes():
                    children.add(int(entry.name))
    return children


def _os_thread_count() -> int:
    return len(os.listdir("/proc/self/task"))


@pytest.fixture(autouse=True)
def no_leftover_processes_or_threads() -> Iterator[None]:
    """After a test, every process it started is reaped and every thread it started (native too) has ended."""
    children_before = child_pids()
    threads_before = _os_thread_count()
    py_threads_before = set(threading.enumerate())
    yield
    deadline = time.monotonic() + LEAK_SETTLE_S
    while True:
        children = child_pids() - children_before
        extra_threads = _os_thread_count() - threads_before
        py_threads = [t.name for t in threading.enumerate() if t not in py_threads_before]
        if not children and extra_threads <= 0 and not py_threads:
            return
        if time.monotonic() > deadline:
            pytest.fail(
                f"left behind: child processes {sorted(children)}, {extra_threads} extra OS threads, "
                f"Python threads {py_threads}",
                pytrace=False,
            )
        time.sleep(0.05)
