"""Versioned binary datagrams between the vision PC and the motion controller (thesis §6.6).

Wire format (network byte order; full description in ``docs/protocol.md``),
version 4::

    offset size field
    0      2    magic          b"JR"
    2      1    version        4
    3      1    type           MsgType
    4      8    session        u64, issued by the controller (WELCOME): the
                               controller's boot id (u32, random per start) in the
                               high half, a random u32 in the low half
    12     4    seq            u32, one per move; retransmissions reuse it
    16     2    payload_len    u16
    18     1    flags          bit 0: an HMAC-SHA256 tag follows the payload
    19     n    payload        depends on type
    19+n   t    tag            t = 32 with flag bit 0 (HMAC-SHA256 of bytes 0 .. 18+n
                               under the shared key), else 0
    19+n+t 4    crc32          zlib.crc32 of every byte before it

Versions 1-3 are still decoded (and encoded for a ``Datagram`` of that
version): version 3 has a u32 session (offsets 4-7; seq at 8, payload_len at
12, flags at 14, payload from 15) and u32 nonces; version 2 in addition the
thesis rig's two-camera moves; version 1 in addition no flags byte and no tag:
the payload starts at offset 14.

Payloads (IEEE-754 doubles, radians and metres).  A *move* is, in version 3,
the camera count n (u8, at most :data:`MAX_CAMERAS`), then (pan, tilt) of
each camera (2n d), then the turn-table angle (d); in versions 1-2, camera-1
pan and tilt, camera-2 pan and the turn-table angle (4 d).

* ``MOVE``        client -> controller: a move
* ``MOVING``      controller -> client: the move echoed, expected seconds (d)
* ``IN_POSITION`` controller -> client: the move echoed, where each camera
  reached -- version 3: every camera's eye x, y, z (3n d); versions 1-2: the
  gantry's x, y and the track's y (3 d) -- and the turn-table angle (d): the
  capture signal
* ``REJECTED``    controller -> client: the move echoed, code (u16), UTF-8 reason
* ``PING`` / ``PONG``: empty
* ``HELLO``       client -> controller: nonce (u64; u32 before version 4);
  header session 0, seq 0
* ``WELCOME``     controller -> client: the nonce echoed (u64; u32 before
  version 4), the controller's boot id (u32); the header's session is the new
  session id the controller issued, seq 0
* ``REFUSED``     controller -> client (version 2 and later): the HELLO's nonce
  echoed (u64; u32 before version 4), code (u16), UTF-8 reason -- no session
  was opened

A :class:`SharedKey` given to :func:`encode` tags the datagram; given to
:func:`decode`, only datagrams with the right tag decode
(:class:`DatagramAuthError` otherwise, a version-1 datagram included).  The
key never appears in a ``repr``, a message or a log line.

:func:`decode` raises :class:`DatagramError` -- and nothing else -- for any
input that is not a well-formed datagram of version 1, 2, 3 or 4.
"""

from __future__ import annotations

import dataclasses
import enum
import hashlib
import hmac
import math
import os
import struct
import zlib
from collections.abc import Sequence

__all__ = [
    "MAGIC",
    "VERSION",
    "VERSIONS",
    "MAX_DATAGRAM",
    "MAX_CAMERAS",
    "FLAG_HMAC",
    "TAG_SIZE",
    "SharedKey",
    "DatagramAuthError",
    "MsgType",
    "RejectCode",
    "Datagram",
    "DatagramError",
    "Move",
    "no_move",
    "Moving",
    "InPosition",
    "Rejected",
    "Hello",
    "Welcome",
    "Refused",
    "encode",
    "decode",
    "session_boot",
]

MAGIC = b"JR"
VERSION = 4  # what this end sends
VERSIONS = (1, 2, 3, 4)  # what it decodes
MAX_DATAGRAM = 512
MAX_CAMERAS = 8  # cameras of a version-3 move (an IN_POSITION of 8 is 388 bytes with a tag)
FLAG_HMAC = 0x01
TAG_SIZE = 32  # HMAC-SHA256

