"""The blobs of a thresholded camera frame: 8-connected components with their pixel moments, and the outer border of
one as OpenCV traces it (sitl/kernels/frame.py runs them on a frame; sitl/perception/detector.py is the shell).

The detector took its blobs from OpenCV (``findContours`` with ``RETR_EXTERNAL``, then ``moments`` of each blob's box,
masked to its own contour where another blob reached in): some 20 Python calls a blob. Here one pass labels every
blob inside the boxes that may hold one and sums its moments as integers, and the border is followed only for a blob
that needs it (one cut by the image border: its outline is what the cone is fitted to). What stays OpenCV's:

- a blob is an 8-connected set of pixels at or above the threshold, as OpenCV's border following joins them;
- blobs are listed in the order ``findContours`` returns them: the reverse of the raster order of their first pixel
  (the border following of OpenCV 4 and 5 starts at the first pixel of each blob in raster order and prepends), so
  the detections keep their order and the flights their bits;
- the outer border is followed as OpenCV's ``CHAIN_APPROX_NONE`` follows it (Suzuki and Abe: from the first pixel,
  the first neighbour clockwise from the left; then each next pixel counter-clockwise from the one it came from),
  every point written, so a cone fitted to it adds its points in the same order;
- moments are exact integer sums, and the central ones are formed as OpenCV forms them (``m20 - m10 * cx`` with
  ``cx = m10 * (1 / m00)``): the same float64 bits (tests/unit/test_blobs.py holds all three to OpenCV).

What differs from OpenCV: a blob lying inside a hole of another blob is its own blob here, where ``RETR_EXTERNAL``
hid it and counted its pixels into the outer one's moments. Spheres' silhouettes have no holes; a ring of several
bodies around a fourth, each drawn whole, would be the first frame to tell.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from sitl.kernels import kernel
from sitl.kernels.render import B_U0, B_U1, B_V0, B_V1

# The label of a pixel at or above the threshold that no blob has claimed yet (background is 0, blobs 1, 2, ...).
UNLABELLED = -1

# A blob's row (int64): the raster index (v * width + u) of its first pixel, its bounding box (u1, v1 exclusive),
# its pixel count and the sums of u, v, u^2, u v and v^2 over its pixels (image coordinates), its label.
K_START = 0
K_U0 = 1
K_V0 = 2
K_U1 = 3
K_V1 = 4
K_M00 = 5
K_SU = 6
K_SV = 7
K_SUU = 8
K_SUV = 9
K_SVV = 10
K_LABEL = 11
BLOB_SIZE = 12

# The eight neighbours in OpenCV's chain-code order: right, then counter-clockwise on the screen (v grows down).
_DU = (1, 1, 0, -1, -1, -1, 0, 1)
_DV = (0, -1, -1, -1, 0, 1, 1, 1)


@kernel("int64(int32[:, ::1], int64[:, ::1], int64, int32[::1], int64[:, ::1])")
def label(
    labels: npt.NDArray[np.int32],
    boxes: npt.NDArray[np.int64],
    n_boxes: int,
    stack: npt.NDArray[np.int32],
    blobs: npt.NDArray[np.int64],
) -> int:
    """Label every blob that has a pixel in the first ``n_boxes`` boxes, and fill its row of ``blobs``; returns how
    many. ``labels`` holds UNLABELLED at the pixels to join and 0 elsewhere (a blob may leave the box it was found
    in, never the image); ``stack`` has a cell per pixel, ``blobs`` a row per possible blob (a pixel each). Rows are
    in the order found, not OpenCV's: see ``opencv_order``."""
    h, w = labels.shape
    n = 0
    for b in range(n_boxes):
        for v in range(boxes[b, B_V0], boxes[b, B_V1]):
            for u in range(boxes[b, B_U0], boxes[b, B_U1]):
                if labels[v, u] != UNLABELLED:
                    continue
                n += 1
                labels[v, u] = n
                stack[0] = v * w + u
                top = 1
                start = v * w + u
                u0, u1, v0, v1 = u, u + 1, v, v + 1
                m00 = su = sv = suu = suv = svv = 0
                while top > 0:
                    top -= 1
                    index = stack[top]
                    pv, pu = index // w, index % w
                    start = min(start, index)
                    u0, u1 = min(u0, pu), max(u1, pu + 1)
                    v0, v1 = min(v0, pv), max(v1, pv + 1)
                    m00 += 1
                    su += pu
                    sv += pv
                    suu += pu * pu
                    suv += pu * pv
                    svv += pv * pv
                    # The 8 neighbours, in any order: a blob's pixels, its box, first pixel and sums do not
                    # depend on the order it is walked in.
                    for qv in range(max(pv - 1, 0), min(pv + 2, h)):
                        for qu in range(max(pu - 1, 0), min(pu + 2, w)):
                            if labels[qv, qu] == UNLABELLED:
                                labels[qv, qu] = n
                                stack[top] = qv * w + qu
                                top += 1
                row = blobs[n - 1]
                row[K_START] = start
                row[K_U0], row[K_V0], row[K_U1], row[K_V1] = u0, v0, u1, v1
                row[K_M00], row[K_SU], row[K_SV] = m00, su, sv
                row[K_SUU], row[K_SUV], row[K_SVV] = suu, suv, svv
                row[K_LABEL] = n
    return n


