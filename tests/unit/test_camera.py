"""The synthetic camera: exact sphere silhouettes, what is and is not drawn, occlusion, attitude and mount
conventions, rigs, obstacles and noise."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from sitl.mathutil import quat_from_euler, quat_to_dcm
from sitl.perception import Camera, CameraConfig, CameraRig, Sphere, VerticalCylinder, render, render_rig, spheres
from sitl.perception.camera import sphere_silhouette

pytestmark = pytest.mark.timeout(30)

LEVEL_Q = np.array((1.0, 0.0, 0.0, 0.0))
DRONE_RADIUS_M = 0.35


def quiet_camera(**overrides: float | int | str) -> Camera:
    """A noise-free camera, so pixel sets can be compared exactly."""
    return Camera(CameraConfig(pixel_noise_sigma=0.0, **overrides))  # type: ignore[arg-type]


def frd(azimuth_deg: float, elevation_deg: float) -> npt.NDArray[np.float64]:
    """Unit vector in body FRD (or a camera frame): azimuth positive right, elevation positive up."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array((math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), -math.sin(el)))


def sphere_at(vec_m: npt.NDArray[np.float64], radius_m: float = DRONE_RADIUS_M) -> Sphere:
    return Sphere(offset_ned_m=(float(vec_m[0]), float(vec_m[1]), float(vec_m[2])), radius_m=radius_m)


def lit(image: npt.NDArray[np.uint8], camera: Camera) -> npt.NDArray[np.bool_]:
    return image >= camera.config.threshold_level


def pixel_rays(camera: Camera) -> npt.NDArray[np.float64]:
    """Unit ray of every pixel centre in the camera frame, computed here from the intrinsics alone."""
    h, w = camera.config.height_px, camera.config.width_px
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    rays = np.dstack((np.full((h, w), camera.focal_px), u - (w - 1) / 2.0, v - (h - 1) / 2.0))
    return rays / np.linalg.norm(rays, axis=2, keepdims=True)


def test_intrinsics_follow_the_field_of_view_and_resolution() -> None:
    camera = Camera(CameraConfig())
    # 90 deg across 160 px: f = 80 px; the vertical field is then 2 atan(60 / 80) = 73.7 deg.
    assert camera.focal_px == pytest.approx(80.0)
    assert math.degrees(camera.fov_v_rad) == pytest.approx(73.74, abs=0.01)
    assert (camera.cx_px, camera.cy_px) == (79.5, 59.5)
    assert camera.config.frame_period_s == pytest.approx(1.0 / 15.0)


@pytest.mark.parametrize(
    "bad",
    [
        {"fov_h_rad": math.radians(180.0)},
        {"width_px": 4},
        {"max_range_m": 0.0},
        {"frame_rate_hz": -1.0},
        {"pixel_noise_sigma": -0.1},
        {"background_level": 200, "body_level": 100},
    ],
)
def test_impossible_configurations_are_refused(bad: dict[str, float]) -> None:
    with pytest.raises(ValueError):
        CameraConfig(**bad)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("distance_m", "azimuth_deg", "elevation_deg"),
    [(5.0, 0.0, 0.0), (2.0, 30.0, 15.0), (1.3, -12.0, -8.0), (8.0, 38.0, -24.0), (12.0, -10.0, 25.0)],
)
def test_a_sphere_is_drawn_as_its_exact_silhouette(distance_m: float, azimuth_deg: float, elevation_deg: float) -> None:
    camera = quiet_camera()
    centre = frd(azimuth_deg, elevation_deg) * distance_m
    image = render(camera, LEVEL_Q, [sphere_at(centre)], np.random.default_rng(0))
    # Oracle: a pixel centre is inside when its ray is closer to the sphere's centre than the angular radius.
    alpha = math.asin(DRONE_RADIUS_M / distance_m)
    angle = np.arccos(np.clip(pixel_rays(camera) @ (centre / distance_m), -1.0, 1.0))
    mask = lit(image, camera)
    assert not (mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any()), "scene must fit the frame"
    wrong = mask != (angle < alpha)
    # Only pixels whose centre is within a tenth of a pixel of the edge may go either way.
    assert np.all(np.abs(angle[wrong] - alpha) < 0.1 / camera.focal_px), np.argwhere(wrong)
    # The area is that of the ellipse the detector inverts (an independent closed form), up to how many pixel
    # centres a lattice happens to fit in it: about R^(2/3) px for radius R (4 px at the smallest blob here).
    _, a_n, b_n = sphere_silhouette(math.acos(centre[0] / distance_m), DRONE_RADIUS_M / distance_m)
    ellipse_area_px = math.pi * a_n * b_n * camera.focal_px**2
    assert mask.sum() == pytest.approx(ellipse_area_px, rel=0.02, abs=4.0)