_HEADER_V1 = struct.Struct("!2sBBIIH")
_HEADER_V2 = struct.Struct("!2sBBIIHB")  # + flags
_HEADER_V4 = struct.Struct("!2sBBQIHB")  # u64 session
_HEADERS = {1: _HEADER_V1, 2: _HEADER_V2, 3: _HEADER_V2, 4: _HEADER_V4}
_CRC = struct.Struct("!I")
_MOVE_V2 = struct.Struct("!4d")  # camera-1 pan, tilt, camera-2 pan, turn-table
_D = struct.Struct("!d")
_CODE = struct.Struct("!H")
# HELLO, WELCOME, REFUSED: before version 4 (u32 nonce), from version 4 on (u64 nonce)
_HELLO = {3: struct.Struct("!I"), 4: struct.Struct("!Q")}
_WELCOME = {3: struct.Struct("!II"), 4: struct.Struct("!QI")}
_REFUSED = {3: struct.Struct("!IH"), 4: struct.Struct("!QH")}
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
    REFUSED = 9  # version 2 and later


_V1_TYPES = frozenset(t for t in MsgType if t != MsgType.REFUSED)


class RejectCode(enum.IntEnum):
    WORKSPACE = 1  # a kinematics / workspace limit
    BAD_REQUEST = 2  # payload the controller cannot act on
    BUSY = 3  # a newer move superseded this one
    UNKNOWN_SESSION = 4  # a session this controller never issued (it restarted since): not executed
    SESSION_CLOSED = 5  # the session was replaced by a newer HELLO: not executed; open a new one
    SESSION_BUSY = 6  # REFUSED: another client's session is live; no session opened


class DatagramError(ValueError):
    """Bytes that are not a valid datagram (corrupt, truncated, foreign, wrong version)."""


class DatagramAuthError(DatagramError):
    """A well-formed datagram whose HMAC tag is missing, unexpected or wrong."""


class SharedKey:
    """The shared secret of an authenticated link (HMAC-SHA256 over every datagram).

    At least :attr:`MIN_BYTES` bytes.  ``repr`` and ``str`` hide it, so it can sit
    in a configuration object that is printed or logged."""

    MIN_BYTES = 16
    __slots__ = ("_key",)

    def __init__(self, key: bytes):
        if not isinstance(key, (bytes, bytearray)):
            raise TypeError(f"a shared key is bytes, not {type(key).__name__}")
        if len(key) < self.MIN_BYTES:
            raise ValueError(f"a shared key needs at least {self.MIN_BYTES} bytes, got {len(key)}")
        self._key = bytes(key)

    @classmethod
    def from_file(cls, path: str | os.PathLike) -> "SharedKey":
        """The bytes of a file, a trailing newline (LF or CR LF) dropped.

        On POSIX the file must be its owner's only (mode 0600 or 0400): one that grants
        its group or others any access is refused (``ValueError``), since anyone who
        can read the key can move the rig, and anyone who can write it can lock it out."""
        with open(path, "rb") as f:
            mode = os.fstat(f.fileno()).st_mode
            if os.name == "posix" and mode & 0o077:
                raise ValueError(f"the key file is open to its group or others (mode {mode & 0o777:04o}); "
                                 f"a shared key must be its owner's only: chmod 600 it")
            data = f.read(4097)
        if len(data) > 4096:
            raise ValueError("a shared key file holds at most 4096 bytes")
        return cls(data.removesuffix(b"\n").removesuffix(b"\r"))

    @classmethod
    def from_env(cls, name: str) -> "SharedKey":
        """The UTF-8 bytes of environment variable ``name``."""
        value = os.environ.get(name)
        if value is None:
            raise ValueError("the environment variable is not set")
        return cls(value.encode("utf-8", "surrogateescape"))

    def tag(self, body: bytes) -> bytes:
        return hmac.new(self._key, body, hashlib.sha256).digest()

    def __repr__(self) -> str:
        return "SharedKey(<hidden>)"

    __str__ = __repr__

    def __eq__(self, other: object) -> bool:
        return isinstance(other, SharedKey) and hmac.compare_digest(self._key, other._key)

    def __hash__(self) -> int:
        return hash(hashlib.sha256(b"jaxrecog-key-id|" + self._key).digest())


