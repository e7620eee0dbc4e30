"""Control allocation: the mixer derived from the airframe, exact when feasible, roll/pitch first when not."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from sitl.control.allocation import ControlAllocator, effectiveness_matrix
from sitl.dynamics.airframe import Airframe, Rotor, load_airframe

QUAD = load_airframe("quad_x_f450")
T_MAX = QUAD.max_thrust_per_rotor_n
HOVER_N = QUAD.mass_kg * 9.80665


def _hexa(base: Airframe) -> Airframe:
    """A hexarotor built from the quad's coefficients: 6 rotors on a 0.225 m circle, alternating spin."""
    rotors = tuple(
        Rotor(
            pos_frd_m=(0.225 * math.cos(math.radians(30 + 60 * i)), 0.225 * math.sin(math.radians(30 + 60 * i)), -0.03),
            spin_dir=1 if i % 2 == 0 else -1,
        )
        for i in range(6)
    )
    return dataclasses.replace(base, name="hexa_test", rotors=rotors)


ALLOC = ControlAllocator(QUAD)
HEXA_ALLOC = ControlAllocator(_hexa(QUAD))

thrust_fraction = st.floats(min_value=0.0, max_value=1.0, allow_nan=False)
any_torque = st.floats(min_value=-20.0, max_value=20.0, allow_nan=False)
any_thrust = st.floats(min_value=-50.0, max_value=100.0, allow_nan=False)


def test_effectiveness_matrix_comes_from_rotor_geometry() -> None:
    # GIVEN the F450 airframe (rotor 1 front-right CCW, 2 rear-left CCW, 3 front-left CW, 4 rear-right CW)
    b = effectiveness_matrix(QUAD)
    # THEN each column is (-y, x, spin * k_q / k_t, 1) of its rotor
    yaw_arm = QUAD.torque_coeff_nm_per_radps2 / QUAD.thrust_coeff_n_per_radps2
    for i, rotor in enumerate(QUAD.rotors):
        x, y, _ = rotor.pos_frd_m
        assert b[:, i] == pytest.approx((-y, x, rotor.spin_dir * yaw_arm, 1.0))
    # AND the front-right rotor rolls left (negative), pitches nose up and yaws right (CCW drag torque)
    assert b[0, 0] < 0.0 and b[1, 0] > 0.0 and b[2, 0] > 0.0


def test_hover_thrust_gives_equal_sqrt_commands() -> None:
    result = ALLOC.allocate((0.0, 0.0, 0.0), HOVER_N)
    expected = math.sqrt(QUAD.hover_thrust_fraction)
    assert result.motor_cmds == pytest.approx((expected,) * 4)
    assert result.rotor_thrusts_n == pytest.approx((HOVER_N / 4,) * 4)
    assert result.saturated_pos == (False, False, False) and result.saturated_neg == (False, False, False)
    assert result.thrust_saturation == 0


@settings(max_examples=300, deadline=None)
@given(st.lists(thrust_fraction, min_size=4, max_size=4))
def test_feasible_commands_are_reproduced_exactly(fractions: list[float]) -> None:
    # GIVEN any torque/thrust command that some rotor thrusts inside [0, T_max] produce
    thrusts = np.array(fractions) * T_MAX
    roll, pitch, yaw, collective = effectiveness_matrix(QUAD) @ thrusts
    # WHEN it is allocated
    result = ALLOC.allocate((roll, pitch, yaw), collective)
    # THEN the rotors produce exactly that command, and nothing is reported saturated
    achieved = ALLOC.achieved(result.rotor_thrusts_n)
    assert achieved == pytest.approx((roll, pitch, yaw, collective), abs=1e-9)
    assert result.motor_cmds == pytest.approx(tuple(np.sqrt(thrusts / T_MAX)), abs=1e-6)
    assert not any(result.saturated_pos) and not any(result.saturated_neg)


