"""Simulated motion controller (the thesis's VxWorks side, §6.6) on 127.0.0.1.

It answers the datagrams of :mod:`.datagram`: a ``MOVE`` carries the planner
angles; the controller converts them with the appendix-C kinematics
(:func:`.kinematics.camera1_position`, :func:`.kinematics.camera2_position`),
rejects moves outside the workspace (``REJECTED``), otherwise "moves" the
gantry, the linear track and the turn-table at finite speed in simulated time
and then sends ``IN_POSITION`` with the achieved positions (quantised to the
encoders: 10 um on the linear axes, 20,000 counts a turn on the turn-table,
thesis §6.3).  Moves that take longer than ``moving_after_s`` are first
acknowledged with ``MOVING``.

Per session, a MOVE with the sequence number already executed is answered from
a cache (idempotent), an older one is ignored (it must never move the rig
backwards), and a newer one is a new move.  A new session id retires the old
one.

Faults, drawn from ``random.Random(seed)`` per datagram (so a run is
reproducible up to thread timing): ``loss`` (each direction), ``duplicate``,
``reorder`` (hold a reply back by ``reorder_delay_s`` so later ones overtake
it), ``corrupt`` (flip one byte), ``delay_s`` (uniform extra latency), and
``silent`` (drop everything, settable at run time).
"""

from __future__ import annotations

import dataclasses
import heapq
import ipaddress
import math
import random
import socket
import threading
import time

from .datagram import (
    Datagram,
    DatagramError,
    InPosition,
    Move,
    Moving,
    MsgType,
    Rejected,
    RejectCode,
    decode,
    encode,
)
from .kinematics import Workspace, WorkspaceError, camera1_position, camera2_position

__all__ = ["LinkFaults", "ControllerSimulator", "ExecutedMove"]

TURNTABLE_COUNTS = 20000  # encoder counts per revolution (thesis §6.3)
LINEAR_RESOLUTION_M = 1e-5


@dataclasses.dataclass
class LinkFaults:
    """Network and controller faults; probabilities are per datagram."""

    loss: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    corrupt: float = 0.0
    delay_s: tuple[float, float] = (0.0, 0.0)
    reorder_delay_s: float = 0.01
    silent: bool = False

    def __post_init__(self):
        for name in ("loss", "duplicate", "reorder", "corrupt"):
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"fault probability {name} = {p} must lie in [0, 1]")
        lo, hi = self.delay_s
        if not 0.0 <= lo <= hi:
            raise ValueError(f"delay_s = {self.delay_s} must be (min, max) with 0 <= min <= max")


@dataclasses.dataclass(frozen=True)
class ExecutedMove:
    session: int
    seq: int
    move: Move
    reply: InPosition


def _quantise(v: float, step: float) -> float:
    return round(v / step) * step