@dataclasses.dataclass(frozen=True)
class Move:
    """Desired planner angles (radians): ``(pan, tilt)`` of each camera, camera 1
    first, and the turn-table angle.

    Versions 1-2 carry camera-1 pan and tilt and camera-2 pan: a move of those
    versions has two cameras and camera 2's tilt 0 (:meth:`for_version` makes one)."""

    # [n] of (pan, tilt), stored as a tuple of float pairs (unparametrised: the run-time
    # type checker would draw a random element of a parametrised one)
    cameras: Sequence
    turntable: float

    def __post_init__(self):
        object.__setattr__(self, "cameras", tuple((float(pan), float(tilt)) for pan, tilt in self.cameras))
        object.__setattr__(self, "turntable", float(self.turntable))

    def astuple(self) -> tuple[float, ...]:
        """Every angle, in wire order: each camera's pan and tilt, then the turn-table."""
        return (*(a for cam in self.cameras for a in cam), self.turntable)

    def for_version(self, version: int) -> "Move":
        """This move as ``version`` carries it: itself from version 3 on; for versions
        1-2 two cameras (a missing camera 2 at pan 0) with camera 2's tilt 0 (the
        controller derives it).  ``ValueError`` for more than two cameras."""
        if version >= 3:
            return self
        if len(self.cameras) > 2:
            raise ValueError(f"protocol version {version} moves at most 2 cameras, not {len(self.cameras)}: "
                             f"a rig of more cameras needs protocol version 3")
        (pan1, tilt1), (pan2, _) = (*self.cameras, (0.0, 0.0), (0.0, 0.0))[:2]
        return Move(((pan1, tilt1), (pan2, 0.0)), self.turntable)


def no_move(version: int) -> Move:
    """What a REJECTED echoes for a request that is no move (a PING): no cameras in
    version 3, the four zeros of versions 1-2."""
    return Move((), 0.0).for_version(version)


@dataclasses.dataclass(frozen=True)
class Moving:
    move: Move
    expected_s: float


@dataclasses.dataclass(frozen=True)
class InPosition:
    """The capture signal: the move it answers, where each camera reached, the turn-table angle.

    ``reached``: in version 3 each camera's eye ``(x, y, z)``; in versions 1-2 the
    thesis rig's motor coordinates ``((gantry x, gantry y), (track y,))``
    (:meth:`~..geometry.kinematics.Carrier.eye` completes them)."""

    move: Move
    reached: Sequence  # [n] of (x, y, z) (version 3), stored as a tuple of float tuples
    turntable: float

    def __post_init__(self):
        object.__setattr__(self, "reached", tuple(tuple(float(v) for v in r) for r in self.reached))
        object.__setattr__(self, "turntable", float(self.turntable))


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


@dataclasses.dataclass(frozen=True)
class Refused:
    """The controller's answer to a HELLO it does not accept (version 2): the nonce
    echoed, a :class:`RejectCode` and the reason; no session was opened."""

    nonce: int
    code: int
    reason: str


Payload = Move | Moving | InPosition | Rejected | Hello | Welcome | Refused | None

_PAYLOAD_TYPE = {
    MsgType.MOVE: Move,
    MsgType.MOVING: Moving,
    MsgType.IN_POSITION: InPosition,
    MsgType.REJECTED: Rejected,
    MsgType.PING: type(None),
    MsgType.PONG: type(None),
    MsgType.HELLO: Hello,
    MsgType.WELCOME: Welcome,
    MsgType.REFUSED: Refused,
}


@dataclasses.dataclass(frozen=True)
class Datagram:
    type: MsgType
    session: int
    seq: int
    payload: Payload = None
    version: int = VERSION  # the protocol version it was (or is to be) sent in


def _finite(values, what: str) -> None:
    for v in values:
        if not math.isfinite(v):
            raise DatagramError(f"{what}: non-finite number {v!r} in payload")


