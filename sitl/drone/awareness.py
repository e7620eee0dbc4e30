"""What a drone perceives of the other bodies: its camera and the relayed neighbour table, fed to the autopilot.

Two sensors, each at its own rate, both ending in the autopilot's collision prevention
(sitl/avoidance/collision_prevention.py):

- the camera rig renders a frame from the shared world's truth (the other drones' true positions and any static
  obstacles the mission declared, this drone's true attitude - the camera is a sensor, and sensors see the world as
  it is) every 1/CAM_RATE simulated seconds; the detector then works on the image alone, and the detections are
  turned into relative positions with this drone's ESTIMATED attitude. Nothing downstream of the image knows where
  anything really is;
- the neighbour table (relayed GLOBAL_POSITION_INT) is converted into this drone's local frame every
  ``RELAY_PERIOD_S``.

Frames can be saved as PNG (``sitl --camera-frames DIR``): one file per camera per frame, named by instance,
camera and simulated time, so any drone's view of any moment can be looked at afterwards.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt
from pymavlink.dialects.v20 import common as mavlink

from sitl.avoidance.collision_prevention import NO_CAMERA
from sitl.drone.closed_loop import ClosedLoop
from sitl.dynamics.geodesy import LocalFrame
from sitl.kernels import avoidance as ak
from sitl.kernels import neighbours as nk
from sitl.params import ParamStore
from sitl.perception.camera import (
    Body,
    CameraConfig,
    CameraRig,
    VerticalCylinder,
    render_rig,
    spheres,
)
from sitl.perception.detector import rig_ned_rows, sense_rig
from sitl.protocol.images import EncodedImage
from sitl.protocol.neighbours import NEIGHBOUR_TIMEOUT_S, NeighbourTable
from sitl.world.shared import RADIUS, SharedWorld
from sitl.world.view import others_ned_m

RELAY_PERIOD_S = 0.05
# Rounding allowance when leaving out drones beyond camera range (metres; distances differ between frames by ~1e-14).
_RANGE_MARGIN_M = 1e-6


class Awareness:
    def __init__(
        self,
        sim: ClosedLoop,
        instance: int,
        frame: LocalFrame,
        *,
        world: SharedWorld | None,
        neighbours: NeighbourTable | None,
        frames_dir: Path | None = None,
        shared_clock: bool = False,
        clock_ns: Callable[[], int] = time.perf_counter_ns,
    ) -> None:
        self._sim = sim
        self._instance = instance
        self._world = world
        self._neighbours = neighbours
        self._frames_dir = frames_dir
        # In lockstep every drone's time_boot_ms is on one clock, so a report's age is known exactly from the
        # sender's own timestamp (transit and relay included); paced, the clocks differ by the spawn stagger and
        # only the arrival time can be trusted.
        self._shared_clock = shared_clock
        if frames_dir is not None:
            frames_dir.mkdir(parents=True, exist_ok=True)
        self._params: ParamStore = sim.params
        self._radius_m = sim.config.airframe.collision_radius_m
        self._prevention = sim.vehicle.collision_prevention
        self._rng = np.random.default_rng(np.random.SeedSequence(sim.config.seed).spawn(3)[2])
        self._rig_version = -1
        self._rig: CameraRig | None = None
        self._next_frame_s = 0.0
        self._next_relay_s = 0.0
        # What the conversion of the relayed reports into this drone's frame computes with (``_update_relay``)
        self._conversion = np.array(frame.conversion, dtype=np.float64)
        self.frames = 0
        self._snapshots = 0  # images sent on request so far (each seeds its own noise)
        # Time spent on actual work (a relay update or a frame), read by benchmarks; the steps with nothing due are
        # not timed, so the clock is read a few dozen times a second instead of twice per physics step.
        self._clock_ns = clock_ns
        self.cpu_ns = 0

    def _camera_rig(self) -> CameraRig:
        """The rig from the CAM_* parameters (rebuilt only when one changed)."""
        if self._rig is None or self._rig_version != self._params.version:
            p = self._params
            self._rig_version = p.version
            config = CameraConfig(
                fov_h_rad=math.radians(p["CAM_HFOV"]),
                max_range_m=p["CAM_RANGE"],
                frame_rate_hz=p["CAM_RATE"],
                noise_seed=self._sim.config.seed,
            )
            self._rig = CameraRig.omni(config) if p["CAM_RIG"] == 1 else CameraRig.forward(config)
        return self._rig

    def update(self, now_s: float) -> None:
        """Call every physics step; does its work only when a camera frame or a relay update is due."""
        relay_due = self._neighbours is not None and now_s >= self._next_relay_s
        frame_due = self._world is not None and now_s >= self._next_frame_s
        if not (relay_due or frame_due):
            return
        t0 = self._clock_ns()
        if relay_due:
            self._next_relay_s = now_s + RELAY_PERIOD_S
            self._update_relay(now_s)
        if frame_due:
            self._next_frame_s = now_s + 1.0 / self._params["CAM_RATE"]
            # Only collision prevention uses a frame, and only in flight: with avoidance off, or while the drone is
            # disarmed (it flies nothing; a swarm spends its boot there, cameras full of its neighbours on the
            # ground), render only when frames are being saved.
            avoiding = self._params["AVOID_ENABLE"] == 1 and self._sim.vehicle.status.armed
            wanted = avoiding or self._frames_dir is not None
            if self._params["CAM_ENABLE"] == 1 and wanted:
                self._capture(now_s)
            else:
                self._prevention.set_camera_rows(NO_CAMERA, now_s)
        self.cpu_ns += self._clock_ns() - t0

    def _update_relay(self, now_s: float) -> None:
        """The neighbour table into collision prevention's rows, in this drone's frame, in one call
        (sitl/kernels/neighbours.py ``relay_rows``)."""
        table = self._neighbours
        assert table is not None
        entries = table.entry_rows()
        out = np.empty((len(entries), ak.NEIGHBOUR_SIZE))
        n = nk.relay_rows(entries, now_s, NEIGHBOUR_TIMEOUT_S, self._conversion, self._shared_clock, table.ages, out)
        self._prevention.set_relay_rows(out[:n])

    def _bodies(self) -> list[Body]:
        """Every body the cameras could see now, as records (the images a reader asks for)."""
        rows, cylinders = self._body_rows()
        bodies: list[Body] = list(spheres(rows[:, :3], rows[:, 3]))
        return bodies + list(cylinders)

    def _body_rows(self) -> tuple[npt.NDArray[np.float64], list[VerticalCylinder]]:
        """Every body the cameras could see now: the spheres as rows (NED offset, radius: the other drones within
        range, then the mission's round obstacles) and the static cylinders."""
        assert self._world is not None
        rig = self._camera_rig()
        ids, offsets = others_ned_m(self._world, self._instance)
        radii = self._world.bodies[ids, RADIUS]  # each body its own size (an attached vehicle may be larger)
        # Drones beyond every camera's range (by more than rounding: the renderer measures the distance in each
        # camera's frame) would be culled by each camera in turn; in a large swarm most are, so they are left out
        # here. A NaN row is kept, to be met as the renderer meets it.
        reach_m = max(camera.config.max_range_m for camera in rig.cameras) + radii + _RANGE_MARGIN_M
        near = ~(np.einsum("ij,ij->i", offsets, offsets) > reach_m * reach_m)
        rows = np.empty((int(near.sum()), 4))
        rows[:, :3] = offsets[near]
        rows[:, 3] = radii[near]
        cylinders: list[VerticalCylinder] = []
        round_obstacles = []
        for ob in self._world.obstacles_from(self._instance):  # static obstacles the mission declared
            if ob.cylinder:
                cylinders.append(
                    VerticalCylinder(offset_ned_m=ob.offset_ned_m, radius_m=ob.radius_m, height_m=ob.height_m)
                )
            else:
                round_obstacles.append((*ob.offset_ned_m, ob.radius_m))
        if round_obstacles:
            rows = np.concatenate((rows, np.array(round_obstacles, dtype=np.float64).reshape(-1, 4)))
        return rows, cylinders

    def image(self, kind: int, quality: int) -> EncodedImage | None:
        """What the cameras see now, side by side, encoded for a MAVLink image request (sitl/protocol/images.py):
        JPEG at ``quality`` or PNG. Rendered on demand with noise of its own, so looking changes nothing the drone
        does (the flight's camera noise, and so a lockstep flight, stay the same with or without a viewer). None
        without a shared world (nothing to see) or before the estimator has an attitude."""
        est = self._sim.estimate
        if self._world is None or est is None or not est.attitude_valid:
            return None
        rng = np.random.default_rng(self._snapshots)
        self._snapshots += 1
        images = render_rig(self._camera_rig(), self._sim.truth.att_q_frd_to_ned, self._bodies(), rng)
        picture = cv2.hconcat(list(images)) if len(images) > 1 else images[0]
        if kind == mavlink.MAVLINK_DATA_STREAM_IMG_JPEG:
            ok, data = cv2.imencode(".jpg", picture, [cv2.IMWRITE_JPEG_QUALITY, quality])
        else:
            ok, data = cv2.imencode(".png", picture)
        if not ok:
            return None
        return EncodedImage(data=data.tobytes(), width_px=int(picture.shape[1]), height_px=int(picture.shape[0]))

    def _capture(self, now_s: float) -> None:
        assert self._world is not None
        est = self._sim.estimate
        if est is None or not est.attitude_valid:
            return
        rig = self._camera_rig()
        rows, cylinders = self._body_rows()
        q_true = self._sim.truth.att_q_frd_to_ned
        self.frames += 1
        # One pass per camera from the bodies to detection rows (sitl/perception/detector.py, ``sense_rig``): a
        # camera that nothing reaches is neither formed nor searched, and one that something does only where it was
        # drawn, with the detections of the whole frame (docs/perception.md, "Empty frames" and "One pass per
        # camera"); frames being saved are formed whole.
        saving = self._frames_dir is not None
        n = sense_rig(rig, q_true, rows, cylinders, self._rng, self._radius_m, whole_frames=saving)
        if self._frames_dir is not None:
            for camera in rig.cameras:
                name = f"drone{self._instance}-{camera.config.name}-{now_s:09.3f}.png"
                cv2.imwrite(str(self._frames_dir / name), camera.frame)
        self._prevention.set_camera_rows(rig_ned_rows(n, est.att_q_frd_to_ned, self._radius_m), now_s)
