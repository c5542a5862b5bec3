"""Simulated motion controller (the thesis's VxWorks side, §6.6) on 127.0.0.1.

It answers the datagrams of :mod:`..devices.datagram`: a ``MOVE`` carries the planner
angles of n cameras; the controller places each camera's carrier with the
appendix-C kinematics (:meth:`..geometry.kinematics.Carrier.place` of the
workspace's carrier for that camera: the thesis rig's gantry and track, or
more), rejects moves outside the workspace (``REJECTED``), otherwise "moves"
the carriers and the turn-table at finite speed in simulated time and then
sends ``IN_POSITION`` with the achieved positions (quantised to the encoders:
10 um on the linear axes, 20,000 counts a turn on the turn-table, thesis
§6.3): each camera's eye in protocol version 3, the gantry's x, y and the
track's y in versions 1-2.  Moves that take longer than ``moving_after_s``
are first acknowledged with ``MOVING``.

Sessions (protocol version 2 and later, ``docs/protocol.md``).  A ``HELLO``
opens a session bound to the address (host, port) it came from: the
controller issues a new session id (answering a repeated HELLO -- same nonce,
same address -- with the same ``WELCOME``) and retires the one before.  Boot
ids and session ids come from the operating system's random source
(:mod:`secrets`), never from ``seed``: a controller that restarts must not
issue an id again.  A version-4 session id is the boot id (high 32 bits) and
a random u32; a version-1-3 one a random u32.  While a session is *live* -- a
request of it arrived, or its move ran, less than ``session_idle_s`` ago; a
session nobody has used yet is not live -- a HELLO from any other address is
answered ``REFUSED(SESSION_BUSY)`` and changes nothing; after that a new
client may take over.  A version-4 HELLO whose nonce already opened a session
since this boot (other than a retransmission of the last one) is a replay:
dropped unanswered (``hello_replay``).  Requests of a session from any address but its own are ignored.
Per session, a MOVE with the sequence number already executed is answered
from a cache (idempotent), an older one is ignored (it must never move the
rig backwards), and a newer one is a new move.  A MOVE (or PING) of a retired
session, from its address, is answered ``REJECTED(SESSION_CLOSED)`` and not
executed, so its client knows to open a new session; one of a session this
controller never issued is answered ``REJECTED(UNKNOWN_SESSION)`` and not
executed -- for a version-4 session of another boot, with a reason naming
both boot ids (``other_boot``: a request from before a restart, or a replay).  With ``key`` every datagram without the right HMAC tag (version-1
ones included) is dropped unanswered (``unauthenticated``).  Replies go out
in the protocol version of the request; a version-1 HELLO that is refused
gets no answer (version 1 has no ``REFUSED``).

Restarts.  :meth:`ControllerSimulator.restart` is a reboot: a new boot id, no
sessions, no cache, nothing queued in or out (the axes keep their encoder
positions), deaf for ``down_s`` seconds.  :meth:`ControllerSimulator.inject_restart`
makes the next new MOVE restart the controller ``"before_execute"`` (it never
runs) or ``"after_execute"`` (it runs, the reply is never sent) -- a restart
between request and reply.

Network faults hit both directions alike: every incoming request and every
outgoing reply goes through the same fault model -- ``loss``, ``duplicate``
(a second copy), ``reorder`` (hold a copy back by ``reorder_delay_s`` so later
datagrams overtake it), ``corrupt`` (flip one bit), ``delay_s`` (uniform
extra latency) -- before it is handled or sent; ``silent`` (settable at run
time) drops everything.  A held-back or duplicated request that arrives after
the client has moved on is *stale* and ignored; a corrupt one fails the CRC
and is dropped like a lost one.

Fault decisions are seeded per datagram: the fate of the ``n``-th copy of a
(direction, message type, seq) seen by the simulator is drawn from a
generator seeded with ``(seed, direction, type, seq, n)``, so a given seed
gives every request and reply the same faults in every run, whatever the
thread timing (only how many retransmissions the client makes depends on
timing).

:attr:`ControllerSimulator.stats` counts what happened: ``request_*`` /
``reply_*`` with ``lost``, ``duplicated``, ``reordered``, ``delayed``,
``corrupted`` (the faults applied), and for the requests that reached the
controller: ``corrupt`` (failed decoding, dropped), ``new`` (a new seq:
executed or rejected), ``repeat`` (the seq just executed: answered from the
cache), ``stale`` (an older seq: ignored), ``retired`` (a retired session:
ignored), ``unknown_session`` (rejected, not executed), ``hello`` /
``hello_repeat`` (sessions opened / WELCOMEs resent), ``hello_refused``
(another address's session was live), ``hello_replay`` (a version-4 HELLO
whose nonce was used before, dropped), ``takeover`` (a session opened from a
new address after the last one went idle), ``other_boot`` (a version-4
request of a session of another boot; also counted ``unknown_session``), ``wrong_address`` (a request of a
session from another address: ignored), ``unauthenticated``, ``restart``,
``request_down`` (arrived while restarting: lost), ``duplicate_copy`` (the
extra copy of a duplicated request, handled like any other).
"""

