"""The suite's machine-wide reader-writer lock (tests/wall_clock.py): a wall-clock test waits for the tests under way,
no new test starts while it waits or runs, and a killed holder's lock goes with it."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.wall_clock import MachineShare

ROOT = Path(__file__).resolve().parents[2]
SETTLE_S = 0.3  # long enough for a thread that could take a lock to have taken it

pytestmark = pytest.mark.timeout(60)


def _in_thread(action: Callable[[], None], got: list[str], name: str) -> threading.Thread:
    def run() -> None:
        action()
        got.append(name)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def test_a_writer_waits_for_the_readers_under_way_and_no_new_reader_overtakes_it(tmp_path: Path) -> None:
    first, writer, second = (MachineShare(tmp_path) for _ in range(3))
    got: list[str] = []
    try:
        # GIVEN a test under way (a share)
        first.share()
        # WHEN a wall-clock test asks for the machine THEN it waits for the test under way
        waiting = _in_thread(writer.whole, got, "writer")
        time.sleep(SETTLE_S)
        assert got == []
        # AND a test asking for a share meanwhile does not get one: the writer is next
        later = _in_thread(second.share, got, "second")
        time.sleep(SETTLE_S)
        assert got == [], "a reader overtook the waiting writer"
        # WHEN the test under way ends THEN the writer has the machine, and the other test still waits
        first.release()
        waiting.join(5)
        time.sleep(SETTLE_S)
        assert got == ["writer"] and writer.held == "exclusive"
        # AND once the writer lets go, it gets its share
        writer.release()
        later.join(5)
        assert got == ["writer", "second"] and second.held == "shared"
    finally:
        for share in (first, writer, second):
            share.close()


def test_a_worker_that_lets_the_machine_go_and_asks_for_a_share_at_once_does_not_overtake_a_waiting_writer(
    tmp_path: Path,
) -> None:
    holder, writer = MachineShare(tmp_path), MachineShare(tmp_path)
    got: list[str] = []
    try:
        # GIVEN a wall-clock test under way, and another worker's wall-clock test waiting for the machine
        holder.whole()
        waiting = _in_thread(writer.whole, got, "writer")
        time.sleep(SETTLE_S)
        assert got == []

        # WHEN the first ends and its worker's next test asks for a share at once (in the same thread, as a worker does)
        def next_test() -> None:
            holder.release()
            holder.share()

        reader = _in_thread(next_test, got, "reader")
        # THEN the waiting writer has the machine first, and the share comes once it let go
        waiting.join(5)
        time.sleep(SETTLE_S)
        assert got == ["writer"] and writer.held == "exclusive", got
        writer.release()
        reader.join(5)
        assert got == ["writer", "reader"] and holder.held == "shared"
    finally:
        holder.close()
        writer.close()


def test_readers_share_the_machine(tmp_path: Path) -> None:
    one, other = MachineShare(tmp_path), MachineShare(tmp_path)
    got: list[str] = []
    try:
        one.share()
        _in_thread(other.share, got, "other").join(5)
        assert got == ["other"]
    finally:
        one.close()
        other.close()


def test_the_machine_held_by_a_killed_worker_is_free_again(tmp_path: Path) -> None:
    code = (f"import sys, time; sys.path.insert(0, {str(ROOT)!r}); from pathlib import Path; "
            f"from tests.wall_clock import MachineShare; MachineShare(Path({str(tmp_path)!r})).whole(); "
            "print('held', flush=True); time.sleep(60)")  # fmt: skip
    holder = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    share = MachineShare(tmp_path)
    got: list[str] = []
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        waiting = _in_thread(share.share, got, "share")
        time.sleep(SETTLE_S)
        assert got == []
        os.kill(holder.pid, signal.SIGKILL)
        waiting.join(5)
        assert got == ["share"]
    finally:
        if holder.poll() is None:
            holder.kill()
        holder.wait(10)
        share.close()
