"""Onboard perception: synthetic cameras (camera.py) and the blob detector that finds other drones in them
(detector.py). Pure code: the caller decides when to render (``CameraConfig.frame_rate_hz``) and with what truth.

Typical use at the camera rate::

    rig = CameraRig.forward()                      # or CameraRig.omni()
    bodies = spheres(offsets_ned_m, radius_m=0.35)  # other drones, NED offsets from this drone
    images = render_rig(rig, q_true, bodies, rng)   # or render_rig_if_drawn: None for an empty frame
    detections = detect_rig(images, rig, known_body_radius_m=0.35)
    positions_ned_m = [to_ned(d, q_estimated) for d in detections]
"""

from sitl.perception.camera import (
    Body,
    Camera,
    CameraConfig,
    CameraRig,
    Sphere,
    VerticalCylinder,
    render,
    render_if_drawn,
    render_rig,
    render_rig_if_drawn,
    spheres,
)
from sitl.perception.detector import Detection, detect, detect_rig, to_ned, to_ned_all

__all__ = [
    "Body",
    "Camera",
    "CameraConfig",
    "CameraRig",
    "Detection",
    "Sphere",
    "VerticalCylinder",
    "detect",
    "detect_rig",
    "render",
    "render_if_drawn",
    "render_rig",
    "render_rig_if_drawn",
    "spheres",
    "to_ned",
    "to_ned_all",
]
