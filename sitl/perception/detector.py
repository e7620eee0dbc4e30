"""Blob detector: bright bodies in a camera frame -> bearing and range, from the image alone.

The detector knows the camera (intrinsics, mount, the grey levels it was tuned for) and, as a prior, the physical
radius of a drone; it does not know where anything is. Per blob:

1. threshold half way between background and body level, so a pixel counts when it is more than half covered;
2. outer contours, then pixel moments of each blob (not contour moments, which lose half a pixel all round and
   would make a 2 px blob look 40 % smaller; not connectedComponentsWithStats, 70 us a frame against 5 us here);
3. the blob is taken to be the exact image of a sphere (an ellipse, stretched radially off axis): its centroid and
   its pixel area fix, through ``sphere_silhouette``, the direction of the sphere's centre and its angular radius
   alpha, and range = radius / sin(alpha). Using the area (every pixel votes) rather than a fitted radius keeps
   range errors a few per cent down to 2 px blobs.

Blobs that are not the image of one whole sphere use the fact that a sphere's outline is a circle of rays around
its centre direction (a cone), so an arc of it fixes both direction and angular radius (``_fit_cone``):

- truncated (touching the image border): the cone is fitted to the outline inside the frame. With the body's centre
  in the frame this is as good as a whole blob; with most of the body outside, a sliver with under 8 outline pixels
  falls back to the visible centroid and the larger of the area-equivalent radius and half the blob's extent along
  the cut border, which can put ``range_m`` far too long. Flagged ``truncated``: treat the range with caution.
- merged (a near body partly in front of a far one, or two bodies side by side): detected when the blob is more
  elongated than one sphere at that place can be. The nearest body is whole (nothing is in front of it): the largest
  inscribed circle (distance transform peak) finds it, and the cone fitted to the outline pixels on that circle
  gives its bearing and range; if that silhouette covers under 45 % of the blob (impossible for equal bodies, so
  the fit failed) the blob is reported as one body from its whole area instead. Otherwise the silhouette is erased
  and a large enough remainder is reported as a second body with the bearing of its centroid and a range from its
  visible area, hence too long. All carry ``merged``. A far body almost wholly hidden leaves a sliver not elongated
  enough to notice: the blob then reads as the near body slightly enlarged (range errs short, the safe side). Three
  or more bodies in one blob yield at most two.

Obstacles that are not drone-sized (a pole, a building) yield ranges computed as if they were a drone: far too
short for larger ones (the safe side), and usually flagged truncated when they fill the frame.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from sitl.kernels import detector as dk
from sitl.mathutil import fast_constructor, quat_to_dcm
from sitl.perception.camera import Camera, CameraRig, GrayImage, sphere_silhouette

# A blob of this many pixels or more is checked for being two bodies; below it pixelation alone makes shapes vary.
_MERGE_CHECK_MIN_AREA_PX = 30
# Measured elongation beyond this multiple of one sphere's elongation means several bodies.
_MERGE_ELONGATION_RATIO = 1.25
# The nearest body of a merged blob covers at least this share of it (half, less pixelation and fit error).
_NEAREST_MIN_SHARE = 0.45
# The remainder of a merged blob is a body when at least this fraction of the near body's area.
_REMAINDER_MIN_FRACTION = 0.05
# A blob cut by the top or bottom border and at least this many times taller than wide is an upright structure.
_UPRIGHT_ASPECT = 2.0
# Detections from two cameras of a rig closer than this (or than the larger angular radius) are one body.
_DUPLICATE_ANGLE_RAD = math.radians(3.0)
# A pair whose cosine is this far below a threshold's cosine is apart whatever the last bits of either.
_COSINE_MARGIN = 1e-9


@dataclass(frozen=True, slots=True, kw_only=True)
class Detection:
    """One body seen in one frame.

    ``azimuth_rad`` (positive right) and ``elevation_rad`` (positive up) are in the camera frame; ``unit_frd`` is
    the same direction in the body FRD frame, ready to rotate into NED with the drone's attitude estimate.
    """

    camera_name: str
    centroid_px: tuple[float, float]
    area_px: int
    azimuth_rad: float
    elevation_rad: float
    unit_frd: tuple[float, float, float]
    range_m: float
    angular_radius_rad: float
    truncated: bool
    merged: bool


def _solve_sphere(c_n: float, target: float, *, by_area: bool) -> tuple[float, float, float, float]:
    """Invert the sphere silhouette: from its centre distance and its area (or across-axis semi-axis), all in
    normalised units, to (theta, alpha, radial semi-axis, across semi-axis) (the kernel ``solve_sphere``)."""
    return dk.solve_sphere(c_n, target, by_area)


# A frame of a crowd yields dozens of detections, at the camera rate on every drone: built through its slots (the
# same frozen record) at a third of the cost of its ``__init__`` (sitl/mathutil.py).
_new_detection = fast_constructor(Detection)


def _ray(camera: Camera, u: float, v: float, theta: float) -> tuple[float, float, float]:
    """Unit vector (camera frame) theta off the optical axis, in the image direction of pixel (u, v)."""
    return dk.ray(camera.kernel_row, u, v, theta)


def _make(
    camera: Camera,
    centroid_px: tuple[float, float],
    vec_cam: tuple[float, float, float],
    alpha: float,
    area_px: int,
    known_body_radius_m: float,
    *,
    truncated: bool,
    merged: bool,
) -> Detection:
    azimuth, elevation = dk.bearing(vec_cam[0], vec_cam[1], vec_cam[2])
    return _new_detection(
        camera_name=camera.config.name,
        centroid_px=centroid_px,
        area_px=area_px,
        azimuth_rad=azimuth,
        elevation_rad=elevation,
        unit_frd=camera.camera_to_body(vec_cam),
        range_m=known_body_radius_m / math.sin(alpha) if alpha > 0.0 else math.inf,
        angular_radius_rad=alpha,
        truncated=truncated,
        merged=merged,
    )


def _normalised(camera: Camera, u: float, v: float) -> float:
    return dk.normalised(camera.kernel_row, u, v)


def _elongation(m: dict[str, float]) -> float:
    """Major over minor axis of a pixel set from its central moments (less the 1/12 px^2 each pixel adds)."""
    area = m["m00"]
    mu20, mu02, mu11 = m["mu20"] / area, m["mu02"] / area, m["mu11"] / area
    mean = (mu20 + mu02) / 2.0
    half_diff = math.hypot((mu20 - mu02) / 2.0, mu11)
    major, minor = mean + half_diff - 1.0 / 12.0, mean - half_diff - 1.0 / 12.0
    return math.sqrt(major / minor) if minor > 0.0 else math.inf


def _fit_cone(
    camera: Camera, boundary_px: npt.NDArray[np.float64], vec: tuple[float, float, float], alpha: float, *, select: bool
) -> tuple[tuple[float, float, float], float] | None:
    """Refine a sphere's centre direction and angular radius from boundary pixels of its image.

    The image of a sphere is bounded by the rays u with axis . u = cos(alpha): points of a plane, so a linear
    least-squares fit n . u = 1 gives axis = n / |n| and cos(alpha) = 1 / |n| wherever the sphere sits in the image
    (no ellipse model needed), from any arc of its outline. Boundary pixel centres lie about half a pixel inside the
    true edge, so each is moved half a pixel out from the current silhouette centre. With ``select`` only pixels
    within a pixel and a half of the current cone take part from the start (this drops the outline of other bodies
    in a merged blob); otherwise all do at first, then the outliers are dropped. Fewer than 8 points leave the
    estimate unchanged (None). Short arcs are not refused: even a sixth of the outline beat the fallback estimate
    for bodies mostly outside the frame (docs/perception.md).
    """
    fitted, ax, ay, az, fitted_alpha = dk.fit_cone(
        camera.kernel_row, np.ascontiguousarray(boundary_px, dtype=np.float64), vec[0], vec[1], vec[2], alpha, select
    )
    return ((ax, ay, az), fitted_alpha) if fitted else None


def _inscribed_peak(padded: npt.NDArray[Any]) -> tuple[int, int, float]:
    """Column, row and distance to the background of the blob pixel farthest from it (the first in row order of
    those equally far): the centre of the largest inscribed circle.

    OpenCV's precise distance transform is the exact Euclidean one, but its float32 square roots are not reproducible:
    the same mask gives a distance a last bit apart from one call to the next (its vector and scalar code paths round
    differently, and which pixels take which depends on where its buffers lie in memory), and a bit decides between
    equally far pixels, so the same frame could yield detections that differ in the twelfth digit, or by a pixel's
    choice of peak, and two runs of the same swarm flight drifted apart. The squared distances are integers (pixel
    offsets), recovered exactly from the float32 distances (relative error 6e-8, squared distances under 2^20), and
    the peak is taken on them."""
    dist = cv2.distanceTransform(padded, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    squared = np.rint(dist.astype(np.float64) ** 2)
    flat = int(np.argmax(squared))
    pv, pu = divmod(flat, squared.shape[1])
    return pu, pv, math.sqrt(float(squared.flat[flat]))


def _split_merged(
    camera: Camera, mask: GrayImage, x0: int, y0: int, known_body_radius_m: float, min_area_px: int, whole: Detection
) -> list[Detection]:
    """The nearest body from the largest inscribed circle of the blob, refined on its arc of the blob boundary,
    then what is left of the blob once that body's silhouette is erased.

    Bodies share one size, so the nearest looks the largest and its whole silhouette covers at least half the blob;
    a split that finds less has measured the wrong arc (small blobs), and the blob is reported as one body instead
    (``whole``: its area-based range is short of the nearest body's, the safe side).
    """
    padded = cv2.copyMakeBorder(mask, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
    pu, pv, peak = _inscribed_peak(padded)
    u, v = x0 + pu - 1.0, y0 + pv - 1.0
    f = camera.focal_px
    # The distance transform at the centre of a pixel disc of radius R is about R + 0.5 (distance to the centre of
    # the first pixel outside it).
    theta, alpha, _, _ = _solve_sphere(_normalised(camera, u, v), max(peak - 0.5, 0.5) / f, by_area=False)
    vec = _ray(camera, u, v, theta)
    contours, _ = cv2.findContours(padded, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    boundary = np.concatenate([c[:, 0, :] for c in contours]).astype(np.float64)
    boundary += (x0 - 1.0, y0 - 1.0)
    fitted = _fit_cone(camera, boundary, vec, alpha, select=True)
    if fitted is not None:
        vec, alpha = fitted
        theta = math.acos(min(1.0, vec[0]))
    c_n, a_n, b_n = sphere_silhouette(theta, math.sin(alpha))
    rho = math.hypot(vec[1], vec[2])
    py, pz = (vec[1] / rho, vec[2] / rho) if rho > 0.0 else (1.0, 0.0)
    uc, vc = camera.cx_px + f * c_n * py, camera.cy_px + f * c_n * pz
    near_area = round(math.pi * a_n * b_n * f * f)
    if near_area < _NEAREST_MIN_SHARE * whole.area_px:
        return [whole]
    found = [_make(camera, (uc, vc), vec, alpha, near_area, known_body_radius_m, truncated=False, merged=True)]
    # Erase the near body's silhouette, a pixel larger all round, and look at what is left.
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
    if best is not None and best[0] >= max(min_area_px, _REMAINDER_MIN_FRACTION * near_area):
        area, ru, rv = best
        theta, alpha, _, _ = _solve_sphere(_normalised(camera, ru, rv), area / (f * f), by_area=True)
        found.append(
            _make(
                camera,
                (ru, rv),
                _ray(camera, ru, rv, theta),
                alpha,
                round(area),
                known_body_radius_m,
                truncated=False,
                merged=True,
            )
        )
    return found


def _truncated(
    camera: Camera, contour: npt.NDArray[Any], centroid_px: tuple[float, float], area_px: int, radius_m: float
) -> Detection:
    """A blob cut by the image border: fit the sphere's cone to the part of its outline inside the frame; when
    that arc is too short, fall back to the visible centroid and the larger of the area-equivalent radius and half
    the extent along the cut border (both only bound the body from one side)."""
    cfg = camera.config
    w, h = cfg.width_px, cfg.height_px
    u, v = centroid_px
    x, y, bw, bh = cv2.boundingRect(contour)
    if (y == 0 or y + bh == h) and x > 0 and x + bw < w and bh >= _UPRIGHT_ASPECT * bw:
        # Cut by the top or bottom only, and much taller than wide: something upright that leaves the frame (a
        # pole), not a sphere cut by the border (whose visible cap is wider than tall). Its outline is two straight
        # edges with no arc to fit, and its area says only how much of it the frame holds: the width is the one
        # size cue, read with the body-size prior. A pole thinner than a drone
        # reads a little far (0.25 m at 6 m reads 8.4 m); the area or a cone fitted to the straight edges read it
        # at 1-2 m wherever it was, so a camera that kept it in view (the side cameras of the omni rig) steered away
        # from it for as long as it saw it.
        vec = _ray(camera, u, v, math.atan(_normalised(camera, u, v)))  # the centroid's own direction
        return _make(camera, centroid_px, vec, math.atan((bw / 2.0) / camera.focal_px), area_px, radius_m,
                     truncated=True, merged=False)  # fmt: skip
    half_extent = max(bh if x == 0 or x + bw == w else 0, bw if y == 0 or y + bh == h else 0) / 2.0
    b_px = max(math.sqrt(area_px / math.pi), half_extent)
    theta, alpha, _, _ = _solve_sphere(_normalised(camera, u, v), b_px / camera.focal_px, by_area=False)
    vec = _ray(camera, u, v, theta)
    pts = contour[:, 0, :]
    inner = pts[(pts[:, 0] > 0) & (pts[:, 0] < w - 1) & (pts[:, 1] > 0) & (pts[:, 1] < h - 1)].astype(np.float64)
    fitted = _fit_cone(camera, inner, vec, alpha, select=False) if len(inner) >= 8 else None
    if fitted is not None:
        vec, alpha = fitted
    return _make(camera, centroid_px, vec, alpha, area_px, radius_m, truncated=True, merged=False)


def detect(image: GrayImage, camera: Camera, known_body_radius_m: float, *, min_area_px: int = 3) -> list[Detection]:
    """Bodies in one frame of ``camera`` (uint8 H x W), largest blob first.

    ``known_body_radius_m`` is the prior on a body's size (a drone's collision radius); ``min_area_px`` rejects
    specks smaller than a drone at the camera's maximum range would be.
    """
    cfg = camera.config
    h, w = cfg.height_px, cfg.width_px
    binary = camera.binary_scratch
    cv2.threshold(image, cfg.threshold_level - 1, 255, cv2.THRESH_BINARY, dst=binary)
    contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    boxes = [cv2.boundingRect(c) for c in contours]
    f = camera.focal_px
    found: list[Detection] = []
    for i, (contour, (x, y, bw, bh)) in enumerate(zip(contours, boxes, strict=True)):
        roi: GrayImage = binary[y : y + bh, x : x + bw]
        if any(
            j != i and x < ox + ow and ox < x + bw and y < oy + oh and oy < y + bh
            for j, (ox, oy, ow, oh) in enumerate(boxes)
        ):
            # Another blob reaches into this one's box: count only this blob's pixels.
            mask = camera.mask_scratch[y : y + bh, x : x + bw]
            mask.fill(0)
            cv2.drawContours(mask, [contour], -1, 255, -1, offset=(-x, -y))
            cv2.bitwise_and(mask, roi, dst=mask)
            roi = mask
        m = cv2.moments(roi, True)
        area = m["m00"]
        if area < min_area_px:
            continue
        u, v = x + m["m10"] / area, y + m["m01"] / area
        truncated = x == 0 or y == 0 or x + bw == w or y + bh == h
        c_n = _normalised(camera, u, v)
        if truncated:
            found.append(_truncated(camera, contour, (u, v), int(area), known_body_radius_m))
            continue
        theta, alpha, a_n, b_n = _solve_sphere(c_n, area / (f * f), by_area=True)
        merged = area >= _MERGE_CHECK_MIN_AREA_PX and _elongation(m) > _MERGE_ELONGATION_RATIO * a_n / b_n
        single = _make(
            camera,
            (u, v),
            _ray(camera, u, v, theta),
            alpha,
            int(area),
            known_body_radius_m,
            truncated=False,
            merged=merged,
        )
        if merged:
            found.extend(_split_merged(camera, roi, x, y, known_body_radius_m, min_area_px, single))
        else:
            found.append(single)
    found.sort(key=lambda det: det.area_px, reverse=True)
    return found


def detect_rig(
    images: Sequence[GrayImage | None], rig: CameraRig, known_body_radius_m: float, *, min_area_px: int = 3
) -> list[Detection]:
    """Detections of every camera of a rig; a body seen by two overlapping cameras is kept once, preferring the
    view where it is whole (not truncated), then the larger one. None stands for a frame known to hold nothing
    (``render_rig_if_drawn``)."""
    found = [
        det
        for image, camera in zip(images, rig.cameras, strict=True)
        if image is not None
        for det in detect(image, camera, known_body_radius_m, min_area_px=min_area_px)
    ]
    found.sort(key=lambda det: (det.truncated, -det.area_px))
    kept: list[Detection] = []
    # Per kept detection: its camera, direction, and the cosine of the largest angle it alone would call the same
    # body. Two are one body when the angle between them is below the larger of both thresholds: when the cosine of
    # that angle is clearly below the smaller of both cosines (by far more than rounding), the arc cosine is not
    # needed to say no, and most pairs in a crowd are far apart.
    seen: list[tuple[str, float, float, float, float]] = []
    for det in found:
        ax, ay, az = det.unit_frd
        own_cos = math.cos(max(_DUPLICATE_ANGLE_RAD, det.angular_radius_rad))
        duplicate = False
        for (name, bx, by, bz, other_cos), other in zip(seen, kept, strict=True):
            if name == det.camera_name:
                continue
            dot = bx * ax + by * ay + bz * az  # as ``_angle_between`` computes it
            if dot < min(own_cos, other_cos) - _COSINE_MARGIN:
                continue
            if _angle_between(other.unit_frd, det.unit_frd) < max(
                _DUPLICATE_ANGLE_RAD, other.angular_radius_rad, det.angular_radius_rad
            ):
                duplicate = True
                break
        if not duplicate:
            kept.append(det)
            seen.append((det.camera_name, ax, ay, az, own_cos))
    return kept


def _angle_between(a: tuple[float, float, float], b: tuple[float, float, float]) -> float:
    dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    return math.acos(max(-1.0, min(1.0, dot)))


def to_ned_all(
    detections: Sequence[Detection], own_att_q_frd_to_ned: npt.ArrayLike
) -> list[tuple[float, float, float]]:
    """``to_ned`` of every detection of a frame, the rotation worked out once: the same figures to the last bit (each
    product and sum in the same order, on the same float64 values)."""
    if not detections:
        return []
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = quat_to_dcm(
        np.asarray(own_att_q_frd_to_ned, dtype=np.float64)
    ).tolist()
    out = []
    for detection in detections:
        range_m = detection.range_m
        ux, uy, uz = detection.unit_frd
        x, y, z = ux * range_m, uy * range_m, uz * range_m
        out.append((r00 * x + r01 * y + r02 * z, r10 * x + r11 * y + r12 * z, r20 * x + r21 * y + r22 * z))
    return out


def to_ned(detection: Detection, own_att_q_frd_to_ned: npt.ArrayLike) -> tuple[float, float, float]:
    """Position of the detected body relative to the drone, NED metres, using the drone's ESTIMATED attitude."""
    r = quat_to_dcm(np.asarray(own_att_q_frd_to_ned, dtype=np.float64))
    x, y, z = (c * detection.range_m for c in detection.unit_frd)
    return (
        float(r[0, 0] * x + r[0, 1] * y + r[0, 2] * z),
        float(r[1, 0] * x + r[1, 1] * y + r[1, 2] * z),
        float(r[2, 0] * x + r[2, 1] * y + r[2, 2] * z),
    )
