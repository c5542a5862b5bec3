"""The ``PanTilt`` interface every pan-tilt unit driver implements, and the driver registry.

:class:`.hardware_rig.HardwareRig` talks to its pan-tilt units only through
this protocol, and builds them from the rig file's ``[[ptu]] driver`` key
through :func:`open_pan_tilt`.  A second driver is one new file with a class
that has these members, plus a config key:

* ``driver = "package.module:Class"`` names it directly (imported on use), or
* :func:`register_pan_tilt` gives it a short name (``driver = "my-unit"``).

The built-in driver is ``"ptu-d46"`` (:class:`.ptu.PTU`, the Directed
Perception PTU-D46 of thesis §6.4), the default when the key is left out.

Errors: a driver raises :class:`PanTiltError` (or a subclass) for every
failure, and :class:`PanTiltConnectionError` when the device itself is gone
or unreachable (unplugged, port closed): the rig reconnects on the second and
fails the move on the first.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Protocol, runtime_checkable

if TYPE_CHECKING:
    from .config import PTUConfig

__all__ = [
    "PanTilt",
    "PanTiltError",
    "PanTiltConnectionError",
    "DEFAULT_PAN_TILT",
    "register_pan_tilt",
    "pan_tilt_driver",
    "pan_tilt_drivers",
    "open_pan_tilt",
]

DEFAULT_PAN_TILT = "ptu-d46"

# name -> driver class, or "module:Class" imported on first use
_DRIVERS: dict[str, type | str] = {DEFAULT_PAN_TILT: "jaxrecog.hardware.ptu:PTU"}


class PanTiltError(RuntimeError):
    """A pan-tilt unit failed to do what was asked."""


class PanTiltConnectionError(PanTiltError):
    """The unit's device is gone or cannot be reached (open, read or write failed)."""


@runtime_checkable
class PanTilt(Protocol):
    """One pan-tilt unit; angles in degrees (the unit's own frame, see ``PTUConfig``)."""

    url: str  # the device it is connected to now

    @classmethod
    def from_config(cls, config: "PTUConfig", port: str | None = None) -> "PanTilt":
        """Open the unit a ``[[ptu]]`` entry describes (``port`` overrides ``config.port``)."""
        ...

    def move_to(self, pan: float | None = None, tilt: float | None = None, *, wait: bool = True) -> None:
        """Absolute move; with ``wait=False`` only start it (then :meth:`await_motion`)."""
        ...

    def await_motion(self) -> None:
        """Block, bounded in time, until the last started move has finished."""
        ...

    def position(self) -> tuple[float, float]:
        """(pan, tilt) in degrees, queried from the unit."""
        ...

    def set_speed(self, pan: float | None = None, tilt: float | None = None) -> None:
        """Axis speeds in degrees/s."""
        ...

    def reconnect(self, url: str | None = None) -> None:
        """Close, reopen (at ``url`` if given) and re-read the unit (resolution, limits, axes)."""
        ...

    def close(self) -> None: ...


def register_pan_tilt(name: str, driver: type | str) -> None:
    """Make ``driver`` (a class, or ``"module:Class"``) available as ``[[ptu]] driver = name``."""
    if not isinstance(name, str) or not name or ":" in name:
        raise ValueError(f"a pan-tilt driver name must be a non-empty string without ':', not {name!r}")
    _DRIVERS[name] = driver


def pan_tilt_drivers() -> tuple[str, ...]:
    """The registered driver names."""
    return tuple(sorted(_DRIVERS))


def pan_tilt_driver(name: str) -> type:
    """The driver class for ``name``: a registered name or ``"module:Class"``.

    Raises:
        KeyError: an unknown name (the message lists the known ones).
        ImportError: ``"module:Class"`` (or a registered string) cannot be imported.
    """
    entry = _DRIVERS.get(name, name if ":" in name else None)
    if entry is None:
        raise KeyError(f"unknown pan-tilt driver {name!r}; known: {list(pan_tilt_drivers())} or 'module:Class'")
    if isinstance(entry, type):
        return entry
    module, _, attr = entry.partition(":")
    try:
        cls = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError, ValueError) as e:
        raise ImportError(f"cannot import pan-tilt driver {entry!r}: {e}") from e
    if not isinstance(cls, type):
        raise ImportError(f"pan-tilt driver {entry!r} is not a class")
    return cls


def open_pan_tilt(config: "PTUConfig", port: str | None = None) -> PanTilt:
    """Build the unit of one ``[[ptu]]`` entry with the driver its ``driver`` key names."""
    return pan_tilt_driver(config.driver).from_config(config, port)
