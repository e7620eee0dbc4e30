"""The pytest plugin for users' own swarm tests, registered as ``swarmsitl`` (entry point ``pytest11``): installing the
project makes its fixtures available to every pytest run, with no import.

- ``swarm``: a swarm launched in lockstep for the test (``@pytest.mark.swarm(4, layout="line", params={...})`` sets
  its ``LaunchOptions``; default 3 drones) and closed after it, whatever happened: every drone lands and stops.
  ``@pytest.mark.swarm(4, invariants=[{"kind": "separation", "min_m": 1.0}])`` checks invariants at every tick
  (docs/invariants.md): a violation fails the test, naming the report.
- ``swarm_factory``: ``swarm_factory(6, **options)`` launches more (each with its own instances and report).
- The assertions of gcs/api/checks.py on a closed session's ``FlightResult``: ``assert_no_collisions``,
  ``assert_min_separation``, ``assert_no_failsafe``, ``assert_reached``.

Each session's flight report goes to the test's ``tmp_path`` (``swarm-0``, ``swarm-1``, ...), so a failure points at
a report. ``--swarm-first-instance N`` moves the drones' instances (ports, sysids) clear of other simulators.
Sessions wait in simulated time (``swarm.sleep``, ``swarm.wait_until``), so a test's outcome does not depend on the
machine's load. The API is imported when a fixture is first used: a pytest run that uses none pays nothing for it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

if TYPE_CHECKING:
    from gcs.api import BlockingSession

INSTANCES_PER_SESSION = 50  # each session of a test starts this many instances after the previous one's first


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("swarmsitl", "simulated drone swarms")
    group.addoption("--swarm-first-instance", type=int, default=0, metavar="N",
                    help="instance of the first simulated drone (sysid N+1, its ports as docs/mavlink.md gives "
                    "them; default 0)")  # fmt: skip


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "swarm(drones=3, **options): the LaunchOptions of the test's `swarm` fixture")


@pytest.fixture
def swarm_factory(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Callable[..., BlockingSession]]:
    """``swarm_factory(drones, **options)``: a swarm in lockstep (unless ``lockstep=False``), its report in
    ``tmp_path``; every one is closed after the test."""
    from gcs.api import BlockingSession, LaunchOptions
    from gcs.api.session import _default_simulation

    sessions: list[BlockingSession] = []
    first = int(request.config.getoption("--swarm-first-instance"))

    def launch(drones: int, **options: Any) -> BlockingSession:
        options.setdefault("lockstep", True)
        options.setdefault("report_dir", tmp_path / f"swarm-{len(sessions)}")
        options.setdefault("first_instance", first + INSTANCES_PER_SESSION * len(sessions))
        session = BlockingSession.start(LaunchOptions(drones=drones, **options), _default_simulation())
        sessions.append(session)
        return session

    try:
        yield launch
    finally:
        broken = []
        for session in sessions:
            result = session.close(interrupt=True)
            violations = result.metrics.get("violations", []) if result is not None else []
            if violations:
                first = violations[0]
                broken.append(f"invariant {first['name']} violated at t={first['time_s']} s: {first['detail']} "
                              f"(report: {result.report_dir})")  # fmt: skip
        if broken:  # the test fails, naming the report (pytest shows it as an error at teardown)
            pytest.fail("; ".join(broken), pytrace=False)


@pytest.fixture
def swarm(request: pytest.FixtureRequest, swarm_factory: Callable[..., BlockingSession]) -> BlockingSession:
    """A swarm for the test, as its ``@pytest.mark.swarm(...)`` says (default: 3 drones), up and ready."""
    marker = request.node.get_closest_marker("swarm")
    options: dict[str, Any] = dict(marker.kwargs) if marker is not None else {}
    drones = int(marker.args[0]) if marker is not None and marker.args else int(options.pop("drones", 3))
    return swarm_factory(drones, **options)
