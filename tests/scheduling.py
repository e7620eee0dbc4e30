"""Files are dealt to the workers longest first, from a committed table of what each file cost (tests/durations.json).

pytest-xdist (``--dist loadfile``) gives each worker whole files, in the order of the collection when it is told not
to reorder them (``--no-loadscope-reorder``, pyproject.toml); by default it deals the files with the most tests first,
which on this suite left a one-test campaign for last and one worker flying it alone for its final minutes. Dealt
longest first, the long files start at once and the short ones fill the gaps at the end (the classic LPT rule).

The table holds each file's own cost in a run (setup + call + teardown less its lease waits: tests/timing.py), by the
tier of its tests, so a file whose tests are split between the suite and the acceptance tier is dealt by what the run
at hand flies of it. A file not in it yet (a new one) is dealt as if it cost ``UNKNOWN_FILE_S``. Refresh the table
with one command, after a change that moves a file's cost by much::

    .venv/bin/pytest --tier all --durations-table tests/durations.json

Files with a test that takes the whole machine (``wall_clock``: tests/wall_clock.py) are dealt before all others: while
one runs every other worker waits, so they are best flown back to back at the start, and the shared files then pack
the gaps. Dealt among the rest, a long campaign holding its share kept the next wall-clock test, and so its worker,
waiting for minutes (the acceptance tier: 186 s of 534).

Tests keep their order inside a file: module-scoped flights are set up by the file's first test that asks for them.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Final

import pytest

from tests.tiers import file_of
from tests.wall_clock import needs_the_machine

TABLE: Final = Path(__file__).resolve().parent / "durations.json"
UNKNOWN_FILE_S: Final = 60.0


Table = dict[str, dict[str, float]]  # test file -> tier -> wall seconds


def load_table(path: Path = TABLE) -> Table:
    try:
        return {
            str(f): {str(t): float(s) for t, s in tiers.items()} for f, tiers in json.loads(path.read_text()).items()
        }
    except (OSError, ValueError, AttributeError):
        return {}


def longest_first(items: list[pytest.Item], table: Table, tier_of: Callable[[pytest.Item], str]) -> None:
    """Reorder ``items`` in place: the files that take the whole machine first, then each group by its cost in
    ``table``, longest first, each file's tests in their order. Every worker sorts alike (the sort is stable and
    depends on nothing else), as pytest-xdist requires."""
    first_seen: dict[str, int] = {}
    exclusive: set[str] = set()
    tiers_run: dict[str, set[str]] = {}
    for item in items:
        path = file_of(item.nodeid)
        first_seen.setdefault(path, len(first_seen))
        tiers_run.setdefault(path, set()).add(tier_of(item))
        if needs_the_machine(item):
            exclusive.add(path)
    cost = {path: sum(table[path].get(t, 0.0) for t in run) if path in table else UNKNOWN_FILE_S
            for path, run in tiers_run.items()}  # fmt: skip

    def key(item: pytest.Item) -> tuple[bool, float, int]:
        path = file_of(item.nodeid)
        return (path not in exclusive, -cost[path], first_seen[path])

    items.sort(key=key)
