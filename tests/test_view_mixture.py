"""The view mixture (``kernels/view_mixture.py``, kinds ``view-mixture`` and
``view-mixture-lowrank``) against NumPy / SciPy: the mixture density, the
one-component case, the moments and the sampler, the Bhattacharyya bound
(its formula, that it is a lower bound, that it is exact for well separated
components), scaling; training from a database's jitter rows (component 0 is
the thesis's Gaussian of the training image, the rest one per jitter image,
in database order), the errors of a database that cannot give every view its
components, the weights option; the model file; calibration, the pairwise
tables, the belief update and a recognizer step on a trained mixture."""

from __future__ import annotations

import functools
import json
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import jax.random as jr
import numpy as np
import pytest
from builders import make_database, odd_images, steps_stay_finite
from oracles import bhattacharyya_ref, joint_uniform_ref, joint_update_ref, kl_ref
from scipy.special import logsumexp
from scipy.stats import multivariate_normal, norm

from jaxrecog import ImageDatabase
from jaxrecog import kernels as K
from jaxrecog.calibration import CalibrationFeatures, CameraFeatures, calibrate_model
from jaxrecog.features import project
from jaxrecog.kernels.view_mixture import mixture_log_weights
from jaxrecog.modelfile import ModelFileContentError, _content_hash, load_model, load_model_meta, save_model
from jaxrecog.planners import make_planner
from jaxrecog.recognizer import Recognizer
from jaxrecog.train import train_model

_FAMILIES = pytest.mark.parametrize("lowrank", [False, True], ids=["diag", "lowrank"])


# -- references ---------------------------------------------------------------

def _mixture(rng, lowrank, V=2, C=3, L=2, M=3, k=4, r=2):
    """A random mixture of either family with non-uniform weights, and its
    parameters as NumPy float64 (``cov [V, C, L, M, K, K]``)."""
    mu = rng.normal(size=(V, C, L, M, k))
    w = rng.dirichlet(np.full(M, 1.5), size=(V, C, L))
    ref = SimpleNamespace(mu=mu, w=w, r=r if lowrank else 0)
    if lowrank:
        ref.W = rng.normal(size=(V, C, L, M, k, r)) * 0.8
        ref.psi = rng.uniform(0.2, 1.0, size=(V, C, L, M, k))
        ref.cov = ref.W @ np.swapaxes(ref.W, -1, -2) + ref.psi[..., None] * np.eye(k)
        lik = K.LowRankViewMixture(jnp.asarray(mu), jnp.asarray(ref.W), jnp.asarray(ref.psi), jnp.asarray(np.log(w)))
    else:
        ref.var = rng.uniform(0.2, 1.0, size=(V, C, L, M, k))
        ref.cov = ref.var[..., None] * np.eye(k)
        lik = K.ViewMixture(jnp.asarray(mu), jnp.asarray(ref.var), jnp.asarray(np.log(w)))
    return lik, ref


def _component_logpdf_ref(g, mu, cov, w):
    """log w[c, l, m] + log N(g; mu[c, l, m], cov[c, l, m]) -> ``[*B, C, L, M]``,
    one component at a time with SciPy (one position's arrays)."""
    g = np.asarray(g, np.float64)
    batch, k = g.shape[:-1], g.shape[-1]
    flat = g.reshape(-1, k)
    out = np.empty((flat.shape[0],) + w.shape)
    for c, l, m in np.ndindex(*w.shape):
        ld = multivariate_normal(mu[c, l, m], cov[c, l, m]).logpdf(flat)
        out[:, c, l, m] = np.log(w[c, l, m]) + np.atleast_1d(ld)
    return out.reshape(batch + w.shape)


def _mixture_logpdf_ref(g, mu, cov, w):
    """log sum_m w[c, l, m] N(g; mu[c, l, m], cov[c, l, m]) -> ``[*B, C, L]``."""
    return logsumexp(_component_logpdf_ref(g, mu, cov, w), axis=-1)


def _mixture_cov_ref(mu, cov, w):
    """Mixture covariance by the law of total covariance (within plus between components)."""
    mean = np.einsum("clm,clmk->clk", w, mu)
    dev = mu - mean[:, :, None, :]
    return mean, np.einsum("clm,clmkj->clkj", w, cov) + np.einsum("clm,clmk,clmj->clkj", w, dev, dev)


def _component_covs(one):
    """``[C, L, M, K, K]`` float64 covariances of a one-position mixture's components, from its fields."""
    if isinstance(one, K.LowRankViewMixture):
        w = np.asarray(one.W, np.float64)
        return w @ np.swapaxes(w, -1, -2) + np.asarray(one.psi, np.float64)[..., None] * np.eye(w.shape[-2])
    var = np.asarray(one.var, np.float64)
    return var[..., None] * np.eye(var.shape[-1])


def _draw_mixture(rng, mu, cov, w, n):
    """``n`` draws of one mixture (NumPy: component by weight, then its Gaussian)."""
    m = rng.choice(len(w), size=n, p=w)
    x = np.empty((n, mu.shape[-1]))
    for j in range(len(w)):
        sel = m == j
        x[sel] = rng.multivariate_normal(mu[j], cov[j], size=int(sel.sum()))
    return x


# -- the family -----------------------------------------------------------------

@_FAMILIES
def test_log_density_is_the_scipy_mixture_for_any_batch(rng, x64, strict_dtype_promotion, lowrank):
    lik, ref = _mixture(rng, lowrank)
    assert lik.n_components == 3 and lik.noise_dim == 1 + ref.r + 4
    both = jax.jit(lambda one, g: (one.log_density(g), one.component_log_density(g)))   # one compile per shape
    for batch in [(), (5,), (2, 3)]:
        g = rng.normal(size=batch + (4,)) * 1.5
        g.reshape(-1, 4)[0] += 25.0       # one point far from every component: no underflow to -inf
        for v in range(2):
            got, comp = (np.asarray(x) for x in both(lik.at(v), jnp.asarray(g)))
            assert got.shape == batch + (3, 2) and comp.shape == batch + (3, 2, 3)
            want = _component_logpdf_ref(g, ref.mu[v], ref.cov[v], ref.w[v])
            np.testing.assert_allclose(comp, want, rtol=1e-12)
            np.testing.assert_allclose(got, logsumexp(want, axis=-1), rtol=1e-12)


