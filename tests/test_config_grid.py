"""The configuration grid (kernels/config_grid.py) against plain NumPy references:
np.ravel_multi_index / np.unravel_index for the flat index, and explicit loops
over every configuration for the broadcast helpers."""

from __future__ import annotations

import itertools
import operator

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxrecog.kernels.config_grid import ConfigGrid, position_rows

GRIDS = [(32, 7), (5,), (3, 2, 4)]


@pytest.mark.parametrize("positions", GRIDS)
def test_flat_index_and_configuration_agree_with_numpy(positions):
    grid = ConfigGrid(positions)
    assert grid.size == int(np.prod(positions)) and grid.n_cameras == len(positions)
    for a in range(grid.size):
        cfg = grid.configuration(a)
        assert cfg == tuple(int(v) for v in np.unravel_index(a, positions))
        assert all(type(v) is int for v in cfg)
        assert grid.index(cfg) == a == np.ravel_multi_index(cfg, positions)
        assert type(grid.index(tuple(np.int64(v) for v in cfg))) is int
        assert grid.configuration(np.int64(a)) == cfg
    want = np.stack(np.unravel_index(np.arange(grid.size), positions), axis=1)
    np.testing.assert_array_equal(grid.configurations(), want)
    # NumPy arrays: elementwise, no check
    np.testing.assert_array_equal(np.stack(grid.configuration(np.arange(grid.size)), axis=1), want)
    np.testing.assert_array_equal(grid.index(tuple(want.T)), np.arange(grid.size))


@pytest.mark.parametrize("positions", GRIDS)
def test_traced_values_under_jit_and_vmap(positions):
    grid = ConfigGrid(positions)
    to_cfg = jax.jit(lambda a: jnp.stack(grid.configuration(a)))
    to_idx = jax.jit(lambda c: grid.index(c))
    cfgs = jax.vmap(to_cfg)(jnp.arange(grid.size, dtype=jnp.int32))
    assert cfgs.dtype == jnp.int32
    np.testing.assert_array_equal(cfgs, np.stack(np.unravel_index(np.arange(grid.size), positions), axis=1))
    idx = jax.vmap(to_idx)(cfgs)
    assert idx.dtype == jnp.int32
    np.testing.assert_array_equal(idx, np.arange(grid.size))
    # clip: jnp.ravel_multi_index(mode="clip") for positions out of range
    rng = np.random.default_rng(0)
    wild = jnp.asarray(rng.integers(-3, max(positions) + 3, size=(50, len(positions))), jnp.int32)
    clipped = jax.vmap(jax.jit(lambda c: grid.index(c, clip=True)))(wild)
    want = jax.vmap(lambda c: jnp.ravel_multi_index(tuple(c), positions, mode="clip"))(wild)
    assert clipped.dtype == want.dtype
    np.testing.assert_array_equal(clipped, want)


def test_concrete_values_are_range_checked():
    grid = ConfigGrid((32, 7))
    with pytest.raises(ValueError, match="outside 0..223"):
        grid.configuration(224)
    with pytest.raises(ValueError, match="outside 0..223"):
        grid.configuration(-1)
    with pytest.raises(ValueError, match=r"\(3, 7\) does not fit the positions \(32, 7\)"):
        grid.index((3, 7))
    with pytest.raises(ValueError, match="does not fit"):
        grid.index((1,))
    with pytest.raises(ValueError, match="one size >= 1"):
        ConfigGrid(())
    with pytest.raises(ValueError, match="one size >= 1"):
        ConfigGrid((3, 0))


def test_a_grid_is_a_hashable_static_value():
    g = ConfigGrid([np.int64(32), 7])
    assert g.positions == (32, 7) and all(type(n) is int for n in g.positions)
    assert g == ConfigGrid((32, 7)) and hash(g) == hash(ConfigGrid((32, 7))) and g != ConfigGrid((7, 32))
    assert repr(g) == "ConfigGrid((32, 7))"
    with pytest.raises(AttributeError):
        g.positions = (1,)
    # a static argument of jit: one compilation per grid
    f = jax.jit(lambda grid, a: jnp.stack(grid.configuration(a)), static_argnums=0)
    np.testing.assert_array_equal(f(g, 7 * 5 + 3), [5, 3])


