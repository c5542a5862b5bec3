"""The synthetic scene moves to a fresh pybullet client every
``REBUILD_AFTER`` bodies (found by the env soak: pybullet keeps
every removed body's data, ~7 kB a reset with boards, so a long env run
grew without bound).  The images do not change across a rebuild, one client
is connected at a time, and memory stays flat."""

from __future__ import annotations

import numpy as np
from soak_env import make_rig, pybullet_clients, rss_mb

from jaxrecog.scene import occluder_factory
from jaxrecog.hardware.render import scene as scene_mod


def _capture(rig, obj, pose, layout, config=(1, 0)):
    rig.reset(obj, pose, layout)
    rig.reseed((0, 1, 2))
    rig.move(config)
    return rig.capture()


def test_a_rebuilt_scene_renders_the_same_images_on_one_client(monkeypatch):
    monkeypatch.setattr(scene_mod, "REBUILD_AFTER", 30)
    rebuilds = []
    real = scene_mod.Scene._rebuild
    monkeypatch.setattr(scene_mod.Scene, "_rebuild", lambda self: (rebuilds.append(1), real(self)))
    rng = np.random.default_rng(0)
    fresh, rig = make_rig(), make_rig()
    occ = occluder_factory(rig)
    try:
        base = pybullet_clients()
        for i in range(40):  # several rebuilds (each reset makes object bodies and 4 boards)
            layout = occ(rng, (1, 0)) if i % 3 else None
            a, b = _capture(rig, i % 3, i % 2, layout), _capture(fresh, i % 3, i % 2, layout)
            for x, y in zip(a.images, b.images):
                np.testing.assert_array_equal(x, y)
            np.testing.assert_allclose(a.occluded, b.occluded)
            assert pybullet_clients() == base
        assert len(rebuilds) > 3  # it did rebuild (pybullet reuses the client number)
        # boards placed before the object survive a rebuild at set_object
        rig.scene._bodies_made = 10**6
        layout = occ(rng, (1, 0))
        rig.scene.set_occluders(layout.boards, key=layout)
        n = len(rebuilds)
        a = _capture(rig, 2, 1, layout)
        assert len(rebuilds) == n + 1
        b = _capture(fresh, 2, 1, layout)
        np.testing.assert_array_equal(a.images[0], b.images[0])
    finally:
        fresh.close()
        rig.close()


def test_memory_stays_flat_over_many_resets_with_boards(monkeypatch):
    monkeypatch.setattr(scene_mod, "REBUILD_AFTER", 400)   # a rebuild every ~80 resets
    rig = make_rig()
    occ = occluder_factory(rig)
    rng = np.random.default_rng(1)
    try:
        for i in range(400):   # warm-up: past the first rebuilds
            rig.reset(i % 3, i % 2, occ(rng, (0, 0)))
        r0 = rss_mb()
        for i in range(1200):
            rig.reset(i % 3, i % 2, occ(rng, (0, 0)))
        grown = rss_mb() - r0
        assert grown < 3.0, f"{grown:.1f} MB in 1200 resets (~8 MB without the rebuilds)"
    finally:
        rig.close()
