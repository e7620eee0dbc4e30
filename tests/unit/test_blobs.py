"""The compiled blob finder (sitl/kernels/blobs.py) and exposure (sitl/kernels/render.py) against what they replaced:
OpenCV's findContours order and border points, cv2.moments, the exposure's rounding, and the pixel work of a merged
blob's split (the precise distance transform, the filled ellipse, the remainder's contours and box moments)."""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from sitl.kernels import blobs as bk
from sitl.kernels import detector as dk
from sitl.kernels import render as rk

pytestmark = pytest.mark.timeout(60)


def random_blobs(rng: np.random.Generator, height: int, width: int) -> npt.NDArray[np.uint8]:
    """A binary image of a few overlapping discs and ellipses, some cut by the border, some one pixel thin."""
    image = np.zeros((height, width), np.uint8)
    for _ in range(int(rng.integers(1, 9))):
        centre = (int(rng.integers(-3, width + 3)), int(rng.integers(-3, height + 3)))
        axes = (int(rng.integers(0, 9)), int(rng.integers(0, 9)))
        cv2.ellipse(image, centre, axes, float(rng.uniform(0, 180)), 0.0, 360.0, 255, -1)
    if rng.random() < 0.5:
        cv2.line(image, (int(rng.integers(0, width)), 0), (int(rng.integers(0, width)), height - 1), 255, 1)
    return image


def labelled(image: npt.NDArray[np.uint8]) -> tuple[npt.NDArray[np.int32], npt.NDArray[np.int64], int]:
    """The kernel's blobs of a whole binary image."""
    height, width = image.shape
    labels = np.where(image > 0, bk.UNLABELLED, 0).astype(np.int32)
    boxes = np.array([(0, width, 0, height)], np.int64)
    blobs = np.zeros((height * width, bk.BLOB_SIZE), np.int64)
    n = bk.label(labels, boxes, 1, np.zeros(height * width, np.int32), blobs)
    return labels, blobs, n


