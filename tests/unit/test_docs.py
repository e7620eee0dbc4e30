"""Generated documentation stays in step with the code."""

from __future__ import annotations

from pathlib import Path

from sitl.paramdoc import render
from sitl.simulation import build_param_store

DOCS = Path(__file__).resolve().parents[2] / "docs"


def test_parameter_table_in_docs_is_current() -> None:
    assert (DOCS / "parameters.md").read_text() == render(build_param_store()), (
        "docs/parameters.md is stale: run `python -m sitl.paramdoc > docs/parameters.md`"
    )
