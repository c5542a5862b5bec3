"""The divergence tables of the pairwise planners and the sample tables of the
Monte Carlo ones, built once per model in a process (jaxrecog.table_cache): a
hit for the same likelihoods by content (another load of the same file), a
miss for another divergence, key, J or model, the same values as a fresh
build, nothing cached under a trace."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxrecog import kernels as K
from jaxrecog import table_cache
from jaxrecog.modelfile import load_model, save_model
from jaxrecog.planners import make_planner


@pytest.fixture
def model_file(moving_model, tmp_path):
    table_cache.clear()
    yield save_model(tmp_path / "m.npz", moving_model[1])
    table_cache.clear()


def test_a_second_load_of_the_same_model_hits(model_file):
    first = make_planner("mi-class-pairwise", load_model(model_file), key=jax.random.PRNGKey(0))
    second = make_planner("mi-class-pairwise-stable", load_model(model_file), key=jax.random.PRNGKey(0))
    assert second.tables is first.tables
    fresh = K.pairwise_tables(load_model(model_file).likelihoods)
    for a, b in zip(jax.tree.leaves(first.tables), jax.tree.leaves(fresh)):
        np.testing.assert_array_equal(a, b)


def test_another_divergence_or_model_misses(model_file):
    model = load_model(model_file)
    bhat = table_cache.divergence_tables(model.likelihoods)
    kl = table_cache.divergence_tables(model.likelihoods, "kl")
    assert kl is not bhat and table_cache.divergence_tables(model.likelihoods) is bhat
    lik = model.likelihoods[0]
    moved = eqx.tree_at(lambda x: x.mu, lik, lik.mu + 1.0)  # another model: other contents, same shapes
    other = table_cache.divergence_tables((moved,) + tuple(model.likelihoods[1:]))
    assert other is not bhat
    # KEEP = 2: the least recently used (kl) went, bhattacharyya (used again above) stayed
    assert table_cache.divergence_tables(model.likelihoods) is bhat
    assert table_cache.divergence_tables(model.likelihoods, "kl") is not kl


def test_nothing_is_cached_under_a_trace(model_file):
    model = load_model(model_file)

    @jax.jit
    def first_entry(likelihoods):
        return table_cache.divergence_tables(likelihoods).log_w[0][0, 0, 0, 0, 0]

    value = first_entry(tuple(model.likelihoods))
    assert table_cache._cache == {}
    assert jnp.isfinite(value)

    @jax.jit
    def tables_inside(key):  # concrete likelihoods, a traced key: the tables come out traced
        return table_cache.sample_tables(model.likelihoods, key=key, samples_per_stratum=1, store="full").z[0]

    tables_inside(jax.random.PRNGKey(0))

    @jax.jit
    def concrete_inputs():  # every input concrete, the build inside a trace: its tracers are not kept
        return table_cache.sample_tables(model.likelihoods, key=jax.random.PRNGKey(1), samples_per_stratum=1,
                                         store="full").z[0]

    concrete_inputs()
    assert table_cache._samples == {}


def test_the_monte_carlo_planners_share_their_sample_tables(model_file):
    """``mi``, ``mi-class`` and ``crlb`` of one model and key: one build, the
    values of a fresh one; another key or J, or another load's other model,
    is a build of its own."""
    key = jax.random.PRNGKey(3)
    mi = make_planner("mi", load_model(model_file), key=key, samples=64)
    assert make_planner("mi-class", load_model(model_file), key=key, samples=64).tables is mi.tables
    crlb = make_planner("crlb", load_model(model_file), key=key, samples=64)
    for a, b in zip(jax.tree.leaves(crlb.tables), jax.tree.leaves(mi.tables)):
        assert a is b
    model = load_model(model_file)
    fresh = K.mi_tables(model.likelihoods, key=key, samples_per_stratum=mi.tables.ld_self[0].shape[-1], store="full")
    for a, b in zip(jax.tree.leaves(mi.tables), jax.tree.leaves(fresh)):
        np.testing.assert_array_equal(a, b)
    assert make_planner("mi", model, key=jax.random.PRNGKey(4), samples=64).tables is not mi.tables
    assert make_planner("mi", model, key=key, samples=4096).tables is not mi.tables
    # a typed key keys the cache by its implementation and bits
    typed = table_cache.sample_tables(model.likelihoods, key=jax.random.key(3), samples_per_stratum=2, store="full")
    assert table_cache.sample_tables(model.likelihoods, key=jax.random.key(3), samples_per_stratum=2,
                                     store="full") is typed
    rbg = jax.random.key(3, impl="rbg")
    assert table_cache.sample_tables(model.likelihoods, key=rbg, samples_per_stratum=2, store="full") is not typed
