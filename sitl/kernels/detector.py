"""The detector's per-blob arithmetic (sitl/kernels/frame.py runs it on every blob of a frame;
sitl/perception/detector.py is the shell: the records).

Inverting a blob's area into a sphere's direction and size (Newton on the silhouette), the pixel ray at an angle off
axis, the cone fit to a blob's outline, a whole, truncated or merged blob solved into detection rows, and a rig's
rows sorted, rid of the bodies two cameras saw and turned into NED: the same operations in the same order as the
Python they replaced, with CPython's ``math.hypot``, Python's ``max`` and ``round`` and numpy's pairwise sums
(sitl/kernels/pymath.py), so detections keep their bits. The split of a merged blob takes its pixel work from
sitl/kernels/blobs.py (the exact distance transform, the outer border, OpenCV's filled ellipse). The method is
sitl/perception/detector.py's docstring.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from sitl.kernels import kernel
from sitl.kernels.blobs import (
    BLOB_SIZE,
    K_LABEL,
    K_START,
    K_U0,
    K_U1,
    K_V0,
    K_V1,
    UNLABELLED,
    box_moments,
    fill_ellipse,
    label,
    opencv_order,
    outer_border,
    round_half_even,
    squared_distances,
)
from sitl.kernels.pymath import hypot2, np_sum, pmax, pmin, py_square
from sitl.kernels.render import B_U0, B_U1, B_V0, B_V1, BOX_SIZE, P_CX, P_CY, P_FOCAL, sphere_silhouette

# A camera's row is the renderer's (sitl/kernels/render.py): focal length and principal point in pixels.
C_FOCAL = P_FOCAL
C_CX = P_CX
C_CY = P_CY

# A blob of this many pixels or more is checked for being two bodies; below it pixelation alone makes shapes vary.
MERGE_CHECK_MIN_AREA_PX = 30
# Measured elongation beyond this multiple of one sphere's elongation means several bodies.
MERGE_ELONGATION_RATIO = 1.25
# The nearest body of a merged blob covers at least this share of it (half, less pixelation and fit error).
NEAREST_MIN_SHARE = 0.45
# The remainder of a merged blob is a body when at least this fraction of the near body's area.
REMAINDER_MIN_FRACTION = 0.05
# The nearest body's silhouette is erased this much larger all round (pixels), drawn with this many fraction bits.
ERASE_MARGIN_PX = 1.0
ERASE_SHIFT = 4
# A blob cut by the top or bottom border and at least this many times taller than wide is an upright structure.
UPRIGHT_ASPECT = 2.0
# Detections from two cameras of a rig closer than this (or than the larger angular radius) are one body.
DUPLICATE_ANGLE_RAD = math.radians(3.0)
# A pair whose cosine is this far below a threshold's cosine is apart whatever the last bits of either.
COSINE_MARGIN = 1e-9

# A detection row (float64), as the records' fields (sitl/perception/detector.py, ``Detection``): the camera's index
# in its rig, the centroid, the pixel area, azimuth and elevation in the camera frame, the unit direction in body
# FRD, range, angular radius, the flags.
R_CAMERA = 0
R_U = 1
R_V = 2
R_AREA = 3
R_AZIMUTH = 4
R_ELEVATION = 5
R_FRD_X = 6
R_FRD_Y = 7
R_FRD_Z = 8
R_RANGE = 9
R_ALPHA = 10
R_TRUNCATED = 11
R_MERGED = 12
ROW_SIZE = 13
# What a pass returns when ``rows`` has no room for another row (the shell grows it and runs the pass again).
ROWS_FULL = -2


@kernel("UniTuple(float64, 2)(float64, float64)")
def across_axis(c_n: float, a_n: float) -> tuple[float, float]:
    """Across-axis semi-axis b of a sphere's image, and db/da, given its centre distance c and radial semi-axis a
    (normalised units, focal length 1).

    The radial extremes of the ellipse are t1 = tan(theta - alpha) = c - a and t2 = tan(theta + alpha) = c + a, and
    b = sin(alpha) / sqrt(cos(theta - alpha) cos(theta + alpha)) = sin(alpha) ((1 + t1^2)(1 + t2^2))^(1/4).
    """
    t1, t2 = c_n - a_n, c_n + a_n
    q1, q2 = 1.0 + t1 * t1, 1.0 + t2 * t2
    alpha = (math.atan(t2) - math.atan(t1)) / 2.0
    root4 = (q1 * q2) ** 0.25
    d_alpha = (1.0 / q2 + 1.0 / q1) / 2.0
    d_product = 2.0 * (t2 * q1 - t1 * q2)
    sin_a = math.sin(alpha)
    return sin_a * root4, math.cos(alpha) * d_alpha * root4 + sin_a * 0.25 * root4 / (q1 * q2) * d_product


@kernel("UniTuple(float64, 4)(float64, float64, boolean)")
def solve_sphere(c_n: float, target: float, by_area: bool) -> tuple[float, float, float, float]:
    """Invert the sphere silhouette: from its centre distance and its area (or across-axis semi-axis), all in
    normalised units, to (theta, alpha, radial semi-axis, across semi-axis).

    Newton's method on the radial semi-axis from the small-angle guess, kept inside a shrinking bracket; area and
    across-axis semi-axis both grow with it. Two or three iterations at drone ranges.
    """
    stretch = math.sqrt(1.0 + c_n * c_n)
    a_n = math.sqrt(target / math.pi * stretch) if by_area else target * stretch
    lo, hi = 0.0, math.inf
    b_n = 0.0
    for _ in range(40):
        b_n, slope = across_axis(c_n, a_n)
        if by_area:
            err, slope = math.pi * a_n * b_n - target, math.pi * (b_n + a_n * slope)
        else:
            err = b_n - target
        if abs(err) <= 1e-8 * target:
            break
        if err > 0.0:
            hi = a_n
        else:
            lo = a_n
        nxt = a_n - err / slope if slope > 0.0 else math.nan
        if not lo < nxt < hi:
            nxt = 0.5 * (lo + hi) if hi < math.inf else 2.0 * a_n
        a_n = nxt
    t1, t2 = math.atan(c_n - a_n), math.atan(c_n + a_n)
    return (t1 + t2) / 2.0, (t2 - t1) / 2.0, a_n, b_n


@kernel("float64(float64[::1], float64, float64)")
def normalised(camera: npt.NDArray[np.float64], u: float, v: float) -> float:
    """Distance of pixel (u, v) from the principal point, in focal lengths."""
    return hypot2(u - camera[C_CX], v - camera[C_CY]) / camera[C_FOCAL]


@kernel("UniTuple(float64, 3)(float64[::1], float64, float64, float64)")
def ray(camera: npt.NDArray[np.float64], u: float, v: float, theta: float) -> tuple[float, float, float]:
    """Unit vector (camera frame) theta off the optical axis, in the image direction of pixel (u, v)."""
    f = camera[C_FOCAL]
    xn, yn = (u - camera[C_CX]) / f, (v - camera[C_CY]) / f
    rho = hypot2(xn, yn)
    if rho > 0.0:
        py, pz = xn / rho, yn / rho
    else:
        py, pz = 1.0, 0.0
    sin_t = math.sin(theta)
    return (math.cos(theta), sin_t * py, sin_t * pz)


@kernel("UniTuple(float64, 2)(float64, float64, float64)")
def bearing(x: float, y: float, z: float) -> tuple[float, float]:
    """Azimuth (positive right) and elevation (positive up) of a camera-frame direction."""
    return math.atan2(y, x), math.atan2(-z, hypot2(x, y))


@kernel("float64[::1](float64[::1], float64[::1], float64[::1])")
def _product(
    a: npt.NDArray[np.float64], b: npt.NDArray[np.float64], out: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """``out[:] = a * b``, element by element (as numpy's ``a * b``), returned."""
    for i in range(a.shape[0]):
        out[i] = a[i] * b[i]
    return out


@kernel(
    "Tuple((boolean, float64, float64, float64, float64))"
    "(float64[::1], float64[:, ::1], float64, float64, float64, float64, boolean)"
)
def fit_cone(
    camera: npt.NDArray[np.float64],
    boundary_px: npt.NDArray[np.float64],
    ax: float,
    ay: float,
    az: float,
    alpha: float,
    select: bool,
) -> tuple[bool, float, float, float, float]:
    """Refine a sphere's centre direction and angular radius from boundary pixels of its image: (fitted, direction,
    angular radius), or (False, the inputs) when the fit is refused.

    The image of a sphere is bounded by the rays u with axis . u = cos(alpha): points of a plane, so a linear
    least-squares fit n . u = 1 gives axis = n / |n| and cos(alpha) = 1 / |n| wherever the sphere sits in the image
    (no ellipse model needed), from any arc of its outline. Boundary pixel centres lie about half a pixel inside the
    true edge, so each is moved half a pixel out from the current silhouette centre. With ``select`` only pixels
    within a pixel and a half of the current cone take part from the start (this drops the outline of other bodies
    in a merged blob); otherwise all do at first, then the outliers are dropped. Fewer than 8 points leave the
    estimate unchanged. Short arcs are not refused: even a sixth of the outline beat the fallback estimate for
    bodies mostly outside the frame (docs/perception.md).
    """
    f = camera[C_FOCAL]
    cx = camera[C_CX]
    cy = camera[C_CY]
    f_sq = f * f
    tolerance = 1.5 / f
    n = boundary_px.shape[0]
    rx = np.empty(n)
    ry = np.empty(n)
    rz = np.empty(n)
    prod = np.empty(n)
    for iteration in range(2):
        sin_a = math.sin(alpha)
        if ax <= 0.0 or ax * ax - sin_a * sin_a <= 0.02:
            return False, ax, ay, az, alpha
        c_n, _a, _b = sphere_silhouette(math.acos(min(1.0, ax)), sin_a)
        rho = hypot2(ay, az)
        if rho > 0.0:
            py, pz = ay / rho, az / rho
        else:
            py, pz = 1.0, 0.0
        centre_u = cx + f * c_n * py
        centre_v = cy + f * c_n * pz
        cos_alpha = math.cos(alpha)
        m = 0
        for i in range(n):
            bu = boundary_px[i, 0]
            bv = boundary_px[i, 1]
            du, dv = bu - centre_u, bv - centre_v
            push = 0.5 / max(math.sqrt(du * du + dv * dv), 1e-9)
            qy, qz = (bu - cx) + du * push, (bv - cy) + dv * push
            inv = 1.0 / math.sqrt(f_sq + qy * qy + qz * qz)
            qx, qy, qz = f * inv, qy * inv, qz * inv
            if (select or iteration > 0) and not abs(qx * ax + qy * ay + qz * az - cos_alpha) <= tolerance * sin_a:
                continue  # |angle to axis - alpha| > tolerance, to first order in cosines
            rx[m] = qx
            ry[m] = qy
            rz[m] = qz
            m += 1
        if select or iteration > 0:
            tolerance = 1.0 / f
        if m < 8:
            return False, ax, ay, az, alpha
        px_ = rx[:m]
        py_ = ry[:m]
        pz_ = rz[:m]
        sxx = np_sum(_product(px_, px_, prod[:m]))
        syy = np_sum(_product(py_, py_, prod[:m]))
        szz = np_sum(_product(pz_, pz_, prod[:m]))
        sxy = np_sum(_product(px_, py_, prod[:m]))
        sxz = np_sum(_product(px_, pz_, prod[:m]))
        syz = np_sum(_product(py_, pz_, prod[:m]))
        r0, r1, r2 = np_sum(px_), np_sum(py_), np_sum(pz_)
        # Cramer's rule on the symmetric normal equations.
        a, b, c = sxx, sxy, sxz
        d, e, f3 = sxy, syy, syz
        g, h, k = sxz, syz, szz
        co0, co1, co2 = e * k - f3 * h, f3 * g - d * k, d * h - e * g
        det = a * co0 + b * co1 + c * co2
        if abs(det) < 1e-12:
            return False, ax, ay, az, alpha
        n0 = (r0 * co0 + b * (f3 * r2 - r1 * k) + c * (r1 * h - e * r2)) / det
        n1 = (a * (r1 * k - f3 * r2) + r0 * co1 + c * (d * r2 - r1 * g)) / det
        n2 = (a * (e * r2 - r1 * h) + b * (r1 * g - d * r2) + r0 * co2) / det
        length = math.sqrt(py_square(n0) + py_square(n1) + py_square(n2))
        if length <= 1.0:
            return False, ax, ay, az, alpha
        ax, ay, az, alpha = n0 / length, n1 / length, n2 / length, math.acos(1.0 / length)
    return True, ax, ay, az, alpha


@kernel(
    "void(float64[::1], float64[:, ::1], int64, float64, float64, float64, float64, float64, float64, float64, float64,"
    " boolean, boolean)"
)
def make_row(
    row: npt.NDArray[np.float64],
    rot_body_cam: npt.NDArray[np.float64],
    camera_index: int,
    u: float,
    v: float,
    vx: float,
    vy: float,
    vz: float,
    alpha: float,
    area_px: float,
    radius_m: float,
    truncated: bool,
    merged: bool,
) -> None:
    """A detection row from a camera-frame direction and an angular radius (the body's size prior gives the range)."""
    azimuth, elevation = bearing(vx, vy, vz)
    row[R_CAMERA] = camera_index
    row[R_U] = u
    row[R_V] = v
    row[R_AREA] = area_px
    row[R_AZIMUTH] = azimuth
    row[R_ELEVATION] = elevation
    row[R_FRD_X] = rot_body_cam[0, 0] * vx + rot_body_cam[0, 1] * vy + rot_body_cam[0, 2] * vz
    row[R_FRD_Y] = rot_body_cam[1, 0] * vx + rot_body_cam[1, 1] * vy + rot_body_cam[1, 2] * vz
    row[R_FRD_Z] = rot_body_cam[2, 0] * vx + rot_body_cam[2, 1] * vy + rot_body_cam[2, 2] * vz
    row[R_RANGE] = radius_m / math.sin(alpha) if alpha > 0.0 else math.inf
    row[R_ALPHA] = alpha
    row[R_TRUNCATED] = 1.0 if truncated else 0.0
    row[R_MERGED] = 1.0 if merged else 0.0


@kernel("float64(float64, float64, float64, float64)")
def elongation(m00: float, mu20: float, mu11: float, mu02: float) -> float:
    """Major over minor axis of a pixel set from its central moments (less the 1/12 px^2 each pixel adds)."""
    area = m00
    mu20, mu02, mu11 = mu20 / area, mu02 / area, mu11 / area
    mean = (mu20 + mu02) / 2.0
    half_diff = hypot2((mu20 - mu02) / 2.0, mu11)
    major, minor = mean + half_diff - 1.0 / 12.0, mean - half_diff - 1.0 / 12.0
    return math.sqrt(major / minor) if minor > 0.0 else math.inf


@kernel(
    "void(float64[::1], float64[:, ::1], int32[:, ::1], int64[::1], int32[:, ::1], float64, float64, float64,"
    " float64, int64, float64[::1])"
)
def solve_truncated(
    camera: npt.NDArray[np.float64],
    rot_body_cam: npt.NDArray[np.float64],
    labels: npt.NDArray[np.int32],
    blob: npt.NDArray[np.int64],
    points: npt.NDArray[np.int32],
    u: float,
    v: float,
    area_px: float,
    radius_m: float,
    camera_index: int,
    row: npt.NDArray[np.float64],
) -> None:
    """A blob cut by the image border: the sphere's cone fitted to the part of its outline inside the frame; when
    that arc is too short, the visible centroid and the larger of the area-equivalent radius and half the extent
    along the cut border (both only bound the body from one side). A blob cut by the top or bottom only and much
    taller than wide is something upright leaving the frame (a pole): its width is the one size cue."""
    h, w = labels.shape
    f = camera[C_FOCAL]
    x, y = blob[K_U0], blob[K_V0]
    bw, bh = blob[K_U1] - x, blob[K_V1] - y
    if (y == 0 or y + bh == h) and x > 0 and x + bw < w and bh >= UPRIGHT_ASPECT * bw:
        vx, vy, vz = ray(camera, u, v, math.atan(normalised(camera, u, v)))  # the centroid's own direction
        alpha = math.atan((bw / 2.0) / f)
        make_row(row, rot_body_cam, camera_index, u, v, vx, vy, vz, alpha, area_px, radius_m, True, False)
        return
    across = bh if x == 0 or x + bw == w else 0
    along = bw if y == 0 or y + bh == h else 0
    half_extent = max(across, along) / 2.0
    b_px = pmax(math.sqrt(area_px / math.pi), half_extent)
    theta, alpha, _a, _b = solve_sphere(normalised(camera, u, v), b_px / f, False)
    vx, vy, vz = ray(camera, u, v, theta)
    n = outer_border(labels, blob[K_LABEL], blob[K_START], points)
    inner = 0
    for i in range(n):
        pu, pv = points[i, 0], points[i, 1]
        if 0 < pu < w - 1 and 0 < pv < h - 1:
            inner += 1
    if inner >= 8:
        boundary = np.empty((inner, 2))
        k = 0
        for i in range(n):
            pu, pv = points[i, 0], points[i, 1]
            if 0 < pu < w - 1 and 0 < pv < h - 1:
                boundary[k, 0] = pu
                boundary[k, 1] = pv
                k += 1
        fitted, ax, ay, az, fitted_alpha = fit_cone(camera, boundary, vx, vy, vz, alpha, False)
        if fitted:
            vx, vy, vz, alpha = ax, ay, az, fitted_alpha
    make_row(row, rot_body_cam, camera_index, u, v, vx, vy, vz, alpha, area_px, radius_m, True, False)


@kernel("uint8[:, ::1](int32[:, ::1], int64[::1])")
def blob_mask(labels: npt.NDArray[np.int32], blob: npt.NDArray[np.int64]) -> npt.NDArray[np.uint8]:
    """The blob's pixels (1) in its bounding box, other blobs' and the background 0, with a border of one background
    pixel all round: pixel (u, v) of the image is (u - u0 + 1, v - v0 + 1) here."""
    x0, y0 = blob[K_U0], blob[K_V0]
    bw, bh = blob[K_U1] - x0, blob[K_V1] - y0
    padded = np.zeros((bh + 2, bw + 2), np.uint8)
    own = blob[K_LABEL]
    for v in range(bh):
        for u in range(bw):
            if labels[y0 + v, x0 + u] == own:
                padded[v + 1, u + 1] = 1
    return padded


@kernel("UniTuple(int64, 3)(uint8[:, ::1])")
def inscribed_peak(padded: npt.NDArray[np.uint8]) -> tuple[int, int, int]:
    """Column, row and squared distance to the background of the mask pixel farthest from it (the first in row order
    of those equally far): the centre of the largest inscribed circle. Squared distances are exact integers, so the
    choice between equally far pixels is the same on every run (OpenCV's float32 distances were not: a last bit
    apart from call to call, by where its buffers lay, which moved the split and made two runs of a flight differ)."""
    squared = np.empty(padded.shape, np.int64)
    squared_distances(padded, squared)
    h, w = padded.shape
    best, pu, pv = -1, 0, 0
    for v in range(h):
        for u in range(w):
            if squared[v, u] > best:
                best, pu, pv = squared[v, u], u, v
    return pu, pv, best


@kernel("UniTuple(int64, 5)(uint8[:, ::1])")
def largest_remainder(padded: npt.NDArray[np.uint8]) -> tuple[int, int, int, int, int]:
    """What is left of a mask with a background border, as the split read it from OpenCV: each 8-connected part's
    bounding box (``findContours`` then ``boundingRect``), the mask pixels in that box counted with their column and
    row sums about its corner (``moments`` of the box: a neighbour reaching in counts too), and the part whose box
    counts most, the first in ``findContours``' order on a tie. Returns (count, box u, box v, column sum, row sum),
    count 0 when nothing is left.

    ``RETR_EXTERNAL`` hid a part inside another's hole, but such a part can never be the answer: the box of the part
    around it holds its box and more, so counts more; every part is looked at here."""
    h, w = padded.shape
    labels = np.zeros((h, w), np.int32)
    left = 0
    for v in range(h):
        for u in range(w):
            if padded[v, u] != 0:
                labels[v, u] = UNLABELLED
                left += 1
    if left == 0:
        return 0, 0, 0, 0, 0
    box = np.empty((1, BOX_SIZE), np.int64)
    box[0, B_U0], box[0, B_U1], box[0, B_V0], box[0, B_V1] = 0, w, 0, h
    parts = np.empty((left, BLOB_SIZE), np.int64)
    n = label(labels, box, 1, np.empty(left, np.int32), parts)
    best = (0, 0, 0, 0, 0)
    for i in opencv_order(parts, n):
        bx, by = parts[i, K_U0], parts[i, K_V0]
        count = su = sv = 0
        for v in range(by, parts[i, K_V1]):
            for u in range(bx, parts[i, K_U1]):
                if padded[v, u] != 0:
                    count += 1
                    su += u - bx
                    sv += v - by
        if count > best[0]:
            best = (count, bx, by, su, sv)
    return best


@kernel(
    "int64(float64[::1], float64[:, ::1], int32[:, ::1], int64[::1], int32[:, ::1], float64, int64, int64,"
    " float64[:, ::1], int64)"
)
def split_merged(
    camera: npt.NDArray[np.float64],
    rot_body_cam: npt.NDArray[np.float64],
    labels: npt.NDArray[np.int32],
    blob: npt.NDArray[np.int64],
    points: npt.NDArray[np.int32],
    radius_m: float,
    min_area_px: int,
    camera_index: int,
    rows: npt.NDArray[np.float64],
    n_rows: int,
) -> int:
    """A merged blob, whose row read as one body is the last of the first ``n_rows``, split: the nearest body from
    the largest inscribed circle, refined on its arc of the blob's outline, in that row's place; then what is left
    of the blob once that body's silhouette is erased, appended when large enough. Returns the new count, or
    ``ROWS_FULL`` when the second row has no room.

    Bodies share one size, so the nearest looks the largest and its whole silhouette covers at least half the blob;
    a split that finds less has measured the wrong arc (small blobs), and the blob stays one body (its area-based
    range is short of the nearest body's, the safe side)."""
    f = camera[C_FOCAL]
    x0, y0 = blob[K_U0], blob[K_V0]
    whole_area = rows[n_rows - 1, R_AREA]
    padded = blob_mask(labels, blob)
    pu, pv, peak_squared = inscribed_peak(padded)
    peak = math.sqrt(float(peak_squared))
    u, v = float(x0 + pu) - 1.0, float(y0 + pv) - 1.0
    # The distance at the centre of a pixel disc of radius R is about R + 0.5 (to the centre of the first pixel
    # outside it).
    theta, alpha, _a, _b = solve_sphere(normalised(camera, u, v), pmax(peak - 0.5, 0.5) / f, False)
    vx, vy, vz = ray(camera, u, v, theta)
    n = outer_border(labels, blob[K_LABEL], blob[K_START], points)
    boundary = np.empty((n, 2))
    for i in range(n):
        boundary[i, 0] = points[i, 0]
        boundary[i, 1] = points[i, 1]
    fitted, ax, ay, az, fitted_alpha = fit_cone(camera, boundary, vx, vy, vz, alpha, True)
    if fitted:
        vx, vy, vz, alpha = ax, ay, az, fitted_alpha
        theta = math.acos(pmin(1.0, vx))
    c_n, a_n, b_n = sphere_silhouette(theta, math.sin(alpha))
    rho = hypot2(vy, vz)
    if rho > 0.0:
        py, pz = vy / rho, vz / rho
    else:
        py, pz = 1.0, 0.0
    uc, vc = camera[C_CX] + f * c_n * py, camera[C_CY] + f * c_n * pz
    near_area = round_half_even(math.pi * a_n * b_n * f * f)
    if near_area < NEAREST_MIN_SHARE * whole_area:
        return n_rows
    make_row(
        rows[n_rows - 1], rot_body_cam, camera_index, uc, vc, vx, vy, vz, alpha, float(near_area), radius_m, False, True
    )
    # Erase the near body's silhouette, a little larger all round, and look at what is left.
    scale = float(1 << ERASE_SHIFT)
    fill_ellipse(
        padded,
        round_half_even((uc - x0 + 1.0) * scale),
        round_half_even((vc - y0 + 1.0) * scale),
        round_half_even((a_n * f + ERASE_MARGIN_PX) * scale),
        round_half_even((b_n * f + ERASE_MARGIN_PX) * scale),
        math.degrees(math.atan2(pz, py)),
        ERASE_SHIFT,
        0,
    )
    count, bx, by, su, sv = largest_remainder(padded)
    area = float(count)
    if count == 0 or area < pmax(float(min_area_px), REMAINDER_MIN_FRACTION * near_area):
        return n_rows
    ru = float(x0 + bx) - 1.0 + float(su) / area
    rv = float(y0 + by) - 1.0 + float(sv) / area
    theta, alpha, _a, _b = solve_sphere(normalised(camera, ru, rv), area / (f * f), True)
    vx, vy, vz = ray(camera, ru, rv, theta)
    if n_rows >= rows.shape[0]:
        return ROWS_FULL
    make_row(rows[n_rows], rot_body_cam, camera_index, ru, rv, vx, vy, vz, alpha, area, radius_m, False, True)
    return n_rows + 1


@kernel(
    "int64(float64[::1], float64[:, ::1], int32[:, ::1], int64[:, ::1], int64, int32[:, ::1], float64, int64, int64,"
    " float64[:, ::1], int64)"
)
def solve_blobs(
    camera: npt.NDArray[np.float64],
    rot_body_cam: npt.NDArray[np.float64],
    labels: npt.NDArray[np.int32],
    blobs: npt.NDArray[np.int64],
    n_blobs: int,
    points: npt.NDArray[np.int32],
    radius_m: float,
    min_area_px: int,
    camera_index: int,
    rows: npt.NDArray[np.float64],
    n_rows: int,
) -> int:
    """Every blob of a frame, in OpenCV's order, solved into detection rows appended to ``rows`` after ``n_rows``
    (one a blob, two for a merged blob that splits); returns the new count, or ``ROWS_FULL``. A blob under
    ``min_area_px`` is a speck."""
    h, w = labels.shape
    f = camera[C_FOCAL]
    keys = np.empty(n_blobs, np.int64)
    for i in range(n_blobs):
        keys[i] = -blobs[i, K_START]  # findContours lists blobs by first pixel, the last in raster order first
    for i in np.argsort(keys):
        blob = blobs[i]
        area, m10, m01, mu20, mu11, mu02 = box_moments(blob)
        if area < min_area_px:
            continue
        x, y = blob[K_U0], blob[K_V0]
        u, v = x + m10 / area, y + m01 / area
        if n_rows >= rows.shape[0]:
            return ROWS_FULL
        row = rows[n_rows]
        n_rows += 1
        if x == 0 or y == 0 or blob[K_U1] == w or blob[K_V1] == h:
            solve_truncated(camera, rot_body_cam, labels, blob, points, u, v, area, radius_m, camera_index, row)
            continue
        theta, alpha, a_n, b_n = solve_sphere(normalised(camera, u, v), area / (f * f), True)
        merged = area >= MERGE_CHECK_MIN_AREA_PX and elongation(area, mu20, mu11, mu02) > (
            MERGE_ELONGATION_RATIO * a_n / b_n
        )
        vx, vy, vz = ray(camera, u, v, theta)
        make_row(row, rot_body_cam, camera_index, u, v, vx, vy, vz, alpha, area, radius_m, False, merged)
        if merged:
            n_rows = split_merged(camera, rot_body_cam, labels, blob, points, radius_m, min_area_px, camera_index,
                                  rows, n_rows)  # fmt: skip
            if n_rows == ROWS_FULL:
                return ROWS_FULL
    return n_rows


@kernel("int64(float64[:, ::1], int64, int64[::1])")
def rig_keep(rows: npt.NDArray[np.float64], n: int, kept: npt.NDArray[np.int64]) -> int:
    """The rows of a rig's frames to keep, in order, written to ``kept``; returns how many. Whole views first, then
    larger ones (a stable sort: ties keep camera and blob order); a row within max(3 deg, either angular radius) of a
    kept row from another camera is the same body seen twice and dropped. Two are apart without an arc cosine when
    the cosine of their angle is clearly (``COSINE_MARGIN``) below the smaller of both thresholds' cosines."""
    order = np.empty(n, np.int64)
    for i in range(n):  # insertion sort by (truncated, -area): stable, and n is a frame's worth
        j = i
        while j > 0 and (
            rows[order[j - 1], R_TRUNCATED] > rows[i, R_TRUNCATED]
            or (
                rows[order[j - 1], R_TRUNCATED] == rows[i, R_TRUNCATED] and rows[order[j - 1], R_AREA] < rows[i, R_AREA]
            )
        ):
            order[j] = order[j - 1]
            j -= 1
        order[j] = i
    own_cos = np.empty(n)
    k = 0
    for pick in order:
        ax, ay, az = rows[pick, R_FRD_X], rows[pick, R_FRD_Y], rows[pick, R_FRD_Z]
        alpha = rows[pick, R_ALPHA]
        own_cos[pick] = math.cos(pmax(DUPLICATE_ANGLE_RAD, alpha))
        duplicate = False
        for j in kept[:k]:
            if rows[j, R_CAMERA] == rows[pick, R_CAMERA]:
                continue
            bx, by, bz = rows[j, R_FRD_X], rows[j, R_FRD_Y], rows[j, R_FRD_Z]
            dot = bx * ax + by * ay + bz * az
            if dot < pmin(own_cos[pick], own_cos[j]) - COSINE_MARGIN:
                continue
            angle = math.acos(pmax(-1.0, pmin(1.0, dot)))
            if angle < pmax(pmax(DUPLICATE_ANGLE_RAD, rows[j, R_ALPHA]), alpha):
                duplicate = True
                break
        if not duplicate:
            kept[k] = pick
            k += 1
    return k


@kernel("void(float64[:, ::1], int64[::1], int64, float64[:, ::1], float64[:, ::1])")
def to_ned(
    rows: npt.NDArray[np.float64],
    kept: npt.NDArray[np.int64],
    k: int,
    dcm_est: npt.NDArray[np.float64],
    out: npt.NDArray[np.float64],
) -> None:
    """The kept rows' bodies relative to the drone in NED metres (``out``, a row each), rotated by the drone's
    ESTIMATED attitude (``dcm_est``, body to NED)."""
    for m in range(k):
        i = kept[m]
        range_m = rows[i, R_RANGE]
        x, y, z = rows[i, R_FRD_X] * range_m, rows[i, R_FRD_Y] * range_m, rows[i, R_FRD_Z] * range_m
        for c in range(3):
            out[m, c] = dcm_est[c, 0] * x + dcm_est[c, 1] * y + dcm_est[c, 2] * z
