"""Driver for Directed Perception PTU-D46 pan-tilt units (thesis §6.4) over a serial line.

The command protocol, the strict reply parser and the errors this driver
raises are in :mod:`..ptu_protocol`.

Asynchronous output.  A unit that reaches a limit switch sends ``!P`` or
``!T`` (two bytes, no line end) at once, whatever is on the line -- also in
the middle of the reply to another command, and during a reset's sweep.  The
driver removes every ``!P`` / ``!T`` from a reply before parsing it.  Outside
a reset or the connect they are *limit events*: counted in
:attr:`PTU.limit_events` (per axis), logged as a warning, and the axis's
position is read back before the next move.

Homing.  After a reset or a power-up the unit calibrates (sweeps to its
limits and home) while still answering commands -- a position command sent
then is acknowledged and lost.  So :meth:`PTU.connect` sends ``A`` (which
answers once every motion, the sweep included, is over) before anything
else, with the timeout ``homing_timeout``; :meth:`PTU.reset` waits for the
reset's ``*`` as long; if either gives up, the next move waits again first.
Every wait in the driver is bounded: a reply line by ``timeout``, ``A`` by
the motion time plus ``await_margin`` but never more than ``max_motion_s``
(:data:`MAX_MOTION_S`, 120 s, whatever distance and speed the unit reports),
or by ``homing_timeout``, a drain by a fixed number of timeouts, a write by ``timeout`` (``write_timeout``; the driver
never calls ``flush()``, whose ``tcdrain`` has no timeout); after a failed
``A`` the axes are read back before the next move.

Angles in this module's public API are **degrees**; the unit works in
**positions**, ``positions = round(degrees * 3600 / resolution_arcsec)``.
Limits are queried from the unit on connect and checked before sending; every
position and speed the unit reports is checked against them too (a reply of
``* 99999999`` to ``PP`` on a unit of +/-3090 positions is a
:class:`..ptu_protocol.PTUGarbageError`, never a target 10^5 s away).

After any failure (a :class:`PTUError`) the input buffer is drained and
flushed, so the next command starts on a clean line; after a timeout the
driver keeps draining until the line has been quiet for a whole reply
timeout, so that a reply that was merely late (it arrives after the driver
gave up) is discarded instead of being read as the answer to the next command.

The driver remembers the commanded target of each axis (relative moves and
the ``A`` timeout are computed from it).  It is updated after each command
the unit acknowledges; when a position command fails the driver cannot know
whether the unit took it (a lost or garbled reply to an executed command, a
refusal), so before the next move it waits for the unit (``A``) and reads the
axes back (``PP``, ``TP``).
"""
from __future__ import annotations

import collections
import logging
import math
import time

import serial

from ..ptu_protocol import (
    ARCSEC_PER_POSITION_D46_17_5,
    PTUConnectionError,
    PTUError,
    PTUErrorReply,
    PTUGarbageError,
    PTUHomingTimeout,
    PTULimitError,
    PTULimits,
    PTUTimeoutError,
    limit_markers,
    parse_reply,
)

try:
    import termios
except ImportError:  # not POSIX
    termios = None  # type: ignore[assignment]

# what a vanished device raises: pyserial's own errors, the OS's, and (from
# Serial.flush on a pty whose other end closed) termios.error, which is neither
_IO_ERRORS: tuple[type[BaseException], ...] = (serial.SerialException, OSError) + (
    (termios.error,) if termios is not None else ()
)

__all__ = ["PTU", "DRIVER", "MAX_MOTION_S"]

#: Default bound (seconds) on the wait for one motion (``A``): a full +/-3090 pan
#: sweep at 50 positions/s, far below any speed the unit is set to in practice.
MAX_MOTION_S = 120.0

log = logging.getLogger(__name__)


