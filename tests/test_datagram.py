"""The controller datagram codec: documented layout (versions 1 to 4), round trips,
corruption, HMAC tags, fuzz."""

from __future__ import annotations

import hashlib
import hmac
import math
import pathlib
import re
import struct
import zlib

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxrecog.hardware.devices.datagram import (
    MAGIC,
    MAX_CAMERAS,
    MAX_DATAGRAM,
    VERSION,
    Datagram,
    DatagramAuthError,
    DatagramError,
    Hello,
    InPosition,
    Move,
    Moving,
    MsgType,
    Refused,
    Rejected,
    SharedKey,
    Welcome,
    decode,
    encode,
    session_boot,
)

KEY = SharedKey(b"jaxrecog example key")  # the key of the documented example

finite = st.floats(allow_nan=False, allow_infinity=False)
u32 = st.integers(0, 2**32 - 1)
u64 = st.integers(0, 2**64 - 1)


def ids(version: int):
    """Session ids and nonces a version carries: u64 from version 4 on, u32 before."""
    return u64 if version >= 4 else u32
pairs = st.tuples(finite, finite)


def moves(version: int):
    """Moves a version carries: two cameras with camera 2's tilt 0 in versions 1-2, 0 to 8 in 3."""
    if version <= 2:
        return st.builds(lambda a, b, c, t: Move(((a, b), (c, 0.0)), t), finite, finite, finite, finite)
    return st.builds(Move, st.lists(pairs, max_size=MAX_CAMERAS), finite)


def in_positions(version: int):
    if version <= 2:
        return st.builds(lambda m, gx, gy, ty, t: InPosition(m, ((gx, gy), (ty,)), t),
                         moves(version), finite, finite, finite, finite)
    return moves(version).flatmap(lambda m: st.builds(
        InPosition, st.just(m), st.lists(st.tuples(finite, finite, finite), min_size=len(m.cameras),
                                         max_size=len(m.cameras)), finite))


def payloads(t: MsgType, version: int):
    return {
        MsgType.MOVE: moves(version),
        MsgType.MOVING: st.builds(Moving, moves(version), finite),
        MsgType.IN_POSITION: in_positions(version),
        MsgType.REJECTED: st.builds(Rejected, moves(version), st.integers(0, 65535), st.text(max_size=50)),
        MsgType.PING: st.none(),
        MsgType.PONG: st.none(),
        MsgType.HELLO: st.builds(Hello, ids(version)),
        MsgType.WELCOME: st.builds(Welcome, ids(version), u32),
        MsgType.REFUSED: st.builds(Refused, ids(version), st.integers(0, 65535), st.text(max_size=50)),
    }[t]


datagrams = st.tuples(st.sampled_from(list(MsgType)), st.sampled_from([1, 2, 3, 4])).filter(
    lambda tv: not (tv[0] == MsgType.REFUSED and tv[1] == 1)).flatmap(
    lambda tv: st.builds(Datagram, st.just(tv[0]), ids(tv[1]), u32, payloads(*tv), st.just(tv[1])))


def by_hand(mtype: int, session: int, seq: int, payload: bytes, version: int = VERSION, magic: bytes = MAGIC,
            flags: int | None = None, key: bytes | None = None) -> bytes:
    """The layout of docs/protocol.md, written out independently of the codec: version 1
    without, versions 2 to 4 with the flags byte (and, with ``key``, the HMAC-SHA256 tag);
    version 4 with an 8-byte session."""
    width = 8 if version >= 4 else 4
    body = magic + bytes([version, mtype]) + session.to_bytes(width, "big") + seq.to_bytes(4, "big")
    body += len(payload).to_bytes(2, "big")
    if version >= 2:
        body += bytes([(1 if key is not None else 0) if flags is None else flags])
    body += payload
    if key is not None:
        body += hmac.new(key, body, hashlib.sha256).digest()
    return body + zlib.crc32(body).to_bytes(4, "big")


def documented_examples() -> list[bytes]:
    """The hex dumps of the Example section of docs/protocol.md, in order."""
    text = pathlib.Path(__file__).parents[1].joinpath("docs", "protocol.md").read_text()
    section = text[text.index("## Example"):]
    dumps = re.findall(r"```\n(.*?)```", section, re.S)
    out = []
    for dump in dumps:
        hexes = []
        for line in dump.splitlines():
            data = re.split(r" {3,}", line.strip())[0]  # a comment follows three or more spaces
            assert re.fullmatch(r"[0-9a-f]{2}( {1,2}[0-9a-f]{2})*", data), line
            hexes += data.split()
        out.append(bytes.fromhex("".join(hexes)))
    return out


