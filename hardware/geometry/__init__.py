"""Rig geometry: the appendix-C kinematics and the pan-tilt angles of a line of
sight (:mod:`.kinematics`), the configuration table (:mod:`.positions`) and the
travel times between positions (:mod:`.motion`).  Pure arithmetic (NumPy), no
devices."""
