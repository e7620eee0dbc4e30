"""The reference flight (tests/closed_loop/reference_flight.py) flies bit for bit as it did when recorded.

It exercises takeoff, goto, hold, offboard (position and attitude), offboard loss, a mission flown from the air and
one started on the ground, RTL, land and a critical battery. A change meant to leave behaviour alone (a refactor)
must leave these figures alone; a deliberate behaviour change re-records them and says why in its commit.
"""

from __future__ import annotations

import pytest

from tests.closed_loop.reference_flight import fly

pytestmark = pytest.mark.timeout(60)

RECORDED_STEPS = 15327
RECORDED_MOTOR_SHA256 = "0f22cc1b9d1ea13cd8a602613de16b2155fa96bba719ef23f8698ef269ebdc5f"
RECORDED_FINAL_TRUTH = (
    -0.14835660160304848,
    -0.03243034605309283,
    -0.1163224088439847,
    -2.7696176077191116e-09,
    -6.357579479407654e-10,
    -2.6709683981398088e-09,
    0.9998178089351963,
    -2.0357019930399763e-11,
    2.2757222766024246e-08,
    0.019087926446388792,
)


def test_the_reference_flight_is_bit_identical_to_the_recorded_one() -> None:
    figures = fly()
    assert figures.steps == RECORDED_STEPS
    assert figures.final_truth == RECORDED_FINAL_TRUTH
    assert figures.motor_sha256 == RECORDED_MOTOR_SHA256
