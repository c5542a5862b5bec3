"""Client end of the vision-PC <-> motion-controller UDP link (thesis §6.6).

:meth:`ControllerLink.move` sends a :class:`.datagram.Move` -- the desired pan
and tilt of each camera and the turn-table angle -- and returns only when the
controller reports ``IN_POSITION`` for exactly that move -- the capture signal.

Reliability over a lossy, duplicating, reordering network:

* every move gets a fresh sequence number; retransmissions reuse it, so the
  controller executes a move at most once (idempotent) and answers a repeat
  with its cached reply;
* after ``timeout`` seconds without an answer the MOVE is resent, at most
  ``retries`` times, then :class:`LinkTimeoutError`;
* a ``MOVING`` reply extends the wait by the controller's estimate of the
  motion time (it does not use up a retry), but never past
  ``(retries + 1) * timeout + max_motion_s`` after the move was first sent:
  a controller that keeps answering ``MOVING`` cannot hold the client forever;
* a reply is accepted only if its CRC, magic, version, session, sequence
  number and echoed angles all match the move in flight.  Corrupt, foreign,
  stale (older seq), duplicated (seq already completed), future and
  mismatched datagrams are dropped and counted in :attr:`ControllerLink.stats`.

Sessions and controller restarts.  Before its first request the link opens a
session (``HELLO`` with a random nonce -> ``WELCOME``): the controller issues
the session id (and tells its boot id); sequence numbers start at 1 in every
session.  A controller that restarted knows no session from before, so it
answers a request of the old session with ``REJECTED(UNKNOWN_SESSION)``
without executing it.  The link then counts ``stats["controller_restart"]``,
logs a warning, opens a new session (new id, seq reset) and fails the move in
flight with :class:`ControllerRestarted`: the old controller may have run it
before it went down, so resending it could run it twice -- a move is either
confirmed (``IN_POSITION``) or failed, never run twice.  The caller may
command it again.

Sessions belong to an address (protocol version 2).  The controller binds a
session to the address its HELLO came from and ignores requests of it from
anywhere else; a HELLO from another address while a session is live is
answered ``REFUSED(SESSION_BUSY)`` (:class:`SessionRefused`, not retried).  A
session the controller replaced after it went idle is answered
``REJECTED(SESSION_CLOSED)``: the link counts ``stats["session_closed"]``,
opens a new session and fails the move in flight with :class:`SessionClosed`
(not resent, as after a restart).

Shared key.  With ``key`` (a :class:`.datagram.SharedKey`) every datagram the
link sends carries an HMAC-SHA256 tag and every reply without the right tag
is dropped and counted (``stats["unauthenticated"]``); a controller with the
same key does the same, so nobody without the key can move the rig or take
its session.  The key is never logged.  ``version=3`` talks to a controller
that speaks only protocol version 3, ``version=2`` to one of version 2 (the
thesis rig's two cameras), ``version=1`` to one of version 1 (no sessions
bound to addresses, no key).

Replays (protocol version 4).  The controller's session ids carry its boot id
(random per start) in their high 32 bits, under the HMAC tag with every
request, and are never issued twice; the HELLO nonce is a random u64.  A
recorded datagram replayed after a controller restart names a session of
another boot and is rejected unrun; replayed within a boot it is a stale seq
or a session bound to another address (ignored), and a replayed HELLO is
dropped (its nonce was used).
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import math
import secrets
import socket
import time
from typing import Callable, Sequence

from .datagram import MAX_CAMERAS, VERSION, VERSIONS, Datagram, DatagramAuthError, DatagramError, Hello, InPosition
from .datagram import Move, Moving
from .datagram import MsgType, Refused, Rejected, RejectCode, SharedKey, Welcome, decode, encode

__all__ = [
    "ControllerLink",
    "LinkError",
    "LinkTimeoutError",
    "ControllerRejected",
    "ControllerRestarted",
    "SessionClosed",
    "SessionRefused",
    "MoveResult",
]

log = logging.getLogger(__name__)


class LinkError(RuntimeError):
    """Base class of controller-link failures."""


class LinkTimeoutError(LinkError):
    """No valid answer after every retry."""


class ControllerRejected(LinkError):
    """The controller refused the move (e.g. outside the workspace); not retried."""

    def __init__(self, move: Move, code: int, reason: str):
        self.move, self.code, self.reason = move, code, reason
        super().__init__(f"controller rejected move {move.astuple()} (code {code}): {reason}")


class ControllerRestarted(LinkError):
    """The controller restarted while this move was in flight: it was not resent (the
    controller may have run it before going down); the link has opened a new session."""

    def __init__(self, move: Move, seq: int, note: str):
        self.move, self.seq = move, seq
        super().__init__(
            f"motion controller restarted while move seq {seq} {move.astuple()} was in flight; "
            f"the move was not resent (it may or may not have run): command it again{note}"
        )


class SessionClosed(LinkError):
    """The controller replaced this link's session (another client's HELLO after it went
    idle) while a move was in flight: the move was not resent; the link re-handshook."""

    def __init__(self, move: Move, seq: int, note: str):
        self.move, self.seq = move, seq
        super().__init__(
            f"motion controller closed this link's session (another client opened one after it went idle) "
            f"while move seq {seq} {move.astuple()} was in flight; the move was not resent (it may or may not "
            f"have run): command it again{note}"
        )


class SessionRefused(LinkError):
    """The controller refused to open a session (another client's session is live)."""

    def __init__(self, address: tuple[str, int], code: int, reason: str):
        self.code, self.reason = code, reason
        super().__init__(f"motion controller {address[0]}:{address[1]} refused a session (code {code}): {reason}")


@dataclasses.dataclass(frozen=True)
class MoveResult:
    """An accepted ``IN_POSITION``: what was sent (``move``, as its protocol version
    carries it) and where each camera and the turn-table are (metres, radians).

    ``reached`` is the datagram's (:class:`.datagram.InPosition`): each camera's eye
    in version 3, the gantry's (x, y) and the track's (y,) in versions 1-2;
    :meth:`eyes` gives the eyes in every version."""

    seq: int
    move: Move
    reached: tuple[tuple[float, ...], ...]
    turntable: float
    attempts: int
    elapsed_s: float
    version: int = VERSION

    def eyes(self, carriers: Sequence) -> tuple[tuple[float, float, float], ...]:
        """Each camera's eye (x, y, z): as reported (version 3), or completed from the
        fixed coordinates of each camera's carrier (:class:`~..geometry.kinematics.Carrier`,
        ``eye(axes)``) in versions 1-2, which report only what the motors set."""
        if self.version >= 3:
            return tuple(tuple(r) for r in self.reached)  # type: ignore[misc]
        return tuple(c.eye(r) for c, r in zip(carriers, self.reached))


def _angles(move: Move) -> list[tuple[str, float]]:
    """(name, value) of every angle of ``move``, for messages."""
    named = [(f"camera {i} {axis}", v)
             for i, cam in enumerate(move.cameras) for axis, v in zip(("pan", "tilt"), cam)]
    return named + [("turntable", move.turntable)]


class ControllerLink:
    """UDP client for the motion controller.

    Args:
        address: (host, port) of the controller.
        timeout: seconds to wait for an answer before resending.
        retries: resends allowed per move (``retries + 1`` transmissions at most).
        max_motion_s: the most seconds ``MOVING`` replies may add to one move's wait.
        key: a :class:`.datagram.SharedKey` (or its bytes): tag every datagram, accept
            only tagged replies.
        version: the protocol version to speak (4; 3, 2 or 1 for a controller of that version).

    Attributes:
        session: the session id the controller issued (``None`` before the first
            request, or after a restart until the next handshake succeeds).
        boot: the controller's boot id from the last ``WELCOME``.
        stats: counters (see the module docstring and ``docs/protocol.md``).
    """

    def __init__(
        self,
        address: tuple[str, int],
        *,
        timeout: float = 0.25,
        retries: int = 5,
        max_motion_s: float = 600.0,
        key: SharedKey | bytes | None = None,
        version: int = VERSION,
    ):
        if not timeout > 0 or not math.isfinite(timeout):
            raise ValueError(f"timeout must be > 0 seconds, got {timeout}")
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        if not max_motion_s > 0 or not math.isfinite(max_motion_s):
            raise ValueError(f"max_motion_s must be > 0 seconds, got {max_motion_s}")
        if version not in VERSIONS:
            raise ValueError(f"protocol version must be one of {VERSIONS}, got {version!r}")
        if isinstance(key, (bytes, bytearray)):
            key = SharedKey(bytes(key))
        if key is not None and version == 1:
            raise ValueError("a shared key needs protocol version 2 or later (version 1 carries no HMAC tag)")
        self.key: SharedKey | None = key
        self.version = int(version)
        self.address = (str(address[0]), int(address[1]))
        self.timeout = float(timeout)
        self.retries = int(retries)
        self.max_motion_s = float(max_motion_s)
        self.session: int | None = None
        self.boot: int | None = None
        self._seq = 0
        self._done = 0  # last seq that completed (accepted or rejected)
        self.stats: collections.Counter[str] = collections.Counter()
        self._sock: socket.socket | None = None
        self._open()

    def _open(self) -> None:
        try:
            infos = socket.getaddrinfo(*self.address, type=socket.SOCK_DGRAM)
            family = infos[0][0]
            self._sock = socket.socket(family, socket.SOCK_DGRAM)
            self._sock.connect(self.address)  # the kernel drops datagrams from other peers
        except OSError as e:
            raise LinkError(f"cannot open a UDP socket to {self.address}: {e}") from e

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> "ControllerLink":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------ receive
    def _decode(self, data: bytes) -> Datagram | None:
        try:
            dg = decode(data, self.key)
        except DatagramAuthError:
            self.stats["unauthenticated"] += 1
            return None
        except DatagramError:
            self.stats["corrupt"] += 1
            return None
        if dg.version != self.version:
            self.stats["version"] += 1
            return None
        return dg

    def _encode(self, dg: Datagram) -> bytes:
        return encode(dataclasses.replace(dg, version=self.version), self.key)

    def _classify(self, data: bytes, seq: int, want: tuple[MsgType, ...], move: Move | None) -> Datagram | None:
        dg = self._decode(data)
        if dg is None:
            return None
        if dg.session != self.session:
            self.stats["foreign"] += 1
        elif dg.seq == self._done and dg.seq != seq:
            self.stats["duplicate"] += 1
        elif dg.seq < seq:
            self.stats["stale"] += 1
        elif dg.seq > seq:
            self.stats["future"] += 1
        elif dg.type not in want:
            self.stats["unexpected_type"] += 1
        elif move is not None and dg.payload.move != move:  # type: ignore[union-attr]
            self.stats["mismatched"] += 1
        else:
            return dg
        return None

    def _classify_welcome(self, data: bytes, nonce: int) -> Datagram | None:
        dg = self._decode(data)
        if dg is None:
            return None
        if dg.type not in (MsgType.WELCOME, MsgType.REFUSED):
            self.stats["unexpected_type"] += 1  # e.g. a late reply of the session before
        elif dg.seq != 0 or dg.payload.nonce != nonce:  # type: ignore[union-attr]
            self.stats["foreign"] += 1
        else:
            return dg
        return None

    def _handshake(self) -> None:
        """HELLO -> WELCOME: a new session issued by the controller; seq starts over."""
        nonce = secrets.randbits(64 if self.version >= 4 else 32)
        packet = self._encode(Datagram(MsgType.HELLO, 0, 0, Hello(nonce)))
        dg, _, _ = self._exchange(packet, lambda data: self._classify_welcome(data, nonce), "WELCOME for HELLO")
        if dg.type == MsgType.REFUSED:
            assert isinstance(dg.payload, Refused)
            self.stats["refused_session"] += 1
            raise SessionRefused(self.address, dg.payload.code, dg.payload.reason)
        welcome = dg.payload
        assert isinstance(welcome, Welcome)
        if self.boot is not None and welcome.boot != self.boot:
            log.warning("motion controller %s: new boot id %08x (was %08x)", self.address, welcome.boot, self.boot)
        self.session, self.boot = dg.session, welcome.boot
        self._seq = self._done = 0
        self.stats["handshake"] += 1

    def _transact(self, mtype: MsgType, payload: Move | None, want: tuple[MsgType, ...]) -> tuple[Datagram, int, float]:
        if self._sock is None:
            raise LinkError("link is closed")
        session = self.open_session()
        self._seq = (self._seq + 1) & 0xFFFFFFFF or 1
        seq = self._seq
        packet = self._encode(Datagram(mtype, session, seq, payload))
        accept = want + (MsgType.MOVING,) if mtype == MsgType.MOVE else want
        try:
            return self._exchange(packet, lambda data: self._classify(data, seq, accept, payload),
                                  f"{'/'.join(w.name for w in want)} for {mtype.name} seq {seq}")
        finally:
            self._done = seq  # late replies for this seq are duplicates from now on

    def _exchange(self, packet: bytes, classify: Callable[[bytes], Datagram | None], what: str) -> tuple[Datagram, int, float]:
        """Send ``packet``, resend after each ``timeout``, until ``classify`` accepts an answer.

        Bounded: at most ``retries + 1`` transmissions, and ``MOVING`` never extends
        the wait past ``(retries + 1) * timeout + max_motion_s`` from the first send."""
        if self._sock is None:
            raise LinkError("link is closed")
        t0 = time.monotonic()
        hard = t0 + (self.retries + 1) * self.timeout + self.max_motion_s
        attempts = 0
        extra = 0.0
        while attempts <= self.retries:
            attempts += 1
            self.stats["sent"] += 1
            if attempts > 1:
                self.stats["retransmit"] += 1
            try:
                self._sock.send(packet)
            except OSError:
                self.stats["send_error"] += 1
            deadline = min(time.monotonic() + self.timeout + extra, hard)
            extra = 0.0
            while True:
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._sock.settimeout(left)
                try:
                    data = self._sock.recv(2048)
                except socket.timeout:
                    break
                except ConnectionRefusedError:  # ICMP port unreachable: like a loss
                    self.stats["refused"] += 1
                    continue
                dg = classify(data)
                if dg is None:
                    continue
                if dg.type == MsgType.MOVING:
                    assert isinstance(dg.payload, Moving)
                    exp = dg.payload.expected_s
                    # wait for the motion without spending a retry, but never past the hard bound
                    want_until = time.monotonic() + min(max(exp, 0.0), self.max_motion_s) + self.timeout
                    deadline = min(max(deadline, want_until), hard)
                    self.stats["moving"] += 1
                    continue
                return dg, attempts, time.monotonic() - t0
            if time.monotonic() >= hard:
                self.stats["motion_cap"] += 1
                break
        raise LinkTimeoutError(
            f"no valid {what} from {self.address} "
            f"after {attempts} transmissions ({time.monotonic() - t0:.3f} s; timeout {self.timeout} s, "
            f"retries {self.retries}, max_motion_s {self.max_motion_s}); dropped so far: {dict(self.stats)}"
        )

    # ------------------------------------------------------------ API
    def move(self, move: Move) -> MoveResult:
        """Command ``move`` (each camera's pan and tilt and the turn-table angle, radians)
        and wait for ``IN_POSITION``.  On a version-1/2 link the move is sent as
        :meth:`.datagram.Move.for_version` gives it (two cameras, camera 2's tilt 0).

        Raises:
            ValueError: a non-finite angle, or more cameras than the protocol
                version carries (nothing is sent).
            ControllerRejected: the controller refused the move.
            ControllerRestarted: the controller restarted while the move was in flight.
            SessionClosed: the controller replaced the session while the move was in flight.
            SessionRefused: the controller would not open a session (another client's is live).
            LinkTimeoutError: no valid answer after every retry (or the session
                could not be opened).
        """
        for name, v in _angles(move):
            if not math.isfinite(v):
                raise ValueError(f"{name} = {v!r} is not a finite angle")
        if len(move.cameras) > MAX_CAMERAS:
            raise ValueError(f"a move of {len(move.cameras)} cameras: the protocol carries at most {MAX_CAMERAS}")
        move = move.for_version(self.version)
        dg, attempts, elapsed = self._transact(MsgType.MOVE, move, (MsgType.IN_POSITION, MsgType.REJECTED))
        if dg.type == MsgType.REJECTED:
            assert isinstance(dg.payload, Rejected)
            if dg.payload.code == RejectCode.UNKNOWN_SESSION:
                raise self._restarted(move, dg.seq)
            if dg.payload.code == RejectCode.SESSION_CLOSED:
                raise self._closed(move, dg.seq)
            raise ControllerRejected(move, dg.payload.code, dg.payload.reason)
        p = dg.payload
        assert isinstance(p, InPosition)
        self.stats["accepted"] += 1
        return MoveResult(dg.seq, move, p.reached, p.turntable, attempts, elapsed, self.version)

    def open_session(self) -> int:
        """Open a session now (``HELLO`` -> ``WELCOME``) unless one is open; its id.

        Requests open one themselves when needed; this is for checking the link up front."""
        if self.session is None:
            self._handshake()
        assert self.session is not None
        return self.session

    def _restarted(self, move: Move, seq: int) -> ControllerRestarted:
        """The controller does not know our session: it restarted.  Re-handshake, report."""
        self.stats["controller_restart"] += 1
        old, self.session = self.session, None
        log.warning("motion controller %s restarted (session %s unknown to it) while move seq %d was in flight; "
                    "opening a new session; the move is failed, not resent", self.address,
                    f"{old:08x}" if old is not None else None, seq)
        return ControllerRestarted(move, seq, self._rehandshake())

    def _closed(self, move: Move, seq: int) -> SessionClosed:
        """The controller replaced our session: re-handshake, report."""
        self.stats["session_closed"] += 1
        old, self.session = self.session, None
        log.warning("motion controller %s closed session %s (another client opened one) while move seq %d was "
                    "in flight; opening a new session; the move is failed, not resent", self.address,
                    f"{old:08x}" if old is not None else None, seq)
        return SessionClosed(move, seq, self._rehandshake())

    def _rehandshake(self) -> str:
        try:
            self._handshake()
            return f" (new session {self.session:08x})"
        except LinkError as e:
            return f" (re-handshake failed: {e}; the next request retries it)"

    def ping(self) -> float:
        """Round-trip time (seconds) of a PING/PONG exchange."""
        dg, _, elapsed = self._transact(MsgType.PING, None, (MsgType.PONG, MsgType.REJECTED))
        if dg.type == MsgType.REJECTED:  # our session is gone: a new one for the next request
            assert isinstance(dg.payload, Rejected)
            self.stats["controller_restart" if dg.payload.code == RejectCode.UNKNOWN_SESSION else "session_closed"] += 1
            self.session = None
            raise LinkError(f"motion controller {self.address} no longer knows this link's session "
                            f"(code {dg.payload.code}: {dg.payload.reason}); the next request opens a new one")
        return elapsed