def test_move_layout_matches_the_documented_bytes():
    """The examples of docs/protocol.md: a two-camera MOVE in version 1 and in version 2
    with the documented key, and a three-camera MOVE in version 3 and in version 4 with the
    key; the codec makes them and decodes them."""
    m = Move(((0.1, 0.5), (-0.3, 0.0)), math.pi)
    angles = struct.pack(">4d", 0.1, 0.5, -0.3, math.pi)
    v1 = encode(Datagram(MsgType.MOVE, 0xDEADBEEF, 7, m, version=1))
    assert v1 == by_hand(1, 0xDEADBEEF, 7, angles, version=1)
    assert len(v1) == 14 + 32 + 4
    v2 = encode(Datagram(MsgType.MOVE, 0xDEADBEEF, 7, m, version=2), KEY)
    assert v2 == by_hand(1, 0xDEADBEEF, 7, angles, version=2, key=b"jaxrecog example key")
    assert len(v2) == 15 + 32 + 32 + 4
    m3 = Move(((0.1, 0.5), (-0.3, 0.25), (0.3, 0.25)), math.pi)
    cameras = bytes([3]) + struct.pack(">7d", 0.1, 0.5, -0.3, 0.25, 0.3, 0.25, math.pi)
    v3 = encode(Datagram(MsgType.MOVE, 0xDEADBEEF, 7, m3, version=3), KEY)
    assert v3 == by_hand(1, 0xDEADBEEF, 7, cameras, version=3, key=b"jaxrecog example key")
    assert len(v3) == 15 + 57 + 32 + 4
    v4 = encode(Datagram(MsgType.MOVE, 0xB0070001DEADBEEF, 7, m3), KEY)
    assert v4 == by_hand(1, 0xB0070001DEADBEEF, 7, cameras, version=4, key=b"jaxrecog example key")
    assert len(v4) == 19 + 57 + 32 + 4
    assert documented_examples() == [v1, v2, v3, v4]
    assert decode(v1) == Datagram(MsgType.MOVE, 0xDEADBEEF, 7, m, version=1)
    assert decode(v2, KEY) == Datagram(MsgType.MOVE, 0xDEADBEEF, 7, m, version=2)
    assert decode(v3, KEY) == Datagram(MsgType.MOVE, 0xDEADBEEF, 7, m3, version=3)
    assert decode(v4, KEY) == Datagram(MsgType.MOVE, 0xB0070001DEADBEEF, 7, m3, version=4)
    plain = encode(Datagram(MsgType.MOVE, 0xDEADBEEF, 7, m3, version=3))
    assert plain == by_hand(1, 0xDEADBEEF, 7, cameras, version=3) and len(plain) == 15 + 57 + 4


def test_version_1_is_still_decoded_and_answered_in_kind():
    """Every version-1 message decodes to a datagram that says version 1 and
    re-encodes to the same bytes; REFUSED and HMAC tags do not exist there."""
    m = Move(((1, 2), (3, 0)), 4)
    for t in MsgType:
        if t == MsgType.REFUSED:
            continue
        example = {MsgType.MOVE: m, MsgType.HELLO: Hello(5), MsgType.WELCOME: Welcome(5, 6),
                   MsgType.REJECTED: Rejected(m, 4, "x"), MsgType.MOVING: Moving(m, 1.5),
                   MsgType.IN_POSITION: InPosition(m, ((5, 6), (7,)), 8)}.get(t)
        dg = Datagram(t, 9, 10, example, version=1)
        raw = encode(dg)
        assert raw[2] == 1 and decode(raw) == dg and encode(decode(raw)) == raw
    with pytest.raises(DatagramError, match="unknown message type 9 in protocol version 1"):
        decode(by_hand(9, 0, 0, struct.pack(">IH", 1, 6), version=1))
    with pytest.raises(DatagramError, match="does not exist in protocol version 1"):
        encode(Datagram(MsgType.REFUSED, 0, 0, Refused(1, 6, "busy"), version=1))
    with pytest.raises(DatagramError, match="version 1 carries no HMAC"):
        encode(Datagram(MsgType.PING, 1, 1, version=1), KEY)
    with pytest.raises(DatagramAuthError, match="without an HMAC tag"):  # a keyed end takes no version-1 datagram
        decode(encode(Datagram(MsgType.PING, 1, 1, version=1)), KEY)


