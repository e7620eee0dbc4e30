"""Swarm frame <-> geodetic <-> each drone's local frame: round trips to well under a millimetre, same definition
as the drones (sitl/dynamics/geodesy.py), and the drone origin recovered from HOME_POSITION."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gcs.flight.arrays import mat_mul
from gcs.flight.frames import DroneFrame, SwarmFrame, _rotate, _rows, origin_from_home
from sitl.dynamics.geodesy import LocalFrame
from sitl.dynamics.plant import DEFAULT_HOME, GeoPoint

pytestmark = pytest.mark.timeout(30)

SWARM = SwarmFrame(DEFAULT_HOME)
MM = 1e-3

positions = st.tuples(
    st.floats(-2000, 2000, allow_nan=False),
    st.floats(-2000, 2000, allow_nan=False),
    st.floats(-500, 50, allow_nan=False),
)
spawn_offsets = st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(-2, 2))


def drone_at(spawn_ned_m: tuple[float, float, float]) -> DroneFrame:
    """A drone whose local origin (where it booted) is at ``spawn_ned_m`` in the swarm frame."""
    return SWARM.drone_frame(SWARM.geo_from_ned(spawn_ned_m))


@settings(max_examples=300, deadline=None)
@given(positions)
def test_swarm_ned_geodetic_round_trip_is_exact_to_a_millimetre(pos: tuple[float, float, float]) -> None:
    # GIVEN a swarm-frame position up to 2 km from the origin / WHEN converted to geodetic and back
    back = SWARM.ned_from_geo(SWARM.geo_from_ned(pos))
    # THEN it is where it started
    np.testing.assert_allclose(back, pos, atol=MM)


@settings(max_examples=300, deadline=None)
@given(positions, spawn_offsets)
def test_drone_local_round_trip_is_exact_to_a_millimetre(
    pos: tuple[float, float, float], spawn: tuple[float, float, float]
) -> None:
    # GIVEN a drone that booted somewhere around the swarm origin
    drone = drone_at(spawn)
    # WHEN a swarm-frame setpoint is converted to its local frame and the local position back
    local = drone.to_local(pos)
    back = drone.to_swarm(local)
    # THEN nothing is lost
    np.testing.assert_allclose(back, pos, atol=MM)


def test_local_coordinates_are_the_swarm_ones_shifted_by_the_spawn_offset() -> None:
    # GIVEN a drone that booted 3 m north, 7 m west and 0.2 m below the swarm origin
    drone = drone_at((3.0, -7.0, 0.2))
    # WHEN a formation slot at 3 m altitude is converted
    local = drone.to_local((10.0, 20.0, -3.0))
    # THEN the drone sees it shifted by its spawn offset (Earth curvature is below 0.1 mm at this scale)
    np.testing.assert_allclose(local, (7.0, 27.0, -3.2), atol=1e-4)
    # AND its own origin is its (0, 0, 0), the swarm origin is minus the offset
    np.testing.assert_allclose(drone.to_local((3.0, -7.0, 0.2)), (0.0, 0.0, 0.0), atol=1e-9)
    np.testing.assert_allclose(drone.to_local((0.0, 0.0, 0.0)), (-3.0, 7.0, -0.2), atol=1e-4)


def test_conversion_is_the_drones_own_definition() -> None:
    # GIVEN a drone 500 m from the swarm origin (curvature matters: tens of centimetres)
    origin = SWARM.geo_from_ned((400.0, -300.0, 0.0))
    drone = SWARM.drone_frame(origin)
    point = (-250.0, 800.0, -30.0)
    # WHEN the ground station converts a point / THEN it is exactly what the drone's geodesy gives for that point
    expected = LocalFrame(origin).ned_from_geo(LocalFrame(DEFAULT_HOME).geo_from_ned(point))
    np.testing.assert_allclose(drone.to_local(point), expected, atol=1e-9)


@settings(max_examples=100, deadline=None)
@given(spawn_offsets, st.tuples(st.floats(-5, 5), st.floats(-5, 5), st.floats(-0.5, 0.5)))
def test_origin_is_recovered_from_home_position(
    spawn: tuple[float, float, float], home_local: tuple[float, float, float]
) -> None:
    # GIVEN a drone whose local origin is known to the simulation, and home set somewhere in its local frame
    origin = SWARM.geo_from_ned(spawn)
    home = LocalFrame(origin).geo_from_ned(home_local)
    # WHEN the ground station recovers the origin from HOME_POSITION (home geodetic + home local)
    recovered = origin_from_home(home, home_local)
    # THEN it is the same point to a micrometre
    np.testing.assert_allclose(SWARM.ned_from_geo(recovered), SWARM.ned_from_geo(origin), atol=1e-6)


def test_home_position_quantisation_costs_less_than_a_centimetre() -> None:
    # GIVEN HOME_POSITION as sent on the wire: degE7 latitude/longitude, millimetre altitude, float32 x/y/z
    origin = SWARM.geo_from_ned((4.0, -6.0, 0.0))
    home_local = (0.37, -0.21, -0.05)
    home = LocalFrame(origin).geo_from_ned(home_local)
    wire = GeoPoint(
        lat_deg=round(home.lat_deg * 1e7) / 1e7,
        lon_deg=round(home.lon_deg * 1e7) / 1e7,
        alt_amsl_m=round(home.alt_amsl_m * 1e3) / 1e3,
    )
    wire_local = tuple(float(np.float32(v)) for v in home_local)
    # WHEN the origin is recovered from it
    recovered = origin_from_home(wire, wire_local)
    # THEN the origin is off by under 1 cm: a constant offset that commands and feedback share
    error = np.subtract(SWARM.ned_from_geo(recovered), SWARM.ned_from_geo(origin))
    assert float(np.linalg.norm(error)) < 0.01


def test_local_float32_setpoints_are_finer_than_global_int_ones() -> None:
    # GIVEN a formation slot 30 m from a drone's origin
    drone = drone_at((2.0, 2.0, 0.0))
    slot = (31.234567, -12.345678, -3.0)
    local = drone.to_local(slot)
    # WHEN carried as float32 metres (LOCAL_NED) or as degE7 integers (GLOBAL_INT)
    local_error = np.abs(np.array(local) - np.array([np.float32(v) for v in local])).max()
    geo = SWARM.geo_from_ned(slot)
    quantised = GeoPoint(
        lat_deg=round(geo.lat_deg * 1e7) / 1e7, lon_deg=round(geo.lon_deg * 1e7) / 1e7, alt_amsl_m=geo.alt_amsl_m
    )
    global_error = np.abs(np.subtract(SWARM.ned_from_geo(quantised), slot)).max()
    # THEN LOCAL_NED is sub-millimetre while GLOBAL_INT is off by millimetres (steps of ~1.1 cm)
    assert local_error < 1e-5
    assert global_error > 10 * local_error
    assert global_error < 0.006


@settings(max_examples=100, deadline=None)
@given(spawn_offsets, st.tuples(st.floats(-10, 10), st.floats(-10, 10), st.floats(-10, 10)))
def test_vectors_rotate_between_tangent_planes_without_changing_length(
    spawn: tuple[float, float, float], vec: tuple[float, float, float]
) -> None:
    # GIVEN a velocity feed-forward in swarm axes
    drone = drone_at(spawn)
    # WHEN rotated into the drone's axes and back
    local = drone.vector_to_local(vec)
    # THEN its length is unchanged, it is nearly the same vector (planes differ by d / R) and it round-trips
    assert math.isclose(float(np.linalg.norm(local)), float(np.linalg.norm(vec)), rel_tol=1e-12, abs_tol=1e-12)
    # The axes of two tangent planes d apart differ by a tilt of d / R plus the meridian convergence
    # d_east * tan(lat) / R about the vertical: bound the change by that angle (with margin) times the length.
    distance = math.hypot(spawn[0], spawn[1])
    angle = distance / 6.371e6 * (1.0 + abs(math.tan(math.radians(DEFAULT_HOME.lat_deg))))
    np.testing.assert_allclose(local, vec, atol=1.5 * angle * float(np.linalg.norm(vec)) + 1e-12)
    np.testing.assert_allclose(drone.vector_to_swarm(local), vec, atol=1e-12)


def test_a_vector_is_rotated_to_the_bit_as_the_array_product_does_signed_zeros_included() -> None:
    # The rotation is written in floats for speed; a lockstep flight's setpoints must keep their bits.
    rng = np.random.default_rng(7)
    for k in range(20_000):
        rows = rng.normal(size=(3, 3)) * 10.0 ** rng.integers(-3, 4)
        vec = rng.normal(size=3) * 10.0 ** rng.integers(-3, 4)
        if k % 5 == 0:
            vec[rng.integers(0, 3)] = -0.0
        if k % 11 == 0:
            vec[:] = -0.0
        want = mat_mul(rows, vec)
        got = _rotate(_rows(rows), (float(vec[0]), float(vec[1]), float(vec[2])))
        assert [v.hex() for v in got] == [float(v).hex() for v in want], (rows, vec)
    drone = drone_at((30.0, -40.0, 0.0))
    vec = (1.5, -0.25, 0.125)
    assert drone.vector_to_local(vec) == drone.vector_to_local(np.array(vec)) == drone.vector_to_local(list(vec))


def test_non_finite_positions_are_refused() -> None:
    drone = drone_at((1.0, 1.0, 0.0))
    with pytest.raises(ValueError):
        drone.to_local((math.nan, 0.0, 0.0))
    with pytest.raises(ValueError):
        drone.to_swarm((0.0, 0.0))
    with pytest.raises(ValueError):
        drone.vector_to_local((0.0, math.inf, 0.0))
    with pytest.raises(ValueError):
        drone.vector_to_local((1e308, 1e308, 1e308 * 10))
    with pytest.raises(ValueError):
        SWARM.geo_from_ned((0.0, math.inf, 0.0))
