"""Device simulators: PTU-D46 units on pseudo-terminals (:mod:`.ptu_sim`) and the
motion controller on 127.0.0.1 (:mod:`.controller_sim`), for tests and for
``SimulatedHardwareRig``."""
