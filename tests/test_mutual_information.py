"""Mutual Information kernel: NumPy reference on the same samples, quadrature on
tiny models, bounds, and ranking (eq. 5.3-5.13)."""

import importlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from kernel_models import as_jax, as_jax_belief, everywhere, gaussians, jitted, random_belief, random_chols, random_model
from oracles import log_likelihood_full_ref, mutual_information_quadrature, mutual_information_ref

from jaxrecog import kernels as K

pytestmark = pytest.mark.usefixtures("strict_dtype_promotion")  # numerics: no implicit promotion

MI_TABLES, MI, _ = jitted()


@pytest.mark.parametrize(
    "levels,positions,dims",
    [((2,), (3,), (2,)), ((2, 3), (3, 2), (3, 2)), ((2, 1, 2), (2, 2, 2), (1, 2, 1))],
)
@pytest.mark.parametrize("target", ["state", "class"])
def test_matches_reference_on_same_samples(rng, getkey, x64, levels, positions, dims, target):
    mus, vars = random_model(rng, 4, levels, positions, dims)
    b = random_belief(rng, 4, levels)
    tables = MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=3)
    assert K.samples_per_configuration(tables) == 4 * int(np.prod(levels)) * 3
    mi = MI(tables, everywhere(b, positions), target=target)
    assert mi.shape == (int(np.prod(positions)),)
    ref, _ = mutual_information_ref(mus, vars, tables.z, np.asarray(K.log_joint(as_jax_belief(b))), target)
    np.testing.assert_allclose(mi, ref, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("target", ["state", "class"])
def test_uniform_offline_tables_equal_belief_path_with_uniform_levels(rng, getkey, x64, target):
    mus, vars = random_model(rng, 5, (2, 3), (3, 2), (2, 2))
    b = as_jax_belief(random_belief(rng, 5, (2, 3)))
    tables = MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=2)
    uni = K.Belief(b.log_pc, tuple(jnp.full_like(x, -np.log(x.shape[1])) for x in b.log_pk))
    a = MI(tables, everywhere(b, (3, 2)), target, levels="uniform")
    c = MI(tables, everywhere(uni, (3, 2)), target, levels="belief")
    np.testing.assert_allclose(a, c, rtol=1e-12, atol=1e-12)
    only = MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=2, store="uniform")
    assert only.ld is None
    with pytest.raises(ValueError, match="store"):
        MI(only, everywhere(b, (3, 2)), target, levels="belief")


@pytest.mark.parametrize("target", ["state", "class"])
def test_uniform_levels_exact_only_where_every_camera_moves(rng, getkey, x64, target):
    """levels="uniform" treats every camera's levels as re-drawn (P_i = 1/L_i at every
    position).  Under the thesis's uniform transition that is exact on configurations
    where every camera moves; a camera that stays keeps its levels, so there the
    uniform variant is the documented approximation, not the exact prediction."""
    levels, positions = (2, 3), (3, 4)
    mus, vars = random_model(rng, 4, levels, positions, (2, 2), spread=2.0)
    b = as_jax_belief(random_belief(rng, 4, levels, concentration=0.3))  # far from uniform level rows
    tables = MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=3)
    current = (1, 2)
    predicted = K.transition_per_position(b, current, positions, "uniform")
    uni = np.asarray(MI(tables, everywhere(b, positions), target, levels="uniform"))
    exact = np.asarray(MI(tables, predicted, target, levels="belief"))
    moved = np.array([v0 != current[0] and v1 != current[1] for v0, v1 in np.ndindex(*positions)])
    assert moved.sum() == (3 - 1) * (4 - 1)
    np.testing.assert_allclose(uni[moved], exact[moved], rtol=1e-10, atol=1e-10)
    # stay configurations: the uniform variant ignores the kept levels ...
    redrawn = K.Belief(b.log_pc, tuple(jnp.full_like(x, -np.log(x.shape[1])) for x in b.log_pk))
    np.testing.assert_allclose(uni[~moved], np.asarray(MI(tables, everywhere(redrawn, positions), target))[~moved],
                               rtol=1e-10, atol=1e-10)
    # ... and so differs from the exact prediction there (an approximation, not exact)
    assert np.all(np.abs(uni[~moved] - exact[~moved]) > 1e-4)


