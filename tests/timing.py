"""Where the suite's time goes, per file: setup + call + teardown of its tests, and how long they waited.

A module-scoped flight runs in the setup of the module's first test and ends in the teardown of its last, so the call
phases alone (pytest's ``--durations``) leave the costliest flights out. A test may also wait: before its setup for
the machine-wide lock (tests/wall_clock.py) while a wall-clock test holds the machine, outside its phases; and inside
a phase for instance leases (tests/integration/instances.py) while other tests hold every block that fits. The waits
are counted in the process that waited and reach the controller with the test's reports (``user_properties``, which
pytest-xdist carries), so the end summary can say what each file cost and what it spent waiting.

``--durations-table PATH`` writes each file's own cost (its phases less its lease waits), by the tier of its tests, as
JSON: the table the scheduler deals files from (tests/scheduling.py)."""

from __future__ import annotations

import contextlib
import json
import time
from collections import defaultdict
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

import pytest
from _pytest.reports import TestReport
from _pytest.terminal import TerminalReporter

from tests.tiers import TIERS, file_of

LOCK: Final = "machine lock"
LEASE: Final = "instance lease"
WAITS: Final = (LOCK, LEASE)
_PROPERTY_PREFIX: Final = "waited for "
FILES_SHOWN: Final = 30

_waited_s: dict[str, float] = dict.fromkeys(WAITS, 0.0)  # this process's waits since its last report


@contextlib.contextmanager
def waiting(kind: str) -> Iterator[None]:
    """Count the time spent inside as a wait of ``kind`` (one of WAITS) of the test under way."""
    start = time.monotonic()
    try:
        yield
    finally:
        _waited_s[kind] += time.monotonic() - start


def _take_waits() -> dict[str, float]:
    taken = {kind: s for kind, s in _waited_s.items() if s > 0.0}
    for kind in _waited_s:
        _waited_s[kind] = 0.0
    return taken


def attach_waits(report: TestReport) -> None:
    """Give ``report`` the waits since the previous report of this process (a phase's own). A new list: pytest
    shares the item's list with every report of it."""
    waits = _take_waits()
    if waits:
        report.user_properties = [*report.user_properties, *((_PROPERTY_PREFIX + k, s) for k, s in waits.items())]


@dataclass
class FileCost:
    """One test file's time in a run, in wall seconds."""

    tests: int = 0
    phases_s: dict[str, float] = field(default_factory=lambda: dict.fromkeys(("setup", "call", "teardown"), 0.0))
    waited_s: dict[str, float] = field(default_factory=lambda: dict.fromkeys(WAITS, 0.0))
    own_by_tier_s: dict[str, float] = field(default_factory=dict)  # phases less lease waits, by the tests' tier

    @property
    def total_s(self) -> float:
        return sum(self.phases_s.values())


def file_costs(reporter: TerminalReporter) -> dict[str, FileCost]:
    costs: dict[str, FileCost] = defaultdict(FileCost)
    for reports in reporter.stats.values():
        for report in reports:
            when = getattr(report, "when", None)
            if not isinstance(report, TestReport) or when not in ("setup", "call", "teardown"):
                continue
            cost = costs[file_of(report.nodeid)]
            cost.phases_s[when] += report.duration
            cost.tests += when == "setup"
            own_s = report.duration
            for name, value in report.user_properties:
                if isinstance(name, str) and name.startswith(_PROPERTY_PREFIX) and isinstance(value, float):
                    kind = name.removeprefix(_PROPERTY_PREFIX)
                    cost.waited_s[kind] += value
                    own_s -= value if kind == LEASE else 0.0  # the lock is waited for outside the phases
            tier = next((t for t in TIERS if t in report.keywords), "")
            cost.own_by_tier_s[tier] = cost.own_by_tier_s.get(tier, 0.0) + max(0.0, own_s)
    return dict(costs)


def summarize(reporter: TerminalReporter, table: Path | None) -> None:
    """The files that cost most, each with its phases and waits; all of them into ``table`` when asked."""
    costs = file_costs(reporter)
    if not costs:
        return
    ranked = sorted(costs.items(), key=lambda kv: -kv[1].total_s)
    reporter.write_sep("=", "cost per file (wall s): setup + call + teardown, the lock waited for, the leases inside")
    columns = ("total", "setup", "call", "teardown", "lock", "lease", "tests")
    reporter.write_line(" ".join(f"{c:>8}" for c in columns) + "  file")
    for path, cost in ranked[:FILES_SHOWN]:
        p, w = cost.phases_s, cost.waited_s
        reporter.write_line(
            " ".join(f"{s:8.1f}" for s in (cost.total_s, p["setup"], p["call"], p["teardown"], w[LOCK], w[LEASE]))
            + f" {cost.tests:8d}  {path}"
        )
    everything = sum(c.total_s for c in costs.values())
    waited = {k: sum(c.waited_s[k] for c in costs.values()) for k in WAITS}
    reporter.write_line(
        f"{len(costs)} files, {everything:.0f} s of tests; before they started they waited {waited[LOCK]:.0f} s for "
        f"the machine lock, and inside them {waited[LEASE]:.0f} s for instance leases"
    )
    if table is not None:
        own = {path: {t: round(s, 1) for t, s in sorted(c.own_by_tier_s.items())} for path, c in sorted(costs.items())}
        table.write_text(json.dumps(own, indent=1) + "\n")
        reporter.write_line(f"each file's own cost written to {table}")


def add_options(parser: pytest.Parser) -> None:
    parser.addoption(
        "--durations-table",
        type=Path,
        default=None,
        metavar="PATH",
        help="write each file's cost in this run (setup + call + teardown less lease waits), by tier, to PATH as JSON",
    )
