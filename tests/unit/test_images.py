"""MAVLink image transmission: the drone's answer to an image request (sitl/protocol/images.py) and the ground
station putting the image back together (gcs/mavlink/images.py), through a wire that really packs and parses."""

from __future__ import annotations

import os

from pymavlink.dialects.v20 import common as mavlink

from gcs.mavlink.images import JPEG, PNG, ImageAssembler, image_request
from sitl.protocol.images import MAX_IMAGES_PER_S, PAYLOAD_BYTES, EncodedImage, ImageService
from sitl.protocol.testing import Wire

DRONE = 7
PICTURE = EncodedImage(data=os.urandom(5 * PAYLOAD_BYTES + 17) + b"\0\0\0", width_px=640, height_px=120)


class Rig:
    def __init__(self, picture: EncodedImage | None = PICTURE) -> None:
        self.asked: list[tuple[int, int]] = []

        def camera(kind: int, quality: int) -> EncodedImage | None:
            self.asked.append((kind, quality))
            return picture

        self.service = ImageService(camera)
        self.up, self.down = Wire(255, 190), Wire(DRONE, 1)
        self.assembler = ImageAssembler()

    def ask(self, now_s: float, kind: int = JPEG, quality: int = 80) -> list[mavlink.MAVLink_message]:
        return self.down.carry(self.service.handle(self.up(image_request(kind, quality)), now_s))


def test_one_request_brings_one_whole_image_back() -> None:
    rig = Rig()
    answer = rig.ask(1.0)
    handshake, packets = answer[0], answer[1:]
    assert handshake.get_type() == "DATA_TRANSMISSION_HANDSHAKE"
    assert (handshake.size, handshake.width, handshake.height) == (len(PICTURE.data), 640, 120)
    assert handshake.packets == len(packets) == 6 and handshake.payload == PAYLOAD_BYTES
    assert [p.seqnr for p in packets] == list(range(6))
    assert rig.asked == [(JPEG, 80)]
    images = [rig.assembler.feed(m, 1.0) for m in answer]
    assert images[:-1] == [None] * 6
    image = images[-1]
    assert image is not None and image.data == PICTURE.data  # trailing zero bytes included: the size says so
    assert (image.sysid, image.mime, image.width_px, image.height_px) == (DRONE, "image/jpeg", 640, 120)


def test_a_lost_packet_loses_that_image_and_the_next_request_brings_another() -> None:
    rig = Rig()
    first = rig.ask(1.0)
    assert [rig.assembler.feed(m, 1.0) for m in first[:3] + first[4:]] == [None] * 6
    second = rig.ask(2.0)
    assert [rig.assembler.feed(m, 2.0) for m in second][-1] is not None


def test_requests_beyond_the_rate_are_ignored() -> None:
    rig = Rig()
    assert rig.ask(1.0)
    assert rig.ask(1.0 + 0.5 / MAX_IMAGES_PER_S) == []
    assert rig.ask(1.0 + 1.0 / MAX_IMAGES_PER_S)
    assert len(rig.asked) == 2


def test_what_cannot_be_served_gets_an_empty_answer_and_the_station_knows() -> None:
    for rig, kind in ((Rig(), mavlink.MAVLINK_DATA_STREAM_IMG_BMP), (Rig(picture=None), PNG)):
        answer = rig.ask(1.0, kind)
        assert [(m.get_type(), m.size, m.packets) for m in answer] == [("DATA_TRANSMISSION_HANDSHAKE", 0, 0)]
        assert rig.assembler.feed(answer[0], 1.0) is None and rig.assembler.refused == {DRONE: 1.0}


def test_a_handshake_that_describes_an_image_is_no_request() -> None:
    rig = Rig()
    answer = rig.ask(1.0)
    assert rig.service.handle(answer[0], 5.0) == []  # another drone's answer heard on a shared link
    # and a quality of 0 asks for the default
    assert Rig().ask(1.0, quality=0)[0].jpg_quality == 80


def test_the_assembler_refuses_an_announcement_it_cannot_hold() -> None:
    assembler = ImageAssembler()
    wire = Wire(DRONE, 1)
    bogus = mavlink.MAVLink_data_transmission_handshake_message(JPEG, 10_000, 1, 1, 2, PAYLOAD_BYTES, 80)
    assembler.feed(wire(bogus), 1.0)  # 10,000 bytes cannot fit in two packets
    for seq in range(2):
        assert assembler.feed(wire(mavlink.MAVLink_encapsulated_data_message(seq, [1] * PAYLOAD_BYTES)), 1.0) is None