def test_per_position_levels_equal_separate_beliefs(rng, getkey, x64):
    levels, positions = (2, 3), (3, 2)
    mus, vars = random_model(rng, 4, levels, positions, (2, 2))
    tables = MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=2)
    base = random_belief(rng, 4, levels)
    rows = [np.stack([random_belief(rng, 4, levels).log_pk[i] for _ in range(positions[i])]) for i in range(2)]
    per_pos = K.PredictedBelief(jnp.asarray(base.log_pc), as_jax(rows))
    mi = MI(tables, per_pos)
    for a, (v0, v1) in enumerate(np.ndindex(*positions)):
        single = per_pos.at((v0, v1))
        assert single.log_pk[1].shape == (4, 3)
        np.testing.assert_allclose(mi[a], MI(tables, everywhere(single, positions))[a], rtol=1e-12)


@pytest.mark.parametrize("target", ["state", "class"])
@pytest.mark.parametrize(
    "levels,positions,dims", [((2,), (2,), (1,)), ((2, 1), (2, 2), (1, 1)), ((1,), (2,), (2,))]
)
def test_against_quadrature_within_4_sigma(rng, getkey, x64, target, levels, positions, dims):
    mus, vars = random_model(rng, 3, levels, positions, dims, spread=1.5)
    b = random_belief(rng, 3, levels, concentration=3.0)
    tables = MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=400)
    mi, se = MI(tables, everywhere(b, positions), target, with_stderr=True)
    lj = np.asarray(K.log_joint(as_jax_belief(b)))
    for a, cfg in enumerate(np.ndindex(*positions)):
        quad = mutual_information_quadrature(mus, vars, lj, cfg, target, n_grid=801 if sum(dims) == 1 else 301)
        assert abs(float(mi[a]) - quad) < 4 * float(se[a]) + 1e-4, (a, float(mi[a]), quad, float(se[a]))


@pytest.mark.slow
def test_bounds_nonnegative_and_below_entropy(rng, getkey, x64):
    mus, vars = random_model(rng, 6, (2, 3), (3, 2), (3, 2), spread=3.0)
    b = as_jax_belief(random_belief(rng, 6, (2, 3)))
    tables = MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=16)
    pb = everywhere(b, (3, 2))
    for target in ("state", "class"):
        mi, se = MI(tables, pb, target, with_stderr=True)
        assert np.all(np.isfinite(mi))
        assert np.all(mi > -4 * se)
        # exact, not up to MC error: p(g|a) >= P(s) p(g|s) for every sample (see below)
        assert np.all(mi <= K.entropy(b, target) + 1e-9)
    # the class information never exceeds the state information on the same samples (up to MC error)
    ms = MI(tables, pb, "state")
    mc = MI(tables, pb, "class")
    assert np.all(mc <= ms + 0.05)


