"""The pairwise MI over the belief's live classes (kernels/pruned_mi.py): the
brute-force oracle on the live classes, the bound on what the pruned mass
changes against the unpruned kernel, and the planner built on it."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from builders import random_sensor_model
from compiles import count_compiles
from kernel_models import as_jax, gaussians, random_belief, random_chols, random_model
from oracles import pruned_pairwise_mi_ref
from test_view_stability import _mixture_model

from jaxrecog import kernels as K
from jaxrecog.kernels import pruned_mi
from jaxrecog.planners import StableViewMIPlanner, make_planner
from jaxrecog.pruned_planner import PRUNE_MIN_CLASSES, PrunedStableViewMIPlanner

LEVELS, POSITIONS, DIMS = (2, 3), (3, 2), (2, 2)


def _covs(vars):
    return tuple(np.einsum("...k,kl->...kl", v, np.eye(v.shape[-1])) for v in vars)


def _belief(rng, n_c, top, rest_mass, levels=LEVELS, positions=POSITIONS):
    """A predicted prior with ``1 - rest_mass`` on ``top`` random classes
    (Dirichlet) and ``rest_mass`` spread (Dirichlet) over the others; random
    level rows per position."""
    order = rng.permutation(n_c)
    p = np.zeros(n_c)
    p[order[:top]] = (1.0 - rest_mass) * rng.dirichlet(np.ones(top))
    p[order[top:]] = rest_mass * rng.dirichlet(np.ones(n_c - top))
    rows = [np.stack([random_belief(rng, n_c, levels).log_pk[i] for _ in range(v)]) for i, v in enumerate(positions)]
    return K.PredictedBelief(jnp.asarray(np.log(p)), as_jax(rows)), rows


@pytest.mark.parametrize("target", ["class", "state"])
def test_live_classes_match_brute_force(rng, x64, target):
    """The kernel's value is the brute-force pairwise MI of the live classes
    under the renormalised belief, the bucket the smallest that holds 1 - mass."""
    n_c = 6
    mus, vars = random_model(rng, n_c, LEVELS, POSITIONS, DIMS, spread=1.5)
    tables = K.pruned_tables(gaussians(mus, vars), uniform=False)
    fn = jax.jit(K.pruned_pairwise_mutual_information, static_argnames=("kind", "target", "mass", "buckets"))
    for top, rest, want_b in ((2, 1e-4, 2), (3, 0.02, 4), (5, 1e-3, 4)):
        b, rows = _belief(rng, n_c, top, rest)
        got = np.asarray(fn(tables, b, target=target, mass=1e-2, buckets=(2, 4)))
        ref, live = pruned_pairwise_mi_ref(mus, _covs(vars), np.asarray(b.log_pc), rows, (2, 4), 1e-2, target=target)
        assert live == want_b == pruned_mi.live_count(b.log_pc, 1e-2, (2, 4))
        np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-11)


_FULL = jax.jit(K.pairwise_mutual_information, static_argnames=("target",))
_PRUNED = jax.jit(K.pruned_pairwise_mutual_information, static_argnames=("kind", "target", "mass", "buckets"))


@pytest.mark.parametrize("kind", ["bhattacharyya", "kl"])
def test_pruned_mass_changes_the_score_within_the_bound(rng, x64, kind):
    """Against the unpruned kernel on random beliefs (concentrated and spread:
    pruned masses from 1e-3 to ~0.3), both targets: |difference| <=
    pruning_bound; and on a model whose pruned classes copy the live ones'
    components (the bound's worst case: pruned mass on top of live states)
    the difference is a good part of the bound, so it is not loose by orders
    of magnitude there."""
    n_c, mass, buckets = 8, 0.05, (2, 4)
    mus, vars = random_model(rng, n_c, LEVELS, POSITIONS, DIMS, spread=2.0)
    copies = (tuple(m.copy() for m in mus), tuple(v.copy() for v in vars))
    for m, v in zip(*copies):
        m[:, 4:], v[:, 4:] = m[:, :4], v[:, :4]
    n_l = int(np.prod(LEVELS))
    worst = 0.0
    for copied, (model_mus, model_vars) in ((False, (mus, vars)), (True, copies)):
        liks = gaussians(model_mus, model_vars)
        full, pruned = K.pairwise_tables(liks, kind=kind), K.pruned_tables(liks, kind=kind, uniform=False)
        for top, rest in ((2, 1e-3), (2, 0.3), (4, 0.01), (4, 0.3)):
            b, _ = _belief(rng, n_c, top, rest)
            if copied:  # the live classes are 0..3, their copies 4..7
                p = np.zeros(n_c)
                p[:4], p[4:] = (1 - rest) * rng.dirichlet(np.ones(4)), rest * rng.dirichlet(np.ones(4))
                b = b._replace(log_pc=jnp.asarray(np.log(p)))
            live = pruned_mi.live_count(b.log_pc, mass, buckets)
            for target in ("class", "state"):
                want = np.asarray(_FULL(full, b, target))
                got = np.asarray(_PRUNED(pruned, b, kind=kind, target=target, mass=mass, buckets=buckets))
                bound = K.pruning_bound(np.asarray(b.log_pc), live, n_l, target)
                diff = np.max(np.abs(got - want))
                assert diff <= bound + 1e-9, (top, rest, target, diff, bound)
                if copied:
                    worst = max(worst, diff / bound)
    assert worst > 0.05


def test_every_class_live_equals_the_unpruned_kernel(rng, x64):
    """mass 0 with C within the buckets, and the first step's uniform belief
    (read from the belief-free table): the unpruned kernel's values to rounding."""
    n_c = 5
    mus, vars = random_model(rng, n_c, LEVELS, POSITIONS, DIMS, spread=1.5)
    liks = gaussians(mus, vars)
    full, pruned = K.pairwise_tables(liks), K.pruned_tables(liks)
    b, _ = _belief(rng, n_c, 3, 0.2)
    first = K.transition_per_position(K.uniform_belief(n_c, LEVELS), (0, 0), POSITIONS)
    for belief in (b, first):
        for target in ("class", "state"):
            np.testing.assert_allclose(np.asarray(_PRUNED(pruned, belief, target=target, mass=0.0, buckets=(2, 8))),
                                       np.asarray(_FULL(full, belief, target)), rtol=1e-10, atol=1e-12)


def test_camera_divergence_equals_the_per_position_closed_forms(rng, x64):
    """The diagonal family's all-positions evaluation and the base class's
    default (the full Gaussian) against ``divergence`` position by position."""
    mus, vars = random_model(rng, 4, LEVELS, POSITIONS, DIMS, spread=1.5)
    chols = random_chols(rng, 4, LEVELS, POSITIONS, DIMS)
    for liks in (gaussians(mus, vars), gaussians(mus, chols=chols)):
        for lik in liks:
            for kind in ("bhattacharyya", "kl"):
                want = np.stack([np.asarray(lik.at(v).divergence(kind)) for v in range(lik.n_positions)])
                np.testing.assert_allclose(np.asarray(lik.camera_divergence(kind)), want, rtol=1e-10, atol=1e-12)
    with pytest.raises(ValueError, match="kind must be"):
        gaussians(mus, vars)[0].camera_divergence("hellinger")


def test_take_classes_gathers_every_class_axis():
    """A view mixture (fields with and without a class axis, derived arrays)
    restricted to two classes holds those classes' arrays in that order."""
    lik = _mixture_model().cameras[0].likelihood
    idx = jnp.asarray([3, 1])
    sub = pruned_mi.take_classes(lik, idx)
    assert sub.n_classes == 2
    for f, spec in {**lik.field_shapes, **lik.derived_shapes}.items():
        axis = spec.split().index("C")
        np.testing.assert_array_equal(np.asarray(getattr(sub, f)), np.take(np.asarray(getattr(lik, f)), [3, 1], axis))


def test_default_planner_prunes_from_many_classes_only():
    """``prune="auto"``: the table planner below PRUNE_MIN_CLASSES classes (its
    scores bit for bit those of StableViewMIPlanner.from_model), the pruned one
    from there; option ``prune`` forces either; bad values are one clear error."""
    small = random_sensor_model((4, 3), n_objects=3, n_poses=2)
    key = jax.random.PRNGKey(0)
    auto = make_planner("mi-class-pairwise-stable", small, key=key)
    assert type(auto) is StableViewMIPlanner
    prior = K.transition_per_position(K.uniform_belief(6, (2, 2))._replace(
        log_pc=jnp.log(jnp.asarray([0.5, 0.2, 0.1, 0.1, 0.05, 0.05], jnp.float32))), (1, 2), (4, 3))
    direct = StableViewMIPlanner.from_model(small)
    assert np.array_equal(np.asarray(auto.scores(prior, key)), np.asarray(direct.scores(prior, key)))
    assert isinstance(make_planner("mi-class-pairwise-stable", small, key=key, prune=True), PrunedStableViewMIPlanner)
    assert type(make_planner("mi-class-pairwise-stable", small, key=key, prune=False)) is StableViewMIPlanner
    big = random_sensor_model((2, 2), n_objects=PRUNE_MIN_CLASSES // 4, n_poses=4, k=2, hw=(2, 2))
    assert isinstance(make_planner("mi-class-pairwise-stable", big, key=key, uniform_table=False),
                      PrunedStableViewMIPlanner)
    for bad in ("yes", 1.5, -0.1):
        with pytest.raises(ValueError, match="prune must be"):
            make_planner("mi-class-pairwise-stable", small, key=key, prune=bad)


def test_pruned_planner_scores_live_mi_minus_the_exact_instability():
    """The pruned stable planner on a view mixture: the pruned MI under the
    belief minus the stability weight times the instability under the *whole*
    belief; beliefs of different buckets and the uniform one run in one
    compiled program (no recompiles after the first call)."""
    model = _mixture_model()
    key = jax.random.PRNGKey(0)
    planner = make_planner("mi-class-pairwise-stable", model, key=key, prune=1e-3, stability=0.7, buckets=(2, 4))
    n_c = model.likelihoods[0].n_classes
    score = jax.jit(lambda p, b: p.scores(b, key))
    rng = np.random.default_rng(0)
    beliefs = [K.transition_per_position(K.uniform_belief(n_c, (2, 2)), (0, 0), model.positions)]
    for sharp in (True, False):
        b = random_belief(rng, n_c, (2, 2))
        log_pc = np.log(np.asarray([0.9, 0.0996] + [0.0001] * (n_c - 2))) if sharp else b.log_pc
        beliefs.append(K.transition_per_position(K.Belief(jnp.asarray(log_pc, jnp.float32),
                                                          as_jax(b.log_pk, jnp.float32)), (1, 2), model.positions))
    jax.block_until_ready(score(planner, beliefs[0]))
    with count_compiles() as later:
        scores = [np.asarray(score(planner, b)) for b in beliefs]
    assert sum(later.values()) == 0, dict(later)
    assert {pruned_mi.live_count(b.log_pc, 1e-3, (2, 4)) for b in beliefs[1:]} == {2, 4}  # more than one bucket ran
    for b, got in zip(beliefs, scores):
        mi = K.pruned_pairwise_mutual_information(planner.tables, b, mass=1e-3, buckets=(2, 4))
        inst = K.view_stability.expected_instability(planner.instability, b.log_pc)
        np.testing.assert_allclose(got, np.asarray(mi - 0.7 * inst), rtol=1e-5, atol=1e-6)
        assert np.all(np.isfinite(got)) and np.any(np.asarray(inst) > 0)


def test_memory_is_linear_in_the_classes():
    """Without the first step's table the pruned planner holds no array with a
    C x C part: every leaf is the model's or [V, C] (instabilities)."""
    model = random_sensor_model((3, 2), n_objects=16, n_poses=4, k=2)
    planner = make_planner("mi-class-pairwise-stable", model, key=jax.random.PRNGKey(0), prune=True,
                           uniform_table=False)
    n_c = 64
    for leaf in jax.tree.leaves(planner):
        assert np.size(leaf) < n_c * n_c, np.shape(leaf)


def test_bad_input_is_one_clear_error(rng):
    mus, vars = random_model(rng, 4, LEVELS, POSITIONS, DIMS)
    tables = K.pruned_tables(gaussians(mus, vars))
    b, _ = _belief(rng, 4, 2, 0.01)
    with pytest.raises(ValueError, match="mass"):
        K.pruned_pairwise_mutual_information(tables, b, mass=1.0)
    with pytest.raises(ValueError, match="kind must be"):
        K.pruned_tables(gaussians(mus, vars), kind="hellinger")
    with pytest.raises(ValueError, match="belief.log_pc has shape"):
        K.pruned_pairwise_mutual_information(tables, b._replace(log_pc=b.log_pc[:3]))
    with pytest.raises(ValueError, match="NaN"):
        K.pruned_pairwise_mutual_information(tables, b._replace(log_pc=b.log_pc.at[0].set(jnp.nan)))
    with pytest.raises(ValueError, match="n_live"):
        K.pruning_bound(np.asarray(b.log_pc), 0, 6)
