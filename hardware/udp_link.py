"""Client end of the vision-PC <-> motion-controller UDP link (thesis §6.6).

:meth:`ControllerLink.move` sends the desired camera-1 pan/tilt, camera-2 pan
and turn-table angle and returns only when the controller reports
``IN_POSITION`` for exactly that move -- the capture signal.

Reliability over a lossy, duplicating, reordering network:

* every move gets a fresh sequence number; retransmissions reuse it, so the
  controller executes a move at most once (idempotent) and answers a repeat
  with its cached reply;
* after ``timeout`` seconds without an answer the MOVE is resent, at most
  ``retries`` times, then :class:`LinkTimeoutError`;
* a ``MOVING`` reply extends the wait by the controller's estimate of the
  motion time (it does not use up a retry);
* a reply is accepted only if its CRC, magic, version, session, sequence
  number and echoed angles all match the move in flight.  Corrupt, foreign,
  stale (older seq), duplicated (seq already completed), future and
  mismatched datagrams are dropped and counted in :attr:`ControllerLink.stats`.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import random
import socket
import time

from .datagram import (
    Datagram,
    DatagramError,
    InPosition,
    Move,
    Moving,
    MsgType,
    Rejected,
    decode,
    encode,
)

__all__ = ["ControllerLink", "LinkError", "LinkTimeoutError", "ControllerRejected", "MoveResult"]


class LinkError(RuntimeError):
    """Base class of controller-link failures."""


class LinkTimeoutError(LinkError):
    """No valid answer after every retry."""


class ControllerRejected(LinkError):
    """The controller refused the move (e.g. outside the workspace); not retried."""

    def __init__(self, move: Move, code: int, reason: str):
        self.move, self.code, self.reason = move, code, reason
        super().__init__(f"controller rejected move {move.astuple()} (code {code}): {reason}")


@dataclasses.dataclass(frozen=True)
class MoveResult:
    """An accepted ``IN_POSITION``: what was asked and where the axes are (metres, radians)."""

    seq: int
    move: Move
    gantry_xy: tuple[float, float]
    track_y: float
    turntable: float
    attempts: int
    elapsed_s: float


class ControllerLink:
    """UDP client for the motion controller.

    Args:
        address: (host, port) of the controller.
        timeout: seconds to wait for an answer before resending.
        retries: resends allowed per move (``retries + 1`` transmissions at most).
        session: 32-bit session id (random if omitted); replies for another
            session are dropped.
    """

    def __init__(
        self,
        address: tuple[str, int],
        *,
        timeout: float = 0.25,
        retries: int = 5,
        session: int | None = None,
    ):
        if timeout <= 0:
            raise ValueError(f"timeout must be > 0 seconds, got {timeout}")
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        self.address = (str(address[0]), int(address[1]))
        self.timeout = float(timeout)
        self.retries = int(retries)
        self.session = random.getrandbits(32) if session is None else int(session) & 0xFFFFFFFF
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
    def _classify(self, data: bytes, seq: int, want: tuple[MsgType, ...], move: Move | None) -> Datagram | None:
        try:
            dg = decode(data)
        except DatagramError:
            self.stats["corrupt"] += 1
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

    def _transact(self, mtype: MsgType, payload: Move | None, want: tuple[MsgType, ...]) -> tuple[Datagram, int, float]:
        if self._sock is None:
            raise LinkError("link is closed")
        self._seq = (self._seq + 1) & 0xFFFFFFFF or 1
        seq = self._seq
        packet = encode(Datagram(mtype, self.session, seq, payload))
        t0 = time.monotonic()
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
            deadline = time.monotonic() + self.timeout + extra
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
                dg = self._classify(data, seq, want + (MsgType.MOVING,) if mtype == MsgType.MOVE else want, payload)
                if dg is None:
                    continue
                if dg.type == MsgType.MOVING:
                    assert isinstance(dg.payload, Moving)
                    exp = dg.payload.expected_s
                    # wait for the motion without spending a retry (bounded by sanity)
                    deadline = max(deadline, time.monotonic() + min(max(exp, 0.0), 600.0) + self.timeout)
                    self.stats["moving"] += 1
                    continue
                self._done = seq
                return dg, attempts, time.monotonic() - t0
        self._done = seq  # late replies for this seq are duplicates from now on
        raise LinkTimeoutError(
            f"no valid {'/'.join(w.name for w in want)} for {mtype.name} seq {seq} from {self.address} "
            f"after {attempts} transmissions ({time.monotonic() - t0:.3f} s; timeout {self.timeout} s, "
            f"retries {self.retries}); dropped so far: {dict(self.stats)}"
        )

    # ------------------------------------------------------------ API
    def move(self, cam1_pan: float, cam1_tilt: float, cam2_pan: float, turntable: float) -> MoveResult:
        """Command a move (radians) and wait for ``IN_POSITION``.

        Raises:
            ValueError: a non-finite angle (nothing is sent).
            ControllerRejected: the controller refused the move.
            LinkTimeoutError: no valid answer after every retry.
        """
        move = Move(float(cam1_pan), float(cam1_tilt), float(cam2_pan), float(turntable))
        for name, v in zip(("cam1_pan", "cam1_tilt", "cam2_pan", "turntable"), move.astuple()):
            if not math.isfinite(v):
                raise ValueError(f"{name} = {v!r} is not a finite angle")
        dg, attempts, elapsed = self._transact(MsgType.MOVE, move, (MsgType.IN_POSITION, MsgType.REJECTED))
        if dg.type == MsgType.REJECTED:
            assert isinstance(dg.payload, Rejected)
            raise ControllerRejected(move, dg.payload.code, dg.payload.reason)
        p = dg.payload
        assert isinstance(p, InPosition)
        self.stats["accepted"] += 1
        return MoveResult(dg.seq, move, (p.gantry_x, p.gantry_y), p.track_y, p.turntable, attempts, elapsed)

    def ping(self) -> float:
        """Round-trip time (seconds) of a PING/PONG exchange."""
        _, _, elapsed = self._transact(MsgType.PING, None, (MsgType.PONG,))
        return elapsed
