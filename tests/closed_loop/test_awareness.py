"""Perception renders frames only when something uses them."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl.drone.awareness import Awareness
from sitl.drone.closed_loop import ClosedLoop, SimConfig
from sitl.dynamics.airframe import load_airframe
from sitl.dynamics.geodesy import LocalFrame
from sitl.protocol.images import EncodedImage
from sitl.world.shared import SharedWorld
from sitl.world.view import WorldParticipant

JPEG = mavlink.MAVLINK_DATA_STREAM_IMG_JPEG

pytestmark = pytest.mark.timeout(60)


@pytest.mark.parametrize(("avoid", "armed", "frames_expected"), [(1, True, True), (1, False, False), (0, True, False)])
def test_the_cameras_render_only_while_avoidance_uses_them(avoid: int, armed: bool, frames_expected: bool) -> None:
    """Collision prevention is the frames' only user, and only in flight: a disarmed drone (a swarm's boot, with
    every neighbour in view on the ground) and a drone with avoidance off render nothing."""
    world = SharedWorld.create()
    try:
        sim = ClosedLoop(SimConfig(airframe=load_airframe(), seed=3))
        sim.params.set("AVOID_ENABLE", avoid)
        part = WorldParticipant(world, 0, 0.35, rest_alt_amsl_m=sim.truth.geo.alt_amsl_m)
        eyes = Awareness(sim, 0, LocalFrame(sim.truth.geo), world=world, neighbours=None)

        def run(seconds: float) -> None:
            for _ in range(round(seconds / sim.dt_s)):
                sim.step()
                part.after_step(sim.truth, sim.vehicle.crashed)
                eyes.update(sim.time_s)

        run(5.0)  # past the estimator's attitude convergence and the pre-arm checks, disarmed
        assert eyes.frames == 0
        if armed:
            assert sim.vehicle.arm().ok
        run(1.0)
        assert (eyes.frames > 0) is frames_expected, eyes.frames
    finally:
        world.close()


def fly_looking(frames_dir: Path, look: bool) -> list[EncodedImage]:
    """Two seconds armed beside a second body 3 m north, the camera frames saved; with ``look``, an image asked
    for every 0.25 s (as a ground station showing this drone's camera)."""
    world = SharedWorld.create()
    try:
        sim = ClosedLoop(SimConfig(airframe=load_airframe(), seed=3))
        part = WorldParticipant(world, 0, 0.35, rest_alt_amsl_m=sim.truth.geo.alt_amsl_m)
        eyes = Awareness(sim, 0, LocalFrame(sim.truth.geo), world=world, neighbours=None, frames_dir=frames_dir)
        home = sim.truth.geo
        world.write(1, 0.0, (home.lat_deg + 3.0 / 111_195.0, home.lon_deg, home.alt_amsl_m), (0.0, 0.0, 0.0), 0.35,
                    False, rest_alt_amsl_m=home.alt_amsl_m)  # fmt: skip
        seen: list[EncodedImage] = []
        for k in range(round(7.0 / sim.dt_s)):
            if k == round(5.0 / sim.dt_s):
                assert sim.vehicle.arm().ok
            sim.step()
            part.after_step(sim.truth, sim.vehicle.crashed)
            eyes.update(sim.time_s)
            if look and k % round(0.25 / sim.dt_s) == 0 and (image := eyes.image(JPEG, 80)) is not None:
                seen.append(image)
        return seen
    finally:
        world.close()


def test_an_image_asked_for_over_mavlink_changes_nothing_the_drone_sees(tmp_path: Path) -> None:
    """Images for a viewer are rendered with noise of their own: the frames avoidance works on are the same, byte for
    byte, whether or not somebody is looking."""
    seen = fly_looking(tmp_path / "looked", look=True)
    fly_looking(tmp_path / "alone", look=False)
    looked, alone = sorted((tmp_path / "looked").iterdir()), sorted((tmp_path / "alone").iterdir())
    assert [p.name for p in looked] == [p.name for p in alone] and len(looked) > 10
    assert all(a.read_bytes() == b.read_bytes() for a, b in zip(looked, alone, strict=True))
    # and what was looked at is the four cameras side by side, as JPEG, with the other body in view
    assert seen and all(image.data.startswith(b"\xff\xd8") for image in seen)
    assert (seen[-1].width_px, seen[-1].height_px) == (4 * 160, 120)
    picture = cv2.imdecode(np.frombuffer(seen[-1].data, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert picture.max() > 150  # the body (level 200) against the background (30)