def test_off_axis_silhouettes_are_stretched_radially() -> None:
    camera = quiet_camera()
    image = render(camera, LEVEL_Q, [sphere_at(frd(38.0, 0.0) * 5.0)], np.random.default_rng(0))
    rows, cols = np.nonzero(lit(image, camera))
    # Spread along the image x axis (radial here) over spread along y: the semi-axis ratio of the ellipse, about
    # 1 / cos 38 deg = 1.27 (a disc of radius f r / depth would give 1).
    ratio = math.sqrt(cols.var() / rows.var())
    _, a_n, b_n = sphere_silhouette(math.radians(38.0), DRONE_RADIUS_M / 5.0)
    assert ratio == pytest.approx(a_n / b_n, rel=0.03)
    assert ratio > 1.2


@pytest.mark.parametrize(
    "centre_m",
    [
        frd(180.0, 0.0) * 3.0,  # behind
        frd(0.0, -89.0) * 3.0,  # straight below the camera, far outside the vertical field
        frd(55.0, 0.0) * 6.0,  # beside the 90 deg field: 6 m away its 3.3 deg radius cannot reach 45 deg
        frd(0.0, 0.0) * 15.5,  # nearest point 15.15 m: beyond the 15 m range
    ],
)
def test_bodies_out_of_view_draw_nothing(centre_m: npt.NDArray[np.float64]) -> None:
    camera = quiet_camera()
    image = render(camera, LEVEL_Q, [sphere_at(centre_m)], np.random.default_rng(0))
    assert np.all(image == camera.config.background_level)


def test_range_limit_is_on_the_nearest_point_of_the_body() -> None:
    camera = quiet_camera()
    image = render(camera, LEVEL_Q, [sphere_at(frd(0.0, 0.0) * 15.3)], np.random.default_rng(0))
    assert lit(image, camera).sum() > 5  # nearest point at 14.95 m


def test_a_near_body_hides_a_far_one_whatever_the_order_given() -> None:
    camera = quiet_camera()
    near, far = sphere_at(frd(10.0, 5.0) * 3.0), sphere_at(frd(10.0, 5.0) * 6.0)
    alone = render(camera, LEVEL_Q, [near], np.random.default_rng(0)).copy()
    assert np.array_equal(render(camera, LEVEL_Q, [far, near], np.random.default_rng(0)), alone)
    assert np.array_equal(render(camera, LEVEL_Q, [near, far], np.random.default_rng(0)), alone)
    # Side by side, the far body adds to the near one's silhouette.
    beside = render(camera, LEVEL_Q, [near, sphere_at(frd(16.0, 5.0) * 6.0)], np.random.default_rng(0))
    assert lit(beside, camera).sum() > lit(alone, camera).sum() + 20


def test_attitude_rotates_the_world_into_the_camera_as_frd_to_ned() -> None:
    camera = quiet_camera()
    rng = np.random.default_rng(7)
    seen_in_body = frd(20.0, -10.0) * 4.0
    reference = render(camera, LEVEL_Q, [sphere_at(seen_in_body)], np.random.default_rng(0)).copy()
    for _ in range(5):
        q = quat_from_euler(rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), rng.uniform(-math.pi, math.pi))
        # The same body-frame offset, expressed in NED through q, must give the same picture.
        image = render(camera, q, [sphere_at(quat_to_dcm(q) @ seen_in_body)], np.random.default_rng(0))
        assert np.array_equal(lit(image, camera), lit(reference, camera))
    # Concretely: yawed 90 deg (nose east), a body 5 m east is dead ahead, one 5 m north is out of view.
    east = quat_from_euler(0.0, 0.0, math.pi / 2.0)
    rows, cols = np.nonzero(lit(render(camera, east, [sphere_at(np.array((0.0, 5.0, 0.0)))], rng), camera))
    assert (cols.mean(), rows.mean()) == (pytest.approx(79.5, abs=0.2), pytest.approx(59.5, abs=0.2))
    assert not lit(render(camera, east, [sphere_at(np.array((5.0, 0.0, 0.0)))], rng), camera).any()


@pytest.mark.parametrize(("yaw_deg", "pitch_deg"), [(0.0, 30.0), (90.0, 0.0), (-45.0, -20.0)])
def test_the_mount_points_the_optical_axis(yaw_deg: float, pitch_deg: float) -> None:
    camera = quiet_camera(mount_yaw_rad=math.radians(yaw_deg), mount_pitch_rad=math.radians(pitch_deg))
    image = render(camera, LEVEL_Q, [sphere_at(frd(yaw_deg, pitch_deg) * 5.0)], np.random.default_rng(0))
    rows, cols = np.nonzero(lit(image, camera))
    assert (cols.mean(), rows.mean()) == (pytest.approx(79.5, abs=0.2), pytest.approx(59.5, abs=0.2))


