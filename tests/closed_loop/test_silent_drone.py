"""A silent drone in the path of a rotating circle of 8 is seen and avoided with default parameters.

Nine drones through JSBSim in one process on one shared world (tests/closed_loop/circle_swarm.py): the circle's
drones hear one another through the relay; the silent one is never relayed, so only the cameras can find it. With
the defaults (four-camera rig, CAM_RIG = 1) nobody touches it; with the former default of one forward camera the
same flight collides, so the scenario really tests what the cameras see.
"""

from __future__ import annotations

import pytest

from tests.closed_loop.circle_swarm import CircleScenario, fly_circle_past_a_silent_drone

pytestmark = pytest.mark.timeout(300)


def test_a_rotating_circle_of_8_avoids_a_silent_drone_hovering_in_its_path_with_default_parameters() -> None:
    # GIVEN a circle of 8 (radius 4 m, 0.3 rad/s) and a silent drone moving onto its path and holding there
    # WHEN the circle turns a full turn and more past it, every parameter at its default
    out = fly_circle_past_a_silent_drone(CircleScenario())
    # THEN nobody collided, each drone of the circle kept clear of it, and it was avoided (not missed by luck)
    assert out.collisions == 0, out.events
    assert out.min_silent_distance_m > 1.0, out.min_silent_distance_m
    assert out.avoidance_episodes >= 8, out.avoidance_episodes
    assert out.silent_hold_error_m < 1.0  # the silent drone did get onto the path and stayed there


def test_with_one_forward_camera_and_the_heading_held_the_circle_flies_into_the_silent_drone() -> None:
    out = fly_circle_past_a_silent_drone(CircleScenario(cam_rig=0, yaw_follow=0, stop_at_collision=True))
    assert out.collisions >= 1 and any("Collision with drone 9" in e for e in out.events), out.events
