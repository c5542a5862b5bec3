"""Quasi-Monte Carlo Fisher information (kernels/fisher_qmc.py): the
Sobol tables and rotated draws against scipy / NumPy, the kernel against the
NumPy reference on the same points, unbiasedness against a high-J Monte Carlo
and against VEGAS on small cases, the planner, and no recompilation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from compiles import count_compiles
from kernel_models import as_jax_belief, everywhere, gaussians, jitted, random_belief, random_model
from oracles import fisher_information_ref
from scipy.special import ndtri
from scipy.stats import qmc

from jaxrecog import kernels as K

pytestmark = pytest.mark.usefixtures("strict_dtype_promotion")  # numerics: no implicit promotion

MI_TABLES, _, FISHER = jitted()
QFI = jax.jit(K.qmc_fisher_information, static_argnames=("n_objects", "n_poses", "sigma_s"))


def test_tables_and_draws_are_rotated_sobol_points(rng, getkey, x64):
    levels, positions, dims = (2, 3), (3, 2), (2, 1)
    mus, vars = random_model(rng, 4, levels, positions, dims)
    qt = K.qmc_fisher_tables(gaussians(mus, vars), seed=7, samples_per_stratum=8)
    n_dim = 2 + sum(1 + k for k in dims)
    for c in range(4):
        u = qmc.Sobol(n_dim, scramble=True, seed=np.random.default_rng([7, c])).random_base2(3)  # [J, dims]
        np.testing.assert_allclose(qt.u_obj[c], u[:, 0])
        np.testing.assert_allclose(qt.u_pose[c], u[:, 1])
        col = 2
        for i, k in enumerate(dims):
            np.testing.assert_allclose(qt.u_occ[i][c], u[:, col])
            for lev in range(levels[i]):  # the same points for every level
                np.testing.assert_allclose(qt.tables.z[i][c, lev], ndtri(u[:, col + 1: col + 1 + k]), rtol=1e-12)
            col += 1 + k
    key = getkey()
    draws = K.qmc_fisher_draws(key, qt)
    shift = np.asarray(jax.random.uniform(key, (4, 2 + len(dims)), jnp.float64))
    np.testing.assert_allclose(draws.eps_obj, ndtri(np.mod(np.asarray(qt.u_obj) + shift[:, :1], 1.0)), rtol=1e-10)
    np.testing.assert_allclose(draws.eps_pose, ndtri(np.mod(np.asarray(qt.u_pose) + shift[:, 1:2], 1.0)), rtol=1e-10)
    for i, l in enumerate(levels):
        want = ndtri(np.mod(np.asarray(qt.u_occ[i]) + shift[:, 2 + i: 3 + i], 1.0))
        np.testing.assert_allclose(draws.eps_occ[i], np.broadcast_to(want[:, None], (4, l, 8)), rtol=1e-10)
    with pytest.raises(ValueError, match="power of 2"):
        K.qmc_fisher_tables(gaussians(mus, vars), seed=0, samples_per_stratum=6)


@pytest.mark.parametrize("levels,positions,dims,m,n", [((2,), (3,), (2,), 2, 2), ((2, 3), (3, 2), (2, 1), 2, 2)])
def test_matches_reference_on_same_points(rng, getkey, x64, levels, positions, dims, m, n):
    mus, vars = random_model(rng, m * n, levels, positions, dims)
    b = as_jax_belief(random_belief(rng, m * n, levels))
    qt = K.qmc_fisher_tables(gaussians(mus, vars), seed=3, samples_per_stratum=4)
    key = getkey()
    fis = QFI(qt, everywhere(b, positions), key=key, n_objects=m, n_poses=n)
    ref, _ = fisher_information_ref(mus, vars, qt.tables.z, K.qmc_fisher_draws(key, qt), np.asarray(K.log_joint(b)), n, 0.4)
    np.testing.assert_allclose(fis, ref, rtol=1e-9, atol=1e-10)


def _replicates(mus, vars, b, m, n, reps, j, sigma=0.4):
    """Independent randomisations (scrambling seed and rotation key): mean and standard error."""
    out = []
    for r in range(reps):
        qt = K.qmc_fisher_tables(gaussians(mus, vars), seed=100 + r, samples_per_stratum=j)
        out.append(np.asarray(QFI(qt, everywhere(b, tuple(x.shape[0] for x in mus)), key=jax.random.PRNGKey(r),
                                  n_objects=m, n_poses=n, sigma_s=sigma)))
    out = np.stack(out)
    return out.mean(0), out.std(0, ddof=1) / np.sqrt(reps)


def test_unbiased_against_high_j_monte_carlo(rng, getkey, x64):
    levels, positions, dims, m, n = (2, 3), (3, 2), (2, 2), 2, 2
    mus, vars = random_model(rng, m * n, levels, positions, dims)
    b = as_jax_belief(random_belief(rng, m * n, levels))
    q, q_se = _replicates(mus, vars, b, m, n, reps=8, j=256)
    tables = MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=4000)
    fm, se = FISHER(tables, everywhere(b, positions), key=getkey(), n_objects=m, n_poses=n, with_stderr=True)
    tol = 4 * np.hypot(q_se, np.asarray(se)) + 1e-6
    assert np.all(np.abs(q - np.asarray(fm)) < tol), np.max(np.abs(q - np.asarray(fm)) / tol)


@pytest.mark.slow
def test_against_vegas_within_error_bars(rng, x64):
    """The 1-camera, 1-pose case of tests/test_fisher.py: every entry within
    4 combined standard errors of VEGAS's integral of eq. 5.28."""
    from test_fisher import vegas_fisher_entries

    sigma = 0.4
    mus, vars = random_model(rng, 2, (2,), (2,), (1,), spread=1.0)
    b = as_jax_belief(random_belief(rng, 2, (2,), concentration=4.0))
    log_p = np.asarray(K.log_joint(b))
    q, q_se = _replicates(mus, vars, b, 2, 1, reps=8, j=1024, sigma=sigma)
    for v, r, c, res in vegas_fisher_entries(mus, vars, log_p, sigma):
        tol = 4 * np.hypot(res.sdev, q_se[v, r, c]) + 1e-6
        assert abs(q[v, r, c] - res.mean) < tol, (v, r, c, q[v, r, c], res.mean, res.sdev, q_se[v, r, c])