@pytest.mark.parametrize("target", ["state", "class"])
def test_weakly_informative_nonnegative_within_small_error_and_below_entropy(rng, getkey, x64, target):
    """Overlapping Gaussians (means within ~0.05, variances within 10 %): MI is
    a few thousandths of a nat and resolved (se ~ 1e-3), so ``mi > -4 se``
    catches a negative bias of ~0.01 nats (e.g. a wrong normalising constant
    in log p(g|s)); a wrongly weighted but normalised mixture for p(g|a) only
    biases MI upwards (Gibbs), which the exact upper bound below catches.  MI <= H holds exactly, sample by sample: p(g|a) >= P(s) p(g|s)
    (state) and p(g|a) >= P(c) p(g|c) (class), so each stratum's term is at most
    -log P(s) (or -log P(c)) and the P-weighted sum at most H."""
    mus, _ = random_model(rng, 4, (2, 3), (3, 2), (2, 2), spread=0.05)
    vars = tuple(rng.uniform(0.9, 1.1, size=m.shape) for m in mus)
    b = as_jax_belief(random_belief(rng, 4, (2, 3)))
    tables = MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=2000)
    mi, se = (np.asarray(x) for x in MI(tables, everywhere(b, (3, 2)), target, with_stderr=True))
    assert np.all(mi < 0.02), mi  # weakly informative indeed
    assert np.all(se < 0.002), se  # ... and resolved: -4 se is a tight floor
    assert np.all(mi > -4 * se), (mi, se)
    assert np.all(mi <= float(K.entropy(b, target)) + 1e-9)
    # the exact bound is attained in the limit of a perfectly separating model
    sharp = MI_TABLES(gaussians(tuple(2000.0 * m for m in mus), vars), key=getkey(), samples_per_stratum=2)
    mi_sharp = np.asarray(MI(sharp, everywhere(b, (3, 2)), target))
    assert np.all(mi_sharp <= float(K.entropy(b, target)) + 1e-9)
    np.testing.assert_allclose(mi_sharp, float(K.entropy(b, target)), atol=1e-3)


@pytest.mark.slow
def test_uninformative_camera(rng, getkey, x64):
    mus, vars = random_model(rng, 4, (2, 3), (3, 2), (2, 2))
    # camera 1: the same Gaussian for every class and level at each position
    mu1 = np.broadcast_to(mus[1][:, :1, :1], mus[1].shape).copy()
    var1 = np.broadcast_to(vars[1][:, :1, :1], vars[1].shape).copy()
    b = as_jax_belief(random_belief(rng, 4, (2, 3)))
    alone = MI_TABLES(gaussians((mu1,), (var1,)), key=getkey(), samples_per_stratum=4)
    b1 = K.Belief(b.log_pc, (b.log_pk[1],))
    np.testing.assert_allclose(MI(alone, everywhere(b1, (2,))), 0.0, atol=1e-10)
    both = MI_TABLES(gaussians((mus[0], mu1), (vars[0], var1)), key=getkey(), samples_per_stratum=4)
    mi = np.asarray(MI(both, everywhere(b, (3, 2)), "class")).reshape(3, 2)
    np.testing.assert_allclose(mi[:, 0], mi[:, 1], rtol=1e-10)  # camera 1's position is irrelevant


def test_separating_configuration_ranks_first(rng, getkey):
    mus, vars = random_model(rng, 8, (2, 2), (3, 2), (3, 2), spread=0.05)
    mu0 = mus[0].copy()
    mu0[2] = 4.0 * rng.normal(size=mu0[2].shape[:1] + (1, mu0.shape[-1]))  # position 2 separates classes
    mu1 = mus[1].copy()
    mu1[1] = 4.0 * rng.normal(size=mu1[1].shape[:1] + (1, mu1.shape[-1]))
    tables = MI_TABLES(gaussians((mu0, mu1), vars), key=getkey(), samples_per_stratum=4)
    b = everywhere(K.uniform_belief(8, (2, 2)), (3, 2))
    for target in ("state", "class"):
        mi = MI(tables, b, target)
        assert int(jnp.argmax(mi)) == 2 * 2 + 1


def test_underflow_fallback_stays_exact(rng, getkey, x64):
    # very sharp Gaussians: shifted exps underflow even in float64, so the exact path must take over
    mus, vars = random_model(rng, 4, (2, 2), (2, 2), (3, 3), spread=3.0)
    vars = tuple(v * 1e-5 for v in vars)
    b = random_belief(rng, 4, (2, 2))
    tables = MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=2)
    mi = MI(tables, everywhere(b, (2, 2)))
    ref, _ = mutual_information_ref(mus, vars, tables.z, np.asarray(K.log_joint(as_jax_belief(b))))
    assert np.all(np.isfinite(mi))
    np.testing.assert_allclose(mi, ref, rtol=1e-9)


