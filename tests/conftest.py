"""The suite's tiers: every test is marked with one from the folder it lives in, and ``heavy`` besides when it needs
what a contributor at work would rather leave to CI (README, "Tests").

- ``unit`` (tests/unit): one part on its own, in this process; a closed loop at most as long as a takeoff.
- ``flight`` (tests/closed_loop): closed-loop flights through JSBSim, every drone in this process.
- ``integration`` (tests/integration): real ``sitl`` and ``swarm`` processes on 127.0.0.1 driven by real clients.
- ``heavy``: a local Ray head (the ``ray_head`` fixture), a browser, CPU burners, benches, floods of frames and swarms
  of more than 40 drones: marked where the module or the test says so (``pytest.mark.heavy``) or from its fixtures.

Besides its tier, a test that flies in wall time (an attached vehicle keeps it) is marked ``wall_clock`` and runs with
the machine to itself (tests/wall_clock.py).

``pytest -m "unit or flight"`` is the quick tier (about 5 minutes on two cores); ``pytest -m "not heavy"`` leaves out
only the heavy tests; ``pytest`` runs everything, as CI does. At the end of a run the slowest tests of each tier are
listed (no test asserts a duration)."""

from __future__ import annotations

import os
import sys
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path

import pytest
from _pytest.terminal import TerminalReporter

from tests.timing import LOCK, add_options, attach_waits, summarize, waiting
from tests.wall_clock import SUITE_DIR, MachineShare, hold_for, release_after

TIER_OF_FOLDER = {"unit": "unit", "closed_loop": "flight", "integration": "integration"}
HEAVY_FIXTURES = frozenset({"ray_head"})
SLOWEST_PER_TIER = 8
_TESTS = Path(__file__).resolve().parent


def tier_of(path: Path) -> str | None:
    """The tier of a test module from its folder under tests/ (None outside the three)."""
    try:
        folder = path.resolve().relative_to(_TESTS).parts[0]
    except (ValueError, IndexError):
        return None
    return TIER_OF_FOLDER.get(folder)


_SHARE = pytest.StashKey[MachineShare]()


def keep_bytecode() -> None:
    """Let every process of the suite cache the project's bytecode, under the temporary directory when the
    environment forbids writing it beside the sources (PYTHONDONTWRITEBYTECODE, which some machines and CI images
    set). Without a cache each of the suite's thousands of ``swarm`` and ``sitl`` processes compiles the modules it
    imports from source again: 0.8 s of a two-drone lockstep flight's 7 s. The tree stays as clean as the setting
    asked for, and the processes the tests start inherit the choice through the environment."""
    if not os.environ.get("PYTHONDONTWRITEBYTECODE"):
        return
    prefix = str(SUITE_DIR / "pycache")
    del os.environ["PYTHONDONTWRITEBYTECODE"]
    os.environ.setdefault("PYTHONPYCACHEPREFIX", prefix)
    sys.dont_write_bytecode = False
    if sys.pycache_prefix is None:
        sys.pycache_prefix = os.environ["PYTHONPYCACHEPREFIX"]


keep_bytecode()


def pytest_addoption(parser: pytest.Parser) -> None:
    add_options(parser)


def pytest_configure(config: pytest.Config) -> None:
    config.stash[_SHARE] = MachineShare()


def pytest_unconfigure(config: pytest.Config) -> None:
    if _SHARE in config.stash:
        config.stash[_SHARE].close()


@pytest.hookimpl(hookwrapper=True, tryfirst=True)  # outside pytest-timeout's: waiting for the machine is not the test's
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    share = item.config.stash[_SHARE]
    with waiting(LOCK):
        hold_for(share, item)
    try:
        yield
    finally:
        release_after(share, item, nextitem)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[None]:
    outcome = yield
    attach_waits(outcome.get_result())  # type: ignore[attr-defined]


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        tier = tier_of(item.path)
        if tier is not None:
            item.add_marker(getattr(pytest.mark, tier))
        if HEAVY_FIXTURES.intersection(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.heavy)


def pytest_terminal_summary(terminalreporter: TerminalReporter, exitstatus: int, config: pytest.Config) -> None:
    """The slowest tests of each tier (call phase), then each file's whole cost (tests/timing.py), so a run shows
    where each tier's time goes."""
    summarize(terminalreporter, config.getoption("--durations-table"))
    by_tier: dict[str, list[tuple[float, str]]] = defaultdict(list)
    for reports in terminalreporter.stats.values():
        for report in reports:
            if getattr(report, "when", None) != "call":
                continue
            keywords = getattr(report, "keywords", {})
            tier = next((t for t in ("unit", "flight", "integration") if t in keywords), None)
            if tier is None:
                continue
            name = f"{tier} (heavy)" if "heavy" in keywords else tier
            by_tier[name].append((report.duration, report.nodeid))
    if not by_tier:
        return
    terminalreporter.write_sep("=", "slowest tests of each tier")
    for name in sorted(by_tier):
        runs = sorted(by_tier[name], reverse=True)
        total = sum(d for d, _ in runs)
        terminalreporter.write_line(f"{name}: {len(runs)} test{'s' if len(runs) != 1 else ''}, {total:.1f} s of calls")
        for duration, nodeid in runs[:SLOWEST_PER_TIER]:
            terminalreporter.write_line(f"  {duration:7.2f}s {nodeid}")