@pytest.mark.parametrize("seed", range(6))
def test_blobs_come_in_opencvs_order_with_its_border_points_and_moments(seed: int) -> None:
    rng = np.random.default_rng(seed)
    compared = 0
    for _ in range(60):
        image = random_blobs(rng, int(rng.integers(12, 60)), int(rng.integers(12, 80)))
        contours, _ = cv2.findContours(image, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        labels, blobs, n = labelled(image)
        if n != len(contours):
            continue  # a blob inside another's hole: OpenCV hides it (the one documented difference)
        compared += 1
        order = bk.opencv_order(blobs, n)
        points = np.zeros((4 * image.size, 2), np.int32)
        for contour, index in zip(contours, order, strict=True):
            blob = blobs[index]
            count = bk.outer_border(labels, blob[bk.K_LABEL], blob[bk.K_START], points)
            assert np.array_equal(points[:count], contour[:, 0, :])
            x, y, w, h = cv2.boundingRect(contour)
            assert (blob[bk.K_U0], blob[bk.K_V0], blob[bk.K_U1], blob[bk.K_V1]) == (x, y, x + w, y + h)
            own = np.where(labels[y : y + h, x : x + w] == blob[bk.K_LABEL], 255, 0).astype(np.uint8)
            m = cv2.moments(own, True)
            assert bk.box_moments(blob) == (m["m00"], m["m10"], m["m01"], m["mu20"], m["mu11"], m["mu02"])
    assert compared >= 50


def test_a_blob_in_another_ones_hole_is_its_own_blob_where_opencv_hid_it() -> None:
    image = np.zeros((20, 20), np.uint8)
    cv2.rectangle(image, (2, 2), (17, 17), 255, 2)
    image[9:11, 9:11] = 255
    contours, _ = cv2.findContours(image, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    _labels, blobs, n = labelled(image)
    assert (len(contours), n) == (1, 2)
    assert sorted(int(blobs[i, bk.K_M00]) for i in range(n)) == [4, int(np.count_nonzero(image)) - 4]


def test_exposure_rounds_once_to_float32_then_half_to_even_and_saturates() -> None:
    rng = np.random.default_rng(3)
    level = 170.0
    # Random clear fractions, and those whose grey lands on or next to a half.
    ties = ((np.arange(0, 171) + 0.5) / level).astype(np.float32)
    clear = np.concatenate(
        (rng.random(20000).astype(np.float32), ties, np.nextafter(ties, np.float32(0)), np.nextafter(ties, 1))
    ).astype(np.float32)
    clear = np.concatenate((clear, np.array((0.0, 1.0, 2.0**-30), np.float32)))
    noise = rng.integers(0, 256, clear.size).astype(np.uint8)
    grey = np.rint(np.abs(np.float32(clear.astype(np.float64) * -level + level))).astype(np.int64)
    want = np.minimum(grey + noise, 255)
    got = np.array([rk.exposed(c, int(n), level) for c, n in zip(clear.tolist(), noise.tolist(), strict=True)])
    assert np.array_equal(got, want)
    frame = np.zeros((1, clear.size), np.uint8)
    tile = np.zeros((3, 2 * clear.size), np.uint8)
    tile[1, 2 : 2 + clear.size] = noise
    rk.expose(clear.reshape(1, -1), tile, 1, 2, level, frame)
    assert np.array_equal(frame[0], want)


def test_rounding_is_pythons_and_cvrounds_half_to_even() -> None:
    rng = np.random.default_rng(7)
    values = np.concatenate((np.arange(-40.0, 40.0, 0.25), rng.normal(0.0, 1e5, 5000), rng.normal(0.0, 3.0, 5000)))
    values = np.concatenate((values, np.nextafter(values, np.inf), np.nextafter(values, -np.inf)))
    assert [bk.round_half_even(x) for x in values.tolist()] == [round(x) for x in values.tolist()]


@pytest.mark.parametrize("seed", range(4))
def test_the_filled_ellipse_is_opencvs_pixel_for_pixel(seed: int) -> None:
    """Centres inside and outside the image, semi-axes from nothing to far beyond it (each of OpenCV's polygon step
    sizes), any angle (every whole degree of its sine table, and halves that round to even), drawn over a mask."""
    rng = np.random.default_rng(seed)
    shift = dk.ERASE_SHIFT
    one = 1 << shift
    for _ in range(4000):
        height, width = int(rng.integers(1, 50)), int(rng.integers(1, 50))
        image = np.where(rng.random((height, width)) < 0.8, 1, 0).astype(np.uint8)
        centre = (int(rng.integers(-12 * one, (width + 12) * one)), int(rng.integers(-12 * one, (height + 12) * one)))
        reach = int(rng.choice((3 * one, 10 * one, 15 * one, 40 * one)))
        axes = (int(rng.integers(0, reach)), int(rng.integers(0, reach)))
        angle = float(rng.uniform(-400.0, 400.0)) if rng.random() < 0.7 else float(rng.integers(-8, 8)) * 22.5
        want = image.copy()
        cv2.ellipse(want, centre, axes, angle, 0.0, 360.0, 0, -1, cv2.LINE_8, shift)
        bk.fill_ellipse(image, centre[0], centre[1], axes[0], axes[1], angle, shift, 0)
        assert np.array_equal(image, want), (height, width, centre, axes, angle)


def test_squared_distances_are_opencvs_precise_transform_squared() -> None:
    rng = np.random.default_rng(11)
    for _ in range(1500):
        height, width = int(rng.integers(1, 45)), int(rng.integers(1, 45))
        padded = np.zeros((height + 2, width + 2), np.uint8)
        padded[1:-1, 1:-1] = np.where(rng.random((height, width)) < rng.uniform(0.3, 1.0), 255, 0)
        want = np.rint(cv2.distanceTransform(padded, cv2.DIST_L2, cv2.DIST_MASK_PRECISE).astype(np.float64) ** 2)
        got = np.empty(padded.shape, np.int64)
        bk.squared_distances(padded, got)
        assert np.array_equal(got, want.astype(np.int64))


def opencv_remainder(padded: npt.NDArray[np.uint8]) -> tuple[int, int, int, int, int]:
    """The part of a mask the split took as the far body, as it took it from OpenCV: the external contours, each one's
    bounding rect and the moments of the mask in it, the most pixels, the first on a tie."""
    contours, _ = cv2.findContours(padded, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    best = (0, 0, 0, 0, 0)
    for contour in contours:
        x, y, w, h = cv2.boundingRect(contour)
        m = cv2.moments(padded[y : y + h, x : x + w], True)
        if m["m00"] > best[0]:
            best = (int(m["m00"]), x, y, int(m["m10"]), int(m["m01"]))
    return best


@pytest.mark.parametrize("seed", range(3))
def test_the_largest_remainder_is_the_one_opencvs_contours_and_box_moments_pick(seed: int) -> None:
    """Parts in any number, reaching into each other's boxes, equal counts (ties), and parts inside another's hole
    (which ``RETR_EXTERNAL`` hides: they never win, the part around them counts more)."""
    rng = np.random.default_rng(seed)
    holes = 0
    for _ in range(300):
        image = random_blobs(rng, int(rng.integers(8, 40)), int(rng.integers(8, 50)))
        if rng.random() < 0.3:
            x, y = int(rng.integers(0, image.shape[1] - 6)), int(rng.integers(0, image.shape[0] - 6))
            cv2.rectangle(image, (x, y), (x + 5, y + 5), 255, 1)
            image[y + 2 : y + 4, x + 2 : x + 2 + int(rng.integers(1, 3))] = 255
        if rng.random() < 0.2:  # two equal squares: a tie
            image[:] = 0
            image[2:5, 2:5] = image[6:9, 10:13] = 255
        padded = np.where(cv2.copyMakeBorder(image, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0) > 0, 1, 0)
        padded = padded.astype(np.uint8)
        _labels, _blobs, n = labelled(padded)
        holes += n != len(cv2.findContours(padded, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)[0])
        assert dk.largest_remainder(padded) == opencv_remainder(padded)
    assert holes >= 10
    assert dk.largest_remainder(np.zeros((4, 5), np.uint8)) == (0, 0, 0, 0, 0)
