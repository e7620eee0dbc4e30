"""Long STATUSTEXTs, cut into chunks by the drone (sitl/protocol/statustext.py), come out whole and once at the
ground station (gcs/mavlink/statustext.py), however they interleave; a text whose end never comes does not pile up."""

from __future__ import annotations

from gcs.mavlink.statustext import MAX_PENDING, StatusTextAssembler
from sitl.protocol.statustext import StatusTextEncoder

LONG = "Avoidance: braking for drone 7 at 1.42 m, closing at 1.9 m/s, heading 231 deg"  # 78 characters
EXACT = "x" * 100  # two full chunks, then an empty one that ends it


def decoded(messages: list) -> list:  # type: ignore[type-arg]
    """As the ground station receives them: packed and parsed by pymavlink."""
    from pymavlink.dialects.v20 import common as mavlink

    parser = mavlink.MAVLink(None, srcSystem=3, srcComponent=1)
    return [parser.decode(bytearray(m.pack(parser))) for m in messages]


def test_a_long_text_comes_out_whole_once_its_last_chunk_arrives() -> None:
    chunks = decoded(StatusTextEncoder().encode(4, LONG))
    assert len(chunks) == 2
    texts = StatusTextAssembler()
    assert texts.feed(3, chunks[0]) is None
    assert texts.feed(3, chunks[1]) == LONG


def test_a_short_text_is_whole_and_a_text_filling_its_chunks_ends_with_an_empty_one() -> None:
    encoder, texts = StatusTextEncoder(), StatusTextAssembler()
    [short] = decoded(encoder.encode(6, "Mode OFFBOARD"))
    assert texts.feed(3, short) == "Mode OFFBOARD"
    exact = decoded(encoder.encode(6, EXACT))
    assert len(exact) == 3 and [texts.feed(3, c) for c in exact] == [None, None, EXACT]


def test_chunks_of_two_drones_and_of_two_texts_interleaved_do_not_mix() -> None:
    a = decoded(StatusTextEncoder().encode(4, LONG))
    b = decoded(StatusTextEncoder().encode(4, LONG.upper()))  # the same chunk ids, from another drone
    texts = StatusTextAssembler()
    out = [texts.feed(sysid, c) for sysid, c in ((3, a[0]), (4, b[0]), (4, b[1]), (3, a[1]))]
    assert out == [None, None, LONG.upper(), LONG]


def test_texts_whose_end_never_comes_are_dropped_beyond_the_pending_limit() -> None:
    encoder, texts = StatusTextEncoder(), StatusTextAssembler()
    for _ in range(MAX_PENDING + 5):
        texts.feed(3, decoded(encoder.encode(4, LONG))[0])  # only the first chunk of each
    assert len(texts._pending) == MAX_PENDING
