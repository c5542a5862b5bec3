"""A PTU-D46 simulator on a pseudo-terminal, for tests and the simulated rig.

``PTUSimulator()`` opens a pty pair (``os.openpty``) and serves the unit's
ASCII protocol (see :mod:`..devices.ptu_protocol`) from a thread on the master side; the driver
opens ``sim.port`` (the slave path) like any serial device.

Like a real unit it starts with echo on and verbose feedback, has the
PTU-D46-17.5's resolution (185.1428 arc-seconds a position) and limits
(pan +/-3090 positions = +/-159 deg, tilt -907..+604 = -46.6..+31.1 deg),
moves each axis at its set speed (default 1000 positions/s) so that ``A``
answers only when the motion is over, and queues moves in slaved mode (``S``)
until ``A``.  ``time_scale`` is the number of wall-clock seconds one simulated
second takes (0.01 = a hundred times faster than the real unit).

Faults (:meth:`PTUSimulator.inject`), each applied to the next reply:

* ``"drop"``  -- execute the command but send no reply (driver: timeout)
* ``"error"`` -- do not execute it, answer ``! Simulated fault``
* ``"noise"`` -- execute it, send a line of random non-protocol bytes instead of the reply
* ``"late"``  -- execute it, send the right reply after ``late_s`` wall seconds
  (set it above the driver's timeout); like a busy unit, it answers the
  commands that follow only after that
* ``"pan_limit"`` / ``"tilt_limit"`` -- execute it, and put the unit's
  asynchronous axis-limit message (``!P`` / ``!T``, two bytes, no line end)
  in the middle of the reply, as a unit that hits a limit switch does
* ``"stall"`` -- the motors stop where they are (lost steps) and the command
  is not answered: an ``A`` that meets it never reports the motion finished
* ``"unplug"`` -- the command arrives, then the serial device disappears (the
  pty closes: the driver's next read or write fails like a USB unplug, the
  path vanishes); it comes back after ``back_after_s`` wall seconds (``None``:
  only :meth:`PTUSimulator.replug` brings it back) under a new path if
  ``back_new_path``, power-cycled and homing for ``back_homing_s`` simulated
  seconds if that is > 0
* ``"silent"`` (attribute ``silent = True``) -- ignore all input until cleared.

``inject(fault, count, after=n)`` lets ``n`` replies through first (e.g. the
``PP`` of a pan+tilt move, so the fault hits its ``TP``).  :meth:`PTUSimulator.answer`
sends a line of the caller's instead of a reply (``"* 99999999"``: a position
outside the unit's own limits, as a garbled line can read).

Homing.  A reset (``R``) or a power-up makes the unit calibrate for
``homing_s`` simulated seconds (0 = at once, the default): the motors sweep
to their limits and back to (0, 0), and the unit sends ``!T``, ``!T``,
``!P``, ``!P`` as it reaches each limit -- asynchronously, into whatever reply
is on the line.  While homing it still answers: queries report the sweep,
position commands are acknowledged (``*``) but lost (the sweep owns the
motors), ``A`` answers when the sweep is over, and ``R``'s own ``*`` comes at
the end.  (This is the model of the field reports: a unit that answers but is
still homing; after a power-up there is no final ``*``.)  ``link`` keeps a
symbolic link (like ``/dev/serial/by-id/...``) pointing at the current pty,
so a replug can come back under the *same* path.
"""

from __future__ import annotations

import collections
import os
import random
import re
import select
import threading
import time
import tty
from typing import Callable

__all__ = ["PTUSimulator", "PTU_FAULTS"]

PTU_FAULTS = ("drop", "error", "noise", "late", "pan_limit", "tilt_limit", "stall", "unplug")
_HOMING_MARKERS = (b"!T", b"!T", b"!P", b"!P")  # at 1/5 .. 4/5 of the sweep
_TOKEN = re.compile(r"([A-Z]+)([+-]?[0-9]+)?")