def test_underflow_fallback_float32_finite(rng, getkey):
    mus, vars = random_model(rng, 6, (3, 2), (3, 2), (4, 4), spread=3.0)
    vars = tuple((v * 1e-3).astype(np.float32) for v in vars)
    mus = tuple(m.astype(np.float32) for m in mus)
    tables = MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=2)
    b = K.uniform_belief(6, (3, 2))
    for target in ("state", "class"):
        mi = MI(tables, everywhere(b, (3, 2)), target)
        assert mi.dtype == jnp.float32 and np.all(np.isfinite(mi))
        assert np.all(mi <= K.entropy(b, target) + 1e-3)


def test_zero_probability_classes(rng, getkey, x64):
    mus, vars = random_model(rng, 4, (2, 2), (3, 2), (2, 2))
    b = random_belief(rng, 4, (2, 2))
    log_pc = np.array([np.log(0.5), -np.inf, np.log(0.5), -np.inf])
    bz = K.Belief(jnp.asarray(log_pc), as_jax(b.log_pk))
    tables = MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=2)
    mi = MI(tables, everywhere(bz, (3, 2)))
    ref, _ = mutual_information_ref(mus, vars, tables.z, np.asarray(K.log_joint(bz)))
    np.testing.assert_allclose(mi, ref, rtol=1e-10)


def test_full_covariance_tables(rng, getkey, x64):
    levels, positions, dims = (2, 2), (2, 2), (2, 3)
    mus, vars = random_model(rng, 3, levels, positions, dims)
    diag_chols = tuple(np.sqrt(v)[..., None] * np.eye(v.shape[-1]) for v in vars)
    key = getkey()
    b = everywhere(random_belief(rng, 3, levels), positions)
    td = MI_TABLES(gaussians(mus, vars), key=key, samples_per_stratum=2)
    tf = MI_TABLES(gaussians(mus, chols=diag_chols), key=key, samples_per_stratum=2)
    np.testing.assert_allclose(MI(tf, b), MI(td, b), rtol=1e-10)
    # a genuine full covariance: MI still matches the quadrature-free sanity bounds
    chols = random_chols(rng, 3, levels, positions, dims)
    tc = MI_TABLES(gaussians(mus, chols=chols), key=key, samples_per_stratum=8)
    mi, se = MI(tc, b, with_stderr=True)
    assert np.all(mi > -4 * se) and np.all(mi < K.entropy(b.at((0, 0))) + 4 * se)


@pytest.mark.parametrize("target", ["state", "class"])
def test_full_covariance_tables_match_reference(rng, getkey, x64, target):
    """A genuinely non-diagonal covariance (a diagonal factor is symmetric, so a
    transposed Cholesky factor in the sampling or the solve would go unnoticed):
    every LD entry is the reference log N(mu + L z; mu', L' L'^T), and the MI is
    the full-covariance reference on the same samples."""
    levels, positions, dims = (2, 3), (2, 2), (3, 2)
    mus, _ = random_model(rng, 3, levels, positions, dims)
    chols = random_chols(rng, 3, levels, positions, dims, scale=1.0)
    for ch in chols:  # far from diagonal, and L != L^T
        off = np.abs(np.tril(ch, -1)).max(axis=(-2, -1))
        assert np.all(off > 0.05) and np.mean(off) > 0.3 * np.mean(np.diagonal(ch, axis1=-2, axis2=-1))
    b = random_belief(rng, 3, levels)
    tables = MI_TABLES(gaussians(mus, chols=chols), key=getkey(), samples_per_stratum=2)
    for i, (mu, ch) in enumerate(zip(mus, chols)):
        z = np.asarray(tables.z[i])
        ld, ld_self = np.asarray(tables.ld[i]), np.asarray(tables.ld_self[i])
        for v, c, k, j in np.ndindex(*ld_self.shape):
            g = mu[v, c, k] + ch[v, c, k] @ z[c, k, j]
            want = log_likelihood_full_ref(g, mu[v], ch[v])
            np.testing.assert_allclose(ld[v, c, k, j], want, rtol=1e-11, atol=1e-11)
            np.testing.assert_allclose(ld_self[v, c, k, j], want[c, k], rtol=1e-11, atol=1e-11)
    mi = MI(tables, everywhere(b, positions), target)
    lj = np.asarray(K.log_joint(as_jax_belief(b)))
    ref, _ = mutual_information_ref(mus, None, tables.z, lj, target, chols=chols)
    np.testing.assert_allclose(mi, ref, rtol=1e-10, atol=1e-10)


