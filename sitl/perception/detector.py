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
its centre direction (a cone), so an arc of it fixes both direction and angular radius (``fit_cone`` in
sitl/kernels/detector.py):

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

Every step runs compiled, in one call per camera (sitl/kernels/frame.py), the split of a merged blob too
(``split_merged`` in sitl/kernels/detector.py): it was done here in Python with OpenCV (its precise distance
transform, contours, filled ellipse and box moments), whose pixel work sitl/kernels/blobs.py reproduces exactly, so
the detections kept their bits (tests/unit/test_frame_pass.py keeps that split as the oracle). This module is the
shell: the row table a process's frames are searched into, and records for a reader that wants them.

Obstacles that are not drone-sized (a pole, a building) yield ranges computed as if they were a drone: far too
short for larger ones (the safe side), and usually flagged truncated when they fill the frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sitl.kernels import avoidance as ak
from sitl.kernels import detector as dk
from sitl.kernels import frame as fk
from sitl.mathutil import fast_constructor, quat_to_dcm
from sitl.perception.camera import (
    Camera,
    CameraRig,
    GrayImage,
    VerticalCylinder,
    draw_bodies,
    frame_pass,
    noise_offset,
)

# A frame's detections are found in OpenCV's order of blobs, then sorted; rows a rig pass starts with (it grows).
_ROWS_START = 64


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


def _detection(row: list[float], camera_name: str) -> Detection:
    """The record of a detection row (sitl/kernels/detector.py, ``R_*``), built only for a reader that wants one."""
    return _new_detection(
        camera_name=camera_name,
        centroid_px=(row[dk.R_U], row[dk.R_V]),
        area_px=int(row[dk.R_AREA]),
        azimuth_rad=row[dk.R_AZIMUTH],
        elevation_rad=row[dk.R_ELEVATION],
        unit_frd=(row[dk.R_FRD_X], row[dk.R_FRD_Y], row[dk.R_FRD_Z]),
        range_m=row[dk.R_RANGE],
        angular_radius_rad=row[dk.R_ALPHA],
        truncated=row[dk.R_TRUNCATED] != 0.0,
        merged=row[dk.R_MERGED] != 0.0,
    )


class _Rows:
    """The detection rows of the frame being searched, for the whole process (it searches one frame at a time, as
    it shares the image buffers: camera.py, ``_scratch``): grown when a frame holds more blobs than ever before."""

    table = np.zeros((_ROWS_START, dk.ROW_SIZE))
    kept = np.zeros(_ROWS_START, np.int64)
    ned = np.zeros((_ROWS_START, 3))

    @classmethod
    def grow(cls, keep: int) -> None:
        """Twice the room, the first ``keep`` rows kept."""
        size = 2 * cls.table.shape[0]
        table = np.zeros((size, dk.ROW_SIZE))
        table[:keep] = cls.table[:keep]
        cls.table, cls.kept, cls.ned = table, np.zeros(size, np.int64), np.zeros((size, 3))


_IDENTITY = np.eye(3)
_NO_SPHERES = np.zeros((0, 4))


def _camera_rows(
    camera: Camera,
    camera_index: int,
    mode: int,
    dcm: npt.NDArray[np.float64],
    spheres_ned: npt.NDArray[np.float64],
    noise_at: tuple[int, int],
    n_rows: int,
    radius_m: float,
    min_area_px: int,
    image: GrayImage | None = None,
) -> int:
    """One camera's frame formed and searched (sitl/kernels/frame.py), merged blobs split, its rows appended to
    ``_Rows.table`` after ``n_rows``; returns the new count (``n_rows`` when ``MODE_BOX`` drew nothing)."""
    while True:
        got = frame_pass(camera, mode, dcm, spheres_ned, noise_at, detect=True, radius_m=radius_m,
                         min_area_px=min_area_px, camera_index=camera_index, rows=_Rows.table, n_rows=n_rows,
                         frame=image)  # fmt: skip
        if got != dk.ROWS_FULL:
            break
        _Rows.grow(n_rows)  # the pass undoes its own writes first, so it is run again from the top
    return n_rows if got < 0 else got


def detect(image: GrayImage, camera: Camera, known_body_radius_m: float, *, min_area_px: int = 3) -> list[Detection]:
    """Bodies in one frame of ``camera`` (uint8 H x W), largest blob first.

    ``known_body_radius_m`` is the prior on a body's size (a drone's collision radius); ``min_area_px`` rejects
    specks smaller than a drone at the camera's maximum range would be.
    """
    n = _image_rows(image, camera, 0, 0, known_body_radius_m, min_area_px)
    found = [_detection(row, camera.config.name) for row in _Rows.table[:n].tolist()]
    found.sort(key=lambda det: det.area_px, reverse=True)
    return found


