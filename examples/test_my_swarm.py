"""A user's own swarm test, written with the project's pytest plugin (installed with the project: no import needed
for the fixtures). Run it with ``pytest examples/test_my_swarm.py``.

The ``swarm`` fixture launches the drones of the test's ``@pytest.mark.swarm(...)`` in lockstep and lands and stops
them after the test, pass or fail; waits are in simulated time, so the outcome does not depend on the machine.
"""

from __future__ import annotations

import pytest

from gcs.api import BlockingSession, LineSpec, assert_min_separation, assert_no_collisions, assert_no_failsafe


@pytest.mark.timeout(180)
@pytest.mark.swarm(2, layout="line", spacing_m=3.0)
def test_two_drones_hold_a_line_without_touching(swarm: BlockingSession) -> None:
    swarm.takeoff(3.0)
    swarm.formation(LineSpec(spacing_m=2.0, alt_m=3.0))
    swarm.sleep(10.0)
    swarm.land()
    result = swarm.close()
    assert_no_collisions(result)
    assert_min_separation(result, 1.5)
    assert_no_failsafe(result)