def _pack_move(m: Move, version: int, what: str) -> bytes:
    if version <= 2:
        if len(m.cameras) != 2 or m.cameras[1][1] != 0.0:
            raise DatagramError(f"{what}: a version-{version} move has camera-1 pan, tilt and camera-2 pan "
                                f"(Move.for_version({version})), got {len(m.cameras)} cameras")
        vals = (*m.cameras[0], m.cameras[1][0], m.turntable)
        _finite(vals, what)
        return _MOVE_V2.pack(*vals)
    n = len(m.cameras)
    if n > MAX_CAMERAS:
        raise DatagramError(f"{what}: {n} cameras, at most {MAX_CAMERAS}")
    vals = m.astuple()
    _finite(vals, what)
    return struct.pack(f"!B{len(vals)}d", n, *vals)


def _pack_reached(p: InPosition, version: int) -> bytes:
    n = len(p.move.cameras)
    shape = [2, 1] if version <= 2 else [3] * n
    if [len(r) for r in p.reached] != shape:
        want = "(gantry x, y), (track y,)" if version <= 2 else f"an (x, y, z) eye for each of the {n} cameras"
        raise DatagramError(f"IN_POSITION: version {version} reports {want}, got {p.reached!r}")
    vals = (*(v for r in p.reached for v in r), p.turntable)
    _finite(vals, "IN_POSITION")
    return struct.pack(f"!{len(vals)}d", *vals)


def _pack_payload(dg: Datagram) -> bytes:
    p = dg.payload
    if not isinstance(p, _PAYLOAD_TYPE[dg.type]):
        raise DatagramError(f"{dg.type.name} needs a {_PAYLOAD_TYPE[dg.type].__name__} payload, got {type(p).__name__}")
    if p is None:
        return b""
    wide = 4 if dg.version >= 4 else 3
    if isinstance(p, (Hello, Welcome, Refused)):
        _uint(p.nonce, _nonce_bits(dg.version), f"{dg.type.name} nonce")
    if isinstance(p, Hello):
        return _HELLO[wide].pack(p.nonce)
    if isinstance(p, Welcome):
        _uint(p.boot, 32, "WELCOME boot")
        return _WELCOME[wide].pack(p.nonce, p.boot)
    if isinstance(p, Refused):
        if not 0 <= p.code <= 0xFFFF:
            raise DatagramError(f"REFUSED code {p.code} does not fit in u16")
        return _REFUSED[wide].pack(p.nonce, p.code) + _reason(p.reason)
    name = dg.type.name
    if isinstance(p, Move):
        return _pack_move(p, dg.version, name)
    move = _pack_move(p.move, dg.version, name)
    if isinstance(p, Moving):
        _finite((p.expected_s,), name)
        return move + _D.pack(p.expected_s)
    if isinstance(p, InPosition):
        return move + _pack_reached(p, dg.version)
    assert isinstance(p, Rejected)
    if not 0 <= p.code <= 0xFFFF:
        raise DatagramError(f"REJECTED code {p.code} does not fit in u16")
    return move + _CODE.pack(p.code) + _reason(p.reason)


def _reason(text: str) -> bytes:
    return text.encode("utf-8")[:_MAX_REASON].decode("utf-8", "ignore").encode("utf-8")


def _uint(v: int, bits: int, what: str) -> None:
    if not 0 <= v < 1 << bits:
        raise DatagramError(f"{what} {v} does not fit in u{bits}")


def _session_bits(version: int) -> int:
    """Bits of the header's session: 64 from version 4 on, 32 before."""
    return 64 if version >= 4 else 32


def _nonce_bits(version: int) -> int:
    """Bits of a HELLO's nonce: 64 from version 4 on, 32 before."""
    return 64 if version >= 4 else 32


def session_boot(session: int) -> int:
    """The boot id a version-4 session id carries (its high 32 bits)."""
    return session >> 32


