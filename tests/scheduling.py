"""Files are dealt to the workers longest first, from a committed table of what each file cost (tests/durations.json).

pytest-xdist (``--dist loadfile``) gives each worker whole files, in the order of the collection when it is told not
to reorder them (``--no-loadscope-reorder``, pyproject.toml); by default it deals the files with the most tests first,
which on this suite left a one-test campaign for last and one worker flying it alone for its final minutes. Dealt
longest first, the long files start at once and the short ones fill the gaps at the end (the classic LPT rule).

The table holds each file's own cost in a run (setup + call + teardown less its waits: tests/timing.py). A file not in
it yet (a new one) is dealt as if it cost ``UNKNOWN_FILE_S``. Refresh the table with one command, after a change that
moves a file's cost by much::

    .venv/bin/pytest --tier all --durations-table tests/durations.json

Tests keep their order inside a file: module-scoped flights are set up by the file's first test that asks for them.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Final

import pytest

TABLE: Final = Path(__file__).resolve().parent / "durations.json"
UNKNOWN_FILE_S: Final = 60.0


def load_table(path: Path = TABLE) -> dict[str, float]:
    try:
        return {str(k): float(v) for k, v in json.loads(path.read_text()).items()}
    except (OSError, ValueError):
        return {}


def longest_first(items: list[pytest.Item], table: dict[str, float]) -> None:
    """Reorder ``items`` in place: files by their cost in ``table``, longest first, each file's tests in their
    order. Every worker sorts alike (the sort is stable and depends on nothing else), as pytest-xdist requires."""
    first_seen: dict[str, int] = {}
    for item in items:
        first_seen.setdefault(item.nodeid.split("::")[0], len(first_seen))

    def key(item: pytest.Item) -> tuple[float, int]:
        path = item.nodeid.split("::")[0]
        return (-table.get(path, UNKNOWN_FILE_S), first_seen[path])

    items.sort(key=key)
