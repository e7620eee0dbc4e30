"""One camera's frame in one call: cull and draw the bodies, expose, threshold, find the blobs and solve them into
detection rows, a merged blob split into its bodies' (sitl/perception/detector.py is the shell: it calls this once
per camera and builds records only for a reader that wants them).

Where the frame is formed (``MODE_*``):

- ``MODE_BOX``, what a flying drone uses when nothing asks for its images: exposed and thresholded only inside the
  boxes the spheres were drawn in. Outside them nothing was drawn, so a pixel there is the background plus its
  noise, and the caller takes this mode only when the camera's whole noise tile stays below the threshold
  (``Camera.noise_cannot_detect``): no pixel outside a box can count, so the blobs, and every detection, are those
  of the whole frame (tests/unit/test_frame_pass.py holds both modes to the same rows, bit for bit). The frame
  itself is not written.
- ``MODE_FULL``: the whole frame exposed into ``frame`` (saved frames, images for a viewer, noise that could reach
  the threshold) and searched whole.
- ``MODE_DRAWN``: as ``MODE_FULL``, with the transmittance drawn by the caller (a frame with a cylinder, which
  OpenCV fills as a polygon).
- ``MODE_IMAGE``: ``frame`` is an image given to the detector (``detect``): thresholded and searched whole.

The buffers are shared by every camera of one image size in a process (sitl/perception/camera.py, ``_scratch``):
each call first undoes what the previous one wrote (``dirty``: transmittance back to one, labels back to zero, in
the boxes it wrote), so a frame costs in proportion to what was drawn, not to the image.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from sitl.kernels import kernel
from sitl.kernels.blobs import UNLABELLED, clear_boxes, label
from sitl.kernels.detector import solve_blobs
from sitl.kernels.render import B_U0, B_U1, B_V0, B_V1, P_LEVEL, P_THRESHOLD, draw_spheres, expose, exposed

MODE_BOX = 0
MODE_FULL = 1
MODE_DRAWN = 2
MODE_IMAGE = 3


@kernel("void(float64[:, ::1], float64[:, ::1], float64[:, ::1])")
def camera_from_ned(
    rot_body_cam: npt.NDArray[np.float64], dcm: npt.NDArray[np.float64], out: npt.NDArray[np.float64]
) -> None:
    """The rotation from NED into the camera frame, ``rot_body_cam.T @ dcm.T``, summed as ``mat_mul`` sums it
    (sitl/mathutil.py: each element ``(a0 b0 + a1 b1) + a2 b2``)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = (rot_body_cam[0, i] * dcm[j, 0] + rot_body_cam[1, i] * dcm[j, 1]) + rot_body_cam[2, i] * dcm[
                j, 2
            ]


@kernel(
    "int64(int64, boolean, float64[:, ::1], float64[:, ::1], float64[::1], float64[:, ::1], float32[:, :, ::1],"
    " float32[:, ::1], uint8[:, ::1], int64, int64, uint8[:, ::1], int32[:, ::1], int32[::1], int64[:, ::1],"
    " int32[:, ::1], int64[:, ::1], int64[:, ::1], int64[::1], float64, int64, int64, float64[:, ::1], int64)"
)
def camera_pass(
    mode: int,
    detect: bool,
    dcm: npt.NDArray[np.float64],
    rot_body_cam: npt.NDArray[np.float64],
    camera: npt.NDArray[np.float64],
    spheres: npt.NDArray[np.float64],
    rays: npt.NDArray[np.float32],
    transmittance: npt.NDArray[np.float32],
    noise_tile: npt.NDArray[np.uint8],
    oy: int,
    ox: int,
    frame: npt.NDArray[np.uint8],
    labels: npt.NDArray[np.int32],
    stack: npt.NDArray[np.int32],
    blobs: npt.NDArray[np.int64],
    points: npt.NDArray[np.int32],
    boxes: npt.NDArray[np.int64],
    dirty: npt.NDArray[np.int64],
    dirty_count: npt.NDArray[np.int64],
    radius_m: float,
    min_area_px: int,
    camera_index: int,
    rows: npt.NDArray[np.float64],
    n_rows: int,
) -> int:
    """One frame of one camera (see the module docstring for ``mode``): spheres (NED offset, radius) seen with the
    TRUE attitude ``dcm`` (body to NED), the noise window at (``oy``, ``ox``); with ``detect``, its detection rows
    appended to ``rows`` after ``n_rows`` (sitl/kernels/detector.py, ``R_*``). Returns the new count, or -1 when
    nothing was drawn in ``MODE_BOX`` (the frame holds nothing to detect, and was not formed)."""
    h, w = labels.shape
    # What the previous frame in these buffers wrote, undone (a caller that drew the transmittance cleared it).
    clear_boxes(labels, transmittance, dirty, dirty_count[0], mode != MODE_DRAWN)
    dirty_count[0] = 0
    n_boxes = 0
    if mode in (MODE_BOX, MODE_FULL):
        r_cam_ned = np.empty((3, 3))
        camera_from_ned(rot_body_cam, dcm, r_cam_ned)
        if spheres.shape[0] > 0:
            n_boxes = draw_spheres(r_cam_ned, camera, spheres, rays, transmittance, boxes)
    level = camera[P_LEVEL]
    threshold = camera[P_THRESHOLD]
    if mode == MODE_BOX:
        if n_boxes == 0:
            return -1
        for b in range(n_boxes):
            for v in range(boxes[b, B_V0], boxes[b, B_V1]):
                for u in range(boxes[b, B_U0], boxes[b, B_U1]):
                    # A pixel no sphere covered shows its noise alone, below the threshold (the mode's premise).
                    clear = transmittance[v, u]
                    if clear != 1.0 and exposed(clear, noise_tile[oy + v, ox + u], level) >= threshold:
                        labels[v, u] = UNLABELLED
        if n_boxes <= dirty.shape[0]:
            dirty[:n_boxes] = boxes[:n_boxes]
            dirty_count[0] = n_boxes
    else:
        if mode != MODE_IMAGE:
            expose(transmittance, noise_tile, oy, ox, level, frame)
        if detect:
            for v in range(h):
                for u in range(w):
                    if frame[v, u] >= threshold:
                        labels[v, u] = UNLABELLED
        n_boxes = 1
    if dirty_count[0] == 0:  # the whole frame (or more boxes than the record holds)
        dirty[0, B_U0], dirty[0, B_U1], dirty[0, B_V0], dirty[0, B_V1] = 0, w, 0, h
        dirty_count[0] = 1
    if not detect:
        return n_rows
    if mode != MODE_BOX:
        boxes[0, B_U0], boxes[0, B_U1], boxes[0, B_V0], boxes[0, B_V1] = 0, w, 0, h
    n_blobs = label(labels, boxes, n_boxes, stack, blobs)
    return solve_blobs(camera, rot_body_cam, labels, blobs, n_blobs, points, radius_m, min_area_px, camera_index,
                       rows, n_rows)  # fmt: skip