def encode(dg: Datagram, key: SharedKey | None = None) -> bytes:
    """Datagram -> bytes (header, payload, [HMAC tag,] CRC32) in ``dg.version``.

    With ``key`` the datagram carries an HMAC-SHA256 tag (version 2 and later)."""
    if dg.version not in VERSIONS:
        raise DatagramError(f"unsupported protocol version {dg.version} (this end speaks {VERSIONS})")
    _uint(dg.session, _session_bits(dg.version), f"version-{dg.version} session")
    _uint(dg.seq, 32, "seq")
    if dg.version == 1 and dg.type not in _V1_TYPES:
        raise DatagramError(f"{dg.type.name} does not exist in protocol version 1")
    payload = _pack_payload(dg)
    if dg.version == 1:
        if key is not None:
            raise DatagramError("protocol version 1 carries no HMAC tag: an authenticated link needs version 2 or later")
        body = _HEADER_V1.pack(MAGIC, 1, int(dg.type), dg.session, dg.seq, len(payload)) + payload
    else:
        flags = FLAG_HMAC if key is not None else 0
        header = _HEADERS[dg.version]
        body = header.pack(MAGIC, dg.version, int(dg.type), dg.session, dg.seq, len(payload), flags) + payload
        if key is not None:
            body += key.tag(body)
    if len(body) + _CRC.size > MAX_DATAGRAM:
        raise DatagramError(f"datagram of {len(body) + _CRC.size} bytes exceeds {MAX_DATAGRAM}")
    return body + _CRC.pack(zlib.crc32(body))


def _size_error(t: MsgType, got: int, want: str) -> DatagramError:
    return DatagramError(f"{t.name} payload is {got} bytes, expected {want}")


def _unpack_move(t: MsgType, raw: bytes, version: int, rest: tuple[int, int]) -> tuple[Move, bytes]:
    """The move at the start of ``raw`` and the bytes after it.  ``rest = (per_camera,
    fixed)``: the bytes that must follow the move, ``per_camera`` for each camera plus
    ``fixed`` (a negative ``fixed``: at least ``-fixed``, e.g. a code and a reason)."""
    if version <= 2:
        per, fixed = rest
        size = _MOVE_V2.size + per + abs(fixed)
        if (len(raw) < size) if fixed < 0 else (len(raw) != size):
            raise _size_error(t, len(raw), str(size))
        vals = _MOVE_V2.unpack_from(raw)
        _finite(vals, t.name)
        return Move(((vals[0], vals[1]), (vals[2], 0.0)), vals[3]), raw[_MOVE_V2.size:]
    if not raw:
        raise _size_error(t, 0, "a camera count")
    n = raw[0]
    if n > MAX_CAMERAS:
        raise DatagramError(f"{t.name}: {n} cameras, at most {MAX_CAMERAS}")
    per, fixed = rest
    head = 1 + 8 * (2 * n + 1)
    size = head + per * n + abs(fixed)
    if (len(raw) < size) if fixed < 0 else (len(raw) != size):
        raise _size_error(t, len(raw), f"{size} for {n} cameras")
    vals = struct.unpack_from(f"!{2 * n + 1}d", raw, 1)
    _finite(vals, t.name)
    return Move(tuple(zip(vals[:-1:2], vals[1:-1:2])), vals[-1]), raw[head:]


def _doubles(t: MsgType, raw: bytes) -> tuple[float, ...]:
    vals = struct.unpack(f"!{len(raw) // 8}d", raw)
    _finite(vals, t.name)
    return vals


def _unpack_payload(t: MsgType, raw: bytes, version: int) -> Payload:
    def need(s: struct.Struct, exact: bool = True) -> tuple:
        if (len(raw) != s.size) if exact else (len(raw) < s.size):
            raise _size_error(t, len(raw), str(s.size))
        return s.unpack_from(raw)

    if t in (MsgType.PING, MsgType.PONG):
        if raw:
            raise DatagramError(f"{t.name} carries no payload, got {len(raw)} bytes")
        return None
    wide = 4 if version >= 4 else 3
    if t == MsgType.HELLO:
        return Hello(*need(_HELLO[wide]))
    if t == MsgType.WELCOME:
        return Welcome(*need(_WELCOME[wide]))
    if t == MsgType.REFUSED:
        nonce, code = need(_REFUSED[wide], exact=False)
        return Refused(nonce, code, _unpack_reason(t, raw[_REFUSED[wide].size:]))
    if t == MsgType.MOVE:
        return _unpack_move(t, raw, version, (0, 0))[0]
    if t == MsgType.MOVING:
        move, rest = _unpack_move(t, raw, version, (0, 8))
        return Moving(move, *_doubles(t, rest))
    if t == MsgType.IN_POSITION:
        move, rest = _unpack_move(t, raw, version, (0, 32) if version <= 2 else (24, 8))
        v = _doubles(t, rest)
        reached = ((v[0], v[1]), (v[2],)) if version <= 2 else tuple(zip(v[:-1:3], v[1:-1:3], v[2:-1:3]))
        return InPosition(move, reached, v[-1])
    move, rest = _unpack_move(t, raw, version, (0, -2))
    (code,) = _CODE.unpack_from(rest)
    return Rejected(move, code, _unpack_reason(t, rest[_CODE.size:]))


