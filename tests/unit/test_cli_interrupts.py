"""``swarm fly`` and ``swarm up`` answer a signal as Ctrl-C, also when Python could only print the interrupt: a
sweep's run whose SIGTERM (its parent died) came while the drone factory was forked flew on to its end."""

from __future__ import annotations

import signal
import sys
import time

import pytest

from gcs.cli import _interrupt_on

pytestmark = pytest.mark.timeout(60)


class Dropped:
    """An object whose ``__del__`` receives a signal: its handler runs inside the ``__del__``, a callback whose
    exceptions the interpreter prints and drops, as it does those of the at-fork hooks around a fork."""

    def __del__(self) -> None:
        signal.raise_signal(signal.SIGUSR1)


def test_an_interrupt_raised_where_python_only_prints_it_is_raised_again(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sys, "unraisablehook", sys.unraisablehook)  # put back after the test
    previous = signal.getsignal(signal.SIGUSR1)
    try:
        _interrupt_on([signal.SIGUSR1])
        started = time.monotonic()
        with pytest.raises(KeyboardInterrupt):
            Dropped()  # the handler's KeyboardInterrupt, raised in __del__, is lost there...
            time.sleep(5)  # ...and raised again here, once the main thread is out of that callback
        assert time.monotonic() - started < 2
    finally:
        signal.signal(signal.SIGUSR1, previous)
