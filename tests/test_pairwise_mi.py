"""Pairwise-distance MI kernel (Kolchinsky & Tracey 2017): divergence tables
against NumPy closed forms, the kernel against brute-force enumeration of all
state pairs, the bounds around the Monte Carlo MI, the exact limits, bad input
and compiles."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from compiles import count_compiles
from kernel_models import as_jax, as_jax_belief, everywhere, gaussians, jitted, random_belief, random_chols, random_model
from oracles import bhattacharyya_ref, kl_ref, pairwise_mi_ref

from jaxrecog import kernels as K
from jaxrecog.kernels import pairwise_mi

pytestmark = pytest.mark.usefixtures("strict_dtype_promotion")  # numerics: no implicit promotion

MI_TABLES, MI, _ = jitted()
PT = jax.jit(K.pairwise_tables, static_argnames=("kind",))
PMI = jax.jit(K.pairwise_mutual_information, static_argnames=("target", "levels", "fast"))


def _covs(vars=None, chols=None):
    if chols is not None:
        return tuple(c @ np.swapaxes(c, -1, -2) for c in chols)
    return tuple(v[..., None] * np.eye(v.shape[-1]) for v in vars)


class _NoClosedForm(K.DiagonalGaussian):
    """A diagonal Gaussian that pretends to have no closed-form divergences
    (not registered): ``divergence`` must fall back to the moment-matched Gaussian."""

    def bhattacharyya(self):
        raise NotImplementedError

    def kl(self):
        raise NotImplementedError


@pytest.mark.parametrize("family", ["diag", "full"])
def test_divergence_tables_against_numpy_closed_forms(rng, x64, family):
    mus, vars = random_model(rng, 3, (2,), (2,), (3,))
    chols = random_chols(rng, 3, (2,), (2,), (3,), scale=1.0) if family == "full" else None
    lik = K.gaussian(jnp.asarray(mus[0]), jnp.asarray(vars[0])) if chols is None else K.gaussian(
        jnp.asarray(mus[0]), chol=jnp.asarray(chols[0]))
    cov = _covs(vars, chols)[0]
    for v in range(2):
        kl = np.asarray(lik.at(v).kl())
        np.testing.assert_allclose(kl, kl_ref(mus[0][v], cov[v]), rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(np.asarray(lik.at(v).divergence("kl")), kl, rtol=0, atol=0)
        np.testing.assert_allclose(np.asarray(lik.at(v).divergence("bhattacharyya")),
                                   bhattacharyya_ref(mus[0][v], cov[v]), rtol=1e-10, atol=1e-12)
        assert np.all(kl >= -1e-12) and np.allclose(np.einsum("ckck->ck", kl), 0.0, atol=1e-12)
    # the tables are -D, per position
    for kind, ref in (("bhattacharyya", bhattacharyya_ref), ("kl", kl_ref)):
        t = K.pairwise_tables((lik,), kind=kind)
        want = np.stack([ref(mus[0][v], cov[v]) for v in range(2)])
        np.testing.assert_allclose(-np.asarray(t.log_w[0]), want, rtol=1e-10, atol=1e-12)


def test_kl_matches_monte_carlo_of_the_log_ratio(rng, x64):
    """The KL closed form is E_p[log p - log q], estimated from samples of p."""
    lik = K.DiagonalGaussian(jnp.asarray(rng.normal(size=(2, 1, 2))), jnp.asarray(rng.uniform(0.3, 1.2, size=(2, 1, 2))))
    z = jnp.asarray(rng.normal(size=(2, 1, 200_000, 2)))
    g = lik.sample(z)  # [C, L, N, K]
    ld = lik.log_density(g)  # [C, L, N, C', L']
    mc = np.asarray(jnp.mean(ld[0, 0, :, 0, 0] - ld[0, 0, :, 1, 0]))
    np.testing.assert_allclose(mc, float(lik.kl()[0, 0, 1, 0]), rtol=2e-2)


def test_moment_matched_fallback_without_closed_forms(rng, x64):
    """A family without closed forms gets the divergence of its moment-matched
    Gaussians: exact here (the family is Gaussian), so equal to the closed form."""
    mus, vars = random_model(rng, 3, (2,), (1,), (3,))
    exact = K.DiagonalGaussian(jnp.asarray(mus[0][0]), jnp.asarray(vars[0][0]))
    approx = _NoClosedForm(jnp.asarray(mus[0][0]), jnp.asarray(vars[0][0]))
    with pytest.raises(NotImplementedError):
        approx.kl()
    for kind in K.DIVERGENCES:
        np.testing.assert_allclose(np.asarray(approx.divergence(kind)), np.asarray(exact.divergence(kind)),
                                   rtol=1e-10, atol=1e-12)
    with pytest.raises(ValueError, match="bhattacharyya"):
        exact.divergence("hellinger")


@pytest.mark.parametrize(
    "levels,positions,dims",
    [((2,), (3,), (2,)), ((2, 3), (3, 2), (3, 2)), ((2, 1, 2), (2, 2, 2), (1, 2, 1))],
)
@pytest.mark.parametrize("target", ["state", "class"])
@pytest.mark.parametrize("kind", ["bhattacharyya", "kl"])
def test_matches_brute_force_reference(rng, x64, levels, positions, dims, target, kind):
    mus, vars = random_model(rng, 3, levels, positions, dims, spread=1.5)
    b = random_belief(rng, 3, levels)
    # per-position level rows, as the planner's predicted prior has
    rows = [np.stack([random_belief(rng, 3, levels).log_pk[i] for _ in range(v)]) for i, v in enumerate(positions)]
    predicted = K.PredictedBelief(jnp.asarray(b.log_pc), as_jax(rows))
    mi = np.asarray(PMI(PT(gaussians(mus, vars), kind=kind), predicted, target))
    assert mi.shape == (int(np.prod(positions)),)
    for a, cfg in enumerate(np.ndindex(*positions)):
        single = predicted.at(cfg)
        lj = np.asarray(K.log_joint(single))
        sub = tuple(m[v:v + 1] for m, v in zip(mus, cfg))
        ref = pairwise_mi_ref(sub, tuple(c[v:v + 1] for c, v in zip(_covs(vars), cfg)), lj, kind, target)
        np.testing.assert_allclose(mi[a], ref[0], rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("target", ["state", "class"])
def test_full_covariance_matches_brute_force(rng, x64, target):
    levels, positions, dims = (2, 2), (2, 2), (3, 2)
    mus, _ = random_model(rng, 3, levels, positions, dims)
    chols = random_chols(rng, 3, levels, positions, dims, scale=1.0)
    b = random_belief(rng, 3, levels)
    lj = np.asarray(K.log_joint(as_jax_belief(b)))
    for kind in K.DIVERGENCES:
        mi = PMI(PT(gaussians(mus, chols=chols), kind=kind), everywhere(b, positions), target)
        np.testing.assert_allclose(mi, pairwise_mi_ref(mus, _covs(chols=chols), lj, kind, target), rtol=1e-9, atol=1e-12)


def test_bhattacharyya_below_monte_carlo_below_kl(rng, getkey, x64):
    """K&T Theorems 2-3 on I(s; g | a): the Bhattacharyya estimate is a lower bound,
    the KL estimate an upper bound; the Monte Carlo MI lies between, within 4 se."""
    for spread in (0.5, 1.0, 2.0):
        mus, vars = random_model(rng, 4, (2, 3), (3, 2), (2, 2), spread=spread)
        b = everywhere(random_belief(rng, 4, (2, 3)), (3, 2))
        mc, se = MI(MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=300), b, "state", with_stderr=True)
        lo = PMI(PT(gaussians(mus, vars), kind="bhattacharyya"), b, "state")
        hi = PMI(PT(gaussians(mus, vars), kind="kl"), b, "state")
        mc, se, lo, hi = (np.asarray(x) for x in (mc, se, lo, hi))
        assert np.all(lo <= mc + 4 * se), (spread, lo - mc, se)
        assert np.all(mc <= hi + 4 * se), (spread, hi - mc, se)
        assert np.all(lo <= hi + 1e-12)
        assert np.all(lo >= -1e-12) and np.all(hi <= float(K.entropy(b.at((0, 0)), "state")) + 1e-9)


@pytest.mark.parametrize("target", ["state", "class"])
@pytest.mark.parametrize("kind", ["bhattacharyya", "kl"])
def test_exact_on_separated_and_on_identical_components(rng, x64, target, kind):
    mus, vars = random_model(rng, 4, (2, 3), (3, 2), (2, 2))
    b = as_jax_belief(random_belief(rng, 4, (2, 3)))
    h = float(K.entropy(b, target))
    b = everywhere(b, (3, 2))
    # perfectly separated: every D -> inf, I = H(s) (state) or H(c) (class)
    sharp = PMI(PT(gaussians(tuple(1e4 * m for m in mus), vars), kind=kind), b, target)
    np.testing.assert_allclose(sharp, h, rtol=1e-10)
    # identical components at every position: D = 0, I = 0
    same_mu = tuple(np.broadcast_to(m[:, :1, :1], m.shape).copy() for m in mus)
    same_var = tuple(np.broadcast_to(v[:, :1, :1], v.shape).copy() for v in vars)
    np.testing.assert_allclose(PMI(PT(gaussians(same_mu, same_var), kind=kind), b, target), 0.0, atol=1e-12)


def test_uniform_levels_equal_belief_path_with_uniform_rows(rng, x64):
    mus, vars = random_model(rng, 4, (2, 3), (3, 2), (2, 2))
    b = as_jax_belief(random_belief(rng, 4, (2, 3)))
    t = PT(gaussians(mus, vars), kind="bhattacharyya")
    uni = K.Belief(b.log_pc, tuple(jnp.full_like(x, -np.log(x.shape[1])) for x in b.log_pk))
    b, uni = everywhere(b, (3, 2)), everywhere(uni, (3, 2))
    for target in ("state", "class"):
        np.testing.assert_allclose(PMI(t, b, target, levels="uniform"), PMI(t, uni, target), rtol=1e-12, atol=1e-12)


def _uniform_class(b):
    """``b`` with the uniform class prior (the level rows kept)."""
    return b._replace(log_pc=jnp.full_like(b.log_pc, -np.log(b.log_pc.shape[0])))


def _transition_beliefs(rng, n_c, levels, positions):
    """Predicted priors of the recognizer's form (transition_per_position, both
    kinds, several current positions) from random posteriors."""
    out = []
    for kind in ("uniform", "sticky"):
        for current in [(0,) * len(positions), tuple(v - 1 for v in positions), tuple(v // 2 for v in positions)]:
            post = as_jax_belief(random_belief(rng, n_c, levels))
            out.append((kind, current, K.transition_per_position(post, current, positions, kind=kind, rho=0.7)))
    return out


@pytest.mark.parametrize("target", ["state", "class"])
@pytest.mark.parametrize(
    "levels,positions,dims", [((2,), (3,), (2,)), ((2, 3), (3, 2), (3, 2)), ((2, 1, 2), (2, 2, 2), (1, 2, 1))]
)
def test_fast_path_equals_general_path(rng, x64, levels, positions, dims, target):
    """The transition-form fast path (precomputed uniform rows, current position
    recomputed) gives the general computation's values on the recognizer's
    predicted priors, and a general belief (non-uniform rows at several
    positions) takes the general computation; both against brute force."""
    mus, vars = random_model(rng, 3, levels, positions, dims, spread=1.5)
    t = PT(gaussians(mus, vars), kind="bhattacharyya")
    cases = _transition_beliefs(rng, 3, levels, positions)
    # the same priors under the uniform class prior (the tempered planner's
    # tau = 0): the uniform-class path, offline values off the current positions
    cases += [(f"{kind}, uniform class", current, _uniform_class(b)) for kind, current, b in cases]
    rows = [np.stack([random_belief(rng, 3, levels).log_pk[i] for _ in range(v)]) for i, v in enumerate(positions)]
    general = K.PredictedBelief(jnp.asarray(random_belief(rng, 3, levels).log_pc), as_jax(rows))
    cases.append(("general", None, general))
    for kind, current, b in cases:
        ok, cur = pairwise_mi._transition_form(b.log_pk)
        if current is None:
            assert not bool(ok), kind
        else:
            assert bool(ok) and tuple(int(c) for c in cur) == current, (kind, current)
        fast = np.asarray(PMI(t, b, target, fast=True))
        slow = np.asarray(PMI(t, b, target, fast=False))
        np.testing.assert_allclose(fast, slow, rtol=1e-12, atol=1e-12, err_msg=f"{kind} {current}")
        if "uniform class" in kind:  # the offline values are read exactly where no camera is at its current position
            shifted = t._replace(u_state=t.u_state + 1.0, u_class=t.u_class + 1.0)
            off = np.array([all(v != c for v, c in zip(cfg, current)) for cfg in np.ndindex(*positions)])
            np.testing.assert_allclose(np.asarray(PMI(shifted, b, target)) - fast, off.astype(float), atol=1e-12)
    # one transition belief, its uniform-class form and the general one against enumeration
    for _, _, b in (cases[1], cases[7], cases[-1]):
        mi = np.asarray(PMI(t, b, target))
        for a, cfg in enumerate(np.ndindex(*positions)):
            single = b.at(cfg)
            sub = tuple(m[v:v + 1] for m, v in zip(mus, cfg))
            ref = pairwise_mi_ref(sub, tuple(c[v:v + 1] for c, v in zip(_covs(vars), cfg)),
                                  np.asarray(K.log_joint(single)), "bhattacharyya", target)
            np.testing.assert_allclose(mi[a], ref[0], rtol=1e-10, atol=1e-12)


def test_fast_path_float32_thesis_like(rng):
    """float32 at a larger size (C = 8, L = 4, 6 x 3 positions): fast and general
    paths agree to float32 rounding on transition beliefs, sharp and graded."""
    levels, positions = (4, 4), (6, 3)
    for spread in (0.3, 3.0):
        mus, vars = random_model(rng, 8, levels, positions, (5, 5), spread=spread)
        mus = tuple(m.astype(np.float32) for m in mus)
        vars = tuple((v * 0.1).astype(np.float32) for v in vars)
        for kind in K.DIVERGENCES:
            t = PT(gaussians(mus, vars), kind=kind)
            beliefs = [b for _, _, b in _transition_beliefs(rng, 8, levels, positions)]
            for b in beliefs + [_uniform_class(b) for b in beliefs[:3]]:
                b = K.PredictedBelief(b.log_pc.astype(jnp.float32), tuple(x.astype(jnp.float32) for x in b.log_pk))
                for target in ("state", "class"):
                    fast = np.asarray(PMI(t, b, target, fast=True))
                    slow = np.asarray(PMI(t, b, target, fast=False))
                    assert fast.dtype == np.float32
                    np.testing.assert_allclose(fast, slow, rtol=2e-5, atol=2e-5)


def test_fast_path_under_vmap(rng, x64):
    """vmap over a batch mixing transition-form and general beliefs: the cond
    becomes a select, the values are those of the unbatched calls."""
    levels, positions = (2, 3), (3, 2)
    mus, vars = random_model(rng, 3, levels, positions, (2, 2))
    t = PT(gaussians(mus, vars), kind="kl")
    bs = [b for _, _, b in _transition_beliefs(rng, 3, levels, positions)][:3]
    rows = [np.stack([random_belief(rng, 3, levels).log_pk[i] for _ in range(v)]) for i, v in enumerate(positions)]
    bs.append(K.PredictedBelief(jnp.asarray(random_belief(rng, 3, levels).log_pc), as_jax(rows)))
    stacked = jax.tree.map(lambda *x: jnp.stack(x), *bs)
    for target in ("state", "class"):
        got = np.asarray(jax.vmap(lambda b: K.pairwise_mutual_information(t, b, target))(stacked))
        want = np.stack([np.asarray(PMI(t, b, target)) for b in bs])
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


def test_float32_sharp_model_falls_back_and_stays_finite(rng, getkey):
    """Sharp thesis-like components in float32: exp(-D) underflows; the exact
    fallbacks keep every score finite and within [0, H]."""
    mus, vars = random_model(rng, 6, (3, 2), (3, 2), (4, 4), spread=3.0)
    mus = tuple(m.astype(np.float32) for m in mus)
    vars = tuple((v * 1e-3).astype(np.float32) for v in vars)
    b = as_jax_belief(random_belief(rng, 6, (3, 2), concentration=0.2))
    b = K.Belief(b.log_pc.astype(jnp.float32), tuple(x.astype(jnp.float32) for x in b.log_pk))
    for kind in K.DIVERGENCES:
        t = PT(gaussians(mus, vars), kind=kind)
        for target in ("state", "class"):
            mi = np.asarray(PMI(t, everywhere(b, (3, 2)), target))
            assert mi.dtype == np.float32 and np.all(np.isfinite(mi))
            assert np.all(mi <= float(K.entropy(b, target)) + 1e-3)  # exact bound, both targets
            if target == "state":
                assert np.all(mi >= -1e-4)  # the state estimate is >= 0 (the class one need not be)


def test_bad_input_and_nan_beliefs(rng):
    mus, vars = random_model(rng, 4, (2, 3), (3, 2), (2, 2))
    t = PT(gaussians(mus, vars), kind="bhattacharyya")
    b = everywhere(K.uniform_belief(4, (2, 3)), (3, 2))
    with pytest.raises(ValueError, match="kind"):
        K.pairwise_tables(gaussians(mus, vars), kind="hellinger")
    with pytest.raises(TypeError):  # arrays: one input form, likelihoods
        K.pairwise_tables(as_jax(mus))
    with pytest.raises(ValueError, match="target"):
        K.pairwise_mutual_information(t, b, "object")
    with pytest.raises(ValueError, match="levels"):
        K.pairwise_mutual_information(t, b, levels="sticky")
    with pytest.raises(ValueError, match="cameras"):
        K.pairwise_mutual_information(t, everywhere(K.uniform_belief(4, (2,)), (3,)))
    with pytest.raises(ValueError, match="C = 4"):
        K.pairwise_mutual_information(t, everywhere(K.uniform_belief(5, (2, 3)), (3, 2)))
    with pytest.raises(TypeError, match="PredictedBelief"):
        K.pairwise_mutual_information(t, K.uniform_belief(4, (2, 3)))
    nan_pc = b._replace(log_pc=b.log_pc.at[1].set(jnp.nan))
    nan_pk = b._replace(log_pk=(b.log_pk[0].at[0, 0, 1].set(jnp.nan), b.log_pk[1]))
    for bad in (nan_pc, nan_pk):
        with pytest.raises(ValueError, match="contains NaN"):
            K.pairwise_mutual_information(t, bad)
        with pytest.raises(ValueError, match="contains NaN"):
            K.mutual_information(MI_TABLES(gaussians(mus, vars), key=jax.random.PRNGKey(0), samples_per_stratum=1), bad)
        # under jit the values are unknown: no error, and no NaN score either
        for target in ("state", "class"):
            mi = np.asarray(PMI(t, bad, target))
            assert not np.any(np.isnan(mi)), mi
    # -inf (a class ruled out) is a valid belief, and its scores are finite
    zero = b._replace(log_pc=b.log_pc.at[1].set(-jnp.inf))
    assert np.all(np.isfinite(np.asarray(K.pairwise_mutual_information(t, zero))))


def test_zero_recompiles_after_warm_up(rng):
    mus, vars = random_model(rng, 4, (2, 3), (3, 2), (2, 2))
    mus = tuple(m.astype(np.float32) for m in mus)
    vars = tuple(v.astype(np.float32) for v in vars)
    t = K.pairwise_tables(gaussians(mus, vars), kind="kl")
    fn = jax.jit(K.pairwise_mutual_information, static_argnames=("target", "levels"))

    def belief():
        r = random_belief(rng, 4, (2, 3))
        rows = tuple(jnp.asarray(np.stack([lp] * v), jnp.float32) for lp, v in zip(r.log_pk, (3, 2)))
        return K.PredictedBelief(jnp.asarray(r.log_pc, jnp.float32), rows)

    for target in ("state", "class"):
        jax.block_until_ready(fn(t, belief(), target))
    with count_compiles() as later:
        for _ in range(5):
            for target in ("state", "class"):
                jax.block_until_ready(fn(t, belief(), target))
    assert sum(later.values()) == 0, dict(later)


def _few_class_beliefs(rng, n_c, levels, positions, live):
    """Transition-form predicted priors with ``live`` classes of weight and the
    others at log P ~ -300 (x64: below the stratum weight floor, so their
    strata add exactly 0), and the live classes."""
    out = []
    for _, _, b in _transition_beliefs(rng, n_c, levels, positions)[::3]:
        log_pc = np.asarray(b.log_pc).copy()
        alive = np.sort(rng.permutation(n_c)[:live])
        dead = np.setdiff1d(np.arange(n_c), alive)
        log_pc[dead] = -300.0 - rng.random(len(dead))
        log_pc[alive] -= np.log(np.sum(np.exp(log_pc[alive])))
        out.append((b._replace(log_pc=jnp.asarray(log_pc)), alive))
    return out


def test_few_live_classes_make_the_grid_alone(rng, x64, monkeypatch):
    """A belief with at most ``_FEW_CLASSES`` classes of nonzero weight makes
    the grid for those classes alone (the others add exactly 0): the values of
    the whole grid's computation and of brute force, on the fast and the
    general path; a belief with more live classes takes the whole grid.  The
    dead classes' own rows are then never read (NaN there changes nothing)
    where one or two classes live, and are read (-inf) where three do.  The
    class target (the default planners'; the loop is the state target's too,
    which adds no own-class term)."""
    target = "class"
    n_c, levels, positions, dims = 6, (2, 3), (3, 2), (2, 2)
    mus, vars = random_model(rng, n_c, levels, positions, dims, spread=1.5)
    t = PT(gaussians(mus, vars), kind="bhattacharyya")
    cases = [_few_class_beliefs(rng, n_c, levels, positions, live)[1] for live in (1, 2, 3)]

    def compiled(few):
        """Traced afresh (a new function) with ``_FEW_CLASSES = few``, the fast
        and the general path; compiles at its first call (here)."""
        monkeypatch.setattr(pairwise_mi, "_FEW_CLASSES", few)
        monkeypatch.setattr(pairwise_mi, "_SMALL_GRID", 0)  # the loop over classes, as at thesis size
        f = jax.jit(lambda tab, b: [K.pairwise_mutual_information(tab, b, target, fast=fast) for fast in (True, False)])
        f(t, cases[0][0])
        return f

    whole, few = compiled(n_c), compiled(2)
    for b, alive in cases:
        want = np.asarray(whole(t, b))
        np.testing.assert_allclose(np.asarray(few(t, b)), want, rtol=1e-12, atol=1e-12)
        for a, cfg in enumerate(np.ndindex(*positions)):
            sub = tuple(m[v:v + 1] for m, v in zip(mus, cfg))
            ref = pairwise_mi_ref(sub, tuple(c[v:v + 1] for c, v in zip(_covs(vars), cfg)),
                                  np.asarray(K.log_joint(b.at(cfg))), "bhattacharyya", target)
            np.testing.assert_allclose(want[0][a], ref[0], rtol=1e-10, atol=1e-12)
        dead = np.setdiff1d(np.arange(n_c), alive)
        got = np.asarray(few(t._replace(u_exp=tuple(e.at[dead].set(jnp.nan) for e in t.u_exp)), b)[0])
        if len(alive) <= 2:
            np.testing.assert_allclose(got, want[0], rtol=1e-12, atol=1e-12)
        else:  # the whole grid reads them (only the current positions' rows are made afresh)
            assert np.sum(np.isneginf(got)) >= got.size - 1
