"""The physical rig behind the ``Rig`` interface: its rig file (:mod:`.config`) and
``HardwareRig`` / ``SimulatedHardwareRig`` (:mod:`.hardware_rig`), which assemble
the devices (:mod:`..devices`), or the device simulators (:mod:`..sim`) and a
renderer, into a rig."""