class ControllerSimulator:
    """The motion controller, serving UDP on ``host`` (loopback only) and an ephemeral port.

    Args:
        workspace: rig geometry and limits (appendix C).
        faults: :class:`LinkFaults`.
        seed: seeds every fault decision.
        time_scale: wall seconds per simulated second.
        linear_speed: gantry / track speed, m/s (simulated).
        turntable_speed: rad/s (simulated).
        moving_after_s: send ``MOVING`` first when a move takes longer (wall seconds).
    """

    def __init__(
        self,
        workspace: Workspace | None = None,
        *,
        faults: LinkFaults | None = None,
        seed: int = 0,
        time_scale: float = 0.01,
        linear_speed: float = 0.25,
        turntable_speed: float = math.radians(90.0),
        moving_after_s: float = 0.05,
        host: str = "127.0.0.1",
        port: int = 0,
    ):
        if not ipaddress.ip_address(host).is_loopback:
            raise ValueError(f"the controller simulator binds to a loopback address only, not {host!r}")
        self.workspace = workspace or Workspace()
        self.faults = faults or LinkFaults()
        self.time_scale = float(time_scale)
        self.linear_speed = float(linear_speed)
        self.turntable_speed = float(turntable_speed)
        self.moving_after_s = float(moving_after_s)
        self._rng = random.Random(seed)
        # state: gantry (x, y), track y, turn-table angle -- start at the centre
        ws = self.workspace
        self.gantry = (ws.object_xyz[0], ws.object_xyz[1])
        self.track_y = ws.object_xyz[1]
        self.turntable = 0.0
        self.executed: list[ExecutedMove] = []
        self.received = 0
        self._session: int | None = None
        self._retired: set[int] = set()
        self._last_seq = 0
        self._cache: Datagram | None = None  # reply to the last executed seq
        self._busy_until = 0.0  # wall time the last move finishes
        self._duration_s = 0.0
        self._queue: list[tuple[float, int, bytes, tuple]] = []
        self._counter = 0
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind((host, port))
        self.address: tuple[str, int] = self._sock.getsockname()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._serve, name="controller-sim", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------ control
    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._sock.close()

    def __enter__(self) -> "ControllerSimulator":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def silent(self) -> bool:
        return self.faults.silent

    @silent.setter
    def silent(self, value: bool) -> None:
        self.faults.silent = bool(value)

    # ------------------------------------------------------------ sending
    def _schedule(self, when: float, data: bytes, peer: tuple) -> None:
        self._counter += 1
        heapq.heappush(self._queue, (when, self._counter, data, peer))

    def _send(self, dg: Datagram, peer: tuple, not_before: float = 0.0) -> None:
        """Queue a reply through the fault model."""
        f, rng = self.faults, self._rng
        if f.silent or rng.random() < f.loss:
            return
        data = encode(dg)
        copies = 2 if rng.random() < f.duplicate else 1
        for _ in range(copies):
            when = max(time.monotonic(), not_before) + rng.uniform(*f.delay_s)
            if rng.random() < f.reorder:
                when += f.reorder_delay_s
            out = data
            if rng.random() < f.corrupt:
                i = rng.randrange(len(data))
                out = data[:i] + bytes([data[i] ^ (1 << rng.randrange(8))]) + data[i + 1:]
            self._schedule(when, out, peer)

    # ------------------------------------------------------------ serving
    def _serve(self) -> None:
        while not self._stop.is_set():
            now = time.monotonic()
            while self._queue and self._queue[0][0] <= now:
                _, _, data, peer = heapq.heappop(self._queue)
                try:
                    self._sock.sendto(data, peer)
                except OSError:
                    pass
            wait = 0.02 if not self._queue else min(0.02, max(self._queue[0][0] - now, 0.0))
            self._sock.settimeout(max(wait, 1e-4))
            try:
                data, peer = self._sock.recvfrom(2048)
            except (socket.timeout, BlockingIOError):
                continue
            except OSError:
                if self._stop.is_set():
                    return
                continue
            if self.faults.silent or self._rng.random() < self.faults.loss:
                continue
            try:
                dg = decode(data)
            except DatagramError:
                continue  # a corrupt request is indistinguishable from a lost one
            self.received += 1
            with self._lock:
                self._handle(dg, peer)

    def _handle(self, dg: Datagram, peer: tuple) -> None:
        if dg.type == MsgType.PING:
            self._send(Datagram(MsgType.PONG, dg.session, dg.seq), peer)
            return
        if dg.type != MsgType.MOVE:
            return
        if dg.session != self._session:
            if dg.session in self._retired:
                return  # a straggler from an earlier client
            if self._session is not None:
                self._retired.add(self._session)
            self._session, self._last_seq, self._cache = dg.session, 0, None
        if dg.seq < self._last_seq:
            return  # stale retransmission: never move backwards
        if dg.seq == self._last_seq and self._cache is not None:
            reply = self._cache
            left = self._busy_until - time.monotonic()
            if reply.type == MsgType.IN_POSITION and left > 0:
                self._send(Datagram(MsgType.MOVING, dg.session, dg.seq, Moving(reply.payload.move, left)), peer)
                self._send(reply, peer, not_before=self._busy_until)
            else:
                self._send(reply, peer)
            return
        assert isinstance(dg.payload, Move)
        self._last_seq = dg.seq
        self._cache = reply = self._execute(dg)
        if reply.type == MsgType.REJECTED:
            self._send(reply, peer)
            return
        start = max(time.monotonic(), self._busy_until)
        self._busy_until = start + self._duration_s
        if self._duration_s > self.moving_after_s:
            self._send(Datagram(MsgType.MOVING, dg.session, dg.seq, Moving(dg.payload, self._duration_s)), peer)
        self._send(reply, peer, not_before=self._busy_until)

    def _execute(self, dg: Datagram) -> Datagram:
        move = dg.payload
        assert isinstance(move, Move)
        ws = self.workspace
        try:
            x, y, _ = camera1_position(ws, move.cam1_pan, move.cam1_tilt)
            (_, ty, _), _ = camera2_position(ws, move.cam2_pan)
        except WorkspaceError as e:
            return Datagram(MsgType.REJECTED, dg.session, dg.seq, Rejected(move, RejectCode.WORKSPACE, str(e)))
        table = move.turntable % (2 * math.pi)
        dist = max(math.hypot(x - self.gantry[0], y - self.gantry[1]), abs(ty - self.track_y))
        dturn = abs(math.remainder(table - self.turntable, 2 * math.pi))
        sim_s = max(dist / self.linear_speed, dturn / self.turntable_speed)
        self._duration_s = sim_s * self.time_scale
        self.gantry = (_quantise(x, LINEAR_RESOLUTION_M), _quantise(y, LINEAR_RESOLUTION_M))
        self.track_y = _quantise(ty, LINEAR_RESOLUTION_M)
        self.turntable = _quantise(table, 2 * math.pi / TURNTABLE_COUNTS) % (2 * math.pi)
        reply = InPosition(move, self.gantry[0], self.gantry[1], self.track_y, self.turntable)
        self.executed.append(ExecutedMove(dg.session, dg.seq, move, reply))
        return Datagram(MsgType.IN_POSITION, dg.session, dg.seq, reply)