def test_zero_recompiles_after_warm_up(rng, getkey):
    mus, vars = random_model(rng, 4, (2, 3), (3, 2), (2, 2))
    qt = K.qmc_fisher_tables(gaussians(mus, vars, dtype=jnp.float32), seed=0, samples_per_stratum=2)

    def belief():
        r = random_belief(rng, 4, (2, 3))
        return everywhere(K.Belief(jnp.asarray(r.log_pc, jnp.float32), tuple(jnp.asarray(x, jnp.float32) for x in r.log_pk)),
                          (3, 2))

    score = lambda b, k: K.crlb_criterion(K.qmc_fisher_information(qt, b, key=k, n_objects=2, n_poses=2))
    jax.block_until_ready(score(belief(), getkey()))
    with count_compiles() as later:
        for _ in range(4):
            jax.block_until_ready(score(belief(), getkey()))
    assert sum(later.values()) == 0, dict(later)


def test_planner_registry_entry(getkey, rng):
    from jaxrecog.planners import QMCCRLBPlanner, make_planner, planner_spec

    class Model:  # the fields a planner's from_model reads
        n_objects, n_poses, positions, cameras, levels = 2, 2, (3, 2), (0, 1), (0, 1)

    mus, vars = random_model(rng, 4, (2, 2), (3, 2), (2, 2))
    Model.likelihoods = K.gaussian_likelihoods(tuple(jnp.asarray(x, jnp.float32) for x in mus),
                                               tuple(jnp.asarray(x, jnp.float32) for x in vars))
    p = make_planner("crlb-qmc", Model, key=getkey(), samples=48, min_per_stratum=1)
    assert isinstance(p, QMCCRLBPlanner) and planner_spec("crlb-qmc").thesis == "crlb"
    assert p.tables.u_obj.shape == (4, 4)  # 48 samples / 16 strata = 3 per stratum -> 4 (a power of 2)
    b = everywhere(K.uniform_belief(4, (2, 2)), (3, 2))
    key = getkey()
    s = np.asarray(p.scores(b, key))
    assert s.shape == (6,) and np.all(np.isfinite(s))
    want = -K.crlb_criterion(K.qmc_fisher_information(p.tables, b, key=key, n_objects=2, n_poses=2))
    np.testing.assert_allclose(s, want, rtol=1e-6)
