"""Fisher information / CRLB kernel: NumPy reference on the same samples and a
VEGAS cross-check of the integral (eq. 5.22-5.28)."""

import jax.numpy as jnp
import numpy as np
import pytest
from kernel_models import as_jax_belief, everywhere, gaussians, jitted, random_belief, random_chols, random_model
from oracles import crlb_criterion_ref, fisher_information_ref, fisher_score_difference_ref
from scipy.special import logsumexp

from jaxrecog import kernels as K

pytestmark = pytest.mark.usefixtures("strict_dtype_promotion")  # numerics: no implicit promotion

MI_TABLES, _, FISHER = jitted()


@pytest.mark.parametrize(
    "levels,positions,dims,m,n", [((2,), (3,), (2,), 2, 2), ((2, 3), (3, 2), (2, 1), 2, 2), ((2, 2), (2, 2), (1, 2), 4, 1)]
)
def test_matches_reference_on_same_samples(rng, getkey, x64, levels, positions, dims, m, n):
    mus, vars = random_model(rng, m * n, levels, positions, dims)
    b = as_jax_belief(random_belief(rng, m * n, levels))
    tables = MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=2)
    key = getkey()
    fis = FISHER(tables, everywhere(b, positions), key=key, n_objects=m, n_poses=n)
    d = 2 + len(levels)
    assert fis.shape == (int(np.prod(positions)), d, d)
    ref, _ = fisher_information_ref(mus, vars, tables.z, K.fisher_draws(key, tables), np.asarray(K.log_joint(b)), n, 0.4)
    np.testing.assert_allclose(fis, ref, rtol=1e-9, atol=1e-10)
    if n > 1:  # with a single pose the pose coordinate carries no information (J singular)
        np.testing.assert_allclose(
            K.crlb_criterion(fis, "logdet", jitter=0.0), crlb_criterion_ref(ref, "logdet"), rtol=1e-8
        )


def test_full_covariance_matches_reference(rng, getkey, x64):
    """Non-diagonal covariances: a transposed Cholesky factor in the sampling or
    the solve changes the samples and the densities, and this reference (which
    samples g = mu + L z and evaluates log N with scipy's triangular solve) sees it."""
    levels, positions, dims, m, n = (2, 2), (2, 2), (2, 3), 2, 2
    mus, _ = random_model(rng, m * n, levels, positions, dims)
    chols = random_chols(rng, m * n, levels, positions, dims, scale=1.0)
    b = as_jax_belief(random_belief(rng, m * n, levels))
    tables = MI_TABLES(gaussians(mus, chols=chols), key=getkey(), samples_per_stratum=2)
    key = getkey()
    fis = FISHER(tables, everywhere(b, positions), key=key, n_objects=m, n_poses=n)
    ref, _ = fisher_information_ref(
        mus, None, tables.z, K.fisher_draws(key, tables), np.asarray(K.log_joint(b)), n, 0.4, chols=chols
    )
    np.testing.assert_allclose(fis, ref, rtol=1e-9, atol=1e-10)


def vegas_fisher_entries(mus, vars, log_p, sigma, *, adapt=(6, 10000), final=(8, 10000)):
    """VEGAS integrals of the smoothed Fisher information's entries (0, 0),
    (0, 2), (2, 2) at each position of camera 0 of a two-position, one-pose
    model: yields ``(v, r, c, result)`` (``result.mean``, ``result.sdev``).
    One integral per entry: vegas adapts its grid to the first component only."""
    import vegas

    for v in range(2):
        mu, var = mus[0][v], vars[0][v]
        lo, hi = np.min(mu - 8 * np.sqrt(var)), np.max(mu + 8 * np.sqrt(var))
        for idx, (r, c) in enumerate([(0, 0), (0, 2), (2, 2)]):
            integ = vegas.Integrator([[-3.2, 4.2], [-3.2, 4.2], [lo, hi]])

            @vegas.lbatchintegrand
            def f(x, idx=idx, mu=mu, var=var):
                return np.ascontiguousarray(_vegas_integrand(np.asarray(x), mu, var, log_p, sigma)[0][:, idx])

            integ(f, nitn=adapt[0], neval=adapt[1])
            yield v, r, c, integ(f, nitn=final[0], neval=final[1])


