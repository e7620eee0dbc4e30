"""How the commands' processes end (swarmcommon/process_end.py): main's exit code, the collector frozen after it.

Policy: each case runs in a fresh interpreter (a frozen collector would stay frozen in the test's own process)."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

pytestmark = pytest.mark.timeout(60)

CASE = textwrap.dedent(
    """
    import gc, sys
    from swarmcommon.process_end import ending

    def main() -> int:
        assert gc.get_freeze_count() == 0  # nothing frozen while main runs
        if sys.argv[1] == "raise":
            raise RuntimeError("main failed")
        return 3

    try:
        code = ending(main)
    except RuntimeError:
        code = 4
    print(gc.get_freeze_count() > 0, flush=True)
    sys.exit(code)
    """
)


@pytest.mark.parametrize(("how", "code"), [("return", 3), ("raise", 4)])
def test_the_collector_is_frozen_once_main_returned_or_raised_and_main_gives_the_exit_code(how: str, code: int) -> None:
    # WHEN a command's main returns (or raises) through ending
    run = subprocess.run([sys.executable, "-c", CASE, how], capture_output=True, text=True, timeout=30)
    # THEN the process exits with main's code and every object was frozen (no last collection visits them)
    assert run.returncode == code, run.stderr
    assert run.stdout.strip() == "True", run
