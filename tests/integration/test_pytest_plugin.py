"""The pytest plugin (gcs/pytest_plugin.py) judged as a user meets it: a user's test file run by pytest in a
subprocess, with the plugin found through its entry point. The example test passes; the same test with the drones
told to fly 0.3 m apart, avoidance off, fails on ``assert_no_collisions`` with the collision in its message; a test
whose marker requires an invariant its drones break fails naming it and the report.

Policy: loopback only; two leased instances (tests/integration/instances.py: each test of the user's file launches
one session there); a time limit; the subprocess's drones are its own (the plugin closes every session).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.integration.instances import Leases

pytestmark = [pytest.mark.sim_only]
pytest_plugins = ["pytester"]

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "test_my_swarm.py"
COLLIDING = """

@pytest.mark.timeout(180)
@pytest.mark.swarm(2, layout="line", spacing_m=3.0, params={"AVOID_ENABLE": 0})
def test_two_drones_told_to_fly_0_3_m_apart(swarm: BlockingSession) -> None:
    swarm.takeoff(3.0)
    swarm.formation(LineSpec(spacing_m=0.3, alt_m=3.0))
    swarm.sleep(8.0)
    assert_no_collisions(swarm.close())


@pytest.mark.timeout(180)
@pytest.mark.swarm(2, layout="line", spacing_m=3.0, invariants=[{"kind": "fence", "radius_m": 0.5, "name": "tight"}])
def test_a_swarm_under_an_invariant_it_breaks(swarm: BlockingSession) -> None:
    swarm.takeoff(3.0)
"""


@pytest.mark.timeout(300)
def test_a_user_test_passes_when_its_drones_keep_apart_and_fails_when_they_collide(
    pytester: pytest.Pytester, instances: Leases
) -> None:
    # GIVEN the example user test file, and beside it the same kind of test commanding a collision
    pytester.makepyfile(test_user=EXAMPLE.read_text() + COLLIDING)
    # WHEN pytest runs it (the plugin comes from the installed entry point)
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider", "--swarm-first-instance", str(instances(2)), "-q",
                                           timeout=280)  # fmt: skip
    # THEN the well-behaved test passes and the colliding one fails on the assertion, naming the collision
    result.assert_outcomes(passed=2, failed=1, errors=1)
    result.stdout.fnmatch_lines(["*AssertionError: 1 collision event(s); the first at t=*Collision with drone*"])
    # AND the one whose marker requires an invariant its drones break (they stand 1.5 m from the origin, outside a
    # 0.5 m fence) fails at its teardown, naming the invariant and the report
    result.stdout.fnmatch_lines(["*invariant tight violated at t=*from the origin (at most 0.5 m) (report: *swarm-0)*"])
