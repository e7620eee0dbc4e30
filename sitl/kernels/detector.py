"""The detector's per-blob arithmetic (sitl/kernels/frame.py runs it on every blob of a frame;
sitl/perception/detector.py is the shell: the records, and the split of a merged blob).

Inverting a blob's area into a sphere's direction and size (Newton on the silhouette), the pixel ray at an angle off
axis, the cone fit to a blob's outline, a whole or truncated blob solved into a detection row, and a rig's rows
sorted, rid of the bodies two cameras saw and turned into NED: the same operations in the same order as the Python
they replaced, with CPython's ``math.hypot``, Python's ``max`` and numpy's pairwise sums (sitl/kernels/pymath.py),
so detections keep their bits. The method is sitl/perception/detector.py's docstring.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from sitl.kernels import kernel
from sitl.kernels.blobs import K_LABEL, K_START, K_U0, K_U1, K_V0, K_V1, box_moments, outer_border
from sitl.kernels.pymath import hypot2, np_sum, pmax, pmin, py_square
from sitl.kernels.render import P_CX, P_CY, P_FOCAL, sphere_silhouette

# A camera's row is the renderer's (sitl/kernels/render.py): focal length and principal point in pixels.
C_FOCAL = P_FOCAL
C_CX = P_CX
C_CY = P_CY

# A blob of this many pixels or more is checked for being two bodies; below it pixelation alone makes shapes vary.
MERGE_CHECK_MIN_AREA_PX = 30
# Measured elongation beyond this multiple of one sphere's elongation means several bodies.
MERGE_ELONGATION_RATIO = 1.25
# A blob cut by the top or bottom border and at least this many times taller than wide is an upright structure.
UPRIGHT_ASPECT = 2.0
# Detections from two cameras of a rig closer than this (or than the larger angular radius) are one body.
DUPLICATE_ANGLE_RAD = math.radians(3.0)
# A pair whose cosine is this far below a threshold's cosine is apart whatever the last bits of either.
COSINE_MARGIN = 1e-9

# A detection row (float64), as the records' fields (sitl/perception/detector.py, ``Detection``): the camera's index
# in its rig, the centroid, the pixel area, azimuth and elevation in the camera frame, the unit direction in body
# FRD, range, angular radius, the flags; SPLIT marks a blob found merged that the shell splits (its row is the blob
# read as one body), BLOB its index among the frame's blobs (sitl/kernels/blobs.py).
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
R_SPLIT = 13
R_BLOB = 14
ROW_SIZE = 15
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
    angular radius), or (False, the inputs) when the fit is refused. See ``sitl.perception.detector`` for the method.
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
    row[R_SPLIT] = 0.0
    row[R_BLOB] = -1.0


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
    """Every blob of a frame, in OpenCV's order, solved into a detection row appended to ``rows`` after ``n_rows``;
    returns the new count. A blob under ``min_area_px`` is a speck; a merged one gets its whole-blob row marked
    ``R_SPLIT`` for the shell."""
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
            row[R_SPLIT] = 1.0
            row[R_BLOB] = i
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
