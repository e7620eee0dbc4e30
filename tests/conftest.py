"""The suite's plumbing: tiers and kinds (tests/tiers.py), the order files are dealt to workers in
(tests/scheduling.py), what each file cost (tests/timing.py), the machine-wide lock for wall-clock tests
(tests/wall_clock.py), a bytecode cache, and the kernels compiled once before the workers start.

``pytest`` runs the suite (the README's test command), ``pytest --tier quick`` the quick tier, ``pytest --tier
acceptance`` the acceptance tier (docs/testing.md). At the end of a run the slowest tests of each kind and the cost of
each file are listed (no test asserts a duration)."""

from __future__ import annotations

import os
import pkgutil
import subprocess
import sys
import time
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path

import pytest
from _pytest.terminal import TerminalReporter

from tests import tiers, timing
from tests.scheduling import load_table, longest_first
from tests.timing import LOCK, attach_waits, waiting
from tests.wall_clock import SUITE_DIR, MachineShare, hold_for, release_after

SLOWEST_PER_KIND = 8


_SHARE = pytest.StashKey[MachineShare]()
_COMPILE_S = pytest.StashKey[float]()


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
    tiers.add_options(parser)
    timing.add_options(parser)


def compile_kernels_once() -> float:
    """Compile the drones' kernels into their on-disk cache (sitl/kernels) before any worker starts, and return how
    long it took. Otherwise, on a cold cache, every worker and every drone or factory the first tests start compiles
    them at once (25-36 s of CPU each on two cores); once cached, this costs a load (about 1 s).

    One child per CPU, the modules dealt among them largest source first to the child with the least so far (a module
    a child imports compiles the kernel modules it imports too, so a small shared one may compile twice): on two
    cores about 11 s instead of one core's 15.6 s while the other waited."""
    import sitl.kernels  # the package alone: numba stays out of this process

    found = pkgutil.iter_modules(sitl.kernels.__path__, "sitl.kernels.")
    sizes = {m.name: Path(sitl.kernels.__path__[0], m.name.rpartition(".")[2] + ".py").stat().st_size for m in found}
    children = max(1, min(len(os.sched_getaffinity(0)), len(sizes)))
    orders: list[list[str]] = [[] for _ in range(children)]
    loads = [0] * children
    for name in sorted(sizes, key=lambda n: (-sizes[n], n)):
        least = loads.index(min(loads))
        orders[least].append(name)
        loads[least] += sizes[name]
    start = time.monotonic()
    procs = [subprocess.Popen([sys.executable, "-c", "; ".join(f"import {m}" for m in order)]) for order in orders]
    failed = [p.args for p in procs if p.wait(timeout=600) != 0]
    if failed:
        raise pytest.UsageError(f"the drones' kernels did not compile: {failed[0]}")
    return time.monotonic() - start


def pytest_configure(config: pytest.Config) -> None:
    config.stash[_SHARE] = MachineShare()
    is_worker = hasattr(config, "workerinput")
    if not is_worker and not config.option.collectonly and not config.option.help:
        config.stash[_COMPILE_S] = compile_kernels_once()


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
    tiers.mark_and_select(config, items)
    longest_first(items, load_table(), tiers.tier_of)


def pytest_terminal_summary(terminalreporter: TerminalReporter, exitstatus: int, config: pytest.Config) -> None:
    """The slowest tests of each kind (call phase), then each file's whole cost (tests/timing.py), so a run shows
    where its time goes."""
    if _COMPILE_S in config.stash:
        terminalreporter.write_line(
            f"kernels compiled or loaded before the workers started: {config.stash[_COMPILE_S]:.1f} s"
        )
    timing.summarize(terminalreporter, config.getoption("--durations-table"))
    by_kind: dict[str, list[tuple[float, str]]] = defaultdict(list)
    for reports in terminalreporter.stats.values():
        for report in reports:
            if getattr(report, "when", None) != "call":
                continue
            keywords = getattr(report, "keywords", {})
            kind = next((k for k in tiers.KIND_OF_FOLDER.values() if k in keywords), None)
            if kind is None:
                continue
            by_kind[kind].append((report.duration, report.nodeid))
    if not by_kind:
        return
    terminalreporter.write_sep("=", "slowest tests of each kind")
    for name in sorted(by_kind):
        runs = sorted(by_kind[name], reverse=True)
        total = sum(d for d, _ in runs)
        terminalreporter.write_line(f"{name}: {len(runs)} test{'s' if len(runs) != 1 else ''}, {total:.1f} s of calls")
        for duration, nodeid in runs[:SLOWEST_PER_KIND]:
            terminalreporter.write_line(f"  {duration:7.2f}s {nodeid}")
