"""The blob detector against scenes of known truth: bearing and range of single and several bodies, occlusion,
bodies out of view, noise, attitude, the omni rig, bodies cut by the image border."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sitl.mathutil import quat_from_euler, quat_to_dcm
from sitl.perception import (
    Camera,
    CameraConfig,
    CameraRig,
    Detection,
    Sphere,
    VerticalCylinder,
    detect,
    detect_rig,
    render,
    render_if_drawn,
    render_rig,
    render_rig_if_drawn,
    spheres,
    to_ned,
    to_ned_all,
)
from sitl.perception.camera import sphere_silhouette
from sitl.perception.detector import _solve_sphere

pytestmark = pytest.mark.timeout(60)

LEVEL_Q = np.array((1.0, 0.0, 0.0, 0.0))
R_M = 0.35  # the F450's collision radius (airframes/quad_x_f450.toml)


def frd(azimuth_deg: float, elevation_deg: float) -> npt.NDArray[np.float64]:
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array((math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), -math.sin(el)))


def sphere_at(vec_m: npt.NDArray[np.float64]) -> Sphere:
    return Sphere(offset_ned_m=(float(vec_m[0]), float(vec_m[1]), float(vec_m[2])), radius_m=R_M)


def bearing_error_deg(estimate_m: tuple[float, float, float], truth_m: npt.NDArray[np.float64]) -> float:
    e = np.asarray(estimate_m)
    cos = float(e @ truth_m) / float(np.linalg.norm(e) * np.linalg.norm(truth_m))
    return math.degrees(math.acos(min(1.0, cos)))


def range_error(det: Detection, truth_m: npt.NDArray[np.float64]) -> float:
    return det.range_m / float(np.linalg.norm(truth_m)) - 1.0


def fits_in_frame(camera: Camera, vec_cam: npt.NDArray[np.float64], distance_m: float) -> bool:
    """The whole silhouette (with a pixel to spare) is inside the image."""
    theta = math.acos(vec_cam[0])
    c_n, a_n, _ = sphere_silhouette(theta, R_M / distance_m)
    rho = math.hypot(vec_cam[1], vec_cam[2]) or 1.0
    f = camera.focal_px
    u = camera.cx_px + f * c_n * vec_cam[1] / rho
    v = camera.cy_px + f * c_n * vec_cam[2] / rho
    reach = f * a_n + 1.5
    return reach < u < camera.config.width_px - 1 - reach and reach < v < camera.config.height_px - 1 - reach


def test_one_body_anywhere_in_view_from_1_to_12_m_under_any_attitude() -> None:
    """Seeded sweep: bearing within 2 deg and range within 15 %, no misses, no extra detections, no flags."""
    camera = Camera(CameraConfig())
    rng = np.random.default_rng(2024)
    bearing_errors: list[float] = []
    range_errors: list[float] = []
    while len(range_errors) < 300:
        distance = rng.uniform(1.0, 12.0)
        vec_cam = frd(rng.uniform(-45.0, 45.0), rng.uniform(-37.0, 37.0))
        if not fits_in_frame(camera, vec_cam, distance):
            continue
        q = quat_from_euler(rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-math.pi, math.pi))
        truth_ned = quat_to_dcm(q) @ (vec_cam * distance)
        detections = detect(render(camera, q, [sphere_at(truth_ned)], rng), camera, R_M)
        assert len(detections) == 1, (distance, vec_cam)
        det = detections[0]
        assert not det.truncated and not det.merged
        bearing_errors.append(bearing_error_deg(to_ned(det, q), truth_ned))
        range_errors.append(range_error(det, truth_ned))
        assert bearing_errors[-1] < 1.0, (distance, vec_cam)
        assert abs(range_errors[-1]) < 0.15, (distance, vec_cam, range_errors[-1])
    # And on average far better than those limits, without bias.
    assert np.mean(bearing_errors) < 0.2
    assert np.mean(np.abs(range_errors)) < 0.03
    assert abs(np.mean(range_errors)) < 0.01


@pytest.mark.parametrize(("distance_m", "azimuth_deg", "elevation_deg"), [(1.2, 25.0, 0.0), (1.5, -15.0, 18.0)])
def test_a_close_off_axis_body_is_not_taken_to_lie_along_its_blob_centroid(
    distance_m: float, azimuth_deg: float, elevation_deg: float
) -> None:
    """Close up, the centre of a sphere's image lies outward of the direction of its centre (2.5 deg at 1.2 m and
    25 deg off axis): the detector must invert the true silhouette, not read the centroid as a direction."""
    camera = Camera(CameraConfig())
    truth = frd(azimuth_deg, elevation_deg) * distance_m
    assert fits_in_frame(camera, truth / distance_m, distance_m)
    detections = detect(render(camera, LEVEL_Q, [sphere_at(truth)], np.random.default_rng(14)), camera, R_M)
    assert len(detections) == 1 and not detections[0].truncated
    assert bearing_error_deg(to_ned(detections[0], LEVEL_Q), truth) < 0.3
    assert abs(range_error(detections[0], truth)) < 0.02


def test_bearing_and_range_hold_in_heavy_pixel_noise() -> None:
    camera = Camera(CameraConfig(pixel_noise_sigma=15.0))
    rng = np.random.default_rng(5)
    for distance, az, el in [(2.0, 10.0, -5.0), (5.0, -30.0, 20.0), (8.0, 35.0, 25.0), (11.0, -5.0, -30.0)]:
        truth = frd(az, el) * distance
        detections = detect(render(camera, LEVEL_Q, [sphere_at(truth)], rng), camera, R_M)
        assert len(detections) == 1
        assert bearing_error_deg(to_ned(detections[0], LEVEL_Q), truth) < 2.0
        assert abs(range_error(detections[0], truth)) < 0.15


def test_several_bodies_are_each_found() -> None:
    camera = Camera(CameraConfig())
    truths = [frd(-30.0, 10.0) * 3.0, frd(-5.0, -15.0) * 7.5, frd(12.0, 20.0) * 11.0, frd(32.0, -5.0) * 5.0]
    detections = detect(render(camera, LEVEL_Q, [sphere_at(t) for t in truths], np.random.default_rng(1)), camera, R_M)
    assert len(detections) == len(truths)
    for truth in truths:
        best = min(detections, key=lambda d: bearing_error_deg(to_ned(d, LEVEL_Q), truth))
        assert bearing_error_deg(to_ned(best, LEVEL_Q), truth) < 2.0
        assert abs(range_error(best, truth)) < 0.15
    assert [d.area_px for d in detections] == sorted((d.area_px for d in detections), reverse=True)


def test_a_body_hidden_behind_a_nearer_one_is_not_reported_and_does_not_spoil_it() -> None:
    camera = Camera(CameraConfig())
    near, far = frd(8.0, 4.0) * 3.0, frd(8.0, 4.0) * 7.0
    detections = detect(
        render(camera, LEVEL_Q, [sphere_at(far), sphere_at(near)], np.random.default_rng(3)), camera, R_M
    )
    assert len(detections) == 1
    assert bearing_error_deg(to_ned(detections[0], LEVEL_Q), near) < 1.0
    assert abs(range_error(detections[0], near)) < 0.05


@pytest.mark.parametrize("far_azimuth_deg", [17.0, 18.5, 20.0])
def test_a_partly_hidden_far_body_is_split_from_the_near_one(far_azimuth_deg: float) -> None:
    camera = Camera(CameraConfig())
    near, far = frd(10.0, 0.0) * 3.0, frd(far_azimuth_deg, 0.0) * 6.0
    image = render(camera, LEVEL_Q, [sphere_at(near), sphere_at(far)], np.random.default_rng(4))
    detections = detect(image, camera, R_M)
    assert len(detections) == 2 and all(d.merged for d in detections)
    first, second = detections
    # The near body is whole: as good as alone.
    assert bearing_error_deg(to_ned(first, LEVEL_Q), near) < 1.0
    assert abs(range_error(first, near)) < 0.05
    # The far one is seen in part: right direction, range from its visible part (so never much too short).
    assert bearing_error_deg(to_ned(second, LEVEL_Q), far) < 2.0
    assert range_error(second, far) > -0.05


def test_a_small_merged_blob_never_puts_the_nearest_body_farther_than_it_is() -> None:
    """Two drones overlapping in a 60 px blob: too few outline pixels to measure the near one on its own. Whatever
    the noise, the nearest detection must not read the near drone as farther away (the unsafe direction)."""
    near, far = frd(7.10, 9.89) * 7.81, frd(3.85, 9.17) * 11.12
    for seed in range(20):
        camera = Camera(CameraConfig(noise_seed=seed))
        image = render(camera, LEVEL_Q, [sphere_at(near), sphere_at(far)], np.random.default_rng(seed))
        detections = detect(image, camera, R_M)
        nearest = min(detections, key=lambda d: d.range_m)
        assert nearest.merged
        assert range_error(nearest, near) < 0.05, seed
        assert bearing_error_deg(to_ned(nearest, LEVEL_Q), near) < 2.0


def test_two_bodies_side_by_side_in_one_blob_are_both_reported() -> None:
    camera = Camera(CameraConfig())
    left, right = frd(-5.0, 0.0) * 5.0, frd(3.0, 0.0) * 5.0
    image = render(camera, LEVEL_Q, [sphere_at(left), sphere_at(right)], np.random.default_rng(6))
    detections = detect(image, camera, R_M)
    assert len(detections) == 2
    for truth in (left, right):
        best = min(detections, key=lambda d: bearing_error_deg(to_ned(d, LEVEL_Q), truth))
        assert bearing_error_deg(to_ned(best, LEVEL_Q), truth) < 1.0
        assert abs(range_error(best, truth)) < 0.1


@pytest.mark.parametrize(
    "centre_m",
    [frd(180.0, 0.0) * 3.0, frd(60.0, 0.0) * 5.0, frd(0.0, 60.0) * 5.0, frd(0.0, 0.0) * 16.0],
    ids=["behind", "beside", "above", "beyond-range"],
)
def test_bodies_out_of_view_are_not_detected(centre_m: npt.NDArray[np.float64]) -> None:
    camera = Camera(CameraConfig())
    assert detect(render(camera, LEVEL_Q, [sphere_at(centre_m)], np.random.default_rng(0)), camera, R_M) == []


@pytest.mark.parametrize("sigma", [4.0, 12.0, 20.0])
def test_noise_alone_gives_no_detections(sigma: float) -> None:
    camera = Camera(CameraConfig(pixel_noise_sigma=sigma, noise_seed=int(sigma)))
    rng = np.random.default_rng(11)
    for _ in range(30):
        assert detect(render(camera, LEVEL_Q, [], rng), camera, R_M) == []


def test_to_ned_uses_the_attitude_it_is_given() -> None:
    """The caller passes its attitude ESTIMATE: a 5 deg heading error turns the reported position by 5 deg."""
    camera = Camera(CameraConfig())
    true_q = quat_from_euler(0.2, -0.1, 1.0)
    truth = quat_to_dcm(true_q) @ (frd(15.0, 10.0) * 6.0)
    det = detect(render(camera, true_q, [sphere_at(truth)], np.random.default_rng(8)), camera, R_M)[0]
    assert bearing_error_deg(to_ned(det, true_q), truth) < 0.5
    estimate_q = quat_from_euler(0.2, -0.1, 1.0 + math.radians(5.0))
    north, east, down = to_ned(det, estimate_q)
    seen_heading = math.atan2(east, north)
    true_heading = math.atan2(truth[1], truth[0])
    assert math.degrees(seen_heading - true_heading) == pytest.approx(5.0, abs=0.5)
    assert down == pytest.approx(truth[2], abs=0.3)


def test_a_camera_mount_is_undone_into_the_body_frame() -> None:
    camera = Camera(CameraConfig(mount_yaw_rad=math.radians(90.0), mount_pitch_rad=math.radians(20.0)))
    truth = frd(100.0, 15.0) * 5.0
    det = detect(render(camera, LEVEL_Q, [sphere_at(truth)], np.random.default_rng(9)), camera, R_M)[0]
    assert bearing_error_deg(det.unit_frd, truth) < 0.5
    # In the camera frame it is 10 deg right of and 5 deg below the optical axis (to first order).
    assert math.degrees(det.azimuth_rad) == pytest.approx(10.0, abs=0.8)
    assert math.degrees(det.elevation_rad) == pytest.approx(-5.0, abs=0.8)


def test_the_omni_rig_sees_a_body_behind_and_reports_a_seam_body_once() -> None:
    rig = CameraRig.omni()
    rng = np.random.default_rng(10)
    behind = frd(180.0, 5.0) * 4.0
    detections = detect_rig(render_rig(rig, LEVEL_Q, [sphere_at(behind)], rng), rig, R_M)
    assert len(detections) == 1 and detections[0].camera_name == "back"
    assert bearing_error_deg(to_ned(detections[0], LEVEL_Q), behind) < 1.0
    assert abs(range_error(detections[0], behind)) < 0.05
    # Near a seam (cameras overlap by 10 deg) a body can be cut by one camera's border and whole in the other's:
    # it is reported once, from the camera that sees it whole.
    for seam_deg, distance in ((48.0, 4.0), (132.0, 4.0), (-132.0, 4.0), (-48.0, 4.0), (45.0, 6.0)):
        truth = frd(seam_deg, 0.0) * distance
        detections = detect_rig(render_rig(rig, LEVEL_Q, [sphere_at(truth)], rng), rig, R_M)
        assert len(detections) == 1, seam_deg
        assert not detections[0].truncated
        assert bearing_error_deg(to_ned(detections[0], LEVEL_Q), truth) < 1.0
        assert abs(range_error(detections[0], truth)) < 0.05


def test_a_body_cut_by_the_border_is_flagged_and_still_located() -> None:
    camera = Camera(CameraConfig())
    rng = np.random.default_rng(12)
    # Centre inside the frame near the right edge: the outline inside the frame still fixes the sphere.
    for distance, az, el in [(1.5, 38.0, 0.0), (2.5, -10.0, 33.0), (1.2, 30.0, -25.0)]:
        truth = frd(az, el) * distance
        detections = detect(render(camera, LEVEL_Q, [sphere_at(truth)], rng), camera, R_M)
        assert len(detections) == 1 and detections[0].truncated
        assert bearing_error_deg(to_ned(detections[0], LEVEL_Q), truth) < 2.0
        assert abs(range_error(detections[0], truth)) < 0.15
    # Centre outside the frame: still reported, pointing the right way, and flagged.
    truth = frd(49.0, 0.0) * 2.0
    detections = detect(render(camera, LEVEL_Q, [sphere_at(truth)], rng), camera, R_M)
    assert len(detections) == 1 and detections[0].truncated
    assert bearing_error_deg(to_ned(detections[0], LEVEL_Q), truth) < 8.0


def test_the_detector_leaves_the_frame_untouched() -> None:
    camera = Camera(CameraConfig())
    frame = render(camera, LEVEL_Q, [sphere_at(frd(5.0, 5.0) * 4.0)], np.random.default_rng(13)).copy()
    kept = frame.copy()
    detect(frame, camera, R_M)
    assert np.array_equal(frame, kept)


@settings(max_examples=200, deadline=None)
@given(
    theta=st.floats(min_value=0.0, max_value=1.2),
    sin_alpha=st.floats(min_value=0.005, max_value=0.6),
    by_area=st.booleans(),
)
def test_the_silhouette_inversion_recovers_direction_and_size(theta: float, sin_alpha: float, by_area: bool) -> None:
    """The closed-form silhouette (what the renderer draws) inverted back (what the detector does), exactly."""
    if math.cos(theta) ** 2 - sin_alpha**2 < 0.05:
        return  # the silhouette is no longer a bounded ellipse in front of the camera
    c_n, a_n, b_n = sphere_silhouette(theta, sin_alpha)
    got_theta, got_alpha, got_a, got_b = _solve_sphere(c_n, math.pi * a_n * b_n if by_area else b_n, by_area=by_area)
    assert got_theta == pytest.approx(theta, abs=1e-6)
    assert math.sin(got_alpha) == pytest.approx(sin_alpha, rel=1e-6)
    assert (got_a, got_b) == (pytest.approx(a_n, rel=1e-6), pytest.approx(b_n, rel=1e-6))


@pytest.mark.parametrize("distance_m", [2.0, 3.0, 6.0])
def test_a_pole_leaving_the_frame_is_ranged_by_its_width_not_taken_for_a_near_drone(distance_m: float) -> None:
    # GIVEN a pole 0.25 m thick standing from the ground (3 m below the camera) to 10 m, seen level by any camera
    # of the omni rig (the side cameras keep a pole in view long after the drone passed it), near enough to leave
    # the frame at the top (further away it is whole in view and reads short, as any body that is not drone-sized)
    rig = CameraRig.omni()
    rng = np.random.default_rng(13)
    for azimuth_deg in (0.0, 90.0, -150.0):
        centre = frd(azimuth_deg, 0.0) * distance_m + np.array((0.0, 0.0, -2.0))  # mid-height 5 m up
        pole = VerticalCylinder(offset_ned_m=tuple(centre.tolist()), radius_m=0.25, height_m=10.0)
        (det,) = detect_rig(render_rig(rig, LEVEL_Q, [pole], rng), rig, R_M)
        # THEN it is one detection in the right direction, flagged, at a range from its width with the drone-size
        # prior: a little far for a pole thinner than a drone (x 1.4), never the 1-2 m its area would give
        assert det.truncated
        n, e, _ = to_ned(det, LEVEL_Q)
        assert abs(math.degrees(math.atan2(e, n)) - azimuth_deg) < 2.0
        assert 0.9 * distance_m < det.range_m < 1.7 * distance_m, det.range_m


@pytest.mark.parametrize("seed", range(6))
def test_skipping_empty_frames_changes_no_detection_and_no_later_noise(seed: int) -> None:
    """A rig rendered with ``render_rig_if_drawn`` (frames nothing reaches are neither composed nor searched) finds
    exactly what the full rendering finds, frame after frame, with the random stream left in the same state: bodies
    near and far, in view and out of it, on camera seams, one camera inside a body, cylinders, and no body at all."""
    rng_scene = np.random.default_rng(seed)
    rig = CameraRig.omni(CameraConfig(noise_seed=seed))
    assert all(camera.noise_cannot_detect for camera in rig.cameras)
    full_rng, skip_rng = np.random.default_rng(100 + seed), np.random.default_rng(100 + seed)
    skipped = found = 0
    for frame in range(60):
        count = int(rng_scene.integers(0, 5))
        bodies: list[Sphere | VerticalCylinder] = []
        for _ in range(count):
            offset = rng_scene.uniform(-25.0, 25.0, 3) * (0.1 if frame % 7 == 0 else 1.0)
            if rng_scene.random() < 0.2:
                bodies.append(VerticalCylinder(offset_ned_m=tuple(offset.tolist()), radius_m=0.5, height_m=6.0))
            else:
                bodies.append(Sphere(offset_ned_m=tuple(offset.tolist()), radius_m=R_M))
        roll, pitch = rng_scene.uniform(-0.5, 0.5, 2)
        q = quat_from_euler(float(roll), float(pitch), float(rng_scene.uniform(-math.pi, math.pi)))
        full = detect_rig(render_rig(rig, q, bodies, full_rng), rig, R_M)
        images = render_rig_if_drawn(rig, q, bodies, skip_rng)
        skipped += sum(image is None for image in images)
        assert detect_rig(images, rig, R_M) == full
        found += len(full)
        assert full_rng.bit_generator.state == skip_rng.bit_generator.state
    assert skipped > 0 and found > 0


def test_a_camera_whose_noise_could_be_detected_is_never_skipped() -> None:
    config = CameraConfig(background_level=100, body_level=130, pixel_noise_sigma=20.0)
    camera = Camera(config)
    assert not camera.noise_cannot_detect
    rng = np.random.default_rng(0)
    assert render_if_drawn(camera, LEVEL_Q, [], rng) is not None
    far = [Sphere(offset_ned_m=(40.0, 0.0, 0.0), radius_m=R_M)]
    reference = Camera(config)
    full_rng, skip_rng = np.random.default_rng(5), np.random.default_rng(5)
    for bodies in ([], far, [Sphere(offset_ned_m=(5.0, 0.5, 0.0), radius_m=R_M)], far):
        full = render(reference, LEVEL_Q, bodies, full_rng)
        image = render_if_drawn(camera, LEVEL_Q, bodies, skip_rng)
        assert image is not None and np.array_equal(image, full)


def kept_once(found: list[Detection]) -> list[Detection]:
    """What ``detect_rig`` keeps of every camera's detections, as its docstring says, pair by pair with arc cosines."""
    found = sorted(found, key=lambda det: (det.truncated, -det.area_px))
    kept: list[Detection] = []
    for det in found:
        if not any(
            other.camera_name != det.camera_name
            and math.acos(max(-1.0, min(1.0, sum(a * b for a, b in zip(other.unit_frd, det.unit_frd, strict=True)))))
            < max(math.radians(3.0), other.angular_radius_rad, det.angular_radius_rad)
            for other in kept
        ):
            kept.append(det)
    return kept