def test_versions_1_and_2_carry_the_thesis_rigs_two_cameras():
    """A version-1/2 move is camera-1 pan, tilt and camera-2 pan: Move.for_version pads a
    missing camera 2 and drops its tilt; encode refuses what that layout cannot hold."""
    three = Move(((0.1, 0.5), (-0.3, 0.2), (0.3, 0.2)), 1.0)
    assert Move(((0.1, 0.5),), 1.0).for_version(2) == Move(((0.1, 0.5), (0.0, 0.0)), 1.0)
    assert three.for_version(3) is three and Move(three.cameras[:2], 1.0).for_version(1).cameras[1] == (-0.3, 0.0)
    with pytest.raises(ValueError, match="protocol version 2 moves at most 2 cameras, not 3"):
        three.for_version(2)
    for bad in (three, Move(three.cameras[:2], 1.0), Move((), 0.0)):
        with pytest.raises(DatagramError, match="a version-2 move has camera-1 pan, tilt and camera-2 pan"):
            encode(Datagram(MsgType.MOVE, 1, 1, bad, version=2))
    with pytest.raises(DatagramError, match=r"version 2 reports \(gantry x, y\), \(track y,\)"):
        encode(Datagram(MsgType.IN_POSITION, 1, 1, InPosition(Move(((1, 2), (3, 0)), 4), ((1, 2, 3), (4, 5, 6)), 7),
                        version=2))


def test_version_3_carries_n_cameras():
    """Count, (pan, tilt) per camera, turn-table; IN_POSITION adds every camera's eye."""
    m = Move(((0.1, 0.5), (-0.3, 0.25), (0.3, 0.25)), 2.0)
    eyes = ((1.0, 2.0, 0.7), (0.75, -0.2, 0.25), (-0.75, 0.2, 0.25))
    raw = encode(Datagram(MsgType.IN_POSITION, 1, 2, InPosition(m, eyes, 2.5)))
    assert raw == by_hand(3, 1, 2, bytes([3]) + struct.pack(">7d", *m.astuple())
                          + struct.pack(">10d", *(v for e in eyes for v in e), 2.5))
    assert decode(raw).payload == InPosition(m, eyes, 2.5)
    for n in (0, 1, MAX_CAMERAS):
        mn = Move([(0.1 * k, 0.2) for k in range(n)], 0.5)
        for dg in (Datagram(MsgType.MOVE, 1, 2, mn), Datagram(MsgType.MOVING, 1, 2, Moving(mn, 3.0)),
                   Datagram(MsgType.REJECTED, 1, 2, Rejected(mn, 2, "no")),
                   Datagram(MsgType.IN_POSITION, 1, 2, InPosition(mn, [(1.0, 2.0, 3.0)] * n, 0.5))):
            assert decode(encode(dg, KEY), KEY) == dg
    with pytest.raises(DatagramError, match=f"9 cameras, at most {MAX_CAMERAS}"):
        encode(Datagram(MsgType.MOVE, 1, 2, Move([(0.0, 0.0)] * 9, 0.0)))
    with pytest.raises(DatagramError, match="an \\(x, y, z\\) eye for each of the 3 cameras"):
        encode(Datagram(MsgType.IN_POSITION, 1, 2, InPosition(m, eyes[:2], 2.5)))


def test_hmac_tag_is_required_checked_and_never_shown():
    dg = Datagram(MsgType.MOVE, 3, 4, Move(((0.1, 0.2), (0.3, 0.4)), 0.5))
    tagged = encode(dg, KEY)
    assert decode(tagged, KEY) == dg
    with pytest.raises(DatagramAuthError, match="tag mismatch"):
        decode(tagged, SharedKey(b"another key of 16+ bytes"))
    with pytest.raises(DatagramAuthError, match="no shared key"):
        decode(tagged)
    with pytest.raises(DatagramAuthError, match="without an HMAC tag"):
        decode(encode(dg), KEY)
    # a forger who recomputes the CRC over changed angles still fails the tag
    forged = bytearray(tagged[:-4])
    forged[20] ^= 0x01
    forged += zlib.crc32(bytes(forged)).to_bytes(4, "big")
    with pytest.raises(DatagramAuthError, match="tag mismatch"):
        decode(bytes(forged), KEY)
    # the key is in no repr, str or message
    secret = "jaxrecog example key"
    assert secret not in repr(KEY) and secret not in str(KEY) and secret not in repr(dg)
    with pytest.raises(ValueError, match="at least 16 bytes") as e:
        SharedKey(b"short secret")
    assert "short secret" not in str(e.value)
    assert KEY == SharedKey(b"jaxrecog example key") and hash(KEY) == hash(SharedKey(b"jaxrecog example key"))