@settings(max_examples=200, deadline=None)
@given(st.lists(thrust_fraction, min_size=6, max_size=6))
def test_hexarotor_uses_the_pseudo_inverse(fractions: list[float]) -> None:
    # GIVEN a command whose minimum-norm rotor solution lies inside [0, T_max] on a hexarotor
    b = HEXA_ALLOC.effectiveness
    command = b @ (np.array(fractions) * T_MAX)
    min_norm = np.linalg.pinv(b) @ command
    assume(min_norm.min() >= 0.0 and min_norm.max() <= T_MAX)
    # WHEN it is allocated THEN that solution is used and the command reproduced
    result = HEXA_ALLOC.allocate((command[0], command[1], command[2]), command[3])
    assert result.rotor_thrusts_n == pytest.approx(tuple(min_norm), abs=1e-9)
    assert HEXA_ALLOC.achieved(result.rotor_thrusts_n) == pytest.approx(tuple(command), abs=1e-9)


@settings(max_examples=500, deadline=None)
@given(any_torque, any_torque, any_torque, any_thrust)
def test_motor_commands_always_in_unit_range(roll: float, pitch: float, yaw: float, thrust: float) -> None:
    for alloc in (ALLOC, HEXA_ALLOC):
        result = alloc.allocate((roll, pitch, yaw), thrust)
        assert all(0.0 <= u <= 1.0 for u in result.motor_cmds)
        assert all(0.0 <= t <= T_MAX for t in result.rotor_thrusts_n)


@settings(max_examples=300, deadline=None)
@given(any_torque, any_torque, any_torque, any_thrust)
def test_roll_pitch_direction_is_kept_and_never_exceeded(roll: float, pitch: float, yaw: float, thrust: float) -> None:
    # Whatever happens to yaw and collective, the delivered roll/pitch is the demand scaled by one factor in (0, 1].
    result = ALLOC.allocate((roll, pitch, yaw), thrust)
    got_roll, got_pitch, _, _ = ALLOC.achieved(result.rotor_thrusts_n)
    demand = math.hypot(roll, pitch)
    assume(demand > 1e-6)
    scale = (got_roll * roll + got_pitch * pitch) / demand**2
    assert 0.0 < scale <= 1.0 + 1e-9
    assert got_roll == pytest.approx(scale * roll, abs=1e-9)
    assert got_pitch == pytest.approx(scale * pitch, abs=1e-9)


def test_large_roll_and_yaw_at_high_thrust_keep_roll_exact() -> None:
    # GIVEN a hard roll demand, a large yaw demand and a collective near the maximum
    roll_demand, yaw_demand, thrust_demand = 1.5, 0.3, 0.9 * 4 * T_MAX
    # WHEN allocated
    result = ALLOC.allocate((roll_demand, 0.0, yaw_demand), thrust_demand)
    roll, pitch, yaw, collective = ALLOC.achieved(result.rotor_thrusts_n)
    # THEN roll is delivered exactly and pitch stays zero
    assert roll == pytest.approx(roll_demand, abs=1e-9)
    assert pitch == pytest.approx(0.0, abs=1e-9)
    # AND yaw is reduced (collective comes before yaw, so here nothing is left) and reported saturated
    assert -1e-9 <= yaw < yaw_demand
    assert result.saturated_pos == (False, False, True)
    # AND the collective was lowered to make room for roll, and reported
    assert collective < thrust_demand
    assert result.thrust_saturation == 1


def test_yaw_takes_what_is_left_beside_roll_at_high_thrust() -> None:
    # GIVEN a roll demand that fits at a high collective, and a yaw demand that does not fit beside them
    result = ALLOC.allocate((1.0, 0.0, 0.1), 0.8 * 4 * T_MAX)
    roll, _, yaw, collective = ALLOC.achieved(result.rotor_thrusts_n)
    # THEN roll and collective are exact and yaw gets part of its demand
    assert roll == pytest.approx(1.0, abs=1e-9)
    assert collective == pytest.approx(0.8 * 4 * T_MAX, abs=1e-9)
    assert 0.0 < yaw < 0.1
    assert result.saturated_pos == (False, False, True) and result.thrust_saturation == 0
    # AND some rotor is at full thrust (yaw used all the room there was)
    assert max(result.rotor_thrusts_n) == pytest.approx(T_MAX)


