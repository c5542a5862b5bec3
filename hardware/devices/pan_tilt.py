"""The ``PanTilt`` interface every pan-tilt unit driver implements, and the driver registry.

:class:`..physical.hardware_rig.HardwareRig` talks to its pan-tilt units only through
this protocol, and builds them from the rig file's ``[[ptu]] driver`` key
through :func:`open_pan_tilt`.  The key is a *registered name*, never a
module path: a rig file cannot make the program import anything.  A driver
is registered

* as a module of :mod:`.pan_tilt_drivers` (the built-in drivers): the module
  ``my_unit.py`` there is the driver ``"my-unit"``, its ``DRIVER`` the class --
  one file, nothing else to edit;
* as an entry point of group :data:`ENTRY_POINT_GROUP` (``jaxrecog.pan_tilt``)
  in another package's ``pyproject.toml``::

      [project.entry-points."jaxrecog.pan_tilt"]
      my-unit = "my_package.my_module:MyUnit"

  (found through ``importlib.metadata``); or
* from code, with :func:`register_pan_tilt` (``register_pan_tilt("my-unit", MyUnit)``).

Listing the drivers imports nothing; a driver's module is imported only when
a rig file names it.  The built-in ``"ptu-d46"``
(:class:`.pan_tilt_drivers.ptu_d46.PTU`, the Directed Perception PTU-D46 of
thesis §6.4) is the default when the key is left out; built-in drivers are
found in their folder, so they work whatever the installed metadata says.  A
name that is not registered is refused before anything is imported.

A driver class may declare ``nominal_range_deg = ((pan_lo, pan_hi), (tilt_lo,
tilt_hi))``: the rig file's table is checked against it when it is loaded
(``[[ptu]] pan_range_deg`` / ``tilt_range_deg`` override it).

Errors: a driver raises :class:`PanTiltError` (or a subclass) for every
failure, and :class:`PanTiltConnectionError` when the device itself is gone
or unreachable (unplugged, port closed): the rig reconnects on the second and
fails the move on the first.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import pkgutil
from typing import TYPE_CHECKING, Protocol, runtime_checkable

from . import pan_tilt_drivers as builtin_drivers  # the package of the built-in drivers

if TYPE_CHECKING:
    from ..physical.config import PTUConfig

__all__ = [
    "PanTilt",
    "PanTiltError",
    "PanTiltConnectionError",
    "DEFAULT_PAN_TILT",
    "ENTRY_POINT_GROUP",
    "register_pan_tilt",
    "pan_tilt_driver",
    "pan_tilt_drivers",
    "open_pan_tilt",
]

DEFAULT_PAN_TILT = "ptu-d46"
ENTRY_POINT_GROUP = "jaxrecog.pan_tilt"

# registered from code (register_pan_tilt): name -> class, or "module:Class"
_DRIVERS: dict[str, type | str] = {}


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
    """Make ``driver`` (a class, or ``"module:Class"``) available as ``[[ptu]] driver = name``.

    For code that sets up a rig (tests, a notebook); an installed package
    registers its driver as an entry point instead (module doc)."""
    if not isinstance(name, str) or not name or ":" in name:
        raise ValueError(f"a pan-tilt driver name must be a non-empty string without ':', not {name!r}")
    _DRIVERS[name] = driver


def _builtin() -> dict[str, str]:
    """The built-in drivers: name -> ``"module:DRIVER"``, one per module of
    :mod:`.pan_tilt_drivers` (``ptu_d46.py`` is ``"ptu-d46"``; ``_*.py`` are helpers).
    Listing imports nothing."""
    return {m.name.replace("_", "-"): f"{builtin_drivers.__name__}.{m.name}:DRIVER"
            for m in pkgutil.iter_modules(builtin_drivers.__path__) if not m.name.startswith("_")}


def _entry_points() -> dict[str, importlib.metadata.EntryPoint]:
    """The drivers installed packages declare (group ``jaxrecog.pan_tilt``); listing imports nothing."""
    try:
        eps = importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)
    except Exception:  # noqa: BLE001 - broken metadata of some package must not break the rig
        return {}
    return {ep.name: ep for ep in eps}


def pan_tilt_drivers() -> tuple[str, ...]:
    """The registered driver names: built-in, registered from code, entry points."""
    return tuple(sorted({*_builtin(), *_DRIVERS, *_entry_points()}))


def pan_tilt_driver(name: str) -> type:
    """The driver class registered as ``name``.

    Raises:
        KeyError: ``name`` is not registered (nothing is imported; the message
            lists the known names and how to register one).
        ImportError: the registered driver cannot be imported, or is not a class.
    """
    if not isinstance(name, str):
        raise KeyError(f"a pan-tilt driver is named by a string, not {type(name).__name__}")
    builtin = _builtin()
    if name in builtin:
        entry: type | str | importlib.metadata.EntryPoint = builtin[name]
    elif name in _DRIVERS:
        entry = _DRIVERS[name]
    else:
        eps = _entry_points()
        if name not in eps:
            known = list(pan_tilt_drivers())
            how = (f"register it as an entry point in group {ENTRY_POINT_GROUP!r} "
                   f"([project.entry-points.\"{ENTRY_POINT_GROUP}\"] in its package's pyproject.toml)")
            if ":" in name:
                raise KeyError(f"unknown pan-tilt driver {name!r}: a rig file names a registered driver, "
                               f"not a module to import; {how}; known: {known}")
            raise KeyError(f"unknown pan-tilt driver {name!r}; known: {known}; a third-party driver: {how}")
        entry = eps[name]
    if isinstance(entry, type):
        return entry
    what = entry if isinstance(entry, str) else entry.value
    try:
        if isinstance(entry, str):
            module, _, attr = entry.partition(":")
            cls = getattr(importlib.import_module(module), attr)
        else:
            cls = entry.load()
    except Exception as e:  # noqa: BLE001 - a broken plugin is a clear error naming it
        raise ImportError(f"cannot import pan-tilt driver {name!r} ({what}): {type(e).__name__}: {e}") from e
    if not isinstance(cls, type):
        raise ImportError(f"pan-tilt driver {name!r} ({what}) is not a class")
    return cls


def open_pan_tilt(config: "PTUConfig", port: str | None = None) -> PanTilt:
    """Build the unit of one ``[[ptu]]`` entry with the driver its ``driver`` key names."""
    return pan_tilt_driver(config.driver).from_config(config, port)