from __future__ import annotations

import collections
import dataclasses
import heapq
import ipaddress
import math
import random
import secrets
import socket
import threading
import time

from ..devices.datagram import VERSION, Datagram, DatagramAuthError, DatagramError, Hello, InPosition, Move, Moving
from ..devices.datagram import MsgType, Refused, Rejected, RejectCode, SharedKey, Welcome, decode, encode, no_move
from ..devices.datagram import session_boot
from ..geometry.kinematics import Gantry, Track, Workspace, WorkspaceError

__all__ = ["LinkFaults", "ControllerSimulator", "ExecutedMove"]

NONCE_WINDOW = 4096  # version-4 HELLO nonces remembered per boot (replays of them are dropped)
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
        workspace: rig geometry and limits (appendix C): one carrier per camera.
        faults: :class:`LinkFaults`.
        seed: seeds every fault decision.
        time_scale: wall seconds per simulated second.
        linear_speed: carrier speed (gantry, track), m/s (simulated).
        turntable_speed: rad/s (simulated).
        moving_after_s: send ``MOVING`` first when a move takes longer (wall seconds).
        key: a :class:`..devices.datagram.SharedKey` (or its bytes): accept only datagrams
            tagged with it, tag every reply.
        session_idle_s: a session is live (HELLOs from other addresses refused)
            until this many wall seconds passed without a request of it.
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
        key: SharedKey | bytes | None = None,
        session_idle_s: float = 10.0,
    ):
        if not ipaddress.ip_address(host).is_loopback:
            raise ValueError(f"the controller simulator binds to a loopback address only, not {host!r}")
        self.workspace = workspace or Workspace()
        self.faults = faults or LinkFaults()
        self.time_scale = float(time_scale)
        self.linear_speed = float(linear_speed)
        self.turntable_speed = float(turntable_speed)
        self.moving_after_s = float(moving_after_s)
        self.seed = int(seed)
        self.key = SharedKey(bytes(key)) if isinstance(key, (bytes, bytearray)) else key
        if not session_idle_s >= 0:
            raise ValueError(f"session_idle_s = {session_idle_s!r} must be >= 0 seconds")
        self.session_idle_s = float(session_idle_s)
        self._occurrences: dict[tuple[str, bytes], int] = {}
        self.stats: collections.Counter[str] = collections.Counter()
        # state: each carrier's motor coordinates and the turn-table angle -- start at the centre
        ws = self.workspace
        self.axes: list[tuple[float, ...]] = [c.axes(ws.object_xyz) for c in ws.carriers]
        self.turntable = 0.0
        self.executed: list[ExecutedMove] = []
        self.received = 0
        self.boots = 0  # restarts so far
        self.boot = self._new_boot()
        self._nonces: collections.OrderedDict[int, None] = collections.OrderedDict()  # version-4 HELLOs this boot
        self._session: int | None = None
        self._issued: dict[int, tuple] = {}  # session -> its client's address, issued since this boot
        self._welcome: tuple[int, tuple, Datagram] | None = None  # (nonce, address, WELCOME) of the last HELLO
        self._active = 0.0  # wall time of the current session's last request
        self._restart_on: tuple[str, float] | None = None  # inject_restart()
        self._down_until = 0.0
        self._last_seq = 0
        self._cache: Datagram | None = None  # reply to the last executed seq
        self._busy_until = 0.0  # wall time the last move finishes
        self._duration_s = 0.0
        self._queue: list[tuple[float, int, bytes, tuple]] = []  # replies due out
        self._inbox: list[tuple[float, int, bytes, tuple, bool]] = []  # requests due in
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

    @staticmethod
    def _new_boot() -> int:
        """A boot id: a random u32, never 0, from the OS (not the seed: it must differ after a restart)."""
        return secrets.randbits(32) or 1

    def _new_session(self, version: int) -> int:
        """A session id never issued before: version 4, this boot's id and a random u32;
        versions 1-3, a random u32 (never 0, none issued since this boot)."""
        while True:
            low = secrets.randbits(32)
            session = (self.boot << 32 | low) if version >= 4 else low
            if low and session not in self._issued:
                return session

    def restart(self, down_s: float = 0.0) -> None:
        """Reboot now: new boot id; sessions, cache and queued datagrams are lost; deaf for ``down_s`` s."""
        with self._lock:
            self._restart(down_s)

    def _restart(self, down_s: float) -> None:
        self.boots += 1
        old, self.boot = self.boot, self._new_boot()
        while self.boot == old:
            self.boot = self._new_boot()
        self._session, self._issued, self._welcome = None, {}, None
        self._nonces.clear()
        self._last_seq, self._cache = 0, None
        self._queue.clear()
        self._inbox.clear()
        self._busy_until = time.monotonic()
        self._down_until = time.monotonic() + down_s
        self._restart_on = None
        self.stats["restart"] += 1

    def inject_restart(self, when: str = "after_execute", down_s: float = 0.0) -> None:
        """Restart on the next new MOVE, ``"before_execute"`` or ``"after_execute"`` (its reply lost)."""
        if when not in ("before_execute", "after_execute"):
            raise ValueError(f"when must be 'before_execute' or 'after_execute', not {when!r}")
        with self._lock:
            self._restart_on = (when, float(down_s))

    @property
    def silent(self) -> bool:
        return self.faults.silent

    @silent.setter
    def silent(self, value: bool) -> None:
        self.faults.silent = bool(value)

    # ------------------------------------------------------------ network faults
    def _fault_rng(self, direction: str, data: bytes) -> random.Random:
        """The generator deciding the fate of this copy of ``data``: seeded with
        (seed, direction, type, seq, how many copies of that type and seq came before)."""
        at = 12 if len(data) > 2 and data[2] >= 4 else 8  # where seq starts (version 4: after a u64 session)
        ident = data[3:4] + data[at:at + 4] if len(data) >= at + 4 else data
        key = (direction, ident)
        if len(self._occurrences) > 100_000:  # bound the memory of a long run
            self._occurrences.clear()
        n = self._occurrences.get(key, 0)
        self._occurrences[key] = n + 1
        return random.Random(b"%d|%s|%s|%d" % (self.seed, direction.encode(), ident.hex().encode(), n))

    def _network(self, direction: str, data: bytes, not_before: float = 0.0) -> list[tuple[float, bytes, bool]]:
        """The copies of ``data`` the faulty network delivers: (due time, bytes, is the extra copy)."""
        f, st = self.faults, self.stats
        if f.silent:
            st[f"{direction}_silenced"] += 1
            return []
        rng = self._fault_rng(direction, data)
        if rng.random() < f.loss:
            st[f"{direction}_lost"] += 1
            return []
        copies = 2 if rng.random() < f.duplicate else 1
        if copies == 2:
            st[f"{direction}_duplicated"] += 1
        out = []
        now = time.monotonic()
        for k in range(copies):
            delay = rng.uniform(*f.delay_s)
            if delay > 0:
                st[f"{direction}_delayed"] += 1
            when = max(now, not_before) + delay
            if rng.random() < f.reorder:
                when += f.reorder_delay_s
                st[f"{direction}_reordered"] += 1
            b = data
            if rng.random() < f.corrupt:
                i = rng.randrange(len(data))
                b = data[:i] + bytes([data[i] ^ (1 << rng.randrange(8))]) + data[i + 1:]
                st[f"{direction}_corrupted"] += 1
            out.append((when, b, k > 0))
        return out

    # ------------------------------------------------------------ sending
    def _send(self, dg: Datagram, peer: tuple, not_before: float = 0.0) -> None:
        """Queue a reply through the fault model (in the version of the request being answered)."""
        dg = dataclasses.replace(dg, version=self._version)
        for when, data, _ in self._network("reply", encode(dg, self.key), not_before):
            self._counter += 1
            heapq.heappush(self._queue, (when, self._counter, data, peer))

    def _receive(self, data: bytes, peer: tuple) -> None:
        """Queue an incoming request through the fault model."""
        self.stats["request_received"] += 1
        for when, b, extra in self._network("request", data):
            self._counter += 1
            heapq.heappush(self._inbox, (when, self._counter, b, peer, extra))

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
            while self._inbox and self._inbox[0][0] <= now:
                _, _, data, peer, extra = heapq.heappop(self._inbox)
                self._deliver(data, peer, extra)
            now = time.monotonic()
            heads = [q[0][0] for q in (self._queue, self._inbox) if q]
            wait = min([0.02] + [max(h - now, 0.0) for h in heads])
            self._sock.settimeout(max(wait, 1e-4))
            try:
                data, peer = self._sock.recvfrom(2048)
            except (socket.timeout, BlockingIOError):
                continue
            except OSError:
                if self._stop.is_set():
                    return
                continue
            self._receive(data, peer)

    def _deliver(self, data: bytes, peer: tuple, extra_copy: bool) -> None:
        """A request that made it through the network: decode and handle it."""
        if self.faults.silent:
            self.stats["request_silenced"] += 1
            return
        if time.monotonic() < self._down_until:
            self.stats["request_down"] += 1
            return
        try:
            dg = decode(data, self.key)
        except DatagramAuthError:
            self.stats["unauthenticated"] += 1
            return  # no key, another key, or forged: not one of ours, no answer
        except DatagramError:
            self.stats["corrupt"] += 1
            return  # a corrupt request is indistinguishable from a lost one
        self.received += 1
        if extra_copy:
            self.stats["duplicate_copy"] += 1
        with self._lock:
            self._version = dg.version
            self._handle(dg, peer)

    _version = VERSION  # the version of the request being answered

    def _live(self) -> bool:
        """A session is open, has been used, and was used (or its move ran) less than ``session_idle_s`` ago."""
        if self._session is None or self._active == -math.inf:  # never used: holds nothing
            return False
        return time.monotonic() - max(self._active, self._busy_until) < self.session_idle_s

    def _session_reject(self, dg: Datagram, peer: tuple) -> bool:
        """Deal with a request that is not of the current session from its own address.
        True when it was handled (ignored or rejected) and must not go further."""
        if dg.session == self._session:
            if peer != self._issued[dg.session]:
                self.stats["wrong_address"] += 1  # someone else using our client's session id: ignored
                return True
            self._active = time.monotonic()
            return False
        move = dg.payload if isinstance(dg.payload, Move) else no_move(dg.version)
        if dg.session in self._issued:
            if peer != self._issued[dg.session]:
                self.stats["wrong_address"] += 1
                return True
            self.stats["retired"] += 1  # its client must open a new session: tell it, do not run it
            reason = "session closed: another client opened a session after this one went idle"
            self._send(Datagram(MsgType.REJECTED, dg.session, dg.seq,
                                Rejected(move, RejectCode.SESSION_CLOSED, reason)), peer)
            return True
        self.stats["unknown_session"] += 1  # issued before a restart, or never: do not run it
        reason = "unknown session (the controller restarted, or no HELLO)"
        if dg.version >= 4 and session_boot(dg.session) != self.boot:
            self.stats["other_boot"] += 1
            reason = (f"session {dg.session:016x} is of boot {session_boot(dg.session):08x}; this controller booted "
                      f"as {self.boot:08x} (it restarted since, or the request is a replay): not executed")
        self._send(Datagram(MsgType.REJECTED, dg.session, dg.seq,
                            Rejected(move, RejectCode.UNKNOWN_SESSION, reason)), peer)
        return True

    def _handle(self, dg: Datagram, peer: tuple) -> None:
        if dg.type == MsgType.HELLO:
            self._hello(dg, peer)
            return
        if dg.type not in (MsgType.PING, MsgType.MOVE):
            return
        if self._session_reject(dg, peer):
            return
        if dg.type == MsgType.PING:
            self.stats["ping"] += 1
            self._send(Datagram(MsgType.PONG, dg.session, dg.seq), peer)
            return
        assert isinstance(dg.payload, Move)
        if dg.seq > self._last_seq and self._restart_on is not None:
            when, down_s = self._restart_on
            if when == "before_execute":
                self._restart(down_s)
                return
            self._execute(dg)
            self._restart(down_s)
            return
        if dg.seq < self._last_seq:
            self.stats["stale"] += 1
            return  # stale retransmission: never move backwards
        if dg.seq == self._last_seq and self._cache is not None:
            self.stats["repeat"] += 1
            reply = self._cache
            left = self._busy_until - time.monotonic()
            if reply.type == MsgType.IN_POSITION and left > 0:
                self._send(Datagram(MsgType.MOVING, dg.session, dg.seq, Moving(reply.payload.move, left)), peer)
                self._send(reply, peer, not_before=self._busy_until)
            else:
                self._send(reply, peer)
            return
        self.stats["new"] += 1
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

    def _hello(self, dg: Datagram, peer: tuple) -> None:
        hello = dg.payload
        assert isinstance(hello, Hello)
        if self._welcome is not None and self._welcome[:2] == (hello.nonce, peer):
            self.stats["hello_repeat"] += 1  # a retransmitted HELLO: the same session, not another
            self._send(self._welcome[2], peer)
            return
        if dg.version >= 4 and hello.nonce in self._nonces:
            self.stats["hello_replay"] += 1  # its nonce opened a session before: a replay, never a new one
            return
        holder = self._issued.get(self._session) if self._session is not None else None
        if holder is not None and holder != peer:
            if self._live():
                self.stats["hello_refused"] += 1  # the live session stays; nothing changes
                if dg.version >= 2:
                    reason = (f"another client's session is live; a new one is opened after "
                              f"{self.session_idle_s:g} s without its requests")
                    self._send(Datagram(MsgType.REFUSED, 0, 0, Refused(hello.nonce, RejectCode.SESSION_BUSY, reason)),
                               peer)
                return
            self.stats["takeover"] += 1
        session = self._new_session(dg.version)
        self._issued[session] = peer
        self._session, self._last_seq, self._cache = session, 0, None  # the one before is retired
        self._active = -math.inf  # live only once a request of it arrives (a replayed HELLO holds nothing)
        if dg.version >= 4:
            self._nonces[hello.nonce] = None
            while len(self._nonces) > NONCE_WINDOW:
                self._nonces.popitem(last=False)
        welcome = Datagram(MsgType.WELCOME, session, 0, Welcome(hello.nonce, self.boot))
        self._welcome = (hello.nonce, peer, welcome)
        self.stats["hello"] += 1
        self._send(welcome, peer)

    def _execute(self, dg: Datagram) -> Datagram:
        move = dg.payload
        assert isinstance(move, Move)
        ws = self.workspace
        carriers = ws.carriers

        def reject(code: int, reason: str) -> Datagram:
            return Datagram(MsgType.REJECTED, dg.session, dg.seq, Rejected(move, code, reason))

        if len(move.cameras) > len(carriers):
            return reject(RejectCode.BAD_REQUEST, f"a move of {len(move.cameras)} cameras: this rig has "
                                                  f"{len(carriers)}")
        if dg.version <= 2 and [type(c) for c in carriers[:2]] != [Gantry, Track]:
            return reject(RejectCode.BAD_REQUEST, f"protocol version {dg.version} moves a gantry camera 1 and a "
                                                  f"track camera 2; this rig needs version 3")
        axes = []
        for i, (c, (pan, tilt)) in enumerate(zip(carriers, move.cameras)):
            try:
                eye, _ = c.place(ws.object_xyz, pan, tilt, camera=i)
            except WorkspaceError as e:
                reason = str(e) if str(e).startswith("camera") else f"camera {i}: {e}"
                return reject(RejectCode.WORKSPACE, reason)
            axes.append(c.axes(eye))
        table = move.turntable % (2 * math.pi)
        dist = max([math.hypot(*(a - b for a, b in zip(new, old))) for new, old in zip(axes, self.axes)] or [0.0])
        dturn = abs(math.remainder(table - self.turntable, 2 * math.pi))
        sim_s = max(dist / self.linear_speed, dturn / self.turntable_speed)
        self._duration_s = sim_s * self.time_scale
        for i, a in enumerate(axes):
            self.axes[i] = tuple(_quantise(v, LINEAR_RESOLUTION_M) for v in a)
        self.turntable = _quantise(table, 2 * math.pi / TURNTABLE_COUNTS) % (2 * math.pi)
        if dg.version <= 2:  # the thesis rig's motor coordinates: gantry (x, y), track (y,)
            reached = tuple(self.axes[:2])
        else:
            reached = tuple(c.eye(a) for c, a in zip(carriers, self.axes[:len(move.cameras)]))
        reply = InPosition(move, reached, self.turntable)
        self.executed.append(ExecutedMove(dg.session, dg.seq, move, reply))
        return Datagram(MsgType.IN_POSITION, dg.session, dg.seq, reply)
