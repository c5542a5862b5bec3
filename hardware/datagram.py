"""Versioned binary datagrams between the vision PC and the motion controller (thesis §6.6).

Wire format (network byte order; full description in ``docs/protocol.md``)::

    offset size field
    0      2    magic          b"JR"
    2      1    version        1
    3      1    type           MsgType
    4      4    session        u32, chosen at random by the client per link
    8      4    seq            u32, one per move; retransmissions reuse it
    12     2    payload_len    u16
    14     n    payload        depends on type
    14+n   4    crc32          zlib.crc32 of bytes 0 .. 14+n-1

Payloads (IEEE-754 doubles, radians and metres):

* ``MOVE``        client -> controller: cam1_pan, cam1_tilt, cam2_pan, turntable (4 d)
* ``MOVING``      controller -> client: the MOVE echoed (4 d), expected seconds (d)
* ``IN_POSITION`` controller -> client: the MOVE echoed (4 d), achieved gantry x, y,
  track y, turntable angle (4 d) -- the capture signal
* ``REJECTED``    controller -> client: the MOVE echoed (4 d), code (u16), UTF-8 reason
* ``PING`` / ``PONG``: empty
* ``HELLO``       client -> controller: nonce (u32); header session 0, seq 0
* ``WELCOME``     controller -> client: the nonce echoed (u32), the controller's
  boot id (u32); the header's session is the new session id the controller
  issued, seq 0

:func:`decode` raises :class:`DatagramError` -- and nothing else -- for any
input that is not a well-formed datagram of this version.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import struct
import zlib

__all__ = [
    "MAGIC",
    "VERSION",
    "MAX_DATAGRAM",
    "MsgType",
    "RejectCode",
    "Datagram",
    "DatagramError",
    "Move",
    "Moving",
    "InPosition",
    "Rejected",
    "Hello",
    "Welcome",
    "encode",
    "decode",
]

MAGIC = b"JR"
VERSION = 1
MAX_DATAGRAM = 512

_HEADER = struct.Struct("!2sBBIIH")
_CRC = struct.Struct("!I")
_MOVE = struct.Struct("!4d")
_MOVING = struct.Struct("!4dd")
_INPOS = struct.Struct("!8d")
_REJ = struct.Struct("!4dH")
_HELLO = struct.Struct("!I")
_WELCOME = struct.Struct("!II")
_MAX_REASON = 200


class MsgType(enum.IntEnum):
    MOVE = 1
    MOVING = 2
    IN_POSITION = 3
    REJECTED = 4
    PING = 5
    PONG = 6
    HELLO = 7
    WELCOME = 8


class RejectCode(enum.IntEnum):
    WORKSPACE = 1  # a kinematics / workspace limit
    BAD_REQUEST = 2  # payload the controller cannot act on
    BUSY = 3  # a newer move superseded this one
    UNKNOWN_SESSION = 4  # a session this controller never issued (it restarted since): not executed


class DatagramError(ValueError):
    """Bytes that are not a valid datagram (corrupt, truncated, foreign, wrong version)."""


@dataclasses.dataclass(frozen=True)
class Move:
    """Desired planner angles (radians): camera-1 pan/tilt, camera-2 pan, turn-table angle."""

    cam1_pan: float
    cam1_tilt: float
    cam2_pan: float
    turntable: float

    def astuple(self) -> tuple[float, float, float, float]:
        return (self.cam1_pan, self.cam1_tilt, self.cam2_pan, self.turntable)


@dataclasses.dataclass(frozen=True)
class Moving:
    move: Move
    expected_s: float


@dataclasses.dataclass(frozen=True)
class InPosition:
    """The capture signal: the move it answers and where the axes actually are."""

    move: Move
    gantry_x: float
    gantry_y: float
    track_y: float
    turntable: float


@dataclasses.dataclass(frozen=True)
class Rejected:
    move: Move
    code: int
    reason: str


@dataclasses.dataclass(frozen=True)
class Hello:
    """Opens a session: ``nonce`` is the client's random tag for the WELCOME it waits for."""

    nonce: int


@dataclasses.dataclass(frozen=True)
class Welcome:
    """The controller's answer to a HELLO: the nonce echoed and its boot id (new after
    every restart); the datagram's ``session`` is the session id it issued."""

    nonce: int
    boot: int


Payload = Move | Moving | InPosition | Rejected | Hello | Welcome | None

_PAYLOAD_TYPE = {
    MsgType.MOVE: Move,
    MsgType.MOVING: Moving,
    MsgType.IN_POSITION: InPosition,
    MsgType.REJECTED: Rejected,
    MsgType.PING: type(None),
    MsgType.PONG: type(None),
    MsgType.HELLO: Hello,
    MsgType.WELCOME: Welcome,
}


@dataclasses.dataclass(frozen=True)
class Datagram:
    type: MsgType
    session: int
    seq: int
    payload: Payload = None


def _finite(values, what: str) -> None:
    for v in values:
        if not math.isfinite(v):
            raise DatagramError(f"{what}: non-finite number {v!r} in payload")