class _Axis:
    def __init__(self, lo: int, hi: int, speed: int, top: int):
        self.lo, self.hi, self.speed, self.top = lo, hi, speed, top
        self.start = 0.0
        self.target = 0
        self.t0 = 0.0  # simulated time the current motion started
        self.pending: int | None = None

    def pos(self, now: float) -> float:
        d = self.target - self.start
        step = self.speed * (now - self.t0)
        if step >= abs(d):
            return float(self.target)
        return self.start + step * (1 if d > 0 else -1)

    def go(self, target: int, now: float) -> None:
        self.start = self.pos(now)
        self.target = target
        self.t0 = now

    def done_at(self) -> float:
        return self.t0 + abs(self.target - self.start) / self.speed

    def halt(self, now: float) -> None:
        self.go(round(self.pos(now)), now)
        self.pending = None


class PTUSimulator:
    """Serve the PTU protocol on a pty.  Use as a context manager or call ``close()``.

    Args:
        resolution_arcsec: (pan, tilt) arc-seconds per position.
        pan_limits, tilt_limits: (min, max) positions.
        speed: initial speed, positions/s; ``speed_max`` the ``PU``/``TU`` limit.
        time_scale: wall seconds per simulated second.
        seed: seeds the noise bytes.
        homing_s: simulated seconds a reset (``R``, power-up) takes.
        link: path of a symbolic link kept pointing at the current pty (optional).
    """

    def __init__(
        self,
        *,
        resolution_arcsec: tuple[float, float] = (185.1428, 185.1428),
        pan_limits: tuple[int, int] = (-3090, 3090),
        tilt_limits: tuple[int, int] = (-907, 604),
        speed: int = 1000,
        speed_max: int = 5833,
        time_scale: float = 0.01,
        seed: int = 0,
        homing_s: float = 0.0,
        link: str | os.PathLike | None = None,
    ):
        if time_scale <= 0:
            raise ValueError(f"time_scale must be > 0, got {time_scale}")
        self.resolution = resolution_arcsec
        self.axes = {"P": _Axis(*pan_limits, speed, speed_max), "T": _Axis(*tilt_limits, speed, speed_max)}
        self.time_scale = float(time_scale)
        self._rng = random.Random(seed)
        self.echo = True
        self.terse = False
        self.slaved = False
        self.silent = False
        self.late_s = 0.3  # wall seconds a "late" reply is held back
        self.homing_s = float(homing_s)
        self.back_after_s: float | None = 0.2  # an "unplug" fault comes back after this long
        self.back_new_path = False
        self.back_homing_s = 0.0
        self.stats: collections.Counter[str] = collections.Counter()  # what the faults did
        self._faults: collections.deque[str | tuple[str, str] | None] = collections.deque()
        self.log: list[str] = []  # commands received (tests read it)
        self._lock = threading.Lock()
        self._origin = time.monotonic()
        self._homing_until = -1.0  # simulated time the current homing sweep ends
        self._homing_t0 = -1.0
        self._homing_from = (0.0, 0.0)
        self._outbox: list[tuple[float, bytes]] = []  # (wall time due, bytes) sent by the serving thread
        self.link = None if link is None else os.fspath(link)
        self._master: int | None = None
        self._slave: int | None = None
        self._generation = 0  # counts the ptys opened (a new device node each time)
        self.port = ""
        self._open_pty()
        self._requests: collections.deque[tuple] = collections.deque()  # unplug/replug for the serving thread
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="ptu-sim", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------ control
    def inject(self, fault: str, count: int = 1, *, after: int = 0) -> None:
        """Apply ``fault`` ("drop", "error", "noise" or "late") to ``count`` replies,
        after letting the next ``after`` replies through (faults already queued come first)."""
        if fault not in PTU_FAULTS:
            raise ValueError(f"unknown PTU fault {fault!r}; choose from {PTU_FAULTS}")
        if count < 1 or after < 0:
            raise ValueError(f"count must be >= 1 and after >= 0, got {count}, {after}")
        with self._lock:
            self._faults.extend([None] * after + [fault] * count)

    def answer(self, text: str, count: int = 1, *, after: int = 0) -> None:
        """Send the line ``text`` (e.g. ``"* 99999999"``, a garbled position) instead of the
        reply to ``count`` commands, after letting ``after`` replies through; the commands
        still execute."""
        if count < 1 or after < 0:
            raise ValueError(f"count must be >= 1 and after >= 0, got {count}, {after}")
        with self._lock:
            self._faults.extend([None] * after + [("answer", str(text))] * count)

    @property
    def plugged(self) -> bool:
        return self._master is not None

    def unplug(self) -> None:
        """The serial device disappears now (the pty closes, the path vanishes)."""
        self._request("unplug")

    def replug(self, *, new_path: bool = False, homing_s: float = 0.0, link: str | os.PathLike | None = None) -> None:
        """The device comes back: under a different pty path if ``new_path``, behind
        the symbolic link ``link`` (default: the one given at construction), and
        power-cycled -- echo on, verbose, homing for ``homing_s`` -- if ``homing_s`` > 0."""
        self._request("replug", new_path, homing_s, link)

    def _request(self, *what) -> None:
        done = threading.Event()
        self._requests.append((*what, done))
        if threading.current_thread() is not self._thread:
            done.wait(2.0)

    def now(self) -> float:
        """Simulated seconds since start."""
        return (time.monotonic() - self._origin) / self.time_scale

    def position(self) -> tuple[float, float]:
        """True (pan, tilt) in positions, as the motors are now."""
        t = self.now()
        return self._pos("P", t), self._pos("T", t)

    def _pos(self, axis: str, now: float) -> float:
        if now < self._homing_until:  # the sweep, drawn as a straight way home
            i = 0 if axis == "P" else 1
            t0 = self._homing_t0
            return self._homing_from[i] * (self._homing_until - now) / max(self._homing_until - t0, 1e-12)
        return self.axes[axis].pos(now)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._close_pty()

    # ------------------------------------------------------------ the device node
    def _open_pty(self, new_path: bool = False) -> None:
        master, slave = os.openpty()
        if new_path and os.ttyname(slave) == self.port:  # the kernel reused the number: take another
            spare = (master, slave)
            master, slave = os.openpty()
            for fd in spare:
                os.close(fd)
        tty.setraw(slave)
        self._slave, self.port = slave, os.ttyname(slave)
        if self.link is not None:
            tmp = f"{self.link}.new"
            if os.path.lexists(tmp):
                os.remove(tmp)
            os.symlink(self.port, tmp)
            os.replace(tmp, self.link)
        self._generation += 1
        self._master = master  # last: the serving thread starts reading now

    def _close_pty(self) -> None:
        fds, self._master, self._slave = (self._master, self._slave), None, None
        self._generation += 1
        for fd in fds:
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        if self.link is not None and os.path.lexists(self.link):
            os.remove(self.link)  # like udev removing /dev/serial/by-id/... on unplug

    def _do_requests(self) -> None:
        while self._requests:
            what, *args, done = self._requests.popleft()
            if what == "unplug":
                self._close_pty()
                self._outbox.clear()
                self.stats["unplugged"] += 1
            elif self._master is None:  # replug
                new_path, homing_s, link = args
                if link is not None:
                    self.link = os.fspath(link)
                self._open_pty(new_path)
                self.stats["replugged"] += 1
                if homing_s > 0:
                    self._power_up(homing_s)
            done.set()

    def _power_up(self, homing_s: float) -> None:
        self.echo, self.terse, self.slaved = True, False, False
        for ax in self.axes.values():
            ax.speed = 1000
        self._start_homing(homing_s, reply=False)

    def __enter__(self) -> "PTUSimulator":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------ serving
    def _write(self, data: bytes) -> None:
        if self._master is None:
            return
        try:
            os.write(self._master, data)
        except OSError:
            pass

    def _flush_due(self) -> None:
        now = time.monotonic()
        while self._outbox and self._outbox[0][0] <= now:
            self._write(self._outbox.pop(0)[1])

    def _wait_until(self, wall: float, still: Callable[[], bool] = lambda: True) -> bool:
        """Sleep until ``wall`` (monotonic) while sending due asynchronous output;
        False if ``still()`` turned false or the simulator is closing first."""
        while time.monotonic() < wall:
            if self._stop.is_set() or not still():
                return False
            self._do_requests()
            self._flush_due()
            time.sleep(min(0.002, max(wall - time.monotonic(), 0.0)))
        self._flush_due()
        return True

    def _serve(self) -> None:
        buf = b""
        while not self._stop.is_set():
            self._do_requests()
            self._flush_due()
            fd, gen = self._master, self._generation
            if fd is None:
                buf = b""
                time.sleep(0.002)
                continue
            r, _, _ = select.select([fd], [], [], 0.005)
            if not r:
                continue
            try:
                data = os.read(fd, 1024)
            except OSError:
                time.sleep(0.01)
                continue
            if self.silent:
                buf = b""
                continue
            if self.echo:
                self._write(data)
            buf += data
            while True:
                m = re.search(rb"[ \r\n]", buf)
                if m is None:
                    break
                token, buf = buf[: m.start()], buf[m.end():]
                if token:
                    self._handle(token)
                if self._generation != gen:  # unplugged while handling: the rest is lost
                    buf = b""
                    break
            if len(buf) > 64:  # no delimiter in sight: discard like a full line buffer
                buf = b""
                self._write(b"! Command too long\r\n")

    def _reply(self, text: str | None, fault: str | None) -> None:
        if fault in ("drop", "stall", "unplug") or text is None:
            return
        if fault == "late":
            time.sleep(self.late_s)
        elif fault == "noise":
            n = self._rng.randint(1, 12)
            junk = bytes(self._rng.choice(b"#$%&\x00\x07\x1b\xfe\x80?@~") for _ in range(n))
            self._write(junk + b"\r\n")
            return
        elif fault in ("pan_limit", "tilt_limit"):
            k = len(text) // 2
            text = text[:k] + ("!P" if fault == "pan_limit" else "!T") + text[k:]
            self.stats[fault] += 1
        self._write(text.encode("ascii") + b"\r\n")

    def _handle(self, token: bytes) -> None:
        try:
            cmd = token.decode("ascii").upper()
        except UnicodeDecodeError:
            self._write(b"! Illegal command\r\n")
            return
        with self._lock:
            fault = self._faults.popleft() if self._faults else None
        self.log.append(cmd)
        if fault == "error":
            self._reply("! Simulated fault", None)
            return
        m = _TOKEN.fullmatch(cmd)
        if m is None:
            self._reply("! Illegal command", fault)
            return
        if fault == "stall":
            for ax in self.axes.values():
                ax.halt(self.now())
            self.stats["stalled"] += 1
            return
        text = self._execute(m.group(1), m.group(2))
        if isinstance(fault, tuple):  # answer(): another line instead of the reply
            self.stats["answered"] += 1
            self._write(fault[1].encode("ascii", "replace") + b"\r\n")
            return
        if fault == "unplug":
            self._close_pty()
            self._outbox.clear()
            self.stats["unplugged"] += 1
            if self.back_after_s is not None:
                back = (self.back_new_path, self.back_homing_s, None, threading.Event())
                timer = threading.Timer(self.back_after_s, lambda: self._requests.append(("replug", *back)))
                timer.daemon = True
                timer.start()
            return
        self._reply(text, fault)

    # ------------------------------------------------------------ homing
    def homing(self, now: float | None = None) -> bool:
        """Is the unit calibrating (after ``R`` or a power-up)?"""
        return (self.now() if now is None else now) < self._homing_until

    def _start_homing(self, homing_s: float, reply: bool) -> None:
        """Sweep for ``homing_s`` simulated seconds, sending the limit markers on the way
        (and ``R``'s ``*`` at the end if ``reply``); the axes end at (0, 0)."""
        now = self.now()
        self._homing_from = self.position()
        for ax in self.axes.values():
            ax.go(0, now)
            ax.t0 = now - 1e9  # at 0 once the sweep is over
            ax.pending = None
        self._homing_t0, self._homing_until = now, now + homing_s
        wall = time.monotonic()
        span = homing_s * self.time_scale
        for k, marker in enumerate(_HOMING_MARKERS):
            self._outbox.append((wall + span * (k + 1) / 5, marker))
        if reply:
            self._outbox.append((wall + span, b"*\r\n"))
        self._outbox.sort(key=lambda x: x[0])

    def _ok(self, value=None, verbose: str = "") -> str:
        if value is None:
            return "*" if self.terse else f"* {verbose}".rstrip()
        return f"* {value}" if self.terse else f"* {verbose} {value}".replace("  ", " ")

    def _execute(self, op: str, arg: str | None) -> str | None:
        now = self.now()
        n = int(arg) if arg is not None else None
        if op in ("ED", "EE"):
            self.echo = op == "EE"
            return self._ok(verbose="Echo " + ("enabled" if self.echo else "disabled"))
        if op in ("FT", "FV"):
            self.terse = op == "FT"
            return self._ok(verbose="Verbose feedback")
        if op in ("I", "S"):
            self.slaved = op == "S"
            return self._ok()
        if op == "A":
            for ax in self.axes.values():
                if ax.pending is not None:
                    ax.go(ax.pending, now)
                    ax.pending = None
            done = max([self._homing_until] + [ax.done_at() for ax in self.axes.values()])
            gen = self._generation
            if not self._wait_until(time.monotonic() + max(done - now, 0.0) * self.time_scale,
                                    lambda: self._generation == gen):
                return None  # unplugged or closing while it waited
            return self._ok()
        if op == "R":
            if self.homing_s <= 0:
                for ax in self.axes.values():
                    ax.go(0, now)
                    ax.t0 = now - 1e9  # reset completes at once
                    ax.pending = None
                return "!T!T!P!P*"
            self._start_homing(self.homing_s, reply=True)
            return None  # the markers and the '*' follow as the sweep goes
        if op == "H":
            for ax in self.axes.values():
                ax.go(round(ax.pos(now)), now)
            return self._ok()
        if len(op) != 2 or op[0] not in "PT":
            return "! Illegal command"
        name = "Pan" if op[0] == "P" else "Tilt"
        ax = self.axes[op[0]]
        kind = op[1]
        if kind in ("R", "N", "X", "U") and n is not None:
            return "! Illegal argument"
        if kind == "R":
            return self._ok(f"{self.resolution[0 if op[0] == 'P' else 1]:.4f}", f"{name} resolution is")
        if kind == "N":
            return self._ok(ax.lo, f"Minimum {name} position is")
        if kind == "X":
            return self._ok(ax.hi, f"Maximum {name} position is")
        if kind == "U":
            return self._ok(ax.top, f"{name} upper speed limit is")
        if kind in ("P", "O"):
            if n is None:
                if kind == "O":
                    return "! Illegal argument"
                return self._ok(round(self._pos(op[0], now)), f"Current {name} position is")
            base = ax.pending if ax.pending is not None else ax.target
            target = n if kind == "P" else base + n
            if target > ax.hi:
                return f"! Maximum allowable {name} position is {ax.hi}"
            if target < ax.lo:
                return f"! Minimum allowable {name} position is {ax.lo}"
            if self.homing(now):  # acknowledged, but the homing sweep owns the motors
                self.stats["lost_while_homing"] += 1
                return self._ok()
            if self.slaved:
                ax.pending = target
            else:
                ax.go(target, now)
            return self._ok()
        if kind == "S":
            if n is None:
                return self._ok(ax.speed, f"Target {name} speed is")
            if n > ax.top:
                return f"! {name} speed cannot exceed {ax.top} pos/sec"
            if n < 1:
                return f"! {name} speed must be at least 1 pos/sec"
            ax.start, ax.t0 = ax.pos(now), now  # keep the current motion continuous
            ax.speed = n
            return self._ok()
        return "! Illegal command"