def _vegas_integrand(x, mu, var, log_p, sigma):
    """p(g, s_obj, s_occ) * [Delta_obj^2, Delta_obj Delta_occ, Delta_occ^2] for a 1-camera,
    1-pose model (states d = (c, k)); x = [n, 3] rows (s_obj, s_occ, g)."""
    s_obj, s_occ, g = x[:, 0], x[:, 1], x[:, 2]
    cs, ks = np.meshgrid(np.arange(mu.shape[0]), np.arange(mu.shape[1]), indexing="ij")
    cs, ks = cs.ravel(), ks.ravel()
    logw0 = (
        log_p.ravel()[None]
        - 0.5 * ((s_obj[:, None] - cs[None]) ** 2 + (s_occ[:, None] - ks[None]) ** 2) / sigma**2
        - np.log(2 * np.pi * sigma**2)
    )
    m, v = mu[:, :, 0].ravel(), var[:, :, 0].ravel()
    ll = -0.5 * ((g[:, None] - m[None]) ** 2 / v[None] + np.log(2 * np.pi * v[None]))
    lg = logw0 + ll
    dens = np.exp(logsumexp(lg, axis=1))
    w0 = np.exp(logw0 - logsumexp(logw0, axis=1, keepdims=True))
    wg = np.exp(lg - logsumexp(lg, axis=1, keepdims=True))
    do = (wg @ cs - w0 @ cs) / sigma**2
    dk = (wg @ ks - w0 @ ks) / sigma**2
    return dens[:, None] * np.stack([do * do, do * dk, dk * dk], axis=1), np.stack([do, dk], 1)


@pytest.mark.slow
def test_against_vegas_within_error_bars(rng, getkey, x64):
    sigma = 0.4
    mus, vars = random_model(rng, 2, (2,), (2,), (1,), spread=1.0)
    bn = random_belief(rng, 2, (2,), concentration=4.0)
    b = as_jax_belief(bn)
    log_p = np.asarray(K.log_joint(b))
    # the vectorised integrand agrees with the brute-force reference score difference
    x = rng.normal(size=(5, 3))
    _, deltas = _vegas_integrand(x, mus[0][1], vars[0][1], log_p, sigma)
    for row, dl in zip(x, deltas):
        want = fisher_score_difference_ref(
            np.array([row[0], 0.0, row[1]]), [row[2:3]], (1,), mus, vars, log_p, 1, sigma
        )
        np.testing.assert_allclose(dl, want[[0, 2]], rtol=1e-10, atol=1e-12)

    tables = MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=4000)
    fis, se = FISHER(tables, everywhere(b, (2,)), key=getkey(), n_objects=2, n_poses=1, sigma_s=sigma, with_stderr=True)
    for v, r, c, res in vegas_fisher_entries(mus, vars, log_p, sigma, adapt=(8, 20000), final=(10, 20000)):
        val, err = res.mean, res.sdev
        tol = 4 * np.hypot(err, float(se[v, r, c])) + 1e-6
        assert abs(float(fis[v, r, c]) - val) < tol, (v, r, c, float(fis[v, r, c]), val, err, float(se[v, r, c]))
    # a single pose: no information on the pose coordinate
    np.testing.assert_allclose(fis[:, 1], 0.0, atol=1e-12)


def test_symmetric_psd_and_criteria(rng, getkey):
    mus, vars = random_model(rng, 6, (2, 3), (3, 2), (3, 2), spread=2.0)
    b = everywhere(random_belief(rng, 6, (2, 3)), (3, 2))
    tables = MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=4)
    fis = FISHER(tables, b, key=getkey(), n_objects=3, n_poses=2)
    assert np.all(np.isfinite(fis))
    np.testing.assert_allclose(fis, np.swapaxes(fis, -1, -2), rtol=1e-6)
    assert np.all(np.linalg.eigvalsh(np.asarray(fis, np.float64)) > -1e-5)
    for kind in ("trace", "logdet", "maxeig"):
        crit = K.crlb_criterion(fis, kind, jitter=0.0)
        np.testing.assert_allclose(crit, crlb_criterion_ref(fis, kind), rtol=2e-3)
    with pytest.raises(ValueError, match="kind"):
        K.crlb_criterion(fis, "det")


def test_singular_fisher_gives_large_finite_criterion():
    fis = jnp.zeros((3, 4, 4)).at[:, 0, 0].set(1.0)
    for kind in ("trace", "logdet", "maxeig"):
        out = K.crlb_criterion(fis, kind)
        assert np.all(np.isfinite(out))
    assert np.all(K.crlb_criterion(fis) > 1e5)