@kernel("int64[::1](int64[:, ::1], int64)")
def opencv_order(blobs: npt.NDArray[np.int64], n: int) -> npt.NDArray[np.int64]:
    """The first ``n`` blobs' indices in the order ``findContours`` lists them: by first pixel, last in raster order
    first (first pixels are distinct, so the order is total)."""
    keys = np.empty(n, np.int64)
    for i in range(n):
        keys[i] = -blobs[i, K_START]
    return np.argsort(keys)


@kernel("UniTuple(float64, 6)(int64[::1])")
def box_moments(blob: npt.NDArray[np.int64]) -> tuple[float, float, float, float, float, float]:
    """``m00, m10, m01, mu20, mu11, mu02`` of a blob's pixels as ``cv2.moments(box, binaryImage=True)`` gives them
    for the blob's bounding box (coordinates from the box's corner)."""
    m00 = blob[K_M00]
    x0, y0 = blob[K_U0], blob[K_V0]
    # Exact integers about the box corner (sum of (u - x0)^2 = suu - 2 x0 su + x0^2 m00, and so on).
    m10 = blob[K_SU] - x0 * m00
    m01 = blob[K_SV] - y0 * m00
    m20 = blob[K_SUU] - 2 * x0 * blob[K_SU] + x0 * x0 * m00
    m11 = blob[K_SUV] - x0 * blob[K_SV] - y0 * blob[K_SU] + x0 * y0 * m00
    m02 = blob[K_SVV] - 2 * y0 * blob[K_SV] + y0 * y0 * m00
    f00, f10, f01 = float(m00), float(m10), float(m01)
    inv_m00 = 1.0 / f00
    cx, cy = f10 * inv_m00, f01 * inv_m00
    return f00, f10, f01, float(m20) - f10 * cx, float(m11) - f10 * cy, float(m02) - f01 * cy


@kernel("int64(int32[:, ::1], int64, int64, int32[:, ::1])")
def outer_border(labels: npt.NDArray[np.int32], blob_label: int, start: int, points: npt.NDArray[np.int32]) -> int:
    """The outer border of the blob ``blob_label`` whose first pixel in raster order is ``start``, written to
    ``points`` as (u, v) rows, as ``findContours(..., RETR_EXTERNAL, CHAIN_APPROX_NONE)`` writes it; returns how many
    points (``points`` needs four rows a pixel of the blob: a one-pixel-wide spur is passed twice each way)."""
    h, w = labels.shape
    u0, v0 = start % w, start // w
    s = 4
    found = False
    for _ in range(8):
        s = (s - 1) & 7
        if s == 4:
            break
        qu, qv = u0 + _DU[s], v0 + _DV[s]
        if 0 <= qu < w and 0 <= qv < h and labels[qv, qu] == blob_label:
            found = True
            break
    if not found:  # a single pixel
        points[0, 0], points[0, 1] = u0, v0
        return 1
    u1, v1 = u0 + _DU[s], v0 + _DV[s]
    u3, v3 = u0, v0
    count = 0
    while True:
        for _ in range(8):
            s = (s + 1) & 7
            qu, qv = u3 + _DU[s], v3 + _DV[s]
            if 0 <= qu < w and 0 <= qv < h and labels[qv, qu] == blob_label:
                break
        points[count, 0], points[count, 1] = u3, v3
        count += 1
        u4, v4 = u3 + _DU[s], v3 + _DV[s]
        if u4 == u0 and v4 == v0 and u3 == u1 and v3 == v1:
            return count
        u3, v3 = u4, v4
        s = (s + 4) & 7


@kernel("void(int32[:, ::1], float32[:, ::1], int64[:, ::1], int64, boolean)")
def clear_boxes(
    labels: npt.NDArray[np.int32],
    transmittance: npt.NDArray[np.float32],
    boxes: npt.NDArray[np.int64],
    n_boxes: int,
    transmittance_too: bool,
) -> None:
    """Labels back to 0 (and with ``transmittance_too`` the transmittance back to 1) in the first ``n_boxes`` boxes:
    what a frame wrote, undone for the next camera that shares the buffers."""
    for b in range(n_boxes):
        for v in range(boxes[b, B_V0], boxes[b, B_V1]):
            for u in range(boxes[b, B_U0], boxes[b, B_U1]):
                labels[v, u] = 0
                if transmittance_too:
                    transmittance[v, u] = 1.0
