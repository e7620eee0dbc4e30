"""The drone's one pass per camera (sitl/kernels/frame.py through ``sense_rig``): exposed and searched only in the
boxes drawn, it finds what the whole frame holds, to the bit, and leaves the random stream where the whole frames
leave it; and it splits a merged blob into the rows OpenCV's split gave, to the bit (the split below, with cv2, is
the Python the pass replaced, kept as the oracle)."""

from __future__ import annotations

import math
from collections import Counter

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from sitl.kernels import blobs as bk
from sitl.kernels import detector as dk
from sitl.mathutil import quat_from_euler
from sitl.perception import (
    Camera,
    CameraConfig,
    CameraRig,
    Sphere,
    VerticalCylinder,
    detect_rig,
    render,
    render_rig,
    to_ned_all,
)
from sitl.perception.camera import sphere_rows, sphere_silhouette
from sitl.perception.detector import _image_rows, _Rows, rig_ned, sense_rig

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


def opencv_row(
    camera: Camera, u: float, v: float, vec: tuple[float, float, float], alpha: float, area: int, radius_m: float
) -> list[float]:
    """A merged body's row as the split made it: its record's fields (bearing, body direction, range) in row order."""
    azimuth, elevation = dk.bearing(*vec)
    range_m = radius_m / math.sin(alpha) if alpha > 0.0 else math.inf
    return [0.0, u, v, area, azimuth, elevation, *camera.camera_to_body(vec), range_m, alpha, 0.0, 1.0]


