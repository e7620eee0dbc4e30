"""The detector's per-blob arithmetic (sitl/perception/detector.py is the shell: thresholds, contours, moments,
merged and truncated blobs, the records).

Inverting a blob's area into a sphere's direction and size (Newton on the silhouette), the pixel ray at an angle off
axis, and the cone fit to a blob's outline: the same operations in the same order as the Python they replaced, with
CPython's ``math.hypot`` and numpy's pairwise sums (sitl/kernels/pymath.py), so detections keep their bits.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from sitl.kernels import kernel
from sitl.kernels.pymath import hypot2, np_sum, py_square
from sitl.kernels.render import P_CX, P_CY, P_FOCAL, sphere_silhouette

# A camera's row is the renderer's (sitl/kernels/render.py): focal length and principal point in pixels.
C_FOCAL = P_FOCAL
C_CX = P_CX
C_CY = P_CY


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