def test_bad_arguments(rng, getkey):
    mus, vars = random_model(rng)
    with pytest.raises(ValueError, match="exactly one"):
        gaussians(mus)
    with pytest.raises(ValueError, match="shape"):
        gaussians(mus, (vars[0], vars[0]))
    # one input form: likelihoods (the Gaussian arrays are refused, naming the builder)
    with pytest.raises(TypeError, match="gaussian_likelihoods"):
        K.likelihood.as_likelihoods(as_jax(mus), where="mi_tables")
    with pytest.raises(TypeError):
        K.mi_tables(as_jax(mus), key=getkey(), samples_per_stratum=2)
    with pytest.raises(ValueError, match="samples_per_stratum"):
        MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=0)
    tables = MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=1)
    b = everywhere(K.uniform_belief(4, (2, 3)), (3, 2))
    with pytest.raises(ValueError, match="target"):
        MI(tables, b, "object")
    with pytest.raises(ValueError, match="stderr"):
        MI(tables, b, with_stderr=True)
    with pytest.raises(ValueError, match="cameras"):
        MI(tables, everywhere(K.uniform_belief(4, (2,)), (3,)))
    with pytest.raises(ValueError, match="C = 4"):
        MI(tables, everywhere(K.uniform_belief(5, (2, 3)), (3, 2)))
    with pytest.raises(ValueError, match=r"log_pk\[1\] has shape \(3, 4, 3\).*\(2, 4, 3\)"):
        MI(tables, everywhere(K.uniform_belief(4, (2, 3)), (3, 3)))  # camera 1 has 2 positions
    # a plain belief: the planners score a prediction (under the tests' jaxtyping the
    # annotation catches it first; without it, the kernel's own check says what to use)
    with pytest.raises(TypeError, match="PredictedBelief"):
        MI(tables, K.uniform_belief(4, (2, 3)))
    with pytest.raises(TypeError, match="PredictedBelief.*at_every_position.*got Belief"):
        K.belief.check_predicted(K.uniform_belief(4, (2, 3)), tables.ld_self)


@pytest.mark.parametrize("target", ["state", "class"])
def test_belief_levels_fallback_when_shifted_sum_underflows(rng, getkey, target):
    """The belief path's fast T_i = M_i + log sum_k' E_i P_i (E_i = exp(LD_i - M_i)
    precomputed) underflows where the belief puts ~all its mass on levels whose
    E_i is ~0; it must then fall back to the exact logsumexp, unchanged results."""
    levels = (2, 2)
    mus, vars = random_model(rng, 3, levels, (2, 3), (30, 30), spread=3.0)
    b = random_belief(rng, 3, levels)
    # camera 0: every class's mass on level 1 (level 0 at log P = -1e30)
    lp0 = np.array(b.log_pk[0])
    lp0[:, 0], lp0[:, 1] = -1e30, 0.0
    b = K.Belief(jnp.asarray(b.log_pc, jnp.float32), (jnp.asarray(lp0, jnp.float32), jnp.asarray(b.log_pk[1], jnp.float32)))
    tables = MI_TABLES(gaussians(mus, vars, dtype=jnp.float32),
                       key=getkey(), samples_per_stratum=2)
    # the fast path's sums do underflow here (samples of level 0 see E ~ 0 at level 1)
    s = np.einsum("vCKclj,vCK->vcljC", np.asarray(tables.ld_exp[0], float), np.exp(lp0.astype(float))[None].repeat(2, 0))
    fi = np.finfo(np.float32)
    assert np.any(s < 2 * fi.tiny / fi.eps)
    a = np.asarray(MI(tables, everywhere(b, (2, 3)), target))
    exact = np.asarray(MI(tables._replace(ld_max=None, ld_exp=None), everywhere(b, (2, 3)), target))
    np.testing.assert_array_equal(a, exact)
    assert np.all(np.isfinite(a))
    ref, _ = mutual_information_ref(mus, vars, tables.z, np.asarray(K.log_joint(b), float), target)
    np.testing.assert_allclose(a, ref, rtol=2e-4, atol=2e-4)