def _unpack_reason(t: MsgType, raw: bytes) -> str:
    try:
        reason = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise DatagramError(f"{t.name} reason is not UTF-8: {e}") from None
    if len(raw) > _MAX_REASON:
        raise DatagramError(f"{t.name} reason longer than {_MAX_REASON} bytes")
    return reason


def decode(data: bytes, key: SharedKey | None = None) -> Datagram:
    """bytes -> Datagram (version 1, 2, 3 or 4); raises :class:`DatagramError` for anything malformed.

    With ``key`` only a version-2 datagram carrying the right HMAC tag decodes;
    without, a tagged one does not (:class:`DatagramAuthError` for both)."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise DatagramError(f"expected bytes, got {type(data).__name__}")
    data = bytes(data)
    if len(data) > MAX_DATAGRAM:
        raise DatagramError(f"datagram of {len(data)} bytes exceeds {MAX_DATAGRAM}")
    if len(data) < _HEADER_V1.size + _CRC.size:
        raise DatagramError(f"datagram of {len(data)} bytes is shorter than header + CRC ({_HEADER_V1.size + _CRC.size})")
    magic, version = data[:2], data[2]
    if magic != MAGIC:
        raise DatagramError(f"bad magic {magic!r} (expected {MAGIC!r})")
    if version not in VERSIONS:
        raise DatagramError(f"unsupported protocol version {version} (this end speaks {', '.join(map(str, VERSIONS))})")
    header = _HEADERS[version]
    if len(data) < header.size + _CRC.size:
        raise DatagramError(f"datagram of {len(data)} bytes is shorter than a version-{version} header + CRC "
                            f"({header.size + _CRC.size})")
    fields = header.unpack_from(data)
    _, _, mtype, session, seq, plen = fields[:6]
    flags = fields[6] if version >= 2 else 0
    if flags & ~FLAG_HMAC:
        raise DatagramError(f"unknown flags 0x{flags:02x}")
    tag_len = TAG_SIZE if flags & FLAG_HMAC else 0
    if len(data) != header.size + plen + tag_len + _CRC.size:
        raise DatagramError(f"length {len(data)} does not match payload_len {plen}" + (" + tag" if tag_len else ""))
    body, (crc,) = data[:-_CRC.size], _CRC.unpack_from(data, len(data) - _CRC.size)
    if zlib.crc32(body) != crc:
        raise DatagramError("CRC32 mismatch (corrupt datagram)")
    signed = body[:len(body) - tag_len]
    if key is not None:
        if not tag_len:
            raise DatagramAuthError("datagram without an HMAC tag: this end requires the shared key")
        if not hmac.compare_digest(key.tag(signed), body[len(signed):]):
            raise DatagramAuthError("HMAC tag mismatch (another key, or a forged datagram)")
    elif tag_len:
        raise DatagramAuthError("datagram with an HMAC tag: this end has no shared key to check it")
    try:
        t = MsgType(mtype)
    except ValueError:
        raise DatagramError(f"unknown message type {mtype}") from None
    if version == 1 and t not in _V1_TYPES:
        raise DatagramError(f"unknown message type {mtype} in protocol version 1")
    return Datagram(t, session, seq, _unpack_payload(t, signed[header.size:], version), version)
