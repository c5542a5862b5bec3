"""The PTU-D46's ASCII command protocol (thesis §6.4): replies, their strict parser and the errors.

The unit speaks an ASCII command protocol: a command is a few letters, an
optional signed integer argument, and a delimiter (space, CR or LF).  With
echo off (``ED``) and terse feedback (``FT``) every command is answered by one
line ending in CR LF:

* ``*``               -- an action succeeded (``PP1000``, ``A``, ``I``, ...)
* ``* <number>``      -- the answer to a query (``PP`` -> ``* 1000``,
  ``PR`` -> ``* 185.1428``)
* ``! <message>``     -- an error (``! Maximum allowable Pan position is 3090``)

Commands the driver (:mod:`.ptu`) uses (pan ``P`` / tilt ``T``):

=========  ==============================================================
``PP n``   absolute position (positions); ``PP`` alone queries it
``PO n``   offset from the current target
``PS n``   speed in positions/s; ``PS`` alone queries it
``PR``     resolution query, arc-seconds per position (185.1428 on -17.5)
``PN PX``  minimum / maximum position query (``TN TX`` for tilt)
``PU``     upper speed limit query (positions/s)
``A``      await: answers once every commanded motion has finished
``I S``    immediate / slaved execution of position commands
``FT ED``  terse feedback / echo off (sent on connect)
``R``      reset (re-calibrates; answers ``!T!T!P!P*`` or similar, then ``*``)
=========  ==============================================================

A unit that reaches a limit switch sends ``!P`` or ``!T`` (two bytes, no
line end) at once, whatever is on the line: :func:`limit_markers` finds and
removes them before a reply is parsed.

Every failure is a :class:`PTUError` naming the command: a missing reply is a
:class:`PTUTimeoutError`, a ``!`` reply is a :class:`PTUErrorReply`, anything
else (noise, malformed numbers, non-ASCII bytes) is a :class:`PTUGarbageError`
(:func:`parse_reply` raises the last two).
"""

from __future__ import annotations

import dataclasses
import re

from .pan_tilt import PanTiltConnectionError, PanTiltError

__all__ = [
    "PTUError",
    "PTUTimeoutError",
    "PTUErrorReply",
    "PTUGarbageError",
    "PTULimitError",
    "PTUConnectionError",
    "PTUHomingTimeout",
    "PTULimits",
    "parse_reply",
    "limit_markers",
    "ARCSEC_PER_POSITION_D46_17_5",
]

#: Nominal resolution of the PTU-D46-17.5 (thesis §6.4: 3.086 arc-minutes); the
#: driver always queries the unit instead of trusting this number.
ARCSEC_PER_POSITION_D46_17_5 = 185.1428


class PTUError(PanTiltError):
    """Base class of every PTU failure; ``command`` is the command that failed."""

    def __init__(self, command: str, message: str):
        self.command = command
        super().__init__(f"PTU command {command!r}: {message}")


class PTUTimeoutError(PTUError):
    """No complete reply line arrived within the timeout."""


class PTUErrorReply(PTUError):
    """The unit answered ``!`` (it refused or failed the command)."""

    def __init__(self, command: str, reply: str):
        self.reply = reply
        super().__init__(command, f"unit reported an error: {reply!r}")


class PTUGarbageError(PTUError):
    """The reply was neither a valid ``*`` answer nor a ``!`` error."""

    def __init__(self, command: str, reply: bytes, why: str):
        self.reply = reply
        super().__init__(command, f"{why}; got {reply[:80]!r}")


class PTULimitError(PTUError, ValueError):
    """A requested position or speed lies outside the unit's limits (checked before sending)."""


class PTUConnectionError(PTUError, PanTiltConnectionError):
    """The serial port could not be opened, read or written."""


class PTUHomingTimeout(PTUTimeoutError):
    """The unit was still busy (homing after a reset or power-up) when the wait ran out."""


_NUMBER = {
    "int": re.compile(rb"\*[ \t]*([+-]?[0-9]{1,12})"),
    "float": re.compile(rb"\*[ \t]*([+-]?[0-9]{1,12}(?:\.[0-9]{1,12})?)"),
}
_ERROR_LINE = re.compile(rb"![ \t]*[\x20-\x7e]*")
_RESET_LINE = re.compile(rb"(?:![PT])*\*")
_LIMIT_MARKER = re.compile(rb"!([PT])")  # asynchronous limit message; never followed by the space of an error


def limit_markers(line: bytes) -> tuple[list[str], bytes]:
    """The axes (``"P"``, ``"T"``) of the asynchronous limit messages in ``line``, and
    ``line`` without them."""
    return [a.decode("ascii") for a in _LIMIT_MARKER.findall(line)], _LIMIT_MARKER.sub(b"", line)


def parse_reply(command: str, line: bytes, expect: str) -> int | float | None:
    """Parse one reply line (terse feedback, echo off) strictly.

    Args:
        command: the command sent (for error messages).
        line: the reply, with or without its trailing CR LF.
        expect: ``"ack"`` (exactly ``*``), ``"int"`` / ``"float"`` (``* <number>``)
            or ``"reset"`` (``!T``/``!P`` limit markers, then ``*``).

    Returns:
        ``None`` for ``ack`` and ``reset``, the number otherwise.

    Raises:
        PTUErrorReply: the line is a well-formed ``!`` error.
        PTUGarbageError: anything else that is not the expected answer.
    """
    if expect not in ("ack", "int", "float", "reset"):
        raise ValueError(f"expect must be 'ack', 'int', 'float' or 'reset', not {expect!r}")
    body = line[:-2] if line.endswith(b"\r\n") else line.rstrip(b"\r\n")
    body = body.rstrip(b" ")
    if expect == "reset":
        if _RESET_LINE.fullmatch(body):
            return None
    if body.startswith(b"!"):
        if _ERROR_LINE.fullmatch(body):
            raise PTUErrorReply(command, body.decode("ascii"))
        raise PTUGarbageError(command, line, "malformed error reply (non-printable bytes)")
    if expect == "ack":
        if body == b"*":
            return None
        raise PTUGarbageError(command, line, "expected '*'")
    if expect == "reset":
        raise PTUGarbageError(command, line, "expected '!T'/'!P' markers and '*'")
    m = _NUMBER[expect].fullmatch(body)
    if m is None:
        raise PTUGarbageError(command, line, f"expected '* <{expect}>'")
    value = int(m.group(1)) if expect == "int" else float(m.group(1))
    return value


@dataclasses.dataclass(frozen=True)
class PTULimits:
    """Limits queried from the unit, in positions (speeds in positions/s)."""

    pan: tuple[int, int]
    tilt: tuple[int, int]
    pan_speed_max: int
    tilt_speed_max: int
