"""Synthetic images: the pybullet scene (:mod:`.scene`), the rendered rig
(:mod:`.synthetic`), occluder boards (:mod:`.occluders`), random objects
(:mod:`.random_objects`) and the image databases rendered from them
(:mod:`.render_db`, :mod:`.turntable`).  pybullet is imported when a scene is
built, not when a module is imported."""