def test_refused_layout():
    raw = encode(Datagram(MsgType.REFUSED, 0, 0, Refused(0x01020304, 6, "busy"), version=3))
    assert raw == by_hand(9, 0, 0, bytes([1, 2, 3, 4, 0, 6]) + b"busy", version=3)
    assert decode(raw).payload == Refused(0x01020304, 6, "busy")
    raw = encode(Datagram(MsgType.REFUSED, 0, 0, Refused(0x0102030405060708, 6, "busy")))
    assert raw == by_hand(9, 0, 0, bytes([1, 2, 3, 4, 5, 6, 7, 8, 0, 6]) + b"busy", version=4)


def test_hello_and_welcome_layout():
    """HELLO carries the client's nonce; WELCOME the nonce and the controller's boot id,
    with the issued session in the header (docs/protocol.md)."""
    hello = encode(Datagram(MsgType.HELLO, 0, 0, Hello(0x01020304), version=1))
    assert hello == by_hand(7, 0, 0, bytes([1, 2, 3, 4]), version=1)
    assert encode(Datagram(MsgType.HELLO, 0, 0, Hello(0x01020304), version=3)) == \
        by_hand(7, 0, 0, bytes([1, 2, 3, 4]), version=3)
    welcome = encode(Datagram(MsgType.WELCOME, 0xCAFEF00D, 0, Welcome(0x01020304, 0xB0070001), version=3))
    assert welcome == by_hand(8, 0xCAFEF00D, 0, bytes([1, 2, 3, 4, 0xB0, 0x07, 0x00, 0x01]), version=3)
    assert decode(welcome).payload == Welcome(0x01020304, 0xB0070001)
    # version 4: a u64 nonce, and a session id whose high half is the boot id
    nonce = bytes([1, 2, 3, 4, 5, 6, 7, 8])
    assert encode(Datagram(MsgType.HELLO, 0, 0, Hello(0x0102030405060708))) == by_hand(7, 0, 0, nonce, version=4)
    welcome = encode(Datagram(MsgType.WELCOME, 0xB0070001CAFEF00D, 0, Welcome(0x0102030405060708, 0xB0070001)))
    assert welcome == by_hand(8, 0xB0070001CAFEF00D, 0, nonce + bytes([0xB0, 0x07, 0x00, 0x01]), version=4)
    assert session_boot(decode(welcome).session) == decode(welcome).payload.boot == 0xB0070001
    with pytest.raises(DatagramError, match="HELLO payload is 3 bytes"):
        decode(by_hand(7, 0, 0, b"abc"))
    with pytest.raises(DatagramError, match="u32"):
        encode(Datagram(MsgType.WELCOME, 1, 0, Welcome(1, 2**32)))
    with pytest.raises(DatagramError, match="HELLO nonce 4294967296 does not fit in u32"):
        encode(Datagram(MsgType.HELLO, 0, 0, Hello(2**32), version=3))


def test_in_position_layout_of_version_2():
    p = InPosition(Move(((1, 2), (3, 0)), 4), ((0.5, -0.25), (1.0,)), 3.0)
    raw = encode(Datagram(MsgType.IN_POSITION, 1, 2, p, version=2))
    assert raw == by_hand(3, 1, 2, struct.pack(">8d", 1, 2, 3, 4, 0.5, -0.25, 1.0, 3.0), version=2)
    assert decode(raw).payload == p


@settings(max_examples=200, deadline=None)
@given(datagrams)
def test_round_trip(dg):
    keys = [None, KEY] if dg.version >= 2 else [None]
    for key in keys:
        raw = encode(dg, key)
        assert len(raw) <= MAX_DATAGRAM
        out = decode(raw, key)
        if dg.type in (MsgType.REJECTED, MsgType.REFUSED):  # reasons are cut to 200 UTF-8 bytes
            assert out.payload.reason == dg.payload.reason.encode()[:200].decode("utf-8", "ignore")
            assert out.payload.code == dg.payload.code
        else:
            assert out == dg