@pytest.mark.parametrize("positions", GRIDS)
def test_combine_expand_flatten_against_loops_over_configurations(positions):
    grid = ConfigGrid(positions)
    rng = np.random.default_rng(1)
    values = [rng.normal(size=(2, v)).astype(np.float32) for v in positions]  # [lead, V_i]
    got = grid.combine(np.maximum, values, np.zeros(positions, np.float32))
    want = np.zeros((2, grid.size), np.float32)
    for a, cfg in enumerate(itertools.product(*(range(v) for v in positions))):
        want[:, a] = np.maximum(0, np.max([values[i][:, v] for i, v in enumerate(cfg)], axis=0))
    np.testing.assert_array_equal(got, want)
    # traced booleans with operator.or_, as the recognizer's position exclusion
    seen = [jnp.asarray(rng.random(v) < 0.4) for v in positions]
    got = jax.jit(lambda s: grid.combine(operator.or_, s, jnp.zeros(positions, bool)))(seen)
    want = [any(bool(seen[i][v]) for i, v in enumerate(cfg)) for cfg in itertools.product(*(range(v) for v in positions))]
    np.testing.assert_array_equal(got, want)
    # expand: the axis lands at grid slot i, other axes kept in place
    x = np.arange(3 * positions[-1] * 2).reshape(3, positions[-1], 2)
    e = grid.expand(x, grid.n_cameras - 1, axis=1)
    assert e.shape == (3,) + (1,) * (grid.n_cameras - 1) + (positions[-1], 2)
    np.testing.assert_array_equal(e.reshape(x.shape), x)
    # flatten / unflatten: row-major, camera 0 slowest
    y = rng.normal(size=(4,) + positions)
    flat = grid.flatten(y)
    for a, cfg in enumerate(itertools.product(*(range(v) for v in positions))):
        np.testing.assert_array_equal(flat[:, a], y[(slice(None),) + cfg])
    np.testing.assert_array_equal(grid.unflatten(flat), y)


def test_helpers_refuse_arrays_that_do_not_fit_the_grid():
    grid = ConfigGrid((4, 3))
    with pytest.raises(ValueError, match="1 per-camera arrays for a grid of 2"):
        grid.combine(np.maximum, [np.zeros(4)], np.zeros((4, 3)))
    with pytest.raises(ValueError, match="camera 1's array has 4 positions"):
        grid.combine(np.maximum, [np.zeros(4), np.zeros(4)], np.zeros((4, 3)))
    with pytest.raises(ValueError, match="does not end in the grid"):
        grid.flatten(np.zeros((3, 4)))
    with pytest.raises(ValueError, match="no trailing axis of A = 12"):
        grid.unflatten(np.zeros(11))
    with pytest.raises(ValueError, match="camera 2 is not one"):
        grid.expand(np.zeros(3), 2)


@pytest.mark.parametrize("front", [(1,), (1, 3), (3, 1), (1, 4)])
def test_position_rows_against_a_loop(front):
    rng = np.random.default_rng(2)
    t = rng.normal(size=(4, 3, 2, 5, 6)).astype(np.float32)  # [V, C, L, J, K]
    got = np.asarray(position_rows(jnp.asarray(t), front))
    rest = [a for a in range(3, 5) if a not in front]
    assert got.shape == tuple(t.shape[a] for a in front) + (4 * 2,) + tuple(t.shape[a] for a in rest)
    for v, k in itertools.product(range(4), range(2)):
        x = v * 2 + k  # row of the (V, L) grid
        assert ConfigGrid((4, 2)).index((v, k)) == x
        want = np.moveaxis(t[v, :, k], [a - 1 - (a > 2) for a in front], list(range(len(front))))
        np.testing.assert_array_equal(np.take(got, x, axis=len(front)), want)
    with pytest.raises(ValueError, match="leave axes 0 and 2"):
        position_rows(jnp.asarray(t), (0,))
