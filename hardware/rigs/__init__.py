"""The ``Rig`` interface the recognition core captures through (:mod:`.rig`: ``Rig``,
``Capture``, the pool interface), the rig pools (:mod:`.rig_pool`) and the rig that
replays an image database (:mod:`.dataset_rig`).

:mod:`.rig` is the one hardware module the core imports when it is itself
imported; this package imports nothing of its own on import.
"""
