"""Drawing spheres into a camera's transmittance (sitl/perception/camera.py is the shell: cameras, cylinders,
exposure and noise).

Every sphere of a frame is drawn in one call: culled by range and field of view, bounded by its exact silhouette's
box, and each pixel of the box multiplied by the fraction of it the sphere leaves clear. The per-pixel arithmetic
is float32, as the image buffers are, written out in one order (no fused multiply-add), so a frame is the same on
every CPU. Before it was compiled, OpenCV drew each sphere (``cv2.transform`` and three more calls), with float32
rounding of its own that depended on the kernels OpenCV picked for the CPU.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from sitl.kernels import kernel

# A silhouette whose conic is this close to a parabola (sphere grazing the plane through the camera centre parallel
# to the image) is unbounded in the image; the whole frame is then evaluated instead of a bounding box.
MIN_CONIC_MARGIN = 0.02

# A camera's row of parameters.
P_FOCAL = 0
P_CX = 1
P_CY = 2
P_CORNER_ANGLE = 3
P_MAX_RANGE = 4
P_LEVEL = 5  # body level less background level: a fully covered pixel's grey above the noise
P_THRESHOLD = 6  # grey level at or above which a pixel counts as covered (the detector's)
PARAMS_SIZE = 7

# A box a sphere was drawn in: columns u0, u1 (exclusive), v0, v1 (exclusive), pixels.
B_U0 = 0
B_U1 = 1
B_V0 = 2
B_V1 = 3
BOX_SIZE = 4


@kernel("UniTuple(float64, 3)(float64, float64)")
def sphere_silhouette(theta_rad: float, sin_alpha: float) -> tuple[float, float, float]:
    """Exact image of a sphere in normalised image units (focal length 1): (centre distance from the principal
    point, semi-axis along that radial direction, semi-axis across it), for a sphere whose centre is theta off the
    optical axis and whose angular radius alpha has sine ``sin_alpha``. Valid while cos^2 theta > sin^2 alpha."""
    cos_t = math.cos(theta_rad)
    conic = cos_t * cos_t - sin_alpha * sin_alpha
    return (
        math.sin(theta_rad) * cos_t / conic,
        sin_alpha * math.sqrt(1.0 - sin_alpha * sin_alpha) / conic,
        sin_alpha / math.sqrt(conic),
    )


@kernel("int64(float64[:, :], float64[::1], float64[:, ::1], float32[:, :, ::1], float32[:, ::1], int64[:, ::1])")
def draw_spheres(
    r_cam_ned: npt.NDArray[np.float64],
    params: npt.NDArray[np.float64],
    spheres: npt.NDArray[np.float64],
    rays: npt.NDArray[np.float32],
    transmittance: npt.NDArray[np.float32],
    boxes: npt.NDArray[np.int64],
) -> int:
    """Draw every sphere (rows: NED offset from the camera centre, radius) into ``transmittance`` (which the caller
    has filled with ones), with the camera frame's rotation from NED and the pixels' unit rays in the camera frame.

    Returns how many spheres were drawn (0 only when each was culled before drawing), and writes the box each was
    drawn in to ``boxes`` (one row per drawn sphere, ``B_U0``.. ``B_V1``, at least as many rows as spheres): outside
    them the transmittance is still one, which is what lets the frame be exposed and searched in them alone."""
    h, w = transmittance.shape
    f = params[P_FOCAL]
    drawn = 0
    for i in range(spheres.shape[0]):
        n = spheres[i, 0]
        e = spheres[i, 1]
        d = spheres[i, 2]
        radius = spheres[i, 3]
        x = r_cam_ned[0, 0] * n + r_cam_ned[0, 1] * e + r_cam_ned[0, 2] * d
        if x < -radius:
            # Wholly behind the camera: at least 90 deg off axis beyond its angular radius, past any corner of the
            # image (under 90 deg).
            continue
        y = r_cam_ned[1, 0] * n + r_cam_ned[1, 1] * e + r_cam_ned[1, 2] * d
        z = r_cam_ned[2, 0] * n + r_cam_ned[2, 1] * e + r_cam_ned[2, 2] * d
        dist = math.sqrt(x * x + y * y + z * z)
        if not dist > radius:
            # Inside the body: it is all the camera sees. (A NaN offset lands here too and covers the frame, as
            # every pixel's clear fraction is NaN, and NaN is clipped to zero.)
            transmittance[:, :] = 0.0
            boxes[drawn, B_U0] = 0
            boxes[drawn, B_U1] = w
            boxes[drawn, B_V0] = 0
            boxes[drawn, B_V1] = h
            drawn += 1
            continue
        if dist - radius > params[P_MAX_RANGE]:
            continue
        s = radius / dist
        cos_t = max(-1.0, min(1.0, x / dist))
        if math.acos(cos_t) - math.asin(s) > params[P_CORNER_ANGLE]:
            continue
        u0, u1, v0, v1 = 0, w, 0, h
        if cos_t * cos_t - s * s > MIN_CONIC_MARGIN and cos_t > 0.0:
            rho = math.sqrt(y * y + z * z)
            if rho > 1e-12 * dist:
                py, pz = y / rho, z / rho
            else:
                py, pz = 1.0, 0.0
            c_n, a_n, b_n = sphere_silhouette(math.acos(cos_t), s)
            uc = params[P_CX] + f * c_n * py
            vc = params[P_CY] + f * c_n * pz
            # The box only bounds the pixels evaluated; 2 px of margin keeps every covered pixel inside it.
            au, bu = a_n * py, b_n * pz
            av, bv = a_n * pz, b_n * py
            half_u = f * math.sqrt(au * au + bu * bu) + 2.0
            half_v = f * math.sqrt(av * av + bv * bv) + 2.0
            u0, u1 = max(0, math.floor(uc - half_u)), min(w, math.ceil(uc + half_u) + 1)
            v0, v1 = max(0, math.floor(vc - half_v)), min(h, math.ceil(vc + half_v) + 1)
            if u0 >= u1 or v0 >= v1:
                continue
        # 1 - coverage = 0.5 - (cos(ray to centre) - cos(alpha)) * ramp, clipped to [0, 1]: the ramp makes one pixel
        # across the edge go from covered to clear; coverage is exactly 0.5 on the true silhouette whatever the
        # ramp, so thresholding recovers the silhouette.
        ramp = f / (s * max(cos_t, 0.2))
        k = ramp / dist
        mx = np.float32(-k * x)
        my = np.float32(-k * y)
        mz = np.float32(-k * z)
        m0 = np.float32(0.5 + ramp * math.sqrt(1.0 - s * s))
        one = np.float32(1.0)
        zero = np.float32(0.0)
        for v in range(v0, v1):
            for u in range(u0, u1):
                clear = mx * rays[v, u, 0] + my * rays[v, u, 1] + mz * rays[v, u, 2] + m0
                if clear > one:
                    clear = one
                elif not clear > zero:
                    clear = zero
                transmittance[v, u] *= clear
        boxes[drawn, B_U0] = u0
        boxes[drawn, B_U1] = u1
        boxes[drawn, B_V0] = v0
        boxes[drawn, B_V1] = v1
        drawn += 1
    return drawn


@kernel("int64(float32, int64, float64)")
def exposed(clear: float, noise: int, level: float) -> int:
    """One pixel's grey level: ``level`` times its covered fraction, rounded, plus its noise, saturated at 255.

    As OpenCV composed it (``convertScaleAbs(transmittance, alpha=-level, beta=level)``, then a saturating ``add``)
    on a CPU with fused multiply-adds: ``clear * -level + level`` rounded once to float32 (the product of a float32
    and a grey level is exact in float64, and so is the sum for every clear fraction above 2^-23; below it the
    result rounds to ``level`` whichever way), then to the nearest integer, halves to even. OpenCV itself rounds
    twice on a CPU without them, so its frames depended on the CPU; this one does not."""
    if clear == 1.0:
        return noise  # nothing covers the pixel: its grey is exactly zero
    grey = abs(float(np.float32(float(clear) * -level + level)))
    whole = math.floor(grey + 0.5)  # exact: grey is a float32 below 256
    if whole - grey == 0.5 and whole % 2 == 1:
        whole -= 1  # a tie goes to the even neighbour
    grey_level = min(whole, 255) + noise
    return grey_level if grey_level < 255 else 255


@kernel("void(float32[:, ::1], uint8[:, ::1], int64, int64, float64, uint8[:, ::1])")
def expose(
    transmittance: npt.NDArray[np.float32],
    noise_tile: npt.NDArray[np.uint8],
    oy: int,
    ox: int,
    level: float,
    frame: npt.NDArray[np.uint8],
) -> None:
    """The whole frame from the drawn transmittance and the window of the noise tile at (``oy``, ``ox``)."""
    h, w = frame.shape
    for v in range(h):
        for u in range(w):
            frame[v, u] = exposed(transmittance[v, u], noise_tile[oy + v, ox + u], level)
