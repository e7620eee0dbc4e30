"""MAVLink image transmission (https://mavlink.io/en/services/image_transmission.html): what the drone's camera sees,
on request, in DATA_TRANSMISSION_HANDSHAKE and ENCAPSULATED_DATA messages.

A request is a DATA_TRANSMISSION_HANDSHAKE whose size, width, height, packets and payload are zero, with the image
type wanted (JPEG, with its ``jpg_quality``, or PNG). The answer is a handshake describing one image (its byte size,
width, height, the number of packets and the payload size per packet, 253) followed by that many ENCAPSULATED_DATA
messages numbered from 0, the last padded with zeros. One request gets one image: the requester asks again for the
next, so a lost packet costs one image and nothing waits for a stream to be stopped. A request the drone cannot
serve (an image type it does not make, no camera, no attitude yet) is answered with a handshake of size 0 and no
packets, so the requester knows at once. Requests beyond ``MAX_IMAGES_PER_S`` are ignored: images are the largest
thing a drone sends, and a flood of requests must not flood its link.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Final

from pymavlink.dialects.v20 import common as mavlink

from sitl.protocol.core import Effect, MAVLinkMessage, PeerInputError, Send, check_now, read_int

PAYLOAD_BYTES: Final = 253  # ENCAPSULATED_DATA's data field
MAX_IMAGES_PER_S: Final = 4.0
IMAGE_TYPES: Final = frozenset({mavlink.MAVLINK_DATA_STREAM_IMG_JPEG, mavlink.MAVLINK_DATA_STREAM_IMG_PNG})
DEFAULT_JPEG_QUALITY: Final = 80  # a request that leaves jpg_quality 0 gets this


@dataclass(frozen=True, slots=True)
class EncodedImage:
    data: bytes  # the file's bytes (JPEG or PNG)
    width_px: int
    height_px: int


ImageSource = Callable[[int, int], EncodedImage | None]  # (MAVLINK_DATA_STREAM type, JPEG quality) -> the image now


def packets_of(image: EncodedImage, kind: int, quality: int) -> list[MAVLinkMessage]:
    """The handshake that describes ``image`` and the ENCAPSULATED_DATA messages that carry it."""
    data = image.data
    count = -(-len(data) // PAYLOAD_BYTES)
    out: list[MAVLinkMessage] = [
        mavlink.MAVLink_data_transmission_handshake_message(
            kind, len(data), image.width_px, image.height_px, count, PAYLOAD_BYTES, quality
        )
    ]
    for seq in range(count):
        chunk = data[seq * PAYLOAD_BYTES : (seq + 1) * PAYLOAD_BYTES]
        out.append(mavlink.MAVLink_encapsulated_data_message(seq, list(chunk.ljust(PAYLOAD_BYTES, b"\0"))))
    return out


class ImageService:
    """Answers image requests from ``source`` (the drone's camera), at most MAX_IMAGES_PER_S."""

    handles: frozenset[int] = frozenset({mavlink.MAVLINK_MSG_ID_DATA_TRANSMISSION_HANDSHAKE})

    def __init__(self, source: ImageSource) -> None:
        self._source = source
        self._next_allowed_s = -1.0

    def handle(self, msg: MAVLinkMessage, now_s: float) -> list[Effect]:
        now_s = check_now(now_s)
        try:
            kind = read_int(msg, "type", lo=0, hi=255)
            quality = read_int(msg, "jpg_quality", lo=0, hi=255)
            described = [read_int(msg, name) for name in ("size", "width", "height", "packets", "payload")]
        except PeerInputError:
            return []
        if any(described):
            return []  # another system's answer, not a request
        if now_s < self._next_allowed_s:
            return []
        self._next_allowed_s = now_s + 1.0 / MAX_IMAGES_PER_S
        quality = min(quality, 100) or DEFAULT_JPEG_QUALITY
        image = self._source(kind, quality) if kind in IMAGE_TYPES else None
        if image is None:
            return [Send(mavlink.MAVLink_data_transmission_handshake_message(kind, 0, 0, 0, 0, PAYLOAD_BYTES, quality))]
        return [Send(m) for m in packets_of(image, kind, quality)]

    def poll(self, now_s: float) -> list[Effect]:
        check_now(now_s)
        return []
