"""The controller datagram codec: documented layout, round trips, corruption, fuzz."""

from __future__ import annotations

import math
import struct
import zlib

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxrecog.hardware.datagram import (
    MAGIC,
    MAX_DATAGRAM,
    VERSION,
    Datagram,
    DatagramError,
    Hello,
    InPosition,
    Move,
    Moving,
    MsgType,
    Rejected,
    Welcome,
    decode,
    encode,
)

finite = st.floats(allow_nan=False, allow_infinity=False)
u32 = st.integers(0, 2**32 - 1)
moves = st.builds(Move, finite, finite, finite, finite)
payloads = {
    MsgType.MOVE: moves,
    MsgType.MOVING: st.builds(Moving, moves, finite),
    MsgType.IN_POSITION: st.builds(InPosition, moves, finite, finite, finite, finite),
    MsgType.REJECTED: st.builds(Rejected, moves, st.integers(0, 65535), st.text(max_size=50)),
    MsgType.PING: st.none(),
    MsgType.PONG: st.none(),
    MsgType.HELLO: st.builds(Hello, u32),
    MsgType.WELCOME: st.builds(Welcome, u32, u32),
}
datagrams = st.sampled_from(list(MsgType)).flatmap(
    lambda t: st.builds(Datagram, st.just(t), u32, u32, payloads[t])
)


def by_hand(mtype: int, session: int, seq: int, payload: bytes, version: int = VERSION, magic: bytes = MAGIC) -> bytes:
    """The layout of docs/protocol.md, written out independently of the codec."""
    body = magic + bytes([version, mtype]) + session.to_bytes(4, "big") + seq.to_bytes(4, "big")
    body += len(payload).to_bytes(2, "big") + payload
    return body + zlib.crc32(body).to_bytes(4, "big")


def test_move_layout_matches_the_documented_bytes():
    m = Move(0.1, 0.5, -0.3, math.pi)
    raw = encode(Datagram(MsgType.MOVE, 0xDEADBEEF, 7, m))
    assert raw == by_hand(1, 0xDEADBEEF, 7, struct.pack(">4d", 0.1, 0.5, -0.3, math.pi))
    assert len(raw) == 14 + 32 + 4


def test_hello_and_welcome_layout():
    """HELLO carries the client's nonce; WELCOME the nonce and the controller's boot id,
    with the issued session in the header (docs/protocol.md)."""
    hello = encode(Datagram(MsgType.HELLO, 0, 0, Hello(0x01020304)))
    assert hello == by_hand(7, 0, 0, bytes([1, 2, 3, 4]))
    welcome = encode(Datagram(MsgType.WELCOME, 0xCAFEF00D, 0, Welcome(0x01020304, 0xB0070001)))
    assert welcome == by_hand(8, 0xCAFEF00D, 0, bytes([1, 2, 3, 4, 0xB0, 0x07, 0x00, 0x01]))
    assert decode(welcome).payload == Welcome(0x01020304, 0xB0070001)
    with pytest.raises(DatagramError, match="HELLO payload is 3 bytes"):
        decode(by_hand(7, 0, 0, b"abc"))
    with pytest.raises(DatagramError, match="u32"):
        encode(Datagram(MsgType.WELCOME, 1, 0, Welcome(1, 2**32)))


def test_in_position_layout():
    p = InPosition(Move(1, 2, 3, 4), 0.5, -0.25, 1.0, 3.0)
    raw = encode(Datagram(MsgType.IN_POSITION, 1, 2, p))
    assert raw == by_hand(3, 1, 2, struct.pack(">8d", 1, 2, 3, 4, 0.5, -0.25, 1.0, 3.0))


@settings(max_examples=200, deadline=None)
@given(datagrams)
def test_round_trip(dg):
    raw = encode(dg)
    assert len(raw) <= MAX_DATAGRAM
    out = decode(raw)
    if dg.type == MsgType.REJECTED:  # reasons are cut to 200 UTF-8 bytes
        assert out.payload.reason == dg.payload.reason.encode()[:200].decode("utf-8", "ignore")
        assert (out.payload.move, out.payload.code) == (dg.payload.move, dg.payload.code)
    else:
        assert out == dg


def test_every_single_bit_flip_is_detected():
    raw = encode(Datagram(MsgType.IN_POSITION, 99, 12345, InPosition(Move(1, 2, 3, 4), 5, 6, 7, 8)))
    for i in range(len(raw) * 8):
        bad = bytearray(raw)
        bad[i // 8] ^= 1 << (i % 8)
        with pytest.raises(DatagramError):
            decode(bytes(bad))


@pytest.mark.parametrize(
    "raw,match",
    [
        (b"", "shorter"),
        (by_hand(1, 1, 1, struct.pack(">4d", 0, 0, 0, 0), version=2), "version 2"),
        (by_hand(1, 1, 1, struct.pack(">4d", 0, 0, 0, 0), magic=b"XX"), "magic"),
        (by_hand(9, 1, 1, b""), "unknown message type"),
        (by_hand(1, 1, 1, struct.pack(">3d", 0, 0, 0)), "payload is 24 bytes"),
        (by_hand(5, 1, 1, b"x"), "no payload"),
        (by_hand(1, 1, 1, struct.pack(">4d", 0, math.nan, 0, 0)), "non-finite"),
        (by_hand(3, 1, 1, struct.pack(">8d", 0, 0, 0, 0, math.inf, 0, 0, 0)), "non-finite"),
        (by_hand(4, 1, 1, struct.pack(">4dH", 0, 0, 0, 0, 1) + b"\xff\xfe"), "UTF-8"),
        (encode(Datagram(MsgType.PING, 1, 1))[:-1], "length|shorter"),
        (encode(Datagram(MsgType.PING, 1, 1)) + b"\x00", "length"),
        (b"JR" + bytes(600), "exceeds"),
    ],
)
def test_malformed_datagrams_are_rejected_with_a_reason(raw, match):
    with pytest.raises(DatagramError, match=match):
        decode(raw)


def test_encode_refuses_what_it_could_not_decode():
    with pytest.raises(DatagramError, match="non-finite"):
        encode(Datagram(MsgType.MOVE, 1, 1, Move(0, math.inf, 0, 0)))
    with pytest.raises(DatagramError, match="u32"):
        encode(Datagram(MsgType.PING, 2**32, 1))
    with pytest.raises(DatagramError, match="payload"):
        encode(Datagram(MsgType.MOVE, 1, 1, None))


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=80))
def test_fuzz_decode_random_bytes(raw):
    try:
        dg = decode(raw)
    except DatagramError:
        return
    assert encode(dg) == raw


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 255), u32, u32, st.binary(max_size=80))
def test_fuzz_decode_valid_envelopes(mtype, session, seq, payload):
    # a correct header and CRC around arbitrary payload bytes reaches the payload parsers
    raw = by_hand(mtype, session, seq, payload)
    try:
        dg = decode(raw)
    except DatagramError:
        return
    assert (dg.type, dg.session, dg.seq) == (mtype, session, seq)
    assert encode(dg) == raw
