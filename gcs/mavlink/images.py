"""A drone's camera image over MAVLink (image transmission: DATA_TRANSMISSION_HANDSHAKE, ENCAPSULATED_DATA), on the
ground station's side: the request, and the image put back together from its packets (pure).

The drone side (sitl/protocol/images.py) answers one request with one image: a handshake describing it, then its
packets numbered from 0. ``ImageAssembler`` keeps one image in progress per drone; a new handshake starts over, and
an image is complete when every packet of it has arrived. A lost packet loses that image (the next request brings
another), and a handshake of size 0 says the drone has no image to give.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Final

from pymavlink.dialects.v20 import common as mavlink

JPEG: Final = mavlink.MAVLINK_DATA_STREAM_IMG_JPEG
PNG: Final = mavlink.MAVLINK_DATA_STREAM_IMG_PNG
MIME: Final = {JPEG: "image/jpeg", PNG: "image/png"}
REQUEST_JPEG_QUALITY: Final = 80
MAX_IMAGE_BYTES: Final = 4 * 1024 * 1024  # a handshake announcing more is not believed


def image_request(kind: int = JPEG, quality: int = REQUEST_JPEG_QUALITY) -> Any:
    """The handshake that asks a drone for one image (every field but the type and quality zero)."""
    return mavlink.MAVLink_data_transmission_handshake_message(kind, 0, 0, 0, 0, 0, quality)


@dataclass(frozen=True, slots=True)
class CameraImage:
    sysid: int
    time_s: float  # when its last packet arrived (the caller's clock)
    mime: str
    width_px: int
    height_px: int
    data: bytes


@dataclass(slots=True)
class _InProgress:
    kind: int
    size: int
    width_px: int
    height_px: int
    packets: int
    payload: int
    chunks: dict[int, bytes] = field(default_factory=dict)


class ImageAssembler:
    """Images from the drones' handshakes and packets: ``feed`` each message; it returns an image once complete."""

    def __init__(self) -> None:
        self._progress: dict[int, _InProgress] = {}
        self.refused: dict[int, float] = {}  # sysid -> when it last said it had no image

    def feed(self, msg: Any, now_s: float) -> CameraImage | None:
        kind = msg.get_type()
        sysid = msg.get_srcSystem()
        if kind == "DATA_TRANSMISSION_HANDSHAKE":
            self._progress.pop(sysid, None)
            if msg.size == 0 or msg.packets == 0:
                if msg.width == 0 and msg.payload > 0:  # an answer without an image (a request has payload 0)
                    self.refused[sysid] = now_s
                return None
            fits = msg.size <= min(msg.packets * msg.payload, MAX_IMAGE_BYTES) and msg.type in MIME
            if fits and msg.payload > 0:
                self._progress[sysid] = _InProgress(msg.type, msg.size, msg.width, msg.height, msg.packets, msg.payload)
            return None
        if kind != "ENCAPSULATED_DATA":
            return None
        image = self._progress.get(sysid)
        if image is None or not 0 <= msg.seqnr < image.packets:
            return None
        image.chunks[msg.seqnr] = bytes(msg.data[: image.payload])
        if len(image.chunks) < image.packets:
            return None
        del self._progress[sysid]
        data = b"".join(image.chunks[k] for k in range(image.packets))[: image.size]
        return CameraImage(sysid=sysid, time_s=now_s, mime=MIME[image.kind], width_px=image.width_px,
                           height_px=image.height_px, data=data)  # fmt: skip