def test_one_component_is_the_component_family(rng, x64, strict_dtype_promotion):
    V, C, L, k, r = 2, 3, 2, 4, 2
    mu = rng.normal(size=(V, C, L, k))
    var = rng.uniform(0.2, 1.0, size=(V, C, L, k))
    W = rng.normal(size=(V, C, L, k, r)) * 0.8
    cov_low = W @ np.swapaxes(W, -1, -2) + var[..., None] * np.eye(k)
    one = jnp.zeros((V, C, L, 1))
    pairs = [
        (K.DiagonalGaussian(jnp.asarray(mu), jnp.asarray(var)),
         K.ViewMixture(jnp.asarray(mu[..., None, :]), jnp.asarray(var[..., None, :]), one),
         var[..., None] * np.eye(k)),
        (K.LowRankGaussian(jnp.asarray(mu), jnp.asarray(W), jnp.asarray(var)),
         K.LowRankViewMixture(jnp.asarray(mu[..., None, :]), jnp.asarray(W[..., None, :, :]),
                              jnp.asarray(var[..., None, :]), one),
         cov_low),
    ]
    g = jnp.asarray(rng.normal(size=(6, k)))
    factor = jnp.asarray([2.5, 0.6])

    @jax.jit
    def compare(a, b, z):
        """(mixture's, component's) of every method; the mixture draws from z, the component from z[1:]."""
        return [(b.log_density(g), a.log_density(g)), (b.bhattacharyya(), a.bhattacharyya()), (b.mean(), a.mean()),
                (b.covariance(), a.covariance()), (b.variance(), a.variance()), (b.sample(z), a.sample(z[..., 1:])),
                (b.scaled(factor).log_density(g), a.scaled(factor).log_density(g))]

    divergences = jax.jit(lambda b: (b.divergence("bhattacharyya"), b.divergence("kl")))
    for comp, mix, cov in pairs:
        assert mix.noise_dim == comp.noise_dim + 1 and mix.n_components == 1
        for v in range(V):
            z = jnp.asarray(rng.normal(size=(C, L, 5, comp.noise_dim + 1)))
            for got, want in compare(comp.at(v), mix.at(v), z):
                np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-13)
            # the planners' divergences: the bound is the exact Gaussian D_B, and the KL
            # fallback (moment-matched Gaussians) is exact with one component
            bhat, kl = divergences(mix.at(v))
            np.testing.assert_allclose(bhat, bhattacharyya_ref(mu[v], cov[v]), rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(kl, kl_ref(mu[v], cov[v]), rtol=1e-9, atol=1e-11)


def test_float32_moments_do_not_cancel():
    """Tiny variances beside large means: E[gg^T] - mean mean^T would lose them in float32
    (0.0 here with weights 0.6/0.2/0.2); the moments about the mixture mean keep them."""
    mu = jnp.full((1, 1, 3, 2), 0.5, jnp.float32)
    var = jnp.full((1, 1, 3, 2), 1e-8, jnp.float32)
    lik = K.ViewMixture(mu, var, jnp.log(jnp.asarray([[[0.6, 0.2, 0.2]]], jnp.float32)))
    np.testing.assert_allclose(np.asarray(lik.variance()), 1e-8, rtol=1e-3)
    np.testing.assert_allclose(np.diagonal(np.asarray(lik.covariance()), axis1=-2, axis2=-1), 1e-8, rtol=1e-3)
    assert np.all(np.isfinite(np.asarray(lik.divergence("kl"))))


@_FAMILIES
def test_moments_are_the_mixtures(rng, x64, strict_dtype_promotion, lowrank):
    lik, ref = _mixture(rng, lowrank)
    moments = jax.jit(lambda one: (one.mean(), one.covariance(), one.variance()))
    for v in range(2):
        got_mean, got_cov, got_var = moments(lik.at(v))
        mean, cov = _mixture_cov_ref(ref.mu[v], ref.cov[v], ref.w[v])
        np.testing.assert_allclose(got_mean, mean, rtol=1e-13, atol=1e-14)
        np.testing.assert_allclose(got_cov, cov, rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(got_var, np.diagonal(cov, axis1=-2, axis2=-1), rtol=1e-12, atol=1e-13)


@_FAMILIES
def test_sampler_picks_components_by_weight_and_has_the_moments(rng, x64, strict_dtype_promotion, lowrank):
    C, L, M, k, n = 2, 2, 3, 3, 40_000
    lik, ref = _mixture(rng, lowrank, V=1, C=C, L=L, M=M, k=k, r=1)
    mu, cov, w = ref.mu[0], ref.cov[0], ref.w[0]
    one = lik.at(0)
    z = rng.normal(size=(C, L, n, one.noise_dim))
    # the first M draws: u = Phi(z[0]) in the middle of component m's weight interval picks m
    z[:, :, :M, 0] = norm.ppf(np.cumsum(w, axis=-1) - 0.5 * w)
    g, mean, cov_mix = (np.asarray(x) for x in jax.jit(lambda o, z: (o.sample(z), o.mean(), o.covariance()))(
        one, jnp.asarray(z)))
    assert g.shape == (C, L, n, k)
    # every draw is one component's draw from z[1:] (NumPy's form of each component)
    zc = z[..., 1:]
    if lowrank:
        cand = (mu[:, :, :, None, :] + np.einsum("clmkr,cljr->clmjk", ref.W[0], zc[..., :1])
                + np.sqrt(ref.psi[0])[:, :, :, None, :] * zc[:, :, None, :, 1:])
    else:
        cand = mu[:, :, :, None, :] + np.sqrt(ref.var[0])[:, :, :, None, :] * zc[:, :, None]
    dist = np.linalg.norm(g[:, :, None] - cand, axis=-1)                     # [C, L, M, n]
    pick = np.argmin(dist, axis=2)
    assert np.max(np.min(dist, axis=2)) < 1e-12
    np.testing.assert_array_equal(pick[:, :, :M], np.broadcast_to(np.arange(M), (C, L, M)))
    freq = np.stack([np.mean(pick == m, axis=-1) for m in range(M)], axis=-1)  # [C, L, M]
    assert np.all(np.abs(freq - w) < 5 * np.sqrt(w * (1 - w) / n)), (freq, w)
    # Monte Carlo moments against mean() / covariance()
    sd = np.sqrt(np.diagonal(cov_mix, axis1=-2, axis2=-1))
    assert np.all(np.abs(g.mean(axis=2) - mean) < 5 * sd / np.sqrt(n))
    d = g - mean[:, :, None, :]
    prod = d[..., :, None] * d[..., None, :]                                 # [C, L, n, K, K]
    se = prod.std(axis=2) / np.sqrt(n)
    assert np.all(np.abs(prod.mean(axis=2) - cov_mix) < 5 * se)


@_FAMILIES
def test_bhattacharyya_is_the_pairwise_bound_formula_and_the_planners_read_the_moments(rng, x64, strict_dtype_promotion, lowrank):
    C, L, M, k = 3, 2, 3, 4
    lik, ref = _mixture(rng, lowrank, C=C, L=L, M=M, k=k)
    both = jax.jit(lambda one: (one.bhattacharyya(), one.divergence("bhattacharyya")))
    for v in range(2):
        w = ref.w[v]
        d = bhattacharyya_ref(ref.mu[v].reshape(C, L * M, k), ref.cov[v].reshape(C, L * M, k, k))
        d = d.reshape(C, L, M, C, L, M)
        want = np.empty((C, L, C, L))
        for a in np.ndindex(C, L):
            for b in np.ndindex(C, L):
                x = 0.5 * np.log(w[a])[:, None] + 0.5 * np.log(w[b])[None, :] - d[a[0], a[1], :, b[0], b[1], :]
                want[a + b] = -logsumexp(x)
        got, div = (np.asarray(x) for x in both(lik.at(v)))
        np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12)
        # between a mixture and itself the bound is <= 0 (the true distance is 0)
        assert np.all(np.diagonal(np.diagonal(got, axis1=0, axis2=2), axis1=0, axis2=1) <= 1e-12)
        # the planners' divergence: the moment-matched Gaussians' closed form
        mean = np.einsum("clm,clmk->clk", w, ref.mu[v])
        dev = ref.mu[v] - mean[:, :, None]
        cov = np.einsum("clm,clmkj->clkj", w, ref.cov[v] + dev[..., :, None] * dev[..., None, :])
        np.testing.assert_allclose(div, bhattacharyya_ref(mean, cov), rtol=1e-10, atol=1e-12)


def _two_mixtures(lowrank, mu, var, w, wvec):
    """A one-position likelihood with two classes (``C = 2``, ``L = 1``, ``M = 2``,
    ``K = 2``) from per-class component means / variances / weights; the
    low-rank family adds one factor ``wvec`` per component.  Returns the
    likelihood and each class's covariances ``[2, M, K, K]``."""
    mu, var, w = np.asarray(mu, float), np.asarray(var, float), np.asarray(w, float)
    log_w = jnp.asarray(np.log(w)[None, :, None, :])
    if lowrank:
        W = np.asarray(wvec, float)[..., None]
        cov = W @ np.swapaxes(W, -1, -2) + var[..., None] * np.eye(2)
        lik = K.LowRankViewMixture(jnp.asarray(mu[None, :, None]), jnp.asarray(W[None, :, None]),
                                   jnp.asarray(var[None, :, None]), log_w)
    else:
        cov = var[..., None] * np.eye(2)
        lik = K.ViewMixture(jnp.asarray(mu[None, :, None]), jnp.asarray(var[None, :, None]), log_w)
    return lik.at(0), cov


def _bhattacharyya_mc(rng, mu, cov, w, n):
    """D_B(p, q) = -log E_p[sqrt(q / p)] for class 0 = p, class 1 = q, by Monte
    Carlo (NumPy draws, SciPy densities), and its standard error
    (Var_p sqrt(q/p) = 1 - BC^2 exactly: sd of the estimate of D = sqrt(1 - BC^2) / (BC sqrt n))."""
    x = _draw_mixture(rng, mu[0], cov[0], w[0], n)
    lp = _mixture_logpdf_ref(x, mu[:, None], cov[:, None], w[:, None])      # [n, 2, 1]
    bc = float(np.mean(np.exp(0.5 * (lp[:, 1, 0] - lp[:, 0, 0]))))
    return -np.log(bc), np.sqrt(max(1.0 - bc * bc, 0.0)) / (bc * np.sqrt(n))


_BHATTACHARYYA = jax.jit(lambda one: one.bhattacharyya())
_VAR = [[(1.0, 0.5), (0.6, 1.2)], [(0.8, 0.9), (1.1, 0.4)]]
_WVEC = [[(0.6, 0.2), (-0.3, 0.5)], [(0.1, -0.4), (0.5, 0.5)]]


@_FAMILIES
def test_bhattacharyya_bound_is_below_the_true_distance(rng, x64, strict_dtype_promotion, lowrank):
    """Overlapping components: the bound is a lower bound of the Monte Carlo
    distance, and strictly below it here (the example tells them apart)."""
    mu = [[(0.0, 0.0), (1.5, 0.5)], [(0.5, -0.3), (2.0, 1.0)]]
    w = [(0.7, 0.3), (0.4, 0.6)]
    lik, cov = _two_mixtures(lowrank, mu, _VAR, w, _WVEC)
    d = np.asarray(_BHATTACHARYYA(lik))[:, 0, :, 0]
    np.testing.assert_allclose(d, d.T, rtol=1e-12)
    true, se = _bhattacharyya_mc(rng, np.asarray(mu), cov, np.asarray(w), 200_000)
    assert d[0, 1] <= true + 5 * se, (d[0, 1], true, se)
    assert d[0, 1] < true - 5 * se, (d[0, 1], true, se)


@_FAMILIES
def test_bhattacharyya_bound_is_exact_for_well_separated_components(rng, x64, strict_dtype_promotion, lowrank):
    """Each component of p sits near one of q, 40 sd from the others: the
    cross terms vanish and sqrt(sum) = sum sqrt holds pointwise, so the bound
    is the distance (to e^-100)."""
    mu = [[(0.0, 0.0), (40.0, 0.0)], [(0.4, -0.3), (40.5, 0.6)]]
    w = [(0.35, 0.65), (0.55, 0.45)]
    lik, cov = _two_mixtures(lowrank, mu, _VAR, w, _WVEC)
    d = float(np.asarray(_BHATTACHARYYA(lik))[0, 0, 1, 0])
    true, se = _bhattacharyya_mc(rng, np.asarray(mu), cov, np.asarray(w), 200_000)
    assert true > 0.05 and se < 0.01 * true        # a distance well resolved by the Monte Carlo
    assert abs(d - true) < 5 * se, (d, true, se)


@_FAMILIES
def test_scaled_multiplies_every_components_covariance(rng, x64, strict_dtype_promotion, lowrank):
    lik, ref = _mixture(rng, lowrank)
    factor = np.array([3.0, 0.7])
    g = rng.normal(size=(5, 4)) * 1.5

    @jax.jit
    def scaled(one, f, x):
        s = one.scaled(f)
        # calibration's path: scaling_terms once, scaled_log_density per factor
        return s, s.log_density(x), s.covariance(), one.scaled_log_density(one.scaling_terms(x), jnp.log(f))

    for v in range(2):
        one = lik.at(v)
        s, ld, cov_s, fast = scaled(one, jnp.asarray(factor), jnp.asarray(g))
        assert type(s) is type(one)
        np.testing.assert_array_equal(s.log_w, one.log_w)
        cov = ref.cov[v] * factor[None, :, None, None, None]
        want = _mixture_logpdf_ref(g, ref.mu[v], cov, ref.w[v])
        np.testing.assert_allclose(ld, want, rtol=1e-12)
        np.testing.assert_allclose(cov_s, _mixture_cov_ref(ref.mu[v], cov, ref.w[v])[1], rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(fast, want, rtol=1e-12)


# -- mixture weights -------------------------------------------------------------

def test_mixture_log_weights():
    np.testing.assert_allclose(np.exp(mixture_log_weights(3)), [1 / 3] * 3, rtol=1e-15)
    np.testing.assert_allclose(np.exp(mixture_log_weights(3, 0.6)), [0.6, 0.2, 0.2], rtol=1e-15)
    np.testing.assert_allclose(np.exp(mixture_log_weights(4, 0.25)), [0.25] * 4, rtol=1e-15)
    np.testing.assert_array_equal(mixture_log_weights(1), [0.0])
    np.testing.assert_array_equal(mixture_log_weights(1, 1.0), [0.0])
    with pytest.raises(ValueError, match="at least one component"):
        mixture_log_weights(0)
    for m, w0 in [(3, 0.0), (3, 1.0), (3, 1.5), (3, -0.2), (3, float("nan")), (1, 0.5), (2, 2)]:
        with pytest.raises(ValueError, match="nominal_weight must be in"):
            mixture_log_weights(m, w0)


# -- training ---------------------------------------------------------------------

def _with_jitter(db: ImageDatabase, jitter) -> ImageDatabase:
    """``db`` plus ``jitter`` rows ``(camera, position, object, pose, image)``."""
    extra = np.stack([j[4] for j in jitter])
    cols = [np.concatenate([getattr(db, f), [j[k] for j in jitter]])
            for k, f in enumerate(("camera", "position", "object", "pose"))]
    return ImageDatabase.from_arrays(np.concatenate([db.images, extra]), *cols,
                                     np.concatenate([db.split, ["jitter"] * len(jitter)]))


_KW = dict(kind="DB2", n_components=3, samples_per_image=10)
_SHIFTS = ((0, 5), (4, 0))


def _jitter_rows(db, same=()):
    """Two jitter images per training view (the training image rolled by each of
    ``_SHIFTS``), all first ones, then all second ones; ``same``: ``(position,
    class, j)`` whose ``j``-th jitter image is the training image itself."""
    rows = np.flatnonzero(db.split == "train")
    out = []
    for j, shift in enumerate(_SHIFTS):
        for r in rows:
            c = db.object[r] * db.n_poses + db.pose[r]
            img = db.images[r] if (db.position[r], c, j) in same else np.roll(db.images[r], shift, axis=(0, 1))
            out.append((db.camera[r], db.position[r], db.object[r], db.pose[r], img))
    return out


_SAME = ((0, 1, 0), (0, 2, 1))   # class 1: component 1 is its training image, class 2: component 2


@pytest.fixture(scope="module")
def trained():
    """One camera, 2 positions, 2 objects x 2 poses (C = 4), DB2 (L = 6), an
    off-grid test image per view, and two jitter images per view (M = 3)."""
    db = make_database(positions=(2,), n_objects=2, n_poses=2, image_shape=(16, 20), n_test=1, view_offset=0.4)
    jdb = _with_jitter(db, _jitter_rows(db, _SAME))
    sampled = {"occluded_jitter": "sampled"}   # every component from its own samples (the default translates)
    mix, info = train_model(jdb, likelihood="view-mixture", likelihood_options=sampled, view_jitter=True,
                            return_info=True, **_KW)
    low, low_info = train_model(jdb, likelihood="view-mixture-lowrank", likelihood_options={"rank": 2, **sampled},
                                view_jitter=True, return_info=True, **_KW)
    return SimpleNamespace(
        db=db, jdb=jdb, mix=mix, info=info, low=low, low_info=low_info,
        plain=train_model(db, likelihood="gaussian-diag", **_KW),
        pooled=train_model(jdb, likelihood="gaussian-diag", view_jitter=True, **_KW),
        nominal=train_model(jdb, likelihood="view-mixture", likelihood_options={"nominal_weight": 0.6, **sampled},
                            view_jitter=True, **_KW),
    )


def test_training_makes_one_component_per_rendered_view(trained):
    lik, plain = trained.mix.cameras[0].likelihood, trained.plain.cameras[0].likelihood
    assert isinstance(lik, K.ViewMixture) and lik.mu.shape == (2, 4, 6, 3, 3) and lik.log_w.shape == (2, 4, 6, 3)
    assert lik.mu.dtype == jnp.float32 and lik.problems() == []
    np.testing.assert_allclose(np.exp(np.asarray(lik.log_w, np.float64)), 1 / 3, rtol=1e-6)
    mu, var = np.asarray(lik.mu), np.asarray(lik.var)
    # component 0: exactly the thesis's Gaussian of the training image, trained without jitter
    np.testing.assert_array_equal(mu[..., 0, :], np.asarray(plain.mu))
    np.testing.assert_array_equal(var[..., 0, :], np.asarray(plain.var))
    # the jitter images in database order: the one identical to the training image gives
    # component 0 again (same augmentation draws), a rolled one does not
    for (v, c, j) in _SAME:
        np.testing.assert_allclose(mu[v, c, :, j + 1], mu[v, c, :, 0], rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(var[v, c, :, j + 1], var[v, c, :, 0], rtol=1e-5, atol=1e-9)
        other = 2 - j
        assert not np.allclose(mu[v, c, :, other], mu[v, c, :, 0], atol=1e-3)
    rolled = np.ones(mu.shape[:2] + (3,), bool)
    rolled[..., 0] = False
    for (v, c, j) in _SAME:
        rolled[v, c, j + 1] = False
    dev = np.abs(mu - mu[..., :1, :]).max(axis=(2, 4))                     # [V, C, M]
    assert np.all(dev[rolled] > 1e-3)
    # all components together: the pooled Gaussian (gaussian-diag with view jitter) has the
    # uniform mixture's mean and variance (equal sample counts per image)
    pooled = trained.pooled.cameras[0].likelihood
    mean = jax.vmap(lambda x: x.mean())(lik)
    variance = jax.vmap(lambda x: x.variance())(lik)
    np.testing.assert_allclose(mean, np.asarray(pooled.mu), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(variance, np.asarray(pooled.var), rtol=1e-4)
    assert trained.info.params["likelihood"] == "view-mixture"
    assert trained.info.params["view_jitter"] == {"mode": "components", "images": 16, "views": 8, "positions": 2}


def test_training_the_lowrank_mixture(trained):
    low, mix = trained.low.cameras[0].likelihood, trained.mix.cameras[0].likelihood
    assert isinstance(low, K.LowRankViewMixture) and low.W.shape == (2, 4, 6, 3, 3, 2)
    assert low.noise_dim == 1 + 2 + 3 and low.problems() == []
    assert trained.low_info.params["likelihood_options"] == {"rank": 2, "occluded_jitter": "sampled"}
    # the same samples per component: the same means as the diagonal mixture
    np.testing.assert_array_equal(np.asarray(low.mu), np.asarray(mix.mu))
    np.testing.assert_array_equal(np.asarray(low.log_w), np.asarray(mix.log_w))


def test_nominal_weight_option(trained):
    nom, mix = trained.nominal.cameras[0].likelihood, trained.mix.cameras[0].likelihood
    np.testing.assert_allclose(np.exp(np.asarray(nom.log_w, np.float64)),
                               np.broadcast_to([0.6, 0.2, 0.2], nom.log_w.shape), rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(nom.mu), np.asarray(mix.mu))    # weights only
    np.testing.assert_array_equal(np.asarray(nom.var), np.asarray(mix.var))
    with pytest.raises(ValueError, match="nominal_weight must be in"):
        train_model(trained.jdb, likelihood="view-mixture", likelihood_options={"nominal_weight": 1.0},
                    view_jitter=True, **_KW)
    with pytest.raises(ValueError, match="has no option 'rank'"):
        train_model(trained.jdb, likelihood="view-mixture", likelihood_options={"rank": 2}, view_jitter=True, **_KW)


@pytest.mark.parametrize("name", ["view-mixture", "view-mixture-lowrank"])
def test_translated_occluded_jitter_components(trained, name):
    """``occluded_jitter="translated"``: the jitter images are augmented at level
    0 only; an occluded jitter component is the training view's component of
    that level moved by the level-0 offset, with its covariance; the rest are
    the sampled mixture's own components."""
    opts = {"rank": 2} if name.endswith("lowrank") else {}
    sampled = (trained.low if opts else trained.mix).cameras[0].likelihood
    model, info = train_model(trained.jdb, likelihood=name, view_jitter=True, return_info=True,
                              likelihood_options=opts, **_KW)   # the default
    assert info.params["likelihood_options"] == {**opts, "occluded_jitter": "translated"}
    lik = model.cameras[0].likelihood
    assert type(lik) is type(sampled) and lik.problems() == []
    fields = [f for f in type(lik).field_shapes if f not in ("mu", "log_w")]
    get = lambda x, f: np.asarray(getattr(x, f), np.float64)  # noqa: E731
    tol = dict(rtol=1e-5, atol=1e-7)
    # level 0 (every image augmented) and the training view's components: the sampled mixture's
    for f in ("mu", *fields):
        np.testing.assert_allclose(get(lik, f)[:, :, 0], get(sampled, f)[:, :, 0], **tol)
        np.testing.assert_allclose(get(lik, f)[:, :, 1:, 0], get(sampled, f)[:, :, 1:, 0], **tol)
        # the occluded jitter components share the training view's covariance of their level
        np.testing.assert_allclose(get(lik, f)[:, :, 1:, 1:],
                                   np.broadcast_to(get(lik, f)[:, :, 1:, :1], get(lik, f)[:, :, 1:, 1:].shape)
                                   if f != "mu" else get(lik, f)[:, :, 1:, 1:], **tol)
    mu = get(lik, "mu")
    want = mu[:, :, 1:, :1] + (mu[:, :, :1, 1:] - mu[:, :, :1, :1])
    np.testing.assert_allclose(mu[:, :, 1:, 1:], want, rtol=1e-5, atol=1e-6)
    # a jitter image equal to the training image: no offset, its components are the training view's
    for (v, c, j) in _SAME:
        np.testing.assert_allclose(mu[v, c, :, j + 1], mu[v, c, :, 0], rtol=1e-5, atol=1e-6)
    # a rolled jitter image: its occluded components differ from the sampled ones (not sampled)
    assert not np.allclose(mu[:, :, 1:, 1:], get(sampled, "mu")[:, :, 1:, 1:], atol=1e-4)
    with pytest.raises(ValueError, match="occluded_jitter must be one of sampled, translated"):
        train_model(trained.jdb, likelihood=name, view_jitter=True, likelihood_options={"occluded_jitter": "x"},
                    **_KW)


@_FAMILIES
def test_translated_fit_reads_no_occluded_jitter_moments(rng, lowrank):
    """``fit(occluded_jitter="translated")`` never reads the moments it derives
    (NaN there is fine), and equals the sampled fit where it fits."""
    c, l, m, k = 3, 4, 3, 5
    mean = rng.normal(size=(c, l, m, k))
    a = rng.normal(size=(c, l, m, k, k))
    cov = a @ np.swapaxes(a, -1, -2) / k + np.eye(k)
    cls, second, opts = (K.LowRankViewMixture, cov, {"rank": 2}) if lowrank else \
        (K.ViewMixture, np.diagonal(cov, axis1=-2, axis2=-1).copy(), {})
    floor = np.full((c, l), 1e-3)
    blank_mean, blank_second = mean.copy(), second.copy()
    blank_mean[:, 1:, 1:] = np.nan
    blank_second[:, 1:, 1:] = np.nan
    tr = cls.fit(blank_mean, blank_second, floor, occluded_jitter="translated", **opts)
    full = cls.fit(mean, second, floor, **opts)
    for f in type(tr).field_shapes:
        x, y = np.asarray(getattr(tr, f)), np.asarray(getattr(full, f))
        assert np.all(np.isfinite(x)), f
        np.testing.assert_allclose(x[:, 0], y[:, 0], rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(x[:, :, 0], y[:, :, 0], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(np.asarray(tr.mu)[:, 1:, 1:],
                               mean[:, 1:, :1] + mean[:, :1, 1:] - mean[:, :1, :1], rtol=1e-12)
    with pytest.raises(ValueError, match="occluded_jitter must be one of"):
        cls.fit(mean, second, floor, occluded_jitter="pooled", **opts)


def test_training_errors(trained):
    db, jdb = trained.db, trained.jdb
    with pytest.raises(ValueError, match="view jitter"):
        train_model(jdb, likelihood="view-mixture", **_KW)
    with pytest.raises(ValueError, match="no 'jitter' rows"):
        train_model(db, likelihood="view-mixture", view_jitter=True, **_KW)
    rows = _jitter_rows(db)
    # class 3 of position 1 loses its second jitter image
    c3 = [i for i, j in enumerate(rows) if j[1] == 1 and j[2] * 2 + j[3] == 3]
    uneven = _with_jitter(db, [j for i, j in enumerate(rows) if i != c3[1]])
    with pytest.raises(ValueError, match="same number"):
        train_model(uneven, likelihood="view-mixture", view_jitter=True, **_KW)
    # position 1 has no jitter image at all
    half = _with_jitter(db, [j for j in rows if j[1] == 0])
    with pytest.raises(ValueError, match=r"\(0, 1\).*no jitter images"):
        train_model(half, likelihood="view-mixture-lowrank", view_jitter=True, **_KW)
    # the pooled family trains on it (jitter where there is any)
    assert isinstance(train_model(half, view_jitter=True, **_KW).cameras[0].likelihood, K.DiagonalGaussian)


# -- model file -------------------------------------------------------------------

def _rewritten(src, dst, change):
    with np.load(src) as z:
        d = {k: z[k] for k in z.files}
    meta = json.loads(bytes(d["meta"]).decode())
    change(d)
    meta["content_sha256"] = _content_hash({k: v for k, v in d.items() if "." in k})
    d["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    np.savez(dst, **d)
    return dst


def _set(field, index, value):
    def change(d):
        d[field] = d[field].copy()
        d[field][index] = value
    return change


def _add(field, index, value):
    def change(d):
        d[field] = d[field].copy()
        d[field][index] += value
    return change


def test_model_file_round_trip(tmp_path, trained):
    for name, model, info in [("view-mixture", trained.mix, trained.info),
                              ("view-mixture-lowrank", trained.low, trained.low_info)]:
        p = save_model(tmp_path / f"{name}.npz", model, training=info.params)
        back = load_model(p)
        assert back.likelihood_kinds == (name,) and load_model_meta(p)["likelihoods"] == [name]
        assert type(back.cameras[0].likelihood) is type(model.cameras[0].likelihood)
        # the stored arrays byte for byte; the derived ones (low-rank whitening, not stored) are
        # recomputed on load from the float32 arrays: equal to float32 rounding
        for cam_a, cam_b in zip(model.cameras, back.cameras):
            a, b = cam_a.likelihood.arrays(), cam_b.likelihood.arrays()
            assert a.keys() == b.keys()
            assert all(np.asarray(a[f]).tobytes() == np.asarray(b[f]).tobytes() for f in a)
            for f in type(cam_a.likelihood).component.derived_shapes:
                np.testing.assert_allclose(np.asarray(getattr(cam_b.likelihood, f)),
                                           np.asarray(getattr(cam_a.likelihood, f)), rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("name, change, message", [
    ("view-mixture", _add("camera0.log_w", (1, 2, 3), 0.1), "camera0.log_w has mixture weights that do not sum to 1"),
    ("view-mixture", _set("camera0.log_w", (0, 0, 0, 1), -30.0),
     "camera0.log_w has mixture weights that do not sum to 1"),
    ("view-mixture", _set("camera0.var", (1, 0, 2, 1, 0), 0.0), "camera0.var has non-positive variances"),
    ("view-mixture", _set("camera0.var", (0, 3, 0, 2, 2), -1.0), "camera0.var has non-positive variances"),
    ("view-mixture", lambda d: d.update({"camera0.log_w": d["camera0.log_w"][..., :2]}),
     r"camera0.log_w has shape \(2, 4, 6, 2\), expected \(2, 4, 6, 3\)"),
    ("view-mixture-lowrank", _set("camera0.psi", (0, 1, 0, 2, 1), 0.0), "camera0.psi has non-positive variances"),
    ("view-mixture-lowrank", _add("camera0.log_w", (0, 0, 0, 0), -0.5),
     "camera0.log_w has mixture weights that do not sum to 1"),
])
def test_bad_fields_are_one_line_errors(tmp_path, trained, name, change, message):
    model = trained.mix if name == "view-mixture" else trained.low
    good = save_model(tmp_path / "good.npz", model)
    with pytest.raises(ModelFileContentError, match=message) as e:
        load_model(_rewritten(good, tmp_path / "bad.npz", change))
    assert "\n" not in str(e.value) and str(tmp_path / "bad.npz") in str(e.value)


# -- calibration, planners, belief -------------------------------------------------

def test_calibration_scales_the_trained_mixture(trained, rng):
    """Held-out features drawn from the mixture with every covariance times 4:
    calibration inflates and lowers the NLL, and the calibrated likelihood is
    the SciPy mixture with the covariances times the fitted factors."""
    model = trained.mix
    lik = model.cameras[0].likelihood
    V, C, L, M, k = lik.mu.shape
    per = 40
    z = jnp.asarray(rng.normal(size=(C, L, per, lik.noise_dim)), jnp.float32)
    g = np.stack([np.asarray(lik.at(v).scaled(jnp.full((L,), 4.0, jnp.float32)).sample(z)) for v in range(V)])
    g = g[:, :, 0]                                                              # level 0 only: [V, C, per, K]
    pos, cls = np.repeat(np.arange(V), C * per), np.tile(np.repeat(np.arange(C), per), V)
    feats = CameraFeatures(g.reshape(-1, k).astype(np.float64), pos, cls)
    cal, info = calibrate_model(model, CalibrationFeatures((feats,)))
    s = np.asarray(info.factors[0], np.float64)                               # [V, L]
    assert np.all(s > 1.0) and np.all(info.nll_after[0] <= info.nll_before[0])
    x = rng.normal(size=(3, k)) * 0.05 + np.asarray(lik.mu[0, 0, 0, 0], np.float64)
    w = np.exp(np.asarray(lik.log_w, np.float64))
    cov = np.asarray(lik.var, np.float64)[..., None] * np.eye(k)
    for v in range(V):
        want = _mixture_logpdf_ref(x, np.asarray(lik.mu[v], np.float64), cov[v] * s[v][None, :, None, None, None], w[v])
        got = np.asarray(cal.cameras[0].likelihood.at(v).log_density(jnp.asarray(x, jnp.float32)), np.float64)
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-3)



@_FAMILIES
def test_the_planners_divergence_tells_overlapping_look_alikes_apart(rng, x64, strict_dtype_promotion, lowrank):
    """Two views 0.5 sd apart per class, the second class the first moved 0.6 sd
    (a sticker): the pairwise bound collapses below 0 (its cross terms sum past
    1), so a planner reading it would see the pair as one; the moment-matched
    divergence is near the distance the Monte Carlo finds, and the pairwise
    tables read it."""
    mu = [[(0.0, 0.0), (0.5, 0.0)], [(0.0, 0.6), (0.5, 0.6)]]
    var = [[(1.0, 1.0), (1.0, 1.0)], [(1.0, 1.0), (1.0, 1.0)]]
    wvec = [[(0.0, 0.0), (0.0, 0.0)], [(0.0, 0.0), (0.0, 0.0)]]
    w = [(0.5, 0.5), (0.5, 0.5)]
    lik, cov = _two_mixtures(lowrank, mu, var, w, wvec)
    bound = float(np.asarray(_BHATTACHARYYA(lik))[0, 0, 1, 0])
    used = float(np.asarray(jax.jit(lambda one: one.divergence("bhattacharyya"))(lik))[0, 0, 1, 0])
    true, se = _bhattacharyya_mc(rng, np.asarray(mu), cov, np.asarray(w), 200_000)
    assert bound < 0.0 < true
    assert abs(used - true) < max(5 * se, 0.02 * true), (used, true, se)
    tables = K.pairwise_tables((jax.tree.map(lambda x: x[None], lik),), kind="bhattacharyya")
    assert float(np.asarray(tables.log_w[0])[0, 0, 0, 1, 0]) == pytest.approx(-used, rel=1e-6)

@pytest.mark.parametrize("name", ["view-mixture", "view-mixture-lowrank"])
def test_pairwise_tables_and_the_belief_update(trained, name):
    model = trained.mix if name == "view-mixture" else trained.low
    lik = model.cameras[0].likelihood
    tables = {kind: jax.jit(functools.partial(K.pairwise_tables, kind=kind))(model.likelihoods)
              for kind in K.DIVERGENCES}
    for t in tables.values():
        for leaf in jax.tree.leaves(t):
            assert np.all(np.isfinite(np.asarray(leaf)))
    t = tables["bhattacharyya"]
    bhat = np.asarray(jax.jit(jax.vmap(lambda one: one.moment_matched_divergence("bhattacharyya")))(lik))
    for v in range(2):
        d = bhat[v]
        want = -np.maximum(d, 0.0)
        c, l = d.shape[:2]
        for a in np.ndindex(c, l):
            want[a + a] = 0.0
        np.testing.assert_allclose(np.asarray(t.log_w[0][v]), want, rtol=1e-5, atol=1e-5)
    # an off-grid test image (taken between the positions): the mixture log-likelihoods
    # against SciPy, and Bayes' rule on them against the joint-state reference
    db = trained.db
    (row,) = np.flatnonzero((db.split == "test") & (db.position == 1) & (db.object == 1) & (db.pose == 0))
    g = project(model, 0, 1, db.images[row])
    c_, l_ = lik.n_classes, lik.n_levels

    @jax.jit
    def bayes(liks, g):
        (ll,) = K.camera_log_likelihoods((g,), jnp.asarray([1]), liks)
        return ll, K.log_joint(K.update(K.uniform_belief(c_, (l_,), dtype=ll.dtype), (ll,)))

    ll, log_joint = bayes(model.likelihoods, g)
    one = lik.at(1)
    ref = _mixture_logpdf_ref(np.asarray(g, np.float64), np.asarray(one.mu, np.float64), _component_covs(one),
                              np.exp(np.asarray(one.log_w, np.float64)))
    np.testing.assert_allclose(np.asarray(ll, np.float64), ref, rtol=2e-4, atol=2e-3)
    joint = np.exp(np.asarray(log_joint, np.float64))
    want = np.exp(joint_update_ref(joint_uniform_ref(c_, (l_,)), [ref]))
    assert np.all(np.isfinite(joint)) and abs(joint.sum() - 1.0) < 1e-5
    np.testing.assert_allclose(joint, want, atol=1e-4)
    assert int(np.argmax(joint.sum(axis=1))) == 2                            # object 1, pose 0


@pytest.mark.parametrize("planner", ["mi-class-pairwise", "mi"])
def test_recognizer_step_with_a_mixture_model(trained, planner):
    """The recognizer step (pairwise: the Bhattacharyya bound; mi: the sampler and
    the density in ``mi_tables``) on an off-grid view and on a blank-ish image:
    finite scores and a finite, normalised belief."""
    model, db = trained.mix, trained.db
    key = jr.PRNGKey(0)
    rec = Recognizer(model, make_planner(planner, model, key=key, samples=32), max_steps=5)
    state = rec.init(config=(1,))
    (row,) = np.flatnonzero((db.split == "test") & (db.position == 1) & (db.object == 0) & (db.pose == 1))
    view = db.images[row][None]
    for t, images in enumerate((view, odd_images(view))):
        state, dec = steps_stay_finite(rec, state, [images], jr.fold_in(key, t))
        assert abs(float(jnp.sum(jnp.exp(dec.trace.posterior.log_pc))) - 1.0) < 1e-5
        assert 0.0 <= float(dec.probability) <= 1.0


# -- the default family with view jitter ----------------------------------------------

def test_view_jitter_trains_the_low_rank_mixture_unless_told_otherwise(tmp_path, monkeypatch, capsys):
    """``jaxrecog train --view-jitter`` without ``--likelihood`` trains
    ``view-mixture-lowrank`` (``kernels.DEFAULT_VIEW_JITTER_LIKELIHOOD``); without
    view jitter the thesis's Gaussian stays the default; ``--likelihood`` wins."""
    from jaxrecog import cli
    from jaxrecog import campaigns as ex

    assert K.DEFAULT_VIEW_JITTER_LIKELIHOOD == "view-mixture-lowrank" and K.DEFAULT_LIKELIHOOD == "gaussian-diag"
    db = make_database(positions=(2,), n_objects=2, n_poses=2, image_shape=(16, 20))
    folder = tmp_path / "db"
    from jaxrecog import write_database

    write_database(folder, _with_jitter(db, _jitter_rows(db)))
    # the thesis recipe's families (the robust recipe's is the view mixture, tests/test_recipes.py)
    base = ["--quiet", "train", str(folder), "--kind", "DB1", "--components", "3", "--samples", "10",
            "--recipe", "thesis"]
    for extra, family in ((["--view-jitter"], K.LowRankViewMixture), ([], K.DiagonalGaussian),
                          (["--view-jitter", "--likelihood", "gaussian-diag"], K.DiagonalGaussian),
                          (["--view-jitter", "--likelihood", "view-mixture"], K.ViewMixture)):
        out = tmp_path / f"m{len(extra)}-{family.__name__}.npz"
        assert cli.main(base + ["--out", str(out)] + extra) == 0, capsys.readouterr().err
        assert type(load_model(out).cameras[0].likelihood) is family
        if extra:  # inspect says how the jitter images were used
            capsys.readouterr()
            assert cli.main(["inspect", str(out)]) == 0
            how = "one mixture component each" if family is not K.DiagonalGaussian else "added to the training"
            assert how in capsys.readouterr().out
    # --rank belongs to the low-rank families: with view jitter it is the default family's option
    out = tmp_path / "r.npz"
    assert cli.main(base + ["--out", str(out), "--view-jitter", "--rank", "1"]) == 0
    assert load_model(out).cameras[0].likelihood.W.shape[-1] == 1
    # --occluded-jitter: recorded in the model file; a mixture's option only
    out = tmp_path / "t.npz"
    for mode in ("sampled", "translated"):
        assert cli.main(base + ["--out", str(out), "--view-jitter", "--occluded-jitter", mode]) == 0
        assert load_model_meta(out)["training"]["likelihood_options"] == {"occluded_jitter": mode}
    # the default is recorded too (a cache key tells it from mixtures trained before it was the default)
    assert load_model_meta(tmp_path / "m1-LowRankViewMixture.npz")["training"]["likelihood_options"] == \
        {"occluded_jitter": "translated"}
    capsys.readouterr()
    assert cli.main(base + ["--out", str(tmp_path / "x.npz"), "--occluded-jitter", "translated"]) == 2
    assert "--occluded-jitter applies to view-mixture, view-mixture-lowrank, not to --likelihood gaussian-diag" \
        in capsys.readouterr().err

    # experiment: --view-jitter N without --likelihood selects the same family
    seen = {}

    class _Stop(Exception):
        pass

    def run_case(name, settings, planners=None, **kw):
        seen["settings"] = settings
        raise _Stop

    monkeypatch.setattr(ex, "run_case", run_case)
    for extra, want in ((["--view-jitter", "2"], "view-mixture-lowrank"), ([], "gaussian-diag"),
                        (["--view-jitter", "2", "--likelihood", "gaussian-diag"], "gaussian-diag")):
        assert cli.main(["--quiet", "experiment", "i", "--out", str(tmp_path / "x")] + extra) == 1
        assert seen.pop("settings").likelihood == want
    assert cli.main(["--quiet", "experiment", "i", "--out", str(tmp_path / "x"), "--view-jitter", "2",
                     "--occluded-jitter", "translated"]) == 1
    assert dict(seen.pop("settings").likelihood_options) == {"occluded_jitter": "translated"}
