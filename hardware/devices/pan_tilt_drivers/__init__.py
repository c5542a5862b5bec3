"""The built-in pan-tilt drivers, one module per driver (:mod:`..pan_tilt`).

A module here *is* the registration: ``[[ptu]] driver = "ptu-d46"`` names the
module ``ptu_d46.py`` (``-`` for ``_``), whose ``DRIVER`` is the driver class
(a :class:`..pan_tilt.PanTilt`).  The registry lists this folder without
importing anything and imports a module only when a rig file names it; a
module whose name starts with ``_`` is a helper, not a driver.  So a new
pan-tilt protocol is one file here plus the ``driver`` key of the rig file.
"""
