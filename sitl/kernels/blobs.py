"""The blobs of a thresholded camera frame: 8-connected components with their pixel moments, the outer border of
one as OpenCV traces it, and the pixel work of splitting a merged one (sitl/kernels/frame.py runs them on a frame,
sitl/kernels/detector.py solves them; sitl/perception/detector.py is the shell).

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

The split of a merged blob was OpenCV's too, and keeps its results (sitl/kernels/detector.py, ``split_merged``):

- the largest inscribed circle is the peak of the exact Euclidean distance transform, which OpenCV's precise one
  is: here on integer squared distances (``squared_distances``), without the last-bit noise of its float32 roots;
- the near body's silhouette is erased as ``cv2.ellipse`` fills it with a fractional shift (``fill_ellipse``): its
  polygon from a table of sines in whole degrees, its fixed-point sides and row fill, pixel for pixel;
- rounding is Python's and ``cvRound``'s, half to even (``round_half_even``).

What differs from OpenCV: a blob lying inside a hole of another blob is its own blob here, where ``RETR_EXTERNAL``
hid it and counted its pixels into the outer one's moments. Spheres' silhouettes have no holes; a ring of several
bodies around a fourth, each drawn whole, would be the first frame to tell.
"""

from __future__ import annotations

import math

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


@kernel("int64(float64)")
def round_half_even(x: float) -> int:
    """The nearest integer to ``x``, a tie to the even one: Python's ``round`` and OpenCV's ``cvRound`` both."""
    whole = math.floor(x)
    # The fraction is exact but for x in (-0.5, 0), where it may round up to 0.5 and either way gives 0.
    rest = x - whole
    if rest > 0.5 or (rest == 0.5 and whole % 2 == 1):
        whole += 1
    return whole


@kernel("void(uint8[:, ::1], int64[:, ::1])")
def squared_distances(mask: npt.NDArray[np.uint8], out: npt.NDArray[np.int64]) -> None:
    """Each pixel's squared Euclidean distance (in pixels, an integer) to the nearest zero pixel of ``mask``, written
    to ``out``: Felzenszwalb and Huttenlocher's separable transform, along the columns, then the lower envelope of
    parabolas along the rows, whose crossings are compared as exact fractions. ``mask`` needs a border of zeros (a
    blob padded by one pixel), so every column has a zero to measure from.

    OpenCV's precise distance transform is this transform with float32 square roots taken at the end; the integers
    are what ``_inscribed_peak`` recovered from them (sitl/perception/detector.py)."""
    h, w = mask.shape
    for u in range(w):
        run = h
        for v in range(h):
            run = 0 if mask[v, u] == 0 else run + 1
            out[v, u] = run
        run = h
        for v in range(h - 1, -1, -1):
            run = 0 if mask[v, u] == 0 else run + 1
            out[v, u] = min(out[v, u], run)
    f = np.empty(w, np.int64)
    apex = np.empty(w, np.int64)  # the columns whose parabolas make up the lower envelope
    # Where parabola k of the envelope takes over from parabola k - 1, as a fraction (numerator, denominator > 0).
    cross_n = np.empty(w, np.int64)
    cross_d = np.empty(w, np.int64)
    for v in range(h):
        for u in range(w):
            f[u] = out[v, u] * out[v, u]
        k = 0
        apex[0] = 0
        for q in range(1, w):
            while True:
                p = apex[k]
                s_n = (f[q] + q * q) - (f[p] + p * p)
                s_d = 2 * (q - p)
                if k > 0 and s_n * cross_d[k] <= cross_n[k] * s_d:
                    k -= 1  # parabola q is below p everywhere p was lowest
                else:
                    break
            k += 1
            apex[k] = q
            cross_n[k], cross_d[k] = s_n, s_d
        last = k
        k = 0
        for q in range(w):
            while k < last and cross_n[k + 1] < q * cross_d[k + 1]:
                k += 1
            p = apex[k]
            out[v, q] = (q - p) * (q - p) + f[p]


# OpenCV's drawing works in fixed point with this many fraction bits.
XY_SHIFT = 16
_XY_ONE = 1 << XY_SHIFT
_XY_HALF = _XY_ONE >> 1


def _table_sine(degrees: int) -> float:
    """OpenCV's sine of a whole number of degrees for drawing: the sine to seven decimals, as a float32 (its table)."""
    quadrant, rest = divmod(degrees, 90)
    first = float(f"{math.sin(math.radians(rest if quadrant % 2 == 0 else 90 - rest)):.7f}")
    return -first if quadrant % 4 >= 2 else first


# Indices 0 to 450, so a cosine is a sine 90 degrees on; 360 holds -0.0 as OpenCV's does.
_SIN_DEGREES = np.array([_table_sine(d) for d in range(451)], np.float32)


@kernel("int64(int64, int64)")
def _c_div(a: int, b: int) -> int:
    """C's integer division: the quotient truncated towards zero (Python's ``//`` floors)."""
    q = abs(a) // abs(b)
    return q if (a < 0) == (b < 0) else -q