@pytest.mark.parametrize("version,key", [(1, None), (2, None), (2, KEY), (3, None), (3, KEY), (4, None), (4, KEY)],
                         ids=["v1", "v2", "v2-hmac", "v3", "v3-hmac", "v4", "v4-hmac"])
def test_every_single_bit_flip_is_detected(version, key):
    m = Move(((1, 2), (3, 0)), 4)
    p = InPosition(m, ((5, 6), (7,)), 8) if version <= 2 else InPosition(m, ((5, 6, 7), (8, 9, 10)), 11)
    raw = encode(Datagram(MsgType.IN_POSITION, 99, 12345, p, version), key)
    for i in range(len(raw) * 8):
        bad = bytearray(raw)
        bad[i // 8] ^= 1 << (i % 8)
        with pytest.raises(DatagramError):
            decode(bytes(bad), key)


@pytest.mark.parametrize(
    "raw,match",
    [
        (b"", "shorter"),
        (by_hand(1, 1, 1, struct.pack(">4d", 0, 0, 0, 0), version=5), "version 5"),
        (by_hand(1, 1, 1, struct.pack(">4d", 0, 0, 0, 0), flags=0x02), "unknown flags"),
        (by_hand(1, 1, 1, struct.pack(">4d", 0, 0, 0, 0), flags=0x01), "length"),  # flag set, no tag
        (by_hand(1, 1, 1, struct.pack(">4d", 0, 0, 0, 0), version=1)[:15] + b"\x00" * 3, "payload_len"),
        (by_hand(1, 1, 1, struct.pack(">4d", 0, 0, 0, 0), magic=b"XX"), "magic"),
        (by_hand(10, 1, 1, b""), "unknown message type"),
        (by_hand(9, 0, 0, b"\x00\x00"), "REFUSED payload is 2 bytes"),
        (by_hand(1, 1, 1, struct.pack(">3d", 0, 0, 0), version=2), "payload is 24 bytes"),
        (by_hand(5, 1, 1, b"x"), "no payload"),
        (by_hand(1, 1, 1, struct.pack(">4d", 0, math.nan, 0, 0), version=2), "non-finite"),
        (by_hand(3, 1, 1, struct.pack(">8d", 0, 0, 0, 0, math.inf, 0, 0, 0), version=2), "non-finite"),
        (by_hand(4, 1, 1, struct.pack(">4dH", 0, 0, 0, 0, 1) + b"\xff\xfe", version=2), "UTF-8"),
        (by_hand(1, 1, 1, b""), "MOVE payload is 0 bytes, expected a camera count"),
        (by_hand(1, 1, 1, bytes([9]) + struct.pack(">19d", *[0] * 19)), "9 cameras, at most 8"),
        (by_hand(1, 1, 1, bytes([2]) + struct.pack(">3d", 0, 0, 0)), "payload is 25 bytes, expected 41 for 2 cameras"),
        (by_hand(1, 1, 1, bytes([1]) + struct.pack(">3d", 0, math.inf, 0)), "non-finite"),
        (by_hand(3, 1, 1, bytes([1]) + struct.pack(">6d", 0, 0, 0, 0, 0, 0)), "IN_POSITION payload is 49 bytes, "
                                                                              "expected 57 for 1 cameras"),
        (by_hand(4, 1, 1, bytes([0]) + struct.pack(">d", 0) + b"\x00"), "REJECTED payload is 10 bytes"),
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
        encode(Datagram(MsgType.MOVE, 1, 1, Move(((0, math.inf),), 0)))
    with pytest.raises(DatagramError, match="version-3 session 4294967296 does not fit in u32"):
        encode(Datagram(MsgType.PING, 2**32, 1, version=3))
    assert decode(encode(Datagram(MsgType.PING, 2**32, 1))).session == 2**32  # version 4: a u64
    with pytest.raises(DatagramError, match="version-4 session .* does not fit in u64"):
        encode(Datagram(MsgType.PING, 2**64, 1))
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
@given(st.integers(0, 255), u32, u32, st.binary(max_size=80), st.sampled_from([1, 2, 3, 4]))
def test_fuzz_decode_valid_envelopes(mtype, session, seq, payload, version):
    # a correct header and CRC around arbitrary payload bytes reaches the payload parsers
    raw = by_hand(mtype, session, seq, payload, version=version)
    try:
        dg = decode(raw)
    except DatagramError:
        return
    assert (dg.type, dg.session, dg.seq) == (mtype, session, seq)
    assert encode(dg) == raw
