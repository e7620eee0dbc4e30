"""The reference flight (tests/closed_loop/reference_flight.py) flies bit for bit as it did when recorded, on any
x86-64 CPU.

It exercises takeoff, goto, hold, offboard (position and attitude), offboard loss, a mission flown from the air and
one started on the ground, RTL, land and a critical battery. A change meant to leave behaviour alone (a refactor)
must leave these figures alone; a deliberate behaviour change re-records them and says why in its commit.

The flight is flown twice: in this process, with whatever BLAS kernels numpy's OpenBLAS chose for this CPU and the
drone's compiled kernels built for this CPU, and in a child with OpenBLAS forced to its SSE-only kernels
(OPENBLAS_CORETYPE=Nehalem, which every x86-64 CPU runs) and the compiled kernels built for a generic x86-64
(NUMBA_CPU_NAME=generic, without SVML). Both must give the recorded figures, which holds only while flight code
keeps off BLAS and LAPACK (sitl/mathutil.py) and kernels off fused multiply-adds and reassociation (no fastmath,
sitl/kernels): before the first, a CPU with AVX-512 flew the recorded flight a few 1e-9 m apart from one without.

Beside it, two swarm flights are held to recorded digests of every drone's true state at every step: the 9-drone
circle and the dense circle (cameras, detector, fusion, ORCA and the safety layer at work in every drone), so moving a
drone's numeric work into compiled kernels is seen to change no bit.
"""

from __future__ import annotations

import ast
import os
import platform
import subprocess
import sys
from pathlib import Path

import pytest

from tests.closed_loop.circle_swarm import CIRCLE, DENSE, CircleScenario, fly_with_digest
from tests.closed_loop.reference_flight import fly

pytestmark = pytest.mark.timeout(60)

RECORDED_STEPS = 15357
RECORDED_MOTOR_SHA256 = "5bf5701a20e489667679ffaffb7a785127bd8d98fbfa9ed7f50f71d8f18dd050"
RECORDED_FINAL_TRUTH = (
    -0.11254673800072858,
    -0.10693414057886415,
    -0.11632240804266303,
    1.9694152527265405e-09,
    1.2952232023839264e-09,
    -6.9172960623687664e-09,
    0.999825128804939,
    4.0834883061008215e-10,
    2.3054541867451927e-08,
    0.018700583150980308,
)
ROOT = Path(__file__).resolve().parents[2]
# Every drone's true state at every step of the two swarm flights (tests/closed_loop/circle_swarm.py): the 9-drone
# circle with a silent drone, and the dense circle of 24 and the silent one, where every drone has 20-odd others in
# camera range and relayed, so perception, association, ORCA and the safety layer all shape the flight.
RECORDED_SWARM_DIGESTS = {
    "circle": "d57c116417bf1cde30885b42c8c8c9f70b2e621c1d4cedb0d79e16797fcff84a",
    "dense": "9133998df30cd76a1b0578d4a15c2b60cc966391c6863a3b492305c98cc4cb36",
}


def test_the_reference_flight_is_bit_identical_to_the_recorded_one() -> None:
    figures = fly()
    assert figures.steps == RECORDED_STEPS
    assert figures.final_truth == RECORDED_FINAL_TRUTH
    assert figures.motor_sha256 == RECORDED_MOTOR_SHA256


@pytest.mark.timeout(240)
@pytest.mark.suite  # a cold compile for a generic CPU into a cache of its own: not for the quick tier
@pytest.mark.skipif(platform.machine() != "x86_64", reason="OpenBLAS kernel names are x86-64's")
def test_the_reference_flight_is_the_same_with_other_blas_kernels_and_kernels_compiled_for_any_cpu(
    tmp_path: Path,
) -> None:
    """OpenBLAS forced to its SSE-only kernels, and the drone's compiled kernels built for a generic x86-64 CPU
    (no AVX, no FMA) without Intel's SVML, into a cache of their own: the recorded bits all the same."""
    script = (
        "from tests.closed_loop.reference_flight import fly; f = fly(); print((f.steps, f.final_truth, f.motor_sha256))"
    )
    env = {**os.environ, "OPENBLAS_CORETYPE": "Nehalem", "NUMBA_CPU_NAME": "generic", "NUMBA_DISABLE_INTEL_SVML": "1",
           "NUMBA_CACHE_DIR": str(tmp_path / "generic-cache"), "SWARM_KERNELS": ""}  # fmt: skip
    out = subprocess.run([sys.executable, "-c", script], cwd=ROOT, env=env, capture_output=True, text=True, timeout=220)
    assert out.returncode == 0, out.stderr[-2000:]
    steps, final_truth, motor_sha256 = ast.literal_eval(out.stdout.strip().splitlines()[-1])
    assert (steps, final_truth, motor_sha256) == (RECORDED_STEPS, RECORDED_FINAL_TRUTH, RECORDED_MOTOR_SHA256)


@pytest.mark.parametrize(("name", "scenario"), [("circle", CIRCLE), ("dense", DENSE)])
def test_the_swarm_flights_are_bit_identical_to_the_recorded_ones(name: str, scenario: CircleScenario) -> None:
    digest, outcome, _ = fly_with_digest(scenario)
    assert outcome.collisions == 0
    assert digest == RECORDED_SWARM_DIGESTS[name]