@kernel("UniTuple(int64, 5)(int64, int64, int64, int64, int64, int64)")
def _clip_line(width: int, height: int, x1: int, y1: int, x2: int, y2: int) -> tuple[int, int, int, int, int]:
    """The part of a segment inside a ``width`` by ``height`` box (fixed point), as OpenCV's ``clipLine`` cuts it:
    (1 if any is inside, the new end points). Each end is moved onto the top or bottom edge first, then onto the
    left or right one, with C's truncating division, the second end from the first's new place."""
    right, bottom = width - 1, height - 1
    c1 = (x1 < 0) + (x1 > right) * 2 + (y1 < 0) * 4 + (y1 > bottom) * 8
    c2 = (x2 < 0) + (x2 > right) * 2 + (y2 < 0) * 4 + (y2 > bottom) * 8
    if (c1 & c2) == 0 and (c1 | c2) != 0:
        if c1 & 12:
            edge = 0 if c1 < 8 else bottom
            x1 += _c_div((edge - y1) * (x2 - x1), y2 - y1)
            y1 = edge
            c1 = (x1 < 0) + (x1 > right) * 2
        if c2 & 12:
            edge = 0 if c2 < 8 else bottom
            x2 += _c_div((edge - y2) * (x2 - x1), y2 - y1)
            y2 = edge
            c2 = (x2 < 0) + (x2 > right) * 2
        if (c1 & c2) == 0 and (c1 | c2) != 0:
            if c1:
                edge = 0 if c1 == 1 else right
                y1 += _c_div((edge - x1) * (y2 - y1), x2 - x1)
                x1 = edge
                c1 = 0
            if c2:
                edge = 0 if c2 == 1 else right
                y2 += _c_div((edge - x2) * (y2 - y1), x2 - x1)
                x2 = edge
                c2 = 0
    return 1 if (c1 | c2) == 0 else 0, x1, y1, x2, y2


@kernel("void(uint8[:, ::1], int64, int64, int64)")
def _put(image: npt.NDArray[np.uint8], u: int, v: int, value: int) -> None:
    """``image[v, u] = value`` where (u, v) is inside the image."""
    h, w = image.shape
    if 0 <= u < w and 0 <= v < h:
        image[v, u] = value


@kernel("void(uint8[:, ::1], int64, int64, int64, int64, int64)")
def _line(image: npt.NDArray[np.uint8], x1: int, y1: int, x2: int, y2: int, value: int) -> None:
    """An 8-connected segment between fixed-point ends, as OpenCV draws a polygon's sides with a fractional shift:
    clipped to the image, stepped one pixel at a time along its longer axis from the end with the smaller coordinate
    there, the other coordinate advanced by a truncated fixed-point slope, the far end set on its own."""
    h, w = image.shape
    inside, x1, y1, x2, y2 = _clip_line(w << XY_SHIFT, h << XY_SHIFT, x1, y1, x2, y2)
    if not inside:
        return
    dx, dy = x2 - x1, y2 - y1
    along_x = abs(dx) > abs(dy)
    if along_x:
        if dx < 0:
            dy = -dy
            x1, y1, x2, y2 = x2, y2, x1, y1
        x_step = _XY_ONE
        y_step = _c_div(dy * _XY_ONE, abs(dx) | 1)
        count = (x2 - x1) >> XY_SHIFT
    else:
        if dy < 0:
            dx = -dx
            x1, y1, x2, y2 = x2, y2, x1, y1
        x_step = _c_div(dx * _XY_ONE, abs(dy) | 1)
        y_step = _XY_ONE
        count = (y2 - y1) >> XY_SHIFT
    x1 += _XY_HALF
    y1 += _XY_HALF
    _put(image, (x2 + _XY_HALF) >> XY_SHIFT, (y2 + _XY_HALF) >> XY_SHIFT, value)
    if along_x:
        x1 >>= XY_SHIFT
        for _ in range(count + 1):
            _put(image, x1, y1 >> XY_SHIFT, value)
            x1 += 1
            y1 += y_step
    else:
        y1 >>= XY_SHIFT
        for _ in range(count + 1):
            _put(image, x1 >> XY_SHIFT, y1, value)
            x1 += x_step
            y1 += 1


