"""A PTU-D46 simulator on a pseudo-terminal, for tests and the simulated rig.

``PTUSimulator()`` opens a pty pair (``os.openpty``) and serves the unit's
ASCII protocol (see :mod:`.ptu`) from a thread on the master side; the driver
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
* ``"silent"`` (attribute ``silent = True``) -- ignore all input until cleared.

``inject(fault, count, after=n)`` lets ``n`` replies through first (e.g. the
``PP`` of a pan+tilt move, so the fault hits its ``TP``).
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

__all__ = ["PTUSimulator", "PTU_FAULTS"]

PTU_FAULTS = ("drop", "error", "noise", "late")
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


class PTUSimulator:
    """Serve the PTU protocol on a pty.  Use as a context manager or call ``close()``.

    Args:
        resolution_arcsec: (pan, tilt) arc-seconds per position.
        pan_limits, tilt_limits: (min, max) positions.
        speed: initial speed, positions/s; ``speed_max`` the ``PU``/``TU`` limit.
        time_scale: wall seconds per simulated second.
        seed: seeds the noise bytes.
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
        self._faults: collections.deque[str | None] = collections.deque()
        self.log: list[str] = []  # commands received (tests read it)
        self._lock = threading.Lock()
        self._origin = time.monotonic()
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)
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

    def now(self) -> float:
        """Simulated seconds since start."""
        return (time.monotonic() - self._origin) / self.time_scale

    def position(self) -> tuple[float, float]:
        """True (pan, tilt) in positions, as the motors are now."""
        t = self.now()
        return self.axes["P"].pos(t), self.axes["T"].pos(t)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> "PTUSimulator":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------ serving
    def _write(self, data: bytes) -> None:
        try:
            os.write(self._master, data)
        except OSError:
            pass

    def _serve(self) -> None:
        buf = b""
        while not self._stop.is_set():
            r, _, _ = select.select([self._master], [], [], 0.02)
            if not r:
                continue
            try:
                data = os.read(self._master, 1024)
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
            if len(buf) > 64:  # no delimiter in sight: discard like a full line buffer
                buf = b""
                self._write(b"! Command too long\r\n")

    def _reply(self, text: str, fault: str | None) -> None:
        if fault == "drop":
            return
        if fault == "late":
            time.sleep(self.late_s)
        elif fault == "noise":
            n = self._rng.randint(1, 12)
            junk = bytes(self._rng.choice(b"#$%&\x00\x07\x1b\xfe\x80?@~") for _ in range(n))
            self._write(junk + b"\r\n")
            return
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
        self._reply(self._execute(m.group(1), m.group(2)), fault)

    def _ok(self, value=None, verbose: str = "") -> str:
        if value is None:
            return "*" if self.terse else f"* {verbose}".rstrip()
        return f"* {value}" if self.terse else f"* {verbose} {value}".replace("  ", " ")

    def _execute(self, op: str, arg: str | None) -> str:
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
            done = max(ax.done_at() for ax in self.axes.values())
            wait = (done - now) * self.time_scale
            if wait > 0:
                time.sleep(wait)
            return self._ok()
        if op == "R":
            for ax in self.axes.values():
                ax.go(0, now)
                ax.t0 = now - 1e9  # reset completes at once in the simulator
                ax.pending = None
            return "!T!T!P!P*"
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
                return self._ok(round(ax.pos(now)), f"Current {name} position is")
            base = ax.pending if ax.pending is not None else ax.target
            target = n if kind == "P" else base + n
            if target > ax.hi:
                return f"! Maximum allowable {name} position is {ax.hi}"
            if target < ax.lo:
                return f"! Minimum allowable {name} position is {ax.lo}"
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
