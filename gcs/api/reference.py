"""The API reference, generated from the docstrings: ``python -m gcs.api.reference > docs/api-reference.md``.

A unit test compares the committed page with this output, so the reference cannot drift from the code.
"""

from __future__ import annotations

import dataclasses
import inspect
import sys
from collections.abc import Callable
from typing import Any

from gcs import api

_INTRO = """# Python API reference

Generated from the docstrings by `python -m gcs.api.reference > docs/api-reference.md` (a test keeps it current).
The guide, with examples, is docs/api.md.
"""
# What the page documents, in this order: the entry points, the sessions, then the types they take and give.
_FUNCTIONS = ("launch", "launch_blocking")
_CLASSES = ("Session", "BlockingSession", "LaunchOptions", "DroneState", "Event", "FlightResult")
_ERRORS = ("ControllerError", "SessionClosed", "SwarmError")


def _doc(obj: Any) -> str:
    return inspect.cleandoc(obj.__doc__) if obj.__doc__ else ""


def _signature(name: str, func: Callable[..., Any]) -> str:
    return f"{name}{inspect.signature(func)}".replace("'", "")


def _class_section(cls: type) -> list[str]:
    lines = [f"## `{cls.__name__}`", "", _doc(cls), ""]
    if dataclasses.is_dataclass(cls):
        lines += ["| field | type | default |", "|---|---|---|"]
        for f in dataclasses.fields(cls):
            if f.default is not dataclasses.MISSING:
                default = repr(f.default)
            elif f.default_factory is not dataclasses.MISSING:
                default = repr(f.default_factory())
            else:
                default = "(required)"
            lines.append(f"| `{f.name}` | `{f.type}` | `{default}` |")
        lines.append("")
    for name, member in inspect.getmembers(cls):
        if name.startswith("_") or member is None:
            continue
        if isinstance(inspect.getattr_static(cls, name), property):
            lines += [f"### `{cls.__name__}.{name}` (property)", "", _doc(member) or "(see the asyncio face)", ""]
        elif inspect.isfunction(member) or inspect.ismethod(member):
            lines += [f"### `{cls.__name__}.{_signature(name, member)}`", "", _doc(member) or _same_as(cls, name), ""]
    return lines


def _same_as(cls: type, name: str) -> str:
    """A blocking method documents itself by its asyncio twin."""
    twin = getattr(api.Session, name, None)
    return f"As `Session.{name}`, blocking." if twin is not None and cls is api.BlockingSession else ""


def reference() -> str:
    lines = [_INTRO]
    for name in _FUNCTIONS:
        lines += [f"## `{_signature(name, getattr(api, name))}`", "", _doc(getattr(api, name)), ""]
    for name in _CLASSES:
        lines += _class_section(getattr(api, name))
    lines += ["## Errors", ""]
    lines += [f"- `{name}`: {_doc(getattr(api, name)).splitlines()[0]}" for name in _ERRORS]
    return "\n".join(lines).rstrip() + "\n"


if __name__ == "__main__":
    sys.stdout.write(reference())