@pytest.mark.parametrize("seed", range(6))
def test_a_crowd_seen_by_the_rig_is_reported_once_per_body_as_pair_by_pair_arc_cosines_say(seed: int) -> None:
    """``detect_rig`` skips the arc cosine for pairs of detections clearly apart: what it keeps must be what the pair
    by pair rule keeps (``kept_once``), on crowds near and far, around the range limit and the field of view's edge,
    one camera inside a body, a cylinder among them; and the rig's frames are each camera's own, pixel for pixel."""
    rng_scene = np.random.default_rng(seed)
    rig = CameraRig.omni(CameraConfig(noise_seed=seed))
    alone = CameraRig.omni(CameraConfig(noise_seed=seed))  # the same cameras, buffers of their own
    rig_rng, alone_rng, skip_rng = (np.random.default_rng(200 + seed) for _ in range(3))
    drawn = found = seen_twice = 0
    for frame in range(30):
        count = int(rng_scene.integers(8, 40))
        distance = rng_scene.uniform(0.5, 1.0, count) * 16.0  # many around the 15 m range limit
        direction = rng_scene.normal(size=(count, 3))
        direction /= np.linalg.norm(direction, axis=1)[:, None]
        offsets = direction * distance[:, None]
        if frame % 10 == 3:
            offsets[0] = (0.1, 0.1, 0.0)  # this drone is inside that body
        bodies: list[Sphere | VerticalCylinder] = list(spheres(offsets, R_M))
        if frame % 5 == 0:
            bodies.insert(count // 2, VerticalCylinder(offset_ned_m=(6.0, 2.0, -1.0), radius_m=0.5, height_m=6.0))
        roll, pitch = rng_scene.uniform(-0.5, 0.5, 2)
        q = quat_from_euler(float(roll), float(pitch), float(rng_scene.uniform(-math.pi, math.pi)))
        expected = [render(camera, q, bodies, alone_rng).copy() for camera in alone.cameras]
        images = render_rig(rig, q, bodies, rig_rng)
        assert all(np.array_equal(a, b) for a, b in zip(images, expected, strict=True))
        detections = detect_rig(images, rig, R_M)
        assert detections == detect_rig(expected, alone, R_M)
        every = [det for image, camera in zip(images, rig.cameras, strict=True) for det in detect(image, camera, R_M)]
        assert detections == kept_once(every)
        seen_twice += len(every) - len(detections)
        assert detect_rig(render_rig_if_drawn(rig, q, bodies, skip_rng), rig, R_M) == detections
        assert rig_rng.bit_generator.state == alone_rng.bit_generator.state == skip_rng.bit_generator.state
        drawn += sum(int((image >= rig.cameras[0].config.threshold_level).any()) for image in images)
        found += len(detections)
    assert drawn > 30 and found > 60 and seen_twice > 5


def test_every_detection_is_turned_to_ned_by_one_rotation_as_by_one_each() -> None:
    rig = CameraRig.omni(CameraConfig(noise_seed=3))
    offsets = np.array([(4.0 * math.cos(a), 4.0 * math.sin(a), 0.3 * math.sin(3 * a)) for a in np.linspace(0, 6, 9)])
    q = quat_from_euler(0.1, -0.2, 0.7)
    detections = detect_rig(render_rig(rig, q, spheres(offsets, R_M), np.random.default_rng(1)), rig, R_M)
    assert len(detections) >= 8
    assert to_ned_all(detections, q) == [to_ned(d, q) for d in detections]
    assert to_ned_all([], q) == []


def test_a_frame_of_merged_blobs_gives_the_same_detections_every_time() -> None:
    """OpenCV's precise distance transform rounds a last bit differently from call to call (by where its buffers
    lie), which moved the split of a merged blob and made two runs of one swarm flight differ; the detector must
    give one answer per frame, whatever the memory around it."""
    scene = np.random.default_rng(5)
    held: list[npt.NDArray[np.uint8]] = []
    merged = 0
    for trial in range(12):
        count = int(scene.integers(8, 30))
        distance = 8.0 * scene.uniform(0.8, 1.0, count) * scene.uniform(0.2, 1.0, count)
        azimuth = scene.uniform(-math.pi, math.pi, count)
        offsets = np.column_stack(
            (distance * np.cos(azimuth), distance * np.sin(azimuth), scene.uniform(-0.3, 0.3, count))
        )
        q = quat_from_euler(0.1, -0.1, float(scene.uniform(-3.0, 3.0)))
        rig = CameraRig.omni(CameraConfig(noise_seed=trial))
        images = [image.copy() for image in render_rig(rig, q, spheres(offsets, R_M), np.random.default_rng(trial))]
        first = detect_rig(images, rig, R_M)
        merged += sum(det.merged for det in first)
        for _ in range(8):
            held.append(np.full(int(scene.integers(1, 5000)), 7, np.uint8))  # move the allocator along
            assert detect_rig(images, rig, R_M) == first
    assert merged >= 10