@kernel("void(uint8[:, ::1], int64, int64, int64, int64, float64, int64, int64)")
def fill_ellipse(
    image: npt.NDArray[np.uint8], cu: int, cv: int, axis_u: int, axis_v: int, angle_deg: float, shift: int, value: int
) -> None:
    """``cv2.ellipse(image, (cu, cv), (axis_u, axis_v), angle_deg, 0, 360, value, -1, cv2.LINE_8, shift)``, pixel
    for pixel (tests/unit/test_blobs.py holds it to OpenCV): centre and semi-axes in fixed point with ``shift``
    fraction bits, the angle rounded to a whole degree.

    As OpenCV draws it: a polygon of the ellipse's points every 5, 18, 30 or 90 degrees (fewer for a smaller
    ellipse), from its table of sines to seven decimals in float32, turned by the angle's tabled sine and cosine in
    float64 and rounded to 16 fraction bits; its sides drawn as 8-connected lines, then its rows filled between two
    edges walked down from the top vertex, each edge's x stepped by its rounded fixed-point slope."""
    h, w = image.shape
    angle = round_half_even(angle_deg)
    cu <<= XY_SHIFT - shift
    cv <<= XY_SHIFT - shift
    axis_u = abs(axis_u << (XY_SHIFT - shift))
    axis_v = abs(axis_v << (XY_SHIFT - shift))
    step = (max(axis_u, axis_v) + _XY_HALF) >> XY_SHIFT  # the longer semi-axis in whole pixels
    step = 90 if step < 3 else (30 if step < 10 else (18 if step < 15 else 5))
    while angle < 0:
        angle += 360
    while angle > 360:
        angle -= 360
    cos_a = np.float64(_SIN_DEGREES[450 - angle])
    sin_a = np.float64(_SIN_DEGREES[angle])
    xs = np.empty(360 // step + 1, np.int64)
    ys = np.empty(360 // step + 1, np.int64)
    n = 0
    for arc in range(0, 360 + step, step):
        degrees = min(arc, 360)
        x = float(axis_u) * np.float64(_SIN_DEGREES[450 - degrees])
        y = float(axis_v) * np.float64(_SIN_DEGREES[degrees])
        pu = float(cu) + x * cos_a - y * sin_a
        pv = float(cv) + x * sin_a + y * cos_a
        # Rounded in two parts, the whole pixels then the fraction (one rounding in effect), as OpenCV does.
        qu = round_half_even(pu / _XY_ONE) << XY_SHIFT
        qv = round_half_even(pv / _XY_ONE) << XY_SHIFT
        qu += round_half_even(pu - qu)
        qv += round_half_even(pv - qv)
        if n == 0 or qu != xs[n - 1] or qv != ys[n - 1]:
            xs[n] = qu
            ys[n] = qv
            n += 1
    if n == 1:  # a point: a polygon of two
        xs[0] = xs[1] = cu
        ys[0] = ys[1] = cv
        n = 2
    # The polygon's outline, and its extent.
    top = 0
    u_min = u_max = xs[0]
    v_min = v_max = ys[0]
    u_prev, v_prev = xs[n - 1], ys[n - 1]
    for i in range(n):
        if ys[i] < v_min:
            v_min = ys[i]
            top = i
        v_max = max(v_max, ys[i])
        u_max = max(u_max, xs[i])
        u_min = min(u_min, xs[i])
        _line(image, u_prev, v_prev, xs[i], ys[i], value)
        u_prev, v_prev = xs[i], ys[i]
    u_min = (u_min + _XY_HALF) >> XY_SHIFT
    u_max = (u_max + _XY_HALF) >> XY_SHIFT
    v_min = (v_min + _XY_HALF) >> XY_SHIFT
    v_max = (v_max + _XY_HALF) >> XY_SHIFT
    if n < 3 or u_max < 0 or v_max < 0 or u_min >= w or v_min >= h:
        return
    v_max = min(v_max, h - 1)
    # The two edges, one walking the vertices forwards from the top one and one backwards: the vertex an edge ends
    # at, its direction, x (fixed point) and its step a row, the row it ends on. Vertices left to walk are shared.
    end = np.full(2, top, np.int64)
    direction = np.array((1, n - 1), np.int64)
    edge_x = np.full(2, -_XY_ONE, np.int64)
    edge_dx = np.zeros(2, np.int64)
    v = v_min
    edge_v = np.full(2, v, np.int64)
    left_to_walk = n
    while True:
        for e in range(2):
            if v < edge_v[e]:
                continue
            start = end[e]
            i = start + direction[e]
            if i >= n:
                i -= n
            while True:
                left_to_walk -= 1
                if left_to_walk < 0:
                    break
                row = (ys[i] + _XY_HALF) >> XY_SHIFT
                if row > v:
                    edge_v[e] = row
                    edge_dx[e] = _c_div((xs[i] - xs[start]) * 2 + (row - v), 2 * (row - v))
                    edge_x[e] = xs[start]
                    end[e] = i
                    break
                start = i
                i += direction[e]
                if i >= n:
                    i -= n
        if left_to_walk < 0:
            break
        if v >= 0:
            left = 1 if edge_x[0] > edge_x[1] else 0
            u1 = (edge_x[left] + _XY_HALF) >> XY_SHIFT
            u2 = (edge_x[1 - left] + _XY_HALF) >> XY_SHIFT
            if u2 >= 0 and u1 < w:
                for u in range(max(u1, 0), min(u2, w - 1) + 1):
                    image[v, u] = value
        edge_x[0] += edge_dx[0]
        edge_x[1] += edge_dx[1]
        v += 1
        if v > v_max:
            break