def test_separating_configuration_has_smallest_bound(rng, getkey, x64):
    mus, vars = random_model(rng, 4, (2, 2), (3, 2), (2, 2), spread=0.05)
    mu0, mu1 = mus[0].copy(), mus[1].copy()
    # camera 0 at position 1 and camera 1 at position 0 separate every class and level
    mu0[1] = 4.0 * rng.normal(size=(4, 2, 2))
    mu1[0] = 4.0 * rng.normal(size=(4, 2, 2))
    tables = MI_TABLES(gaussians((mu0, mu1), vars), key=getkey(), samples_per_stratum=8)
    fis = FISHER(tables, everywhere(K.uniform_belief(4, (2, 2)), (3, 2)), key=getkey(), n_objects=2, n_poses=2)
    best = 1 * 2 + 0
    # the bound is J^-1 of the full 4 x 4 J: rank by the default criterion, trace(J^-1)
    crit = np.asarray(K.crlb_criterion(fis))
    assert int(np.argmin(crit)) == best, crit
    assert crit[best] < 0.5 * np.min(np.delete(crit, best)), crit  # by a clear margin
    np.testing.assert_allclose(K.crlb_criterion(fis, jitter=0.0), crlb_criterion_ref(fis, "trace"), rtol=1e-8)


def test_bad_arguments(rng, getkey):
    mus, vars = random_model(rng)
    tables = K.mi_tables(gaussians(mus, vars), key=getkey(), samples_per_stratum=1)
    b = everywhere(K.uniform_belief(4, (2, 3)), (3, 2))
    with pytest.raises(TypeError, match="PredictedBelief"):
        K.fisher_information(tables, K.uniform_belief(4, (2, 3)), key=getkey(), n_objects=2, n_poses=2)
    with pytest.raises(ValueError, match="n_objects"):
        K.fisher_information(tables, b, key=getkey(), n_objects=3, n_poses=2)
    with pytest.raises(ValueError, match="sigma_s"):
        K.fisher_information(tables, b, key=getkey(), n_objects=2, n_poses=2, sigma_s=0.0)
    only = K.mi_tables(gaussians(mus, vars), key=getkey(), samples_per_stratum=1, store="uniform")
    with pytest.raises(ValueError, match="store"):
        K.fisher_information(only, b, key=getkey(), n_objects=2, n_poses=2)


def test_few_live_classes_make_the_strata_alone(rng, getkey, x64, monkeypatch):
    """With more than ``_FEW_CLASSES`` classes the score outer products are
    summed over the strata of the classes of nonzero weight alone, that many
    at a time (one chunk for 1 or 2 live classes, two for 3): the whole
    computation's values and the NumPy reference's; the dead classes' own
    sample rows never reach a value (NaN there changes nothing)."""
    import importlib

    import jax

    fisher = importlib.import_module("jaxrecog.kernels.fisher")
    m, n, levels, positions, dims = 3, 2, (2, 3), (3, 2), (2, 1)
    mus, vars = random_model(rng, m * n, levels, positions, dims)
    tables = MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=2)
    draws = K.fisher_draws(getkey(), tables)
    b0 = as_jax_belief(random_belief(rng, m * n, levels))
    cases = []
    for live in (1, 2, 3):
        alive = np.sort(rng.permutation(m * n)[:live])
        log_pc = np.full(m * n, -300.0)  # x64: below the weights' floor tiny^(1/3)
        log_pc[alive] = np.log(rng.dirichlet(np.ones(live)))
        cases.append((everywhere(b0._replace(log_pc=jnp.asarray(log_pc)), positions), alive))

    def compiled(few):
        """Traced afresh (a new function) with ``_FEW_CLASSES = few``; compiles at its first call (here)."""
        monkeypatch.setattr(fisher, "_FEW_CLASSES", few)
        f = jax.jit(lambda t, b: fisher.fisher_from_draws(t, b, draws, m, n, 0.4))
        f(tables, cases[0][0])
        return f

    whole, few = compiled(m * n), compiled(2)
    for b, alive in cases:
        want = np.asarray(whole(tables, b))
        np.testing.assert_allclose(np.asarray(few(tables, b)), want, rtol=1e-10, atol=1e-12)
        ref, _ = fisher_information_ref(mus, vars, tables.z, draws, np.asarray(K.log_joint(b.at((0, 0)))), n, 0.4)
        np.testing.assert_allclose(want, ref, rtol=1e-9, atol=1e-10)
        dead = jnp.asarray(np.setdiff1d(np.arange(m * n), alive))
        poisoned = tables._replace(ld=tuple(t.at[:, dead].set(jnp.nan) for t in tables.ld))
        np.testing.assert_allclose(np.asarray(few(poisoned, b)), want, rtol=1e-10, atol=1e-12)