def _pack_payload(dg: Datagram) -> bytes:
    p = dg.payload
    if not isinstance(p, _PAYLOAD_TYPE[dg.type]):
        raise DatagramError(f"{dg.type.name} needs a {_PAYLOAD_TYPE[dg.type].__name__} payload, got {type(p).__name__}")
    if p is None:
        return b""
    if isinstance(p, Hello):
        _u32(p.nonce, "HELLO nonce")
        return _HELLO.pack(p.nonce)
    if isinstance(p, Welcome):
        _u32(p.nonce, "WELCOME nonce")
        _u32(p.boot, "WELCOME boot")
        return _WELCOME.pack(p.nonce, p.boot)
    if isinstance(p, Move):
        vals = p.astuple()
        _finite(vals, "MOVE")
        return _MOVE.pack(*vals)
    if isinstance(p, Moving):
        vals = (*p.move.astuple(), p.expected_s)
        _finite(vals, "MOVING")
        return _MOVING.pack(*vals)
    if isinstance(p, InPosition):
        vals = (*p.move.astuple(), p.gantry_x, p.gantry_y, p.track_y, p.turntable)
        _finite(vals, "IN_POSITION")
        return _INPOS.pack(*vals)
    assert isinstance(p, Rejected)
    _finite(p.move.astuple(), "REJECTED")
    if not 0 <= p.code <= 0xFFFF:
        raise DatagramError(f"REJECTED code {p.code} does not fit in u16")
    reason = p.reason.encode("utf-8")[:_MAX_REASON].decode("utf-8", "ignore").encode("utf-8")
    return _REJ.pack(*p.move.astuple(), p.code) + reason


def _u32(v: int, what: str) -> None:
    if not 0 <= v <= 0xFFFFFFFF:
        raise DatagramError(f"{what} {v} does not fit in u32")


def encode(dg: Datagram) -> bytes:
    """Datagram -> bytes (header, payload, CRC32)."""
    for name in ("session", "seq"):
        _u32(getattr(dg, name), name)
    payload = _pack_payload(dg)
    head = _HEADER.pack(MAGIC, VERSION, int(dg.type), dg.session, dg.seq, len(payload))
    body = head + payload
    return body + _CRC.pack(zlib.crc32(body))


def _unpack_payload(t: MsgType, raw: bytes) -> Payload:
    def need(s: struct.Struct, exact: bool = True) -> tuple:
        if (len(raw) != s.size) if exact else (len(raw) < s.size):
            raise DatagramError(f"{t.name} payload is {len(raw)} bytes, expected {s.size}")
        vals = s.unpack_from(raw)
        return vals

    if t in (MsgType.PING, MsgType.PONG):
        if raw:
            raise DatagramError(f"{t.name} carries no payload, got {len(raw)} bytes")
        return None
    if t == MsgType.HELLO:
        return Hello(*need(_HELLO))
    if t == MsgType.WELCOME:
        return Welcome(*need(_WELCOME))
    if t == MsgType.MOVE:
        v = need(_MOVE)
        _finite(v, t.name)
        return Move(*v)
    if t == MsgType.MOVING:
        v = need(_MOVING)
        _finite(v, t.name)
        return Moving(Move(*v[:4]), v[4])
    if t == MsgType.IN_POSITION:
        v = need(_INPOS)
        _finite(v, t.name)
        return InPosition(Move(*v[:4]), *v[4:])
    v = need(_REJ, exact=False)
    _finite(v[:4], t.name)
    try:
        reason = raw[_REJ.size:].decode("utf-8")
    except UnicodeDecodeError as e:
        raise DatagramError(f"REJECTED reason is not UTF-8: {e}") from None
    if len(raw) - _REJ.size > _MAX_REASON:
        raise DatagramError(f"REJECTED reason longer than {_MAX_REASON} bytes")
    return Rejected(Move(*v[:4]), v[4], reason)


def decode(data: bytes) -> Datagram:
    """bytes -> Datagram; raises :class:`DatagramError` for anything malformed."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise DatagramError(f"expected bytes, got {type(data).__name__}")
    data = bytes(data)
    if len(data) > MAX_DATAGRAM:
        raise DatagramError(f"datagram of {len(data)} bytes exceeds {MAX_DATAGRAM}")
    if len(data) < _HEADER.size + _CRC.size:
        raise DatagramError(f"datagram of {len(data)} bytes is shorter than header + CRC ({_HEADER.size + _CRC.size})")
    magic, version, mtype, session, seq, plen = _HEADER.unpack_from(data)
    if magic != MAGIC:
        raise DatagramError(f"bad magic {magic!r} (expected {MAGIC!r})")
    if version != VERSION:
        raise DatagramError(f"unsupported protocol version {version} (this end speaks {VERSION})")
    if len(data) != _HEADER.size + plen + _CRC.size:
        raise DatagramError(f"length {len(data)} does not match payload_len {plen}")
    body, (crc,) = data[:-_CRC.size], _CRC.unpack_from(data, len(data) - _CRC.size)
    if zlib.crc32(body) != crc:
        raise DatagramError("CRC32 mismatch (corrupt datagram)")
    try:
        t = MsgType(mtype)
    except ValueError:
        raise DatagramError(f"unknown message type {mtype}") from None
    return Datagram(t, session, seq, _unpack_payload(t, body[_HEADER.size:]))