def _image_rows(image: GrayImage, camera: Camera, index: int, n_rows: int, radius_m: float, min_area_px: int) -> int:
    """``_camera_rows`` of an image given to the detector (thresholded and searched whole, left untouched)."""
    return _camera_rows(camera, index, fk.MODE_IMAGE, _IDENTITY, _NO_SPHERES, (0, 0), n_rows, radius_m, min_area_px,
                        np.ascontiguousarray(image, dtype=np.uint8))  # fmt: skip


def detect_rig(
    images: Sequence[GrayImage | None], rig: CameraRig, known_body_radius_m: float, *, min_area_px: int = 3
) -> list[Detection]:
    """Detections of every camera of a rig; a body seen by two overlapping cameras is kept once, preferring the
    view where it is whole (not truncated), then the larger one. None stands for a frame known to hold nothing
    (``render_rig_if_drawn``)."""
    n = 0
    for index, (image, camera) in enumerate(zip(images, rig.cameras, strict=True)):
        if image is not None:
            n = _image_rows(image, camera, index, n, known_body_radius_m, min_area_px)
    k = dk.rig_keep(_Rows.table, n, _Rows.kept)
    rows = _Rows.table.tolist()
    return [_detection(rows[i], rig.cameras[int(rows[i][dk.R_CAMERA])].config.name) for i in _Rows.kept[:k].tolist()]


def sense_rig(
    rig: CameraRig,
    own_att_q_frd_to_ned: npt.ArrayLike,
    spheres_ned: npt.NDArray[np.float64],
    cylinders: Sequence[VerticalCylinder],
    rng: np.random.Generator,
    known_body_radius_m: float,
    *,
    whole_frames: bool = False,
    min_area_px: int = 3,
) -> int:
    """A drone's camera frame, every camera of its rig formed and searched from the TRUE attitude and the bodies
    (``spheres_ned``: NED offset and radius per row, as ``sphere_rows`` gives them; cylinders drawn by OpenCV);
    returns how many detection rows it left in the process's row table for ``rig_ned``.

    Each camera draws its noise offset, formed or not, so the noise of every later frame is what it would have
    been. Where the camera's noise cannot reach the threshold, the frame is exposed and searched only in the boxes
    its spheres were drawn in (sitl/kernels/frame.py, ``MODE_BOX``; nothing at all when none was drawn), with the
    same detections as the whole frame gives; ``whole_frames`` forms every frame whole into ``camera.frame`` (to
    save it), as does a camera whose noise could reach the threshold."""
    dcm = quat_to_dcm(np.asarray(own_att_q_frd_to_ned, dtype=np.float64))
    n = 0
    for index, camera in enumerate(rig.cameras):
        if cylinders:
            drawn = draw_bodies(camera, dcm, spheres_ned, cylinders)
            noise_at = noise_offset(camera, rng)
            if drawn or whole_frames or not camera.noise_cannot_detect:
                n = _camera_rows(camera, index, fk.MODE_DRAWN, dcm, spheres_ned, noise_at, n, known_body_radius_m,
                                 min_area_px)  # fmt: skip
            continue
        box = camera.noise_cannot_detect and not whole_frames
        noise_at = noise_offset(camera, rng)
        if box and len(spheres_ned) == 0:
            continue  # nothing to draw: the box pass would draw nothing and form nothing
        mode = fk.MODE_BOX if box else fk.MODE_FULL
        n = _camera_rows(camera, index, mode, dcm, spheres_ned, noise_at, n, known_body_radius_m, min_area_px)
    return n


def rig_ned(n_rows: int, own_att_q_frd_to_ned: npt.ArrayLike) -> list[tuple[float, float, float]]:
    """The bodies of the last ``sense_rig``'s rows, each seen by two cameras kept once (as ``detect_rig``), relative
    to the drone in NED metres, rotated by its ESTIMATED attitude: the figures ``to_ned_all(detect_rig(...))``
    gives, to the bit, with no record built."""
    return [(n, e, d) for n, e, d, _, _ in rig_ned_rows(n_rows, own_att_q_frd_to_ned, 0.0).tolist()]


def rig_ned_rows(n_rows: int, own_att_q_frd_to_ned: npt.ArrayLike, radius_m: float) -> npt.NDArray[np.float64]:
    """``rig_ned`` as collision prevention's camera rows (sitl/kernels/avoidance.py ``CAMERA_SIZE``: the position,
    ``radius_m``, age 0 at capture), an array of their own (the rig's buffers serve the next frame)."""
    k = dk.rig_keep(_Rows.table, n_rows, _Rows.kept)
    rows = np.zeros((k, ak.CAMERA_SIZE))
    if k:
        dk.to_ned(
            _Rows.table, _Rows.kept, k, quat_to_dcm(np.asarray(own_att_q_frd_to_ned, dtype=np.float64)), _Rows.ned
        )
        rows[:, :3] = _Rows.ned[:k]
        rows[:, 3] = radius_m
    return rows


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
