"""``report.html``: the flight report as one self-contained page that replays the flight (gcs/view/replay.py's
document, drawn by the live view's own code, static/draw.js and static/replay.js).

Nothing is fetched when it opens: three.js, the page's scripts, the flight and the plots are all inside the file,
each script and the flight gzipped and base64-encoded (three.js alone is 2.2 MB as shipped, 0.56 MB so), which the
page unpacks with the browser's DecompressionStream. The file is the same for the same flight (gzip without a
timestamp), so reports can be compared and committed.
"""

from __future__ import annotations

import base64
import gzip
import html
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

from gcs.view.server import STATIC

REPORT_PAGE_FILE: Final = "report.html"
PAYLOADS: Final = {  # the page's element id -> the file under static/
    "three-core": "vendor/three/three.core.js",
    "three-module": "vendor/three/three.module.js",
    "orbit-controls": "vendor/three/OrbitControls.js",
    "draw": "draw.js",
    "replay": "replay.js",
}


def _packed(data: bytes) -> str:
    return base64.b64encode(gzip.compress(data, compresslevel=9, mtime=0)).decode("ascii")


def _payload(element_id: str, data: bytes) -> str:
    return f'<script type="application/octet-stream" id="{element_id}">\n{_packed(data)}\n</script>'


def report_page(document: dict[str, Any], *, title: str, summary: str, plots: Sequence[Path]) -> str:
    """The page's HTML: the replay ``document``, the summary text and the plots (PNG files) inlined."""
    payloads = [_payload(element_id, (STATIC / name).read_bytes()) for element_id, name in PAYLOADS.items()]
    payloads.append(_payload("flight", json.dumps(document, separators=(",", ":"), allow_nan=False).encode()))
    images = "\n  ".join(
        f'<img alt="{html.escape(p.stem)}" src="data:image/png;base64,{base64.b64encode(p.read_bytes()).decode()}">'
        for p in plots
    )
    fields = {
        "title": html.escape(title),
        "view_css": (STATIC / "view.css").read_text(encoding="utf-8"),
        "report_css": (STATIC / "report.css").read_text(encoding="utf-8"),
        "summary": html.escape(summary),
        "plots": images,
        "payloads": "\n".join(payloads),
    }
    page = (STATIC / "report.html").read_text(encoding="utf-8")
    for name, value in fields.items():
        page = page.replace("{{" + name + "}}", value)
    return page


def write_report_page(document: dict[str, Any], out_dir: Path, *, title: str, summary: str,
                      plots: Sequence[Path]) -> Path:  # fmt: skip
    path = out_dir / REPORT_PAGE_FILE
    path.write_text(report_page(document, title=title, summary=summary, plots=plots), encoding="utf-8")
    return path