@settings(max_examples=300, deadline=None)
@given(any_torque, any_torque, any_torque, any_thrust, st.integers(min_value=0, max_value=3))
def test_output_moves_continuously_with_the_demand(
    roll: float, pitch: float, yaw: float, thrust: float, axis: int
) -> None:
    # A tiny change of any demand axis never makes the rotor thrusts jump (limits are reached smoothly).
    demand = [roll, pitch, yaw, thrust]
    nudged = list(demand)
    nudged[axis] += 1e-6
    before = ALLOC.allocate((demand[0], demand[1], demand[2]), demand[3]).rotor_thrusts_n
    after = ALLOC.allocate((nudged[0], nudged[1], nudged[2]), nudged[3]).rotor_thrusts_n
    assert max(abs(a - b) for a, b in zip(before, after, strict=True)) < 1e-3


def test_roll_pitch_beyond_rotor_range_is_scaled_down_together() -> None:
    # GIVEN a roll/pitch demand no thrust setting can deliver
    result = ALLOC.allocate((-5.0, 2.5, 0.0), HOVER_N)
    roll, pitch, _, _ = ALLOC.achieved(result.rotor_thrusts_n)
    # THEN both are scaled by the same factor (the correction axis is kept)
    assert roll / -5.0 == pytest.approx(pitch / 2.5)
    assert 0.0 < roll / -5.0 < 1.0
    # AND the axes report saturation in the direction of the demand
    assert result.saturated_neg == (True, False, False)
    assert result.saturated_pos == (False, True, False)
    # AND some rotor sits at each end of its range (the authority is fully used)
    assert min(result.rotor_thrusts_n) == pytest.approx(0.0, abs=1e-9)
    assert max(result.rotor_thrusts_n) == pytest.approx(T_MAX, abs=1e-9)


def test_zero_and_negative_thrust_stop_the_rotors() -> None:
    for thrust in (0.0, -10.0):
        result = ALLOC.allocate((0.0, 0.0, 0.0), thrust)
        assert result.motor_cmds == (0.0, 0.0, 0.0, 0.0)
        assert result.thrust_saturation == -1 if thrust < 0.0 else result.thrust_saturation == 0


def test_torque_at_zero_thrust_raises_the_collective_just_enough() -> None:
    # GIVEN a pitch demand with no collective
    result = ALLOC.allocate((0.0, 0.5, 0.0), 0.0)
    _, pitch, _, collective = ALLOC.achieved(result.rotor_thrusts_n)
    # THEN the pitch torque is delivered, with the least collective that allows it (rear rotors stopped)
    assert pitch == pytest.approx(0.5, abs=1e-9)
    assert collective > 0.0 and result.thrust_saturation == -1
    assert min(result.rotor_thrusts_n) == pytest.approx(0.0, abs=1e-12)


def test_yaw_is_dropped_before_the_collective() -> None:
    # GIVEN hover and a yaw demand beyond what hover thrust allows
    result = ALLOC.allocate((0.0, 0.0, -2.0), HOVER_N)
    _, _, yaw, collective = ALLOC.achieved(result.rotor_thrusts_n)
    # THEN the collective is untouched and yaw gets what fits, reported as negative saturation
    assert collective == pytest.approx(HOVER_N)
    assert -2.0 < yaw < 0.0
    assert result.saturated_neg == (False, False, True) and result.thrust_saturation == 0


def test_rotor_layout_without_collective_is_refused() -> None:
    # Three rotors in a line cannot produce a roll torque independently of thrust.
    line = tuple(Rotor(pos_frd_m=(x, 0.0, 0.0), spin_dir=1 if x > 0 else -1) for x in (-0.2, 0.0, 0.2))
    with pytest.raises(ValueError, match="cannot control"):
        ControlAllocator(dataclasses.replace(QUAD, rotors=line))
