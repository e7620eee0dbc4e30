"""Synthetic grayscale cameras: a pinhole projection of the other drones and of static obstacles.

The renderer is the ground truth the detector is measured against, so it draws the exact silhouette of a sphere
rather than a disc of radius f r / depth: off the optical axis a sphere projects to an ellipse stretched radially by
about 1/cos(angle off axis) (1.4x at the edge of a 90 deg lens), and close up its centre in the image sits outside
the projection of its centre. A pixel is covered when the angle between its ray and the sphere's centre is below the
sphere's angular radius; coverage ramps over about one pixel at the edge (anti-aliasing), so a threshold half way
between background and body recovers the true silhouette to a small fraction of a pixel. OpenCV's own filled
ellipses were measured 0.5 px too large and not monotonic below 3 px radius, which would bias every range, far
drones most (0.5 px is a fifth of a drone's image radius at 12 m); they are not used for spheres.

Frames (see docs/perception.md):
- body FRD and world NED as everywhere in the project; the attitude quaternion (w, x, y, z) rotates FRD into NED;
- camera frame: x along the optical axis, y to the image right, z to the image bottom. A camera with zero mount
  angles has its frame equal to the body FRD frame. The mount is yaw about body z, then pitch about the new y
  (positive pitch looks up, as for the vehicle);
- pixel (row v, column u) has its centre at (u, v); the principal point is the image centre ((W-1)/2, (H-1)/2).

Everything here is pure: no clocks, no IO. Noise comes from a tile generated once from the camera's seed and
sampled at a random offset each frame (one add instead of drawing 19,200 normal deviates: 5 us against 39 us).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import cv2
import numpy as np
import numpy.typing as npt

from sitl.kernels import blobs as bk
from sitl.kernels import frame as fk
from sitl.kernels import render as rk
from sitl.kernels.render import sphere_silhouette as sphere_silhouette  # one definition, here and in kernels
from sitl.mathutil import fast_constructor, mat_mul, quat_to_dcm

GrayImage = npt.NDArray[np.uint8]

# Near clipping plane for polygonal obstacles, metres in front of the camera.
_NEAR_CLIP_M = 0.05
# Fixed-point fraction bits for OpenCV polygon vertices (1/16 px).
_SHIFT_BITS = 4
_CYLINDER_SIDES = 24


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraConfig:
    """One camera's mount, lens, sensor and noise.

    160x120 at 90 deg is the default: a drone (0.35 m radius) at 15 m is still a 1.9 px radius blob and bearing and
    range errors stay well inside what avoidance needs; 240x180 halves the errors for 10-30 % more time per frame
    (docs/perception.md has both).
    """

    name: str = "front"
    mount_yaw_rad: float = 0.0
    mount_pitch_rad: float = 0.0
    fov_h_rad: float = math.radians(90.0)
    width_px: int = 160
    height_px: int = 120
    max_range_m: float = 15.0
    frame_rate_hz: float = 15.0
    background_level: int = 30
    body_level: int = 200
    pixel_noise_sigma: float = 4.0
    noise_seed: int = 0

    def __post_init__(self) -> None:
        if not 0.0 < self.fov_h_rad < math.radians(170.0):
            raise ValueError(f"camera {self.name}: fov_h_rad must be in (0, 170 deg), got {self.fov_h_rad}")
        if self.width_px < 8 or self.height_px < 8:
            raise ValueError(f"camera {self.name}: resolution {self.width_px}x{self.height_px} is below 8x8")
        if self.max_range_m <= 0.0 or self.frame_rate_hz <= 0.0 or self.pixel_noise_sigma < 0.0:
            raise ValueError(f"camera {self.name}: max range and frame rate must be positive, noise non-negative")
        if not 0 <= self.background_level < self.body_level <= 255:
            raise ValueError(f"camera {self.name}: need 0 <= background_level < body_level <= 255")

    @property
    def frame_period_s(self) -> float:
        return 1.0 / self.frame_rate_hz

    @property
    def threshold_level(self) -> int:
        """Grey level half way between background and body: pixels at or above it are more than half covered."""
        return (self.background_level + self.body_level) // 2


@dataclass(frozen=True, slots=True, kw_only=True)
class Sphere:
    """A drone (radius = its collision radius) or a spherical obstacle; offset from the camera centre in NED."""

    offset_ned_m: tuple[float, float, float]
    radius_m: float


@dataclass(frozen=True, slots=True, kw_only=True)
class VerticalCylinder:
    """A static obstacle (pole, pylon, tree trunk): axis along NED down, offset is its centre at mid-height."""

    offset_ned_m: tuple[float, float, float]
    radius_m: float
    height_m: float


Body = Sphere | VerticalCylinder
# Every other drone is a sphere in every frame: built through its slots, the same frozen record (sitl/mathutil.py).
_new_sphere = fast_constructor(Sphere)


def spheres(offsets_ned_m: npt.ArrayLike, radius_m: npt.ArrayLike) -> list[Sphere]:
    """Spheres from an (N, 3) array of NED offsets (e.g. ``SharedWorld.others_ned_m``) and one radius or N radii
    (e.g. the table's radius column)."""
    rows = np.asarray(offsets_ned_m, dtype=np.float64).reshape(-1, 3)
    radii = np.broadcast_to(np.asarray(radius_m, dtype=np.float64), (len(rows),)).tolist()
    return [_new_sphere(offset_ned_m=(n, e, d), radius_m=r) for (n, e, d), r in zip(rows.tolist(), radii, strict=True)]


def _mount_rotation(yaw_rad: float, pitch_rad: float) -> npt.NDArray[np.float64]:
    """Columns are the camera axes in body FRD: Rz(yaw) @ Ry(pitch)."""
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    rz = np.array(((cy, -sy, 0.0), (sy, cy, 0.0), (0.0, 0.0, 1.0)))
    ry = np.array(((cp, 0.0, sp), (0.0, 1.0, 0.0), (-sp, 0.0, cp)))
    return mat_mul(rz, ry)


@functools.cache
def _pixel_rays(width_px: int, height_px: int, focal_px: float, cx_px: float, cy_px: float) -> npt.NDArray[np.float32]:
    """The unit ray of every pixel in the camera frame, (x, y, z) per pixel: its dot product with a body's direction
    is the cosine of the angle between the pixel's ray and the body's centre (sitl/kernels/render.py).

    One table per intrinsics in a process, shared by every camera that has them (a host's drones carry the same
    cameras: 230 kB each at 160x120, four per drone); no one writes it."""
    u = (np.arange(width_px, dtype=np.float64) - cx_px) / focal_px
    v = (np.arange(height_px, dtype=np.float64) - cy_px) / focal_px
    x_n, y_n = np.meshgrid(u, v)
    inv_norm = 1.0 / np.sqrt(1.0 + x_n * x_n + y_n * y_n)
    return np.ascontiguousarray(np.dstack((inv_norm, x_n * inv_norm, y_n * inv_norm)), dtype=np.float32)


@functools.cache
def _noise_tile(seed: int, width_px: int, height_px: int, background_level: int,
                sigma: float) -> npt.NDArray[np.uint8]:  # fmt: skip
    """A camera's sensor noise, twice its size each way; each frame's noise is a window of it. Made from the
    camera's seed alone, so cameras with one seed share one tile, and a host has many: its drones' seeds run on
    from the swarm's (seed + k) and a drone's cameras from its own (seed + i), so the k-th drone's second camera
    and the next drone's first have the same. No one writes it."""
    tile = np.random.default_rng(seed).normal(background_level, sigma, (2 * height_px, 2 * width_px))
    return np.clip(np.rint(tile), 0, 255).astype(np.uint8)


@dataclass(frozen=True, slots=True)
class _Scratch:
    """The image-sized buffers a frame is drawn, exposed and searched in (sitl/kernels/frame.py). A process renders
    and detects one frame at a time, so its cameras of one size share one set (four cameras of 160x120 kept 0.5 MB
    of them per drone). Each frame undoes what the last one wrote in them (``dirty``: the boxes it wrote), so a
    frame costs what it drew, not the image.

    ``transmittance``: the fraction of each pixel's light that passes every body drawn (one where nothing was);
    ``labels``: each pixel's blob (0: background); ``stack`` and ``blobs`` (a cell and a row per pixel, the most
    there can be): the labelling's; ``points``: one blob's outer border (four points a pixel at most); ``boxes``:
    where the spheres were drawn, a row per sphere (grown for a larger crowd, ``boxes_for``)."""

    transmittance: npt.NDArray[np.float32]
    labels: npt.NDArray[np.int32]
    stack: npt.NDArray[np.int32]
    blobs: npt.NDArray[np.int64]
    points: npt.NDArray[np.int32]
    dirty: npt.NDArray[np.int64]
    dirty_count: npt.NDArray[np.int64]
    boxes: list[npt.NDArray[np.int64]]

    def boxes_for(self, n_spheres: int) -> npt.NDArray[np.int64]:
        """A box array with a row for each of ``n_spheres`` spheres (and one for the whole frame)."""
        if self.boxes[0].shape[0] <= n_spheres:
            self.boxes[0] = np.zeros((2 * n_spheres + 1, rk.BOX_SIZE), np.int64)
        return self.boxes[0]


# Boxes the scratch remembers to undo; a frame that drew in more is undone whole.
_DIRTY_BOXES = 256


@functools.cache
def _scratch(width_px: int, height_px: int) -> _Scratch:
    shape = (height_px, width_px)
    pixels = width_px * height_px
    return _Scratch(
        transmittance=np.ones(shape, np.float32),
        labels=np.zeros(shape, np.int32),
        stack=np.zeros(pixels, np.int32),
        blobs=np.zeros((pixels, bk.BLOB_SIZE), np.int64),
        points=np.zeros((4 * pixels, 2), np.int32),
        dirty=np.zeros((_DIRTY_BOXES, rk.BOX_SIZE), np.int64),
        dirty_count=np.zeros(1, np.int64),
        boxes=[np.zeros((64, rk.BOX_SIZE), np.int64)],
    )


class Camera:
    """One camera: its configuration, intrinsics, mount rotation and the buffers every frame reuses.

    ``frame`` is overwritten by each ``render`` (and by a detection pass that forms the whole frame); copy it to keep
    it. The buffers a frame is drawn and searched in are shared by every camera of the same size in the process
    (``scratch``), the pixel rays by every camera of the same intrinsics and the noise tile by every camera of the
    same seed, so a frame allocates no image-sized array.
    """

    def __init__(self, config: CameraConfig) -> None:
        self.config = config
        w, h = config.width_px, config.height_px
        self.focal_px = (w / 2.0) / math.tan(config.fov_h_rad / 2.0)
        self.cx_px = (w - 1) / 2.0
        self.cy_px = (h - 1) / 2.0
        self.fov_v_rad = 2.0 * math.atan((h / 2.0) / self.focal_px)
        self.rot_body_cam = _mount_rotation(config.mount_yaw_rad, config.mount_pitch_rad)
        self._rot_rows: list[list[float]] = self.rot_body_cam.tolist()
        # Angle off axis of the image corner, plus half a pixel: beyond it a silhouette cannot touch the image.
        self.corner_angle_rad = math.atan(math.hypot(w / 2.0 + 1.0, h / 2.0 + 1.0) / self.focal_px)
        self._rays = _pixel_rays(w, h, self.focal_px, self.cx_px, self.cy_px)  # shared: never written
        # The camera as the compiled kernels take it (sitl/kernels/render.py, detector.py): one float64 row.
        self.kernel_row = np.zeros(rk.PARAMS_SIZE)
        self.kernel_row[rk.P_FOCAL] = self.focal_px
        self.kernel_row[rk.P_CX] = self.cx_px
        self.kernel_row[rk.P_CY] = self.cy_px
        self.kernel_row[rk.P_CORNER_ANGLE] = self.corner_angle_rad
        self.kernel_row[rk.P_MAX_RANGE] = config.max_range_m
        self.kernel_row[rk.P_LEVEL] = config.body_level - config.background_level
        self.kernel_row[rk.P_THRESHOLD] = config.threshold_level
        self.scratch = _scratch(w, h)  # one set per image size in a process
        self._noise_tile = _noise_tile(config.noise_seed, w, h, config.background_level, config.pixel_noise_sigma)
        # A frame with no body drawn is a window of this tile; the detector counts pixels at or above the threshold,
        # so when the whole tile stays below it such a frame holds nothing to detect (with the default noise, 4
        # grey levels around 30 against a threshold of 115, by twenty standard deviations).
        self.noise_cannot_detect = int(self._noise_tile.max()) < config.threshold_level
        self.frame = np.zeros((h, w), np.uint8)  # the camera's own: it is kept (and saved) after the next render

    def camera_to_body(self, vec_cam: tuple[float, float, float]) -> tuple[float, float, float]:
        """A camera-frame vector in body FRD."""
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = self._rot_rows
        x, y, z = vec_cam
        return (r00 * x + r01 * y + r02 * z, r10 * x + r11 * y + r12 * z, r20 * x + r21 * y + r22 * z)


@dataclass(frozen=True, slots=True)
class CameraRig:
    """The cameras one drone carries."""

    cameras: tuple[Camera, ...]

    @classmethod
    def forward(cls, config: CameraConfig | None = None) -> CameraRig:
        """One camera looking along the body x axis (the default)."""
        return cls((Camera(config or CameraConfig()),))

    @classmethod
    def omni(
        cls, config: CameraConfig | None = None, *, count: int = 4, fov_h_rad: float = math.radians(100.0)
    ) -> CameraRig:
        """``count`` cameras evenly spaced in yaw. With 4 x 100 deg, neighbours overlap by 10 deg at the horizon, so
        a body under 10 deg across (a drone beyond 4 m) is whole in at least one of them and ``detect_rig`` keeps
        that view; a nearer one on a seam is cut in both and reported once, flagged truncated."""
        if count * fov_h_rad < 2.0 * math.pi:
            raise ValueError(f"{count} cameras of {math.degrees(fov_h_rad):.0f} deg leave gaps in the horizontal plane")
        base = config or CameraConfig()
        names = ("front", "right", "back", "left") if count == 4 else tuple(f"cam{i}" for i in range(count))
        return cls(
            tuple(
                Camera(
                    replace(
                        base,
                        name=names[i],
                        mount_yaw_rad=base.mount_yaw_rad + 2.0 * math.pi * i / count,
                        fov_h_rad=fov_h_rad,
                        noise_seed=base.noise_seed + i,
                    )
                )
                for i in range(count)
            )
        )


def render(
    camera: Camera, own_att_q_frd_to_ned: npt.ArrayLike, bodies: Sequence[Body], rng: np.random.Generator
) -> GrayImage:
    """Render one frame: bodies (offsets from the camera centre, NED) seen from a drone with TRUE attitude q.

    Returns ``camera.frame`` (uint8, H x W), overwritten by the next call. A body whose nearest point is beyond the
    maximum range, or whose silhouette misses the field of view, is not drawn; a camera inside a body sees only that
    body. Occlusion needs no drawing order: every body has the same brightness, so a pixel's value depends only on
    the fraction of it that no body covers (the product of each body's transmittance), which is what a near body
    in front of a far one looks like. Bodies of different brightness would have to be drawn far to near instead.
    """
    dcm = quat_to_dcm(np.asarray(own_att_q_frd_to_ned, dtype=np.float64))
    rows, cylinders = sphere_rows(bodies)
    draw_bodies(camera, dcm, rows, cylinders)
    return _expose(camera, dcm, rows, rng)


def render_if_drawn(
    camera: Camera, own_att_q_frd_to_ned: npt.ArrayLike, bodies: Sequence[Body], rng: np.random.Generator
) -> GrayImage | None:
    """``render``, or None when no body reaches the camera's range and field of view and its noise alone cannot
    reach the detector's threshold (``Camera.noise_cannot_detect``): that frame is background noise in which the
    detector finds nothing, so it is neither composed nor looked at. The random offset of the noise is drawn all
    the same, so every later frame gets the noise it would have had."""
    dcm = quat_to_dcm(np.asarray(own_att_q_frd_to_ned, dtype=np.float64))
    rows, cylinders = sphere_rows(bodies)
    if not draw_bodies(camera, dcm, rows, cylinders) and camera.noise_cannot_detect:
        noise_offset(camera, rng)
        return None
    return _expose(camera, dcm, rows, rng)


def sphere_rows(bodies: Sequence[Body]) -> tuple[npt.NDArray[np.float64], list[VerticalCylinder]]:
    """The spheres as the kernels take them (rows: NED offset, radius; in the order given) and the cylinders."""
    rows = [(*b.offset_ned_m, b.radius_m) for b in bodies if isinstance(b, Sphere)]
    cylinders = [b for b in bodies if isinstance(b, VerticalCylinder)]
    return np.array(rows, dtype=np.float64).reshape(-1, 4), cylinders


def draw_bodies(
    camera: Camera,
    dcm: npt.NDArray[np.float64],
    spheres_ned: npt.NDArray[np.float64],
    cylinders: Sequence[VerticalCylinder],
) -> bool:
    """Draw every body into the camera's transmittance, from the whole frame up (a frame with a cylinder, which
    OpenCV fills as a polygon, and the images a reader asks for); whether any body may have covered a pixel (False
    only when each was culled before drawing: beyond range, outside the field of view, or an empty bounding box).
    A detection pass without cylinders draws inside its one call instead (``frame_pass``)."""
    scratch = camera.scratch
    scratch.transmittance.fill(1.0)
    r_cam_ned = mat_mul(camera.rot_body_cam.T, dcm.T)
    boxes = scratch.boxes_for(len(spheres_ned))
    drawn = (
        len(spheres_ned) > 0
        and rk.draw_spheres(r_cam_ned, camera.kernel_row, spheres_ned, camera._rays, scratch.transmittance, boxes) > 0
    )
    for body in cylinders:
        drawn = _draw_cylinder(camera, r_cam_ned, body) or drawn
    return drawn


_NO_ROWS = np.zeros((0, 0))


def frame_pass(
    camera: Camera,
    mode: int,
    dcm: npt.NDArray[np.float64],
    spheres_ned: npt.NDArray[np.float64],
    noise_at: tuple[int, int],
    *,
    detect: bool = False,
    radius_m: float = 0.0,
    min_area_px: int = 0,
    camera_index: int = 0,
    rows: npt.NDArray[np.float64] = _NO_ROWS,
    n_rows: int = 0,
    frame: GrayImage | None = None,
) -> int:
    """One call of sitl/kernels/frame.py's ``camera_pass`` with this camera's buffers (its docstring says what the
    modes and the result are); ``frame`` is the image to search in ``MODE_IMAGE`` (else the camera's own)."""
    scratch = camera.scratch
    return int(
        fk.camera_pass(
            mode, detect, dcm, camera.rot_body_cam, camera.kernel_row, spheres_ned, camera._rays,
            scratch.transmittance, camera._noise_tile, noise_at[0], noise_at[1],
            camera.frame if frame is None else frame, scratch.labels,
            scratch.stack, scratch.blobs, scratch.points, scratch.boxes_for(len(spheres_ned)), scratch.dirty,
            scratch.dirty_count, radius_m, min_area_px, camera_index, rows, n_rows,
        )
    )  # fmt: skip


def noise_offset(camera: Camera, rng: np.random.Generator) -> tuple[int, int]:
    """Where this frame's noise is cut from the camera's tile. Two scalar draws give the same numbers and leave
    ``rng`` in the same state as one draw with the bounds as an array (numpy draws each element on its own;
    tests/unit/test_camera.py holds it to that), at a third of the cost: 6 against 16 us, four cameras at 15 Hz."""
    oy = int(rng.integers(0, camera.config.height_px + 1))
    ox = int(rng.integers(0, camera.config.width_px + 1))
    return oy, ox


def _expose(
    camera: Camera, dcm: npt.NDArray[np.float64], spheres_ned: npt.NDArray[np.float64], rng: np.random.Generator
) -> GrayImage:
    """The frame from the drawn transmittance: body level where covered, background plus noise elsewhere."""
    frame_pass(camera, fk.MODE_DRAWN, dcm, spheres_ned, noise_offset(camera, rng))
    return camera.frame


def render_rig(
    rig: CameraRig, own_att_q_frd_to_ned: npt.ArrayLike, bodies: Sequence[Body], rng: np.random.Generator
) -> list[GrayImage]:
    """One frame per camera of the rig (each the camera's own reused buffer)."""
    return [render(camera, own_att_q_frd_to_ned, bodies, rng) for camera in rig.cameras]


def render_rig_if_drawn(
    rig: CameraRig, own_att_q_frd_to_ned: npt.ArrayLike, bodies: Sequence[Body], rng: np.random.Generator
) -> list[GrayImage | None]:
    """``render_if_drawn`` for every camera of the rig: None for a frame with nothing the detector could find."""
    return [render_if_drawn(camera, own_att_q_frd_to_ned, bodies, rng) for camera in rig.cameras]


_RING = np.array(
    [
        (math.cos(2.0 * math.pi * k / _CYLINDER_SIDES), math.sin(2.0 * math.pi * k / _CYLINDER_SIDES))
        for k in range(_CYLINDER_SIDES)
    ]
)
_K = np.arange(_CYLINDER_SIDES)
# Edges of the prism: top ring, bottom ring, vertical sides (indices into 2K vertices: top first).
_EDGES = np.concatenate(
    (
        np.column_stack((_K, (_K + 1) % _CYLINDER_SIDES)),
        np.column_stack((_K + _CYLINDER_SIDES, (_K + 1) % _CYLINDER_SIDES + _CYLINDER_SIDES)),
        np.column_stack((_K, _K + _CYLINDER_SIDES)),
    )
)


def _draw_cylinder(camera: Camera, r_cam_ned: npt.NDArray[np.float64], body: VerticalCylinder) -> bool:
    """Silhouette of a 24-sided prism: convex hull of its vertices in front of the near plane and of the points
    where its edges cross that plane (exact for the prism, since central projection keeps convex hulls). False when
    it was culled (beyond range, behind the camera) and nothing was drawn."""
    n, e, d = body.offset_ned_m
    half_h = body.height_m / 2.0
    out_h = max(0.0, math.hypot(n, e) - body.radius_m)
    out_v = max(0.0, abs(d) - half_h)
    if math.hypot(out_h, out_v) > camera.config.max_range_m:
        return False
    if out_h == 0.0 and out_v == 0.0:
        camera.scratch.transmittance.fill(0.0)
        return True
    ring = np.column_stack((n + body.radius_m * _RING[:, 0], e + body.radius_m * _RING[:, 1]))
    top = np.column_stack((ring, np.full(_CYLINDER_SIDES, d - half_h)))
    bottom = np.column_stack((ring, np.full(_CYLINDER_SIDES, d + half_h)))
    pts = mat_mul(np.concatenate((top, bottom)), r_cam_ned.T)
    front = pts[:, 0] >= _NEAR_CLIP_M
    if not front.any():
        return False
    ia, ib = _EDGES[:, 0], _EDGES[:, 1]
    crossing = front[ia] != front[ib]
    pa, pb = pts[ia[crossing]], pts[ib[crossing]]
    t = (_NEAR_CLIP_M - pa[:, 0]) / (pb[:, 0] - pa[:, 0])
    kept = np.concatenate((pts[front], pa + t[:, None] * (pb - pa)))
    f = camera.focal_px
    scale = float(1 << _SHIFT_BITS)
    uv = np.column_stack((camera.cx_px + f * kept[:, 1] / kept[:, 0], camera.cy_px + f * kept[:, 2] / kept[:, 0]))
    hull = cv2.convexHull(np.rint(uv * scale).astype(np.int32))
    cv2.fillConvexPoly(camera.scratch.transmittance, hull, 0.0, cv2.LINE_8, _SHIFT_BITS)
    return True