def opencv_split(
    camera: Camera, mask: npt.NDArray[np.uint8], x0: int, y0: int, radius_m: float, min_area_px: int, whole: list[float]
) -> list[list[float]]:
    """The split of a merged blob as sitl/perception/detector.py did it before the pass did, OpenCV and all."""
    padded = cv2.copyMakeBorder(mask, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
    dist = cv2.distanceTransform(padded, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    squared = np.rint(dist.astype(np.float64) ** 2)
    flat = int(np.argmax(squared))
    pv, pu = divmod(flat, squared.shape[1])
    peak = math.sqrt(float(squared.flat[flat]))
    u, v = x0 + pu - 1.0, y0 + pv - 1.0
    f = camera.focal_px
    theta, alpha, _, _ = dk.solve_sphere(dk.normalised(camera.kernel_row, u, v), max(peak - 0.5, 0.5) / f, False)
    vec = dk.ray(camera.kernel_row, u, v, theta)
    contours, _ = cv2.findContours(padded, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    boundary = np.concatenate([c[:, 0, :] for c in contours]).astype(np.float64)
    boundary += (x0 - 1.0, y0 - 1.0)
    fitted, ax, ay, az, fitted_alpha = dk.fit_cone(camera.kernel_row, boundary, *vec, alpha, True)
    if fitted:
        vec, alpha = (ax, ay, az), fitted_alpha
        theta = math.acos(min(1.0, vec[0]))
    c_n, a_n, b_n = sphere_silhouette(theta, math.sin(alpha))
    rho = math.hypot(vec[1], vec[2])
    py, pz = (vec[1] / rho, vec[2] / rho) if rho > 0.0 else (1.0, 0.0)
    uc, vc = camera.cx_px + f * c_n * py, camera.cy_px + f * c_n * pz
    near_area = round(math.pi * a_n * b_n * f * f)
    if near_area < 0.45 * whole[dk.R_AREA]:
        return [whole]
    found = [opencv_row(camera, uc, vc, vec, alpha, near_area, radius_m)]
    centre = (round((uc - x0 + 1.0) * 16), round((vc - y0 + 1.0) * 16))
    axes = (round((a_n * f + 1.0) * 16), round((b_n * f + 1.0) * 16))
    cv2.ellipse(padded, centre, axes, math.degrees(math.atan2(pz, py)), 0.0, 360.0, 0, -1, cv2.LINE_8, 4)
    contours, _ = cv2.findContours(padded, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    best: tuple[float, float, float] | None = None
    for contour in contours:
        bx, by, bw, bh = cv2.boundingRect(contour)
        m = cv2.moments(padded[by : by + bh, bx : bx + bw], True)
        if m["m00"] > 0 and (best is None or m["m00"] > best[0]):
            best = (m["m00"], x0 + bx - 1.0 + m["m10"] / m["m00"], y0 + by - 1.0 + m["m01"] / m["m00"])
    if best is not None and best[0] >= max(min_area_px, 0.05 * near_area):
        area, ru, rv = best
        theta, alpha, _, _ = dk.solve_sphere(dk.normalised(camera.kernel_row, ru, rv), area / (f * f), True)
        found.append(opencv_row(camera, ru, rv, dk.ray(camera.kernel_row, ru, rv, theta), alpha, round(area), radius_m))
    return found


def opencv_rows(
    image: npt.NDArray[np.uint8], camera: Camera, radius_m: float, min_area_px: int, tally: Counter[str]
) -> list[list[float]]:
    """An image's rows as the detector gave them when merged blobs were split in Python: the compiled labelling and
    the rows of whole and cut blobs (the pass's own kernels), each merged blob's row replaced by ``opencv_split``'s
    (counted in ``tally``: merged blobs, those kept whole, split in two, lying within 3 px of the border)."""
    height, width = image.shape
    labels = np.where(image >= camera.config.threshold_level, bk.UNLABELLED, 0).astype(np.int32)
    blobs = np.zeros((height * width, bk.BLOB_SIZE), np.int64)
    n = bk.label(labels, np.array([(0, width, 0, height)], np.int64), 1, np.zeros(height * width, np.int32), blobs)
    points = np.zeros((4 * height * width, 2), np.int32)
    f = camera.focal_px
    rows: list[list[float]] = []
    for index in bk.opencv_order(blobs, n).tolist():
        blob = blobs[index]
        area, m10, m01, mu20, mu11, mu02 = bk.box_moments(blob)
        if area < min_area_px:
            continue
        x0, y0, x1, y1 = (int(blob[k]) for k in (bk.K_U0, bk.K_V0, bk.K_U1, bk.K_V1))
        u, v = x0 + m10 / area, y0 + m01 / area
        row = np.zeros(dk.ROW_SIZE)
        if x0 == 0 or y0 == 0 or x1 == width or y1 == height:
            dk.solve_truncated(camera.kernel_row, camera.rot_body_cam, labels, blob, points, u, v, area, radius_m, 0,
                               row)  # fmt: skip
            rows.append(row.tolist())
            continue
        theta, alpha, a_n, b_n = dk.solve_sphere(dk.normalised(camera.kernel_row, u, v), area / (f * f), True)
        merged = area >= dk.MERGE_CHECK_MIN_AREA_PX and dk.elongation(area, mu20, mu11, mu02) > (
            dk.MERGE_ELONGATION_RATIO * a_n / b_n
        )
        vx, vy, vz = dk.ray(camera.kernel_row, u, v, theta)
        dk.make_row(row, camera.rot_body_cam, 0, u, v, vx, vy, vz, alpha, area, radius_m, False, merged)
        if not merged:
            rows.append(row.tolist())
            continue
        mask = np.where(labels[y0:y1, x0:x1] == blob[bk.K_LABEL], 255, 0).astype(np.uint8)
        whole = row.tolist()
        parts = opencv_split(camera, mask, x0, y0, radius_m, min_area_px, whole)
        rows.extend(parts)
        tally["merged"] += 1
        tally["kept whole" if parts[0] is whole else f"in {len(parts)}"] += 1
        tally["near the border"] += min(x0, y0, width - x1, height - y1) <= 3
    return rows


def merged_scene(rng: np.random.Generator, camera: Camera) -> list[Sphere]:
    """Two or three spheres of different sizes overlapping in the image: the first at a random bearing (one scene in
    four by a border of the image) and range (one in four far, a small blob), the others a fraction of its angular
    radius away, a little nearer or farther."""
    half_h, half_v = camera.config.fov_h_rad / 2.0, camera.fov_v_rad / 2.0
    azimuth, elevation = rng.uniform(-0.8, 0.8) * half_h, rng.uniform(-0.8, 0.8) * half_v
    if rng.random() < 0.25:  # the centre 80 to 100 % of the way out to a border
        out = rng.uniform(0.8, 1.0) * rng.choice((-1.0, 1.0))
        if rng.random() < 0.5:
            azimuth = math.atan(out * math.tan(half_h))
        else:
            elevation = math.atan(out * math.tan(half_v))
    distance = rng.uniform(8.0, 16.0) if rng.random() < 0.25 else math.exp(rng.uniform(math.log(1.5), math.log(8.0)))
    bodies: list[Sphere] = []
    for k in range(int(rng.integers(2, 4))):
        if k > 0:
            reach = math.asin(min(0.99, bodies[0].radius_m / distance)) * rng.uniform(0.7, 1.7)
            turn = rng.uniform(-math.pi, math.pi)
            azimuth, elevation = azimuth + reach * math.cos(turn), elevation + reach * math.sin(turn)
            distance = distance * rng.uniform(0.8, 1.3)
        direction = (math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth),
                     -math.sin(elevation))  # fmt: skip
        bodies.append(Sphere(offset_ned_m=tuple(distance * c for c in direction), radius_m=rng.uniform(0.2, 0.5)))
    return bodies


@pytest.mark.parametrize("seed", range(4))
def test_a_merged_blob_is_split_in_the_pass_as_opencv_split_it_to_the_bit(seed: int) -> None:
    # GIVEN cameras of two sizes, with and without noise, and scenes of overlapping spheres (merged blobs)
    rng = np.random.default_rng(100 + seed)
    cameras = [
        Camera(CameraConfig(noise_seed=seed)),
        Camera(CameraConfig(width_px=240, height_px=180, pixel_noise_sigma=0.0)),
    ]
    tally: Counter[str] = Counter()
    for trial in range(300):
        camera = cameras[trial % 2]
        image = render(camera, (1.0, 0.0, 0.0, 0.0), merged_scene(rng, camera), rng).copy()
        # WHEN the pass searches the image, and the Python of old splits its merged blobs with OpenCV
        n = _image_rows(image, camera, 0, 0, R_M, 3)
        got = _Rows.table[:n].copy()
        want = np.array(opencv_rows(image, camera, R_M, 3, tally), dtype=np.float64).reshape(-1, dk.ROW_SIZE)
        # THEN both give the same rows, every bit (signed zeros too)
        assert got.shape == want.shape
        assert np.array_equal(got.view(np.int64), want.view(np.int64)), trial
    # AND the scenes held every way a split ends: in two, the near body alone, the blob kept whole; by a border too
    assert tally["merged"] >= 100 and tally["in 2"] >= 90, tally
    assert tally["in 1"] >= 1 and tally["kept whole"] >= 1 and tally["near the border"] >= 1, tally
