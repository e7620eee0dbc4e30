"""The drone's one pass per camera (sitl/kernels/frame.py through ``sense_rig``): exposed and searched only in the
boxes drawn, it finds what the whole frame holds, to the bit, and leaves the random stream where the whole frames
leave it."""

from __future__ import annotations

import numpy as np
import pytest

from sitl.mathutil import quat_from_euler
from sitl.perception import CameraConfig, CameraRig, Sphere, VerticalCylinder, detect_rig, render_rig, to_ned_all
from sitl.perception.camera import sphere_rows
from sitl.perception.detector import rig_ned, sense_rig

pytestmark = pytest.mark.timeout(60)

R_M = 0.35


def crowd(rng: np.random.Generator, frame: int) -> list[Sphere | VerticalCylinder]:
    """Bodies near (merged and cut blobs) and far, in view and out of it, now and then a pole, now and then none."""
    bodies: list[Sphere | VerticalCylinder] = []
    near = frame % 3 == 0
    for _ in range(int(rng.integers(0, 25))):
        direction = rng.standard_normal(3)
        direction[2] *= 0.3
        offset = direction / np.linalg.norm(direction) * rng.uniform(0.7, 5.0 if near else 17.0)
        bodies.append(Sphere(offset_ned_m=tuple(offset.tolist()), radius_m=R_M))
    if frame % 11 == 5:
        bodies.append(VerticalCylinder(offset_ned_m=(3.0, float(rng.uniform(-4, 4)), 0.0), radius_m=0.3, height_m=8.0))
    return bodies


@pytest.mark.parametrize("seed", range(4))
def test_the_box_pass_finds_what_the_whole_frames_hold_to_the_bit(seed: int) -> None:
    # GIVEN an omnidirectional rig whose noise cannot reach the threshold, and crowds around it
    rng_scene = np.random.default_rng(seed)
    rig = CameraRig.omni(CameraConfig(noise_seed=seed))
    assert all(camera.noise_cannot_detect for camera in rig.cameras)
    whole_rng, box_rng, saved_rng = (np.random.default_rng(50 + seed) for _ in range(3))
    merged = truncated = found = 0
    for frame in range(40):
        bodies = crowd(rng_scene, frame)
        q_true = quat_from_euler(*rng_scene.uniform(-0.4, 0.4, 2).tolist(), float(rng_scene.uniform(-3.2, 3.2)))
        q_est = quat_from_euler(*rng_scene.uniform(-0.4, 0.4, 2).tolist(), float(rng_scene.uniform(-3.2, 3.2)))
        rows, cylinders = sphere_rows(bodies)
        # WHEN the frames are formed whole and searched whole (the detector on images), formed and searched only
        # in the boxes drawn (the drone's pass), and formed whole inside the pass (frames being saved)
        images = [image.copy() for image in render_rig(rig, q_true, bodies, whole_rng)]
        whole = detect_rig(images, rig, R_M)
        boxed = rig_ned(sense_rig(rig, q_true, rows, cylinders, box_rng, R_M), q_est)
        saved = rig_ned(sense_rig(rig, q_true, rows, cylinders, saved_rng, R_M, whole_frames=True), q_est)
        # THEN every figure is the same, and so is the noise every later frame gets
        assert boxed == to_ned_all(whole, q_est)
        assert saved == boxed
        assert all(np.array_equal(camera.frame, image) for camera, image in zip(rig.cameras, images, strict=True))
        assert whole_rng.bit_generator.state == box_rng.bit_generator.state == saved_rng.bit_generator.state
        merged += sum(det.merged for det in whole)
        truncated += sum(det.truncated for det in whole)
        found += len(whole)
    assert merged > 0 and truncated > 0 and found > 100


def test_a_rig_that_sees_nothing_forms_no_frame_but_draws_its_noise() -> None:
    rig = CameraRig.omni(CameraConfig())
    rng, reference = np.random.default_rng(1), np.random.default_rng(1)
    far = np.array(((40.0, 0.0, 0.0, R_M),))
    assert rig_ned(sense_rig(rig, (1.0, 0.0, 0.0, 0.0), far, [], rng, R_M), (1.0, 0.0, 0.0, 0.0)) == []
    for camera in rig.cameras:
        reference.integers(0, camera.config.height_px + 1)
        reference.integers(0, camera.config.width_px + 1)
    assert rng.bit_generator.state == reference.bit_generator.state