class PTU:
    """One pan-tilt unit on a serial port (any URL ``serial.serial_for_url`` takes).

    Args:
        url: ``/dev/ttyUSB0``, ``/dev/pts/5``, ``spy:///dev/ttyUSB0``, ``rfc2217://...``, ...
        baudrate: 9600 (8N1) is the unit's factory default.
        timeout: seconds to wait for one reply line.
        await_margin: extra seconds allowed for ``A`` on top of the motion time
            estimated from distance / speed.
        homing_timeout: seconds to wait for a unit that is homing (after a reset
            or a power-up) before giving up with :class:`PTUHomingTimeout`.
        max_motion_s: the longest wait for one motion (``A``), whatever the
            estimate from the distance and speed the unit reports.
        connect: open and initialise now (``ED``, ``FT``, ``I``, ``A``,
            resolution and limit queries).

    Attributes:
        limit_events: ``Counter`` of the asynchronous limit messages (``"P"``,
            ``"T"``) seen outside a reset or the connect.
    """

    #: The PTU-D46-17.5's travel in degrees, ((pan min, max), (tilt min, max)):
    #: +/-3090 pan and -907..+604 tilt positions of 185.1428 arc-seconds.  A rig
    #: file's table is checked against it when the file is loaded (the unit's
    #: own limits, queried on connect, are checked again before every move).
    nominal_range_deg = (
        (-3090 * ARCSEC_PER_POSITION_D46_17_5 / 3600, 3090 * ARCSEC_PER_POSITION_D46_17_5 / 3600),
        (-907 * ARCSEC_PER_POSITION_D46_17_5 / 3600, 604 * ARCSEC_PER_POSITION_D46_17_5 / 3600),
    )

    def __init__(
        self,
        url: str,
        *,
        baudrate: int = 9600,
        timeout: float = 0.5,
        await_margin: float = 2.0,
        homing_timeout: float = 30.0,
        max_motion_s: float = MAX_MOTION_S,
        connect: bool = True,
    ):
        for name, value in (("timeout", timeout), ("homing_timeout", homing_timeout), ("max_motion_s", max_motion_s)):
            if not (value > 0 and math.isfinite(value)):
                raise ValueError(f"{name} must be > 0 seconds, got {value}")
        self.max_motion_s = float(max_motion_s)
        self.url = url
        self.baudrate = int(baudrate)
        self.timeout = float(timeout)
        self.await_margin = float(await_margin)
        self.homing_timeout = float(homing_timeout)
        self.limit_events: collections.Counter[str] = collections.Counter()
        self._homing_markers = 0  # markers seen during a reset or the connect (expected there)
        self._expect_markers = False
        self._homing_pending = False  # a reset or the connect gave up waiting: wait before moving
        self._move_start: tuple[int, int] | None = None
        self._ser: serial.SerialBase | None = None
        self.resolution_arcsec: tuple[float, float] | None = None
        self.limits: PTULimits | None = None
        self._speed: tuple[int, int] = (0, 0)
        self._target: tuple[int, int] = (0, 0)
        self._unsure = [False, False]  # a failed PP/TP/PO/TO left this axis's target unknown
        if connect:
            self.connect()

    @classmethod
    def from_config(cls, config, port: str | None = None) -> "PTU":
        """The unit of a ``[[ptu]]`` entry (:class:`...physical.config.PTUConfig`); ``port`` overrides its ``port``."""
        return cls(
            config.port if port is None else port,
            baudrate=config.baudrate,
            timeout=config.timeout_s,
            homing_timeout=config.homing_timeout_s,
            max_motion_s=config.max_motion_s,
        )

    # ------------------------------------------------------------ connection
    def connect(self) -> None:
        """Open the port and initialise the unit (echo off, terse, immediate mode, queries)."""
        try:
            self._ser = serial.serial_for_url(
                self.url,
                baudrate=self.baudrate,
                bytesize=serial.EIGHTBITS,
                parity=serial.PARITY_NONE,
                stopbits=serial.STOPBITS_ONE,
                timeout=self.timeout,
                write_timeout=self.timeout,
            )
        except (serial.SerialException, ValueError, OSError) as e:
            raise PTUConnectionError("open", f"cannot open {self.url!r}: {e}") from e
        try:
            self._handshake()
        except BaseException:
            self.close()  # a unit that does not answer is not connected; reconnect() retries
            raise

    def reconnect(self, url: str | None = None) -> None:
        """Close and reopen the port (``url`` if given: a device that came back
        under a new path), then initialise the unit again."""
        self.close()
        if url is not None:
            self.url = url
        self.connect()

    def close(self) -> None:
        if self._ser is not None:
            try:
                self._ser.close()
            except _IO_ERRORS:
                pass
            self._ser = None

    def __enter__(self) -> "PTU":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _handshake(self) -> None:
        # At power-up the unit echoes input and answers verbosely; the replies to
        # these two mode switches are therefore accepted leniently (a '*' somewhere).
        self._drain()
        self._expect_markers = True  # a unit homing after a power-up sends its limit markers now
        try:
            for cmd in ("ED", "FT"):
                line = self._exchange(cmd)
                if b"*" not in line:
                    self._recover()
                    if line.lstrip().startswith(b"!"):
                        raise PTUErrorReply(cmd, line.decode("ascii", "replace").strip())
                    raise PTUGarbageError(cmd, line, "expected a '*' acknowledgement")
            self.command("I")
            # a unit that answers may still be homing: A answers once every motion is over
            self._wait_idle()
        finally:
            self._expect_markers = False
        self.resolution_arcsec = (self.query_float("PR"), self.query_float("TR"))
        for axis, r in zip("PT", self.resolution_arcsec):
            if not (0.0 < r < 3600.0 * 10):
                raise PTUGarbageError(f"{axis}R", str(r).encode(), "implausible resolution")
        pan = (self.query_int("PN"), self.query_int("PX"))
        tilt = (self.query_int("TN"), self.query_int("TX"))
        for name, (lo, hi) in (("pan", pan), ("tilt", tilt)):
            if lo >= hi:
                raise PTUGarbageError(name, f"{lo} {hi}".encode(), "minimum limit not below maximum")
        tops = (self.query_int("PU"), self.query_int("TU"))
        for axis, top in zip("PT", tops):
            if top < 1:
                raise PTUGarbageError(f"{axis}U", f"* {top}".encode(), "upper speed limit below 1 position/s")
        self.limits = PTULimits(pan, tilt, *tops)
        self._speed = self._speed_counts()
        self._target = self.position_counts()
        self._unsure = [False, False]
        self._move_start = None

    def _wait_idle(self) -> None:
        """``A`` with the homing timeout: wait for a reset's or power-up's sweep to end.

        After a reset the driver gave up on, the reset's own ``*`` comes at the end
        of the sweep, together with the answer to this ``A``: the line is drained
        afterwards so that the second one is not read as the next reply."""
        expecting, self._expect_markers = self._expect_markers, True  # the sweep's markers are no limit events
        try:
            self.command("A", timeout=self.homing_timeout)
        except PTUTimeoutError as e:
            self._homing_pending = True
            raise PTUHomingTimeout("A", f"unit still busy (homing?) after {self.homing_timeout:.3g} s; "
                                        "no move was sent") from e
        finally:
            self._expect_markers = expecting
        if self._homing_pending:
            self._drain(quiet=self.timeout, longest=2.0 * self.timeout)
        self._homing_pending = False

    # ------------------------------------------------------------ raw I/O
    def _port(self, command: str) -> serial.SerialBase:
        if self._ser is None:
            raise PTUConnectionError(command, f"port {self.url!r} is not open (call reconnect())")
        return self._ser

    def _drain(self, quiet: float = 0.02, longest: float = 0.2) -> None:
        """Read and discard input until the line has been quiet for ``quiet`` seconds."""
        ser = self._ser
        if ser is None:
            return
        old = ser.timeout
        try:
            ser.timeout = quiet
            end = time.monotonic() + longest
            while time.monotonic() < end:
                if not ser.read(max(1, ser.in_waiting)):
                    break
            ser.reset_input_buffer()
        except _IO_ERRORS:
            pass
        finally:
            try:
                ser.timeout = old
            except _IO_ERRORS:
                pass

    def _recover(self) -> None:
        self._drain()

    def _exchange(self, command: str, timeout: float | None = None) -> bytes:
        """Send ``command`` and return one raw reply line (with CR LF)."""
        ser = self._port(command)
        try:
            # (no flush(): tcdrain ignores write_timeout and can block for ever on a
            # hung adapter; write() already returns within write_timeout)
            ser.write(command.encode("ascii") + b" ")
            if timeout is not None:
                ser.timeout = timeout
            line = ser.read_until(b"\n", 256)
        except _IO_ERRORS as e:
            self._unsure = [True, True]  # whatever happened to this command, read the axes back
            raise PTUConnectionError(command, f"serial I/O failed on {self.url!r}: {e}") from e
        finally:
            if timeout is not None and self._ser is not None:
                try:
                    self._ser.timeout = self.timeout
                except _IO_ERRORS:
                    pass
        line = self._strip_markers(command, line)
        if not line.endswith(b"\n"):
            # the reply may only be late: wait for the line to stay quiet for a
            # whole reply timeout, so it cannot be taken for the next answer
            self._drain(quiet=self.timeout, longest=4.0 * self.timeout + 0.2)
            wait = self.timeout if timeout is None else timeout
            raise PTUTimeoutError(command, f"no complete reply within {wait:.3g} s (got {line[:40]!r})")
        return line

    def _strip_markers(self, command: str, line: bytes) -> bytes:
        """Remove the asynchronous ``!P`` / ``!T`` limit messages from a reply and account for them."""
        axes, stripped = limit_markers(line)
        if not axes:
            return line
        if self._expect_markers:
            self._homing_markers += len(axes)
            log.debug("PTU %s: %d homing limit markers in the reply to %r", self.url, len(axes), command)
        else:
            for axis in axes:
                self.limit_events[axis] += 1
                self._unsure[0 if axis == "P" else 1] = True  # read the axis back before the next move
                log.warning(
                    "PTU %s: %s axis reached a limit (asynchronous '!%s' in the reply to %r; %d so far); "
                    "its position is read back before the next move",
                    self.url, "pan" if axis == "P" else "tilt", axis, command, self.limit_events[axis],
                )
        return stripped

    def _checked(self, command: str, expect: str, timeout: float | None = None):
        line = self._exchange(command, timeout)
        try:
            return parse_reply(command, line, expect)
        except PTUError:
            self._recover()
            raise

    def command(self, command: str, timeout: float | None = None) -> None:
        """Send an action command and require the ``*`` acknowledgement."""
        self._checked(command, "ack", timeout)

    def query_int(self, command: str) -> int:
        return self._checked(command, "int")

    def query_float(self, command: str) -> float:
        return self._checked(command, "float")

    # ------------------------------------------------------------ units
    def _res(self, axis: str) -> float:
        if self.resolution_arcsec is None:
            raise PTUConnectionError(f"{axis}R", "resolution unknown: the unit was never initialised")
        return self.resolution_arcsec[0 if axis == "P" else 1]

    def to_positions(self, axis: str, degrees: float) -> int:
        """Degrees -> positions (rounded), checked against the queried limits."""
        if axis not in ("P", "T"):
            raise ValueError(f"axis must be 'P' or 'T', not {axis!r}")
        if not math.isfinite(degrees):
            raise PTULimitError(f"{axis}P", f"angle {degrees!r} is not finite")
        pos = int(round(degrees * 3600.0 / self._res(axis)))
        self._check_position(axis, pos, degrees)
        return pos

    def to_degrees(self, axis: str, positions: int) -> float:
        return positions * self._res(axis) / 3600.0

    def _check_position(self, axis: str, pos: int, degrees: float | None = None) -> None:
        assert self.limits is not None
        lo, hi = self.limits.pan if axis == "P" else self.limits.tilt
        if not lo <= pos <= hi:
            what = f"{degrees:.4f} deg = " if degrees is not None else ""
            name = "pan" if axis == "P" else "tilt"
            raise PTULimitError(
                f"{axis}P{pos}",
                f"{name} {what}{pos} positions is outside the unit's limits [{lo}, {hi}]"
                f" = [{self.to_degrees(axis, lo):.3f}, {self.to_degrees(axis, hi):.3f}] deg",
            )

    # ------------------------------------------------------------ motion
    def move_to(self, pan: float | None = None, tilt: float | None = None, *, wait: bool = True) -> None:
        """Absolute move (``PP`` / ``TP``) to ``pan`` / ``tilt`` degrees; both checked before either is sent."""
        cmds = []
        target = list(self._target)
        for i, (axis, deg) in enumerate((("P", pan), ("T", tilt))):
            if deg is not None:
                pos = self.to_positions(axis, deg)
                cmds.append((i, f"{axis}P{pos}"))
                target[i] = pos
        self.resync()
        self._send_moves(cmds, target, wait)

    def move_by(self, pan: float = 0.0, tilt: float = 0.0, *, wait: bool = True) -> None:
        """Relative move (``PO`` / ``TO``) by ``pan`` / ``tilt`` degrees from the current target."""
        self.resync()  # the base of a relative move must be what the unit really holds
        cmds = []
        target = list(self._target)
        for i, (axis, deg) in enumerate((("P", pan), ("T", tilt))):
            if deg:
                if not math.isfinite(deg):
                    raise PTULimitError(f"{axis}O", f"offset {deg!r} is not finite")
                off = int(round(deg * 3600.0 / self._res(axis)))
                self._check_position(axis, target[i] + off)
                cmds.append((i, f"{axis}O{off}"))
                target[i] += off
        self._send_moves(cmds, target, wait)

    def _send_moves(self, cmds: list[tuple[int, str]], target: list[int], wait: bool) -> None:
        start = self._target
        self._move_start = start
        for i, c in cmds:
            try:
                self.command(c)
            except PTUError:
                self._unsure[i] = True  # did the unit take it? resync() finds out
                raise
            now = list(self._target)
            now[i] = target[i]
            self._target = (now[0], now[1])  # committed axis by axis
        if wait:
            self.await_motion(start)

    def resync(self) -> None:
        """After a failed position command: wait for the unit (``A``) and read
        its axes back (``PP``, ``TP``) as the new target.  A no-op otherwise.

        (In slaved mode the ``A`` also starts any queued move.)  When a reset or
        the connect gave up waiting for the unit to finish homing, it waits for
        that first (``A``, at most ``homing_timeout``) instead of sending moves."""
        if self._homing_pending:
            self._wait_idle()
            self._unsure = [True, True]
        if not any(self._unsure):
            return
        assert self.limits is not None
        span = max(self.limits.pan[1] - self.limits.pan[0], self.limits.tilt[1] - self.limits.tilt[0])
        longest = span / max(min(self._speed), 1)
        self.command("A", timeout=self._motion_wait(longest))
        self._target = self.position_counts()
        self._unsure = [False, False]

    @property
    def target(self) -> tuple[int, int]:
        """The last commanded (pan, tilt) in positions (where the unit is heading)."""
        return self._target

    def await_motion(self, start: tuple[int, int] | None = None) -> None:
        """``A``: block until the unit reports that every motion has finished.

        The reply may take as long as the motion, so the timeout is the estimated
        motion time (distance / speed from ``start``, by default where the last
        move started) plus ``await_margin``.  If ``A`` fails (a stalled axis never
        finishes, a lost reply), the axes are read back before the next move."""
        if start is None:
            start = self._move_start
        est = 0.0
        if start is not None:
            for i in range(2):
                speed = max(self._speed[i], 1)
                est = max(est, abs(self._target[i] - start[i]) / speed)
        try:
            self.command("A", timeout=self._motion_wait(est))
        except PTUError:
            self._unsure = [True, True]  # where did the motors stop? resync() finds out
            raise
        self._move_start = None

    def position(self) -> tuple[float, float]:
        """Current (pan, tilt) in degrees, queried (``PP``, ``TP``)."""
        p, t = self.position_counts()
        return self.to_degrees("P", p), self.to_degrees("T", t)

    def position_counts(self) -> tuple[int, int]:
        """(pan, tilt) in positions, queried; each within the unit's limits."""
        assert self.limits is not None
        return (self._query_within("PP", *self.limits.pan, "pan position"),
                self._query_within("TP", *self.limits.tilt, "tilt position"))

    def _speed_counts(self) -> tuple[int, int]:
        """(pan, tilt) speeds in positions/s, queried; each within [0, the unit's upper limit]."""
        assert self.limits is not None
        return (self._query_within("PS", 0, self.limits.pan_speed_max, "pan speed"),
                self._query_within("TS", 0, self.limits.tilt_speed_max, "tilt speed"))

    def _query_within(self, command: str, lo: int, hi: int, what: str) -> int:
        """``query_int``, refusing a number outside ``[lo, hi]`` (a garbled reply): what a
        unit cannot hold must not become a target or a wait."""
        value = self.query_int(command)
        if not lo <= value <= hi:
            raise PTUGarbageError(command, f"* {value}".encode(),
                                  f"{what} {value} is outside the unit's limits [{lo}, {hi}]")
        return value

    def _motion_wait(self, estimate_s: float) -> float:
        """Seconds to wait for ``A``: reply timeout + motion estimate + ``await_margin``,
        at most ``max_motion_s``."""
        return min(self.timeout + estimate_s + self.await_margin, self.max_motion_s)

    def set_speed(self, pan: float | None = None, tilt: float | None = None) -> None:
        """Set the speed (``PS`` / ``TS``) in degrees/s, checked against ``PU`` / ``TU``."""
        assert self.limits is not None
        speed = list(self._speed)
        for i, (axis, dps) in enumerate((("P", pan), ("T", tilt))):
            if dps is None:
                continue
            top = self.limits.pan_speed_max if axis == "P" else self.limits.tilt_speed_max
            pos = int(round(dps * 3600.0 / self._res(axis))) if math.isfinite(dps) else -1
            if not 1 <= pos <= top:
                raise PTULimitError(
                    f"{axis}S{pos}",
                    f"speed {dps!r} deg/s = {pos} positions/s is outside [1, {top}]",
                )
            self.command(f"{axis}S{pos}")
            speed[i] = pos
        self._speed = (speed[0], speed[1])

    def speed(self) -> tuple[float, float]:
        """Current speeds (pan, tilt) in degrees/s, queried (``PS``, ``TS``)."""
        p, t = self._speed = self._speed_counts()
        return self.to_degrees("P", p), self.to_degrees("T", t)

    def set_mode(self, mode: str) -> None:
        """``"immediate"`` (``I``) or ``"slaved"`` (``S``: moves start at the next ``A``)."""
        cmds = {"immediate": "I", "slaved": "S"}
        if mode not in cmds:
            raise ValueError(f"mode must be 'immediate' or 'slaved', not {mode!r}")
        self.command(cmds[mode])

    def reset(self, timeout: float | None = None) -> None:
        """``R``: recalibrate (the unit sweeps to its limits and back to 0, 0).

        Waits for the reset's final ``*`` (the ``!P`` / ``!T`` markers of the sweep
        on the way are expected) at most ``timeout`` seconds (default
        ``homing_timeout``); if it gives up, the next move first waits for the
        unit to finish (:meth:`resync`)."""
        self._expect_markers = True
        try:
            self._checked("R", "reset", self.homing_timeout if timeout is None else timeout)
        except PTUError:
            self._homing_pending = True
            self._unsure = [True, True]
            raise
        finally:
            self._expect_markers = False
        self._target = (0, 0)
        self._unsure = [False, False]


#: the class the registry (:mod:`..pan_tilt`) hands out for ``driver = "ptu-d46"``
DRIVER = PTU