def test_the_omni_rig_sees_all_round_and_a_body_behind_only_in_the_back_camera() -> None:
    rig = CameraRig.omni(CameraConfig(pixel_noise_sigma=0.0))
    assert [c.config.name for c in rig.cameras] == ["front", "right", "back", "left"]
    behind = render_rig(rig, LEVEL_Q, [sphere_at(frd(180.0, 0.0) * 4.0)], np.random.default_rng(0))
    assert [bool(lit(image, cam).any()) for image, cam in zip(behind, rig.cameras, strict=True)] == [
        False,
        False,
        True,
        False,
    ]
    for azimuth in range(0, 360, 15):
        images = render_rig(rig, LEVEL_Q, [sphere_at(frd(azimuth, 0.0) * 5.0)], np.random.default_rng(0))
        whole = [
            mask.any() and not (mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())
            for mask in (lit(image, cam) for image, cam in zip(images, rig.cameras, strict=True))
        ]
        assert any(whole), f"a body at azimuth {azimuth} deg is whole in no camera"
    with pytest.raises(ValueError):
        CameraRig.omni(count=3, fov_h_rad=math.radians(100.0))


def test_a_camera_inside_a_body_sees_nothing_else() -> None:
    camera = quiet_camera()
    image = render(camera, LEVEL_Q, [sphere_at(np.array((0.1, 0.0, 0.0)), 0.5)], np.random.default_rng(0))
    assert lit(image, camera).all()


def test_a_vertical_pole_spans_the_frame_with_its_apparent_width() -> None:
    camera = quiet_camera()
    pole = VerticalCylinder(offset_ned_m=(4.0, 0.0, 0.0), radius_m=0.2, height_m=30.0)
    mask = lit(render(camera, LEVEL_Q, [pole], np.random.default_rng(0)), camera)
    assert mask[0].any() and mask[-1].any()
    widths = mask.sum(axis=1)
    # Near the horizon the pole is 2 f r / d = 8 px wide (2 f tan(asin(r / d)), to the pixel).
    assert widths[59] == pytest.approx(8.0, abs=1.0)
    # A short post standing below the camera shows only in the lower half of the frame.
    post = VerticalCylinder(offset_ned_m=(5.0, -1.0, 1.5), radius_m=0.3, height_m=1.0)
    rows, _ = np.nonzero(lit(render(camera, LEVEL_Q, [post], np.random.default_rng(0)), camera))
    assert rows.min() > 59.5 + camera.focal_px * 0.9 / 5.0 - 2.0


def test_noise_has_the_configured_level_and_spread_and_is_reproducible() -> None:
    config = CameraConfig(pixel_noise_sigma=6.0, noise_seed=3)
    camera = Camera(config)
    frame = render(camera, LEVEL_Q, [], np.random.default_rng(1))
    assert frame is camera.frame  # the buffer is reused, not reallocated
    first = frame.copy()
    assert first.mean() == pytest.approx(config.background_level, abs=0.3)
    assert first.std() == pytest.approx(6.0, rel=0.1)
    assert not np.array_equal(render(camera, LEVEL_Q, [], np.random.default_rng(2)), first)
    assert np.array_equal(render(Camera(config), LEVEL_Q, [], np.random.default_rng(1)), first)


def test_spheres_are_built_from_a_table_of_offsets_with_one_or_many_radii() -> None:
    offsets = np.array(((1.0, 2.0, 3.0), (4.0, 5.0, 6.0)))
    assert spheres(offsets, 0.35) == [
        Sphere(offset_ned_m=(1.0, 2.0, 3.0), radius_m=0.35),
        Sphere(offset_ned_m=(4.0, 5.0, 6.0), radius_m=0.35),
    ]
    assert [s.radius_m for s in spheres(offsets, [0.3, 0.5])] == [0.3, 0.5]
    assert spheres(np.zeros((0, 3)), 0.35) == []


@pytest.mark.parametrize("bounds", [(121, 161), (181, 241), (2**31 + 1, 3), (7, 2**33 + 3)])
def test_the_noise_offset_draws_what_one_draw_of_both_bounds_would(bounds: tuple[int, int]) -> None:
    """The renderer draws a frame's noise offset as two scalars, which must be the numbers (and leave the stream
    where) numpy's array-bounds draw would, or skipped and rendered frames would get different noise; the large
    bounds make numpy reject and redraw often."""
    for seed in range(100):
        array_rng, scalar_rng = np.random.default_rng(seed), np.random.default_rng(seed)
        for _ in range(20):
            expected = array_rng.integers(0, bounds).tolist()
            assert [int(scalar_rng.integers(0, bounds[0])), int(scalar_rng.integers(0, bounds[1]))] == expected
        assert array_rng.bit_generator.state == scalar_rng.bit_generator.state
