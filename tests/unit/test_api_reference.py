"""docs/api-reference.md is what ``python -m gcs.api.reference`` makes of the API's docstrings."""

from __future__ import annotations

from pathlib import Path

from gcs.api.reference import reference

PAGE = Path(__file__).resolve().parents[2] / "docs" / "api-reference.md"


def test_the_committed_api_reference_is_current() -> None:
    assert PAGE.read_text() == reference(), "run: python -m gcs.api.reference > docs/api-reference.md"