@pytest.mark.parametrize("target", ["state", "class"])
def test_few_live_classes_make_the_strata_alone(rng, getkey, x64, monkeypatch, target):
    """With more than ``_FEW_CLASSES`` classes the strata are summed over the
    classes of nonzero weight alone, that many at a time (the others add
    exactly 0; the mixtures keep every class): one chunk (1 or 2 live classes)
    or two (3), the whole computation's values and the brute-force
    reference's, for both level modes.  The dead classes' own sample rows
    never reach a value (NaN there changes nothing)."""
    mi_mod = importlib.import_module("jaxrecog.kernels.mutual_information")  # the module, not the function
    n_c, levels, positions, dims = 6, (2, 3), (3, 2), (2, 2)
    mus, vars = random_model(rng, n_c, levels, positions, dims)
    tables = MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=3)
    cases = []
    for live in (1, 2, 3):
        b = random_belief(rng, n_c, levels)
        alive = np.sort(rng.permutation(n_c)[:live])
        log_pc = np.full(n_c, -300.0)  # x64: below the weights' floor tiny^(1/3) ~ e^-236
        log_pc[alive] = np.log(rng.dirichlet(np.ones(live)))
        cases.append((K.PredictedBelief(jnp.asarray(log_pc), everywhere(b, positions).log_pk), alive))
    body = mi_mod._mutual_information.__wrapped__

    def compiled(few):
        """The kernel traced afresh (a new function) with ``_FEW_CLASSES = few``,
        both level modes; each compiles once, at its first call (here)."""
        monkeypatch.setattr(mi_mod, "_FEW_CLASSES", few)
        f = jax.jit(lambda t, b: [body(t, b, target, lv, False) for lv in ("belief", "uniform")])
        f(tables, cases[0][0])
        return f

    whole, few = compiled(n_c), compiled(2)  # n_c: not above it, the whole computation
    for b, alive in cases:
        want = np.asarray(whole(tables, b))
        np.testing.assert_allclose(np.asarray(few(tables, b)), want, rtol=1e-11, atol=1e-12)
        ref, _ = mutual_information_ref(mus, vars, tables.z, np.asarray(K.log_joint(b.at((0, 0)))), target)
        np.testing.assert_allclose(want[0], ref, rtol=1e-9, atol=1e-10)
        dead = jnp.asarray(np.setdiff1d(np.arange(n_c), alive))
        poisoned = tables._replace(ld=tuple(t.at[:, dead].set(jnp.nan) for t in tables.ld),
                                   ld_self=tuple(t.at[:, dead].set(jnp.nan) for t in tables.ld_self),
                                   ld_max=tuple(t.at[:, dead].set(jnp.nan) for t in tables.ld_max),
                                   ld_exp=tuple(t.at[:, :, :, dead].set(jnp.nan) for t in tables.ld_exp),
                                   t_uniform=tuple(t.at[:, dead].set(jnp.nan) for t in tables.t_uniform))
        np.testing.assert_allclose(np.asarray(few(poisoned, b)), want, rtol=1e-11, atol=1e-12)
