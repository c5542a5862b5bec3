"""The sensor-model seam (:class:`jaxrecog.kernels.Likelihood`).

Each family against SciPy / NumPy (log-density, moments, sampler, Bhattacharyya,
scaling), the full-covariance form on a diagonal covariance against the
diagonal form, the registry, and a third family defined in this file and
registered in one line, run through training, the recognizer step (MI and
CRLB planners), calibration and the model file — with a third camera and mixed
kinds, and no change to the estimation code.
"""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import jax.random as jr
import numpy as np
import pytest
from kernel_models import jitted, random_chols
from scipy.stats import multivariate_normal, norm

from jaxrecog import kernels as K
from jaxrecog.calibration import CalibrationFeatures, CameraFeatures, apply_calibration, calibrate_model
from oracles import bhattacharyya_ref
from jaxrecog.modelfile import ModelFileContentError, _content_hash, load_model, load_model_meta, save_model
from jaxrecog.planners import make_planner
from jaxrecog.recognizer import Recognizer
from jaxrecog.sensor_model import CameraModel, GaussianAccumulator, SensorModel


class IsotropicGaussian(K.Likelihood):
    """A toy third family: N(g; mu[c, k], s2[c, k] I), one variance per component."""

    kind = "test-isotropic"
    field_shapes = {"mu": "V C L K", "s2": "V C L"}

    mu: jax.Array
    s2: jax.Array

    def log_density(self, g):
        n = g.ndim - 1
        mu, s2 = (x.reshape((1,) * n + x.shape) for x in (self.mu, self.s2))
        d = g[..., None, None, :] - mu
        return -0.5 * (jnp.sum(d * d, -1) / s2 + self.dim * jnp.log(2 * jnp.pi * s2))

    def sample(self, z):
        return self.mu[:, :, None, :] + jnp.sqrt(self.s2)[:, :, None, None] * z

    def mean(self):
        return self.mu

    def covariance(self):
        return jnp.einsum("...,kl->...kl", self.s2, jnp.eye(self.dim, dtype=self.s2.dtype))

    def scaled(self, factor):
        return IsotropicGaussian(self.mu, self.s2 * factor[None, :])

    def problems(self):
        return [("s2", "has non-positive variances")] if np.any(np.asarray(self.s2) <= 0) else []

    @classmethod
    def fit(cls, mean, second, floor):
        return cls(mean, np.maximum(second.mean(axis=-1), floor))


K.register_likelihood(IsotropicGaussian)  # the one registry line a new family needs


# ---------------------------------------------------------------- the two Gaussians


def _gaussian(rng, kind, V=2, C=3, L=2, k=3):
    """A stacked likelihood of ``kind`` and its NumPy ``(mu, cov)``."""
    mu = rng.normal(size=(V, C, L, k))
    if kind == "diag":
        var = rng.uniform(0.3, 1.5, size=(V, C, L, k))
        return K.DiagonalGaussian(jnp.asarray(mu), jnp.asarray(var)), mu, var[..., None] * np.eye(k)
    chol = random_chols(rng, C, (L,), (V,), (k,), scale=1.0)[0]
    return K.FullGaussian(jnp.asarray(mu), jnp.asarray(chol)), mu, chol @ np.swapaxes(chol, -1, -2)


@pytest.mark.parametrize("kind", ["diag", "full"])
def test_log_density_against_scipy_for_any_batch(rng, x64, kind):
    lik, mu, cov = _gaussian(rng, kind)
    g = rng.normal(size=(2, 4, 3)) * 1.5
    for v in range(2):
        got = np.asarray(lik.at(v).log_density(jnp.asarray(g)))
        assert got.shape == (2, 4, 3, 2)
        one = np.asarray(lik.at(v).log_density(jnp.asarray(g[1, 2])))
        np.testing.assert_allclose(one, got[1, 2], rtol=1e-13)
        for c, l in np.ndindex(3, 2):
            want = multivariate_normal(mu[v, c, l], cov[v, c, l]).logpdf(g)
            np.testing.assert_allclose(got[..., c, l], want, rtol=1e-12)


@pytest.mark.parametrize("kind", ["diag", "full"])
def test_moments_and_sampler(rng, x64, kind):
    lik, mu, cov = _gaussian(rng, kind, V=1, C=2, L=2)
    one = lik.at(0)
    np.testing.assert_allclose(one.mean(), mu[0], rtol=1e-14)
    np.testing.assert_allclose(one.covariance(), cov[0], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(one.variance(), np.diagonal(cov[0], axis1=-2, axis2=-1), rtol=1e-12)
    # the draw is the affine map of z the planners' common random numbers assume
    z = rng.normal(size=(2, 2, 5, 3))
    want = mu[0][:, :, None, :] + np.einsum("clkm,cljm->cljk", np.linalg.cholesky(cov[0]), z)
    np.testing.assert_allclose(one.sample(jnp.asarray(z)), want, rtol=1e-11, atol=1e-12)
    # and its moments are the family's (5 standard errors)
    n = 40_000
    g = np.asarray(one.sample(jnp.asarray(rng.normal(size=(2, 2, n, 3)))))
    sd = np.sqrt(np.diagonal(cov[0], axis1=-2, axis2=-1))
    assert np.all(np.abs(g.mean(axis=2) - mu[0]) < 5 * sd / np.sqrt(n))
    emp = np.einsum("cljk,cljm->clkm", g - g.mean(2, keepdims=True), g - g.mean(2, keepdims=True)) / n
    outer = sd[..., :, None] * sd[..., None, :]
    assert np.all(np.abs(emp - cov[0]) < 5 * np.sqrt(2.0 / n) * outer)


def test_full_form_on_a_diagonal_covariance_is_the_diagonal_form(rng, x64):
    diag, mu, cov = _gaussian(rng, "diag")
    full = K.FullGaussian(diag.mu, jnp.einsum("...k,kl->...kl", jnp.sqrt(diag.var), jnp.eye(3)))
    np.testing.assert_allclose(full.var, diag.var, rtol=1e-14)
    g = jnp.asarray(rng.normal(size=(4, 3)))
    z = jnp.asarray(rng.normal(size=(3, 2, 4, 3)))
    factor = jnp.asarray([2.0, 0.5])
    d, f = diag.at(1), full.at(1)
    for a, b in [(d.log_density(g), f.log_density(g)), (d.sample(z), f.sample(z)),
                 (d.covariance(), f.covariance()), (d.bhattacharyya(), f.bhattacharyya()),
                 (d.scaled(factor).log_density(g), f.scaled(factor).log_density(g)),
                 (d.scaled_log_density(d.scaling_terms(g), jnp.log(factor)),
                  f.scaled_log_density(f.scaling_terms(g), jnp.log(factor)))]:
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("kind", ["diag", "full"])
def test_bhattacharyya_against_numpy_reference(rng, x64, kind):
    lik, mu, cov = _gaussian(rng, kind)
    for v in range(2):
        got = np.asarray(lik.at(v).bhattacharyya())
        np.testing.assert_allclose(got, bhattacharyya_ref(mu[v], cov[v]), rtol=1e-10, atol=1e-12)
        assert np.allclose(got, np.transpose(got, (2, 3, 0, 1)))
        assert np.allclose(np.einsum("clcl->cl", got), 0.0, atol=1e-12) and np.all(got >= -1e-12)


def test_bhattacharyya_is_minus_log_overlap_by_quadrature(x64):
    """D_B = -log ∫ sqrt(p q) dg, integrated on a fine grid (K = 1)."""
    mu = np.array([[[0.0]], [[1.3]], [[-0.4]]])      # [C=3, L=1, K=1]
    var = np.array([[[0.5]], [[2.0]], [[0.1]]])
    got = np.asarray(K.DiagonalGaussian(jnp.asarray(mu), jnp.asarray(var)).bhattacharyya())[:, 0, :, 0]
    x = np.linspace(-12, 12, 200_001)
    for a in range(3):
        for b in range(3):
            p, q = (norm(mu[i, 0, 0], np.sqrt(var[i, 0, 0])).pdf(x) for i in (a, b))
            np.testing.assert_allclose(got[a, b], -np.log(np.trapezoid(np.sqrt(p * q), x)), rtol=1e-7, atol=1e-9)


@pytest.mark.parametrize("kind", ["diag", "full"])
def test_scaled_is_the_inflated_covariance(rng, x64, kind):
    lik, mu, cov = _gaussian(rng, kind, V=1)
    factor = np.array([3.0, 0.7])
    g = rng.normal(size=(5, 3))
    got = np.asarray(lik.at(0).scaled(jnp.asarray(factor)).log_density(jnp.asarray(g)))
    fast = np.asarray(lik.at(0).scaled_log_density(lik.at(0).scaling_terms(jnp.asarray(g)), jnp.log(factor)))
    for c, l in np.ndindex(3, 2):
        want = multivariate_normal(mu[0, c, l], factor[l] * cov[0, c, l]).logpdf(g)
        np.testing.assert_allclose(got[:, c, l], want, rtol=1e-12)
        np.testing.assert_allclose(fast[:, c, l], want, rtol=1e-12)


def test_fit_from_moments_applies_the_floor(rng):
    mean = rng.normal(size=(2, 1, 3))
    var = np.array([[[1.0, 1e-9, 0.5]], [[2.0, 0.2, 1e-12]]])
    floor = np.array([[1e-3], [1e-2]])
    d = K.DiagonalGaussian.fit(mean, var, floor)
    np.testing.assert_array_equal(d.var, np.maximum(var, floor[..., None]))
    a = rng.normal(size=(2, 1, 3, 3))
    cov = a @ np.swapaxes(a, -1, -2)
    f = K.FullGaussian.fit(mean, cov, floor)
    want = cov + floor[..., None, None] * np.eye(3)
    np.testing.assert_allclose(f.chol @ np.swapaxes(f.chol, -1, -2), want, rtol=1e-12)
    np.testing.assert_allclose(f.var, np.diagonal(want, axis1=-2, axis2=-1), rtol=1e-14)
    acc = GaussianAccumulator(1, 1, 3, full=True)
    with pytest.raises(ValueError, match="'diag' second moments"):
        acc.fit(K.DiagonalGaussian)


def test_registry_and_interface_errors(rng, unchecked):
    assert K.LIKELIHOODS["diag"] is K.DiagonalGaussian and K.LIKELIHOODS["full"] is K.FullGaussian
    assert K.likelihood_class("test-isotropic") is IsotropicGaussian
    with pytest.raises(ValueError, match="unknown likelihood 'nope'; registered: .*diag, full"):
        K.likelihood_class("nope")
    assert K.register_likelihood(IsotropicGaussian) is IsotropicGaussian  # idempotent

    class Other(IsotropicGaussian):
        kind = "diag"

    with pytest.raises(ValueError, match="already DiagonalGaussian"):
        K.register_likelihood(Other)
    with unchecked(), pytest.raises(TypeError, match="not a Likelihood"):  # the guard, not the checker
        K.register_likelihood(dict)
    with unchecked(), pytest.raises(ValueError, match="var has K = 4, another field has K = 3"):  # the guard, not the checker
        K.DiagonalGaussian(jnp.zeros((2, 3, 1, 3)), jnp.ones((2, 3, 1, 4)))
    toy = IsotropicGaussian(jnp.zeros((2, 3, 1, 2)), jnp.ones((2, 3, 1)))
    assert (toy.n_positions, toy.n_classes, toy.n_levels, toy.dim) == (2, 3, 1, 2)
    with pytest.raises(NotImplementedError, match="'test-isotropic' likelihood has no closed-form"):
        toy.at(0).bhattacharyya()
    with pytest.raises(ValueError, match="no position axis"):
        K.mi_tables((toy.at(0),), key=jr.PRNGKey(0), samples_per_stratum=1)


# ---------------------------------------------------------------- a third family, a third camera


_HW, _POS, _N_OBJ, _N_POSE, _LEVELS, _K = (6, 8), (3, 2, 2), 2, 2, (0.0, 0.1), 3


def _models(seed=0):
    """The same sensor model twice, three cameras: once as (toy, full, diag)
    likelihoods, once all diagonal (the toy's s2 broadcast over K, the full
    one's covariance diagonal)."""
    rng = np.random.default_rng(seed)
    d, c, l = _HW[0] * _HW[1], _N_OBJ * _N_POSE, len(_LEVELS)
    eigen, mixed, plain = [], [], []
    for i, v in enumerate(_POS):
        eigen.append((rng.normal(0, 0.01, (v, d)), np.linalg.qr(rng.normal(size=(v, d, _K)))[0], np.ones((v, _K))))
        mu = rng.normal(0, 0.3, (v, c, l, _K))
        if i == 0:
            s2 = rng.uniform(0.01, 0.05, (v, c, l))
            mixed.append(IsotropicGaussian(jnp.asarray(mu), jnp.asarray(s2)))
            var = np.repeat(s2[..., None], _K, axis=-1)
        else:
            var = rng.uniform(0.01, 0.05, (v, c, l, _K))
            mixed.append(K.FullGaussian(jnp.asarray(mu), jnp.asarray(np.sqrt(var)[..., None] * np.eye(_K)))
                         if i == 1 else K.DiagonalGaussian(jnp.asarray(mu), jnp.asarray(var)))
        plain.append(K.DiagonalGaussian(jnp.asarray(mu), jnp.asarray(var)))

    def model(liks):
        cams = tuple(CameraModel(*(jnp.asarray(x) for x in e), likelihood=lik) for e, lik in zip(eigen, liks))
        return SensorModel(cams, _N_OBJ, _N_POSE, _LEVELS, _HW)

    return model(mixed), model(plain)


def _run(model, planner, n_steps=2, seed=0):
    key = jr.PRNGKey(seed)
    rec = Recognizer(model, make_planner(planner, model, key=key, samples=64), max_steps=10)
    state = rec.init(config=(1, 0, 1))
    images = np.random.default_rng(seed + 1).integers(1, 255, (n_steps, 3) + _HW).astype(np.uint8)
    out = []
    for t in range(n_steps):
        state, dec = rec.step(state, jnp.asarray(images[t]), jr.fold_in(key, t), trace=True)
        out.append(dec)
    return out


@pytest.mark.slow
def test_third_family_and_camera_through_the_planner_kernels(x64, getkey):
    """MI and Fisher read the likelihoods only through the sample tables: the
    mixed-kind model's tables, MI and J_g equal the all-diagonal model's."""
    tables, mi, fisher = jitted()
    mixed, plain = _models()
    key, fkey = getkey(), getkey()
    a, b = (tables(m.likelihoods, key=key, samples_per_stratum=2) for m in (mixed, plain))
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        np.testing.assert_allclose(x, y, rtol=1e-10, atol=1e-10)
    belief = K.at_every_position(K.uniform_belief(_N_OBJ * _N_POSE, (len(_LEVELS),) * 3, dtype=jnp.float64),
                                 mixed.positions)
    np.testing.assert_allclose(mi(a, belief, "class"), mi(b, belief, "class"), rtol=1e-9, atol=1e-12)
    fa, fb = (fisher(t, belief, key=fkey, n_objects=_N_OBJ, n_poses=_N_POSE) for t in (a, b))
    np.testing.assert_allclose(fa, fb, rtol=1e-8, atol=1e-12)


def test_third_family_and_camera_through_the_recognizer(x64):
    mixed, plain = _models()
    assert mixed.likelihood_kinds == ("test-isotropic", "full", "diag") and mixed.covariance == "mixed"
    for a, b in zip(_run(mixed, "mi-class"), _run(plain, "mi-class")):
        assert bool(a.valid) and int(a.next_index) == int(b.next_index)
        np.testing.assert_allclose(a.trace.scores, b.trace.scores, rtol=1e-8, atol=1e-10)
        for x, y in zip(jax.tree.leaves(a.trace.posterior), jax.tree.leaves(b.trace.posterior)):
            np.testing.assert_allclose(x, y, rtol=1e-10, atol=1e-10)


def test_third_family_model_file_round_trip_and_validation(tmp_path):
    mixed, _ = _models()
    path = save_model(tmp_path / "m.npz", mixed)
    assert load_model_meta(path)["likelihoods"] == ["test-isotropic", "full", "diag"]
    back = load_model(path)
    assert back.likelihood_kinds == mixed.likelihood_kinds
    assert isinstance(back.cameras[0].likelihood, IsotropicGaussian)
    for a, b in zip(jax.tree.leaves(mixed), jax.tree.leaves(back)):
        assert np.asarray(a).tobytes() == np.asarray(b).tobytes()

    def rewritten(name, change):
        with np.load(path) as z:
            d = {k: z[k] for k in z.files}
        meta = json.loads(bytes(d["meta"]).decode())
        change(d, meta)
        meta["content_sha256"] = _content_hash({k: v for k, v in d.items() if "." in k})
        d["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
        np.savez(tmp_path / name, **d)
        return tmp_path / name

    def set_s2(value):
        def change(d, meta):
            d["camera0.s2"] = d["camera0.s2"].copy()
            d["camera0.s2"][1, 2, 0] = value
        return change

    cases = [
        (set_s2(-1.0), "camera0.s2 has non-positive variances"),
        (set_s2(np.nan), "camera0.s2 contains NaN"),
        (lambda d, m: d.update({"camera0.s2": d["camera0.s2"][..., None]}),
         r"camera0.s2 has shape \(3, 4, 2, 1\), expected \(3, 4, 2\)"),
        (lambda d, m: d.pop("camera0.s2"), "missing array camera0.s2"),
        (lambda d, m: m.update(likelihoods=["nope", "full", "diag"]), "camera 0: unknown likelihood 'nope'"),
    ]
    for i, (change, msg) in enumerate(cases):
        with pytest.raises(ModelFileContentError, match=msg) as e:
            load_model(rewritten(f"bad{i}.npz", change))
        assert "\n" not in str(e.value)


@pytest.mark.parametrize("covariance", ["diag", "full"])
def test_model_files_without_likelihoods_entry_load_as_they_are(tmp_path, small_db, covariance):
    """Files written before the seam (format 2, kind only in ``covariance``)."""
    from jaxrecog.train import train_model

    model = train_model(small_db, kind="DB1", n_components=2, samples_per_image=5, covariance=covariance)
    path = save_model(tmp_path / "new.npz", model)
    with np.load(path) as z:
        d = {k: z[k] for k in z.files}
    meta = json.loads(bytes(d["meta"]).decode())
    del meta["likelihoods"]
    d["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    np.savez(tmp_path / "old.npz", **d)
    back = load_model(tmp_path / "old.npz")
    assert back.likelihood_kinds == (covariance, covariance)
    for a, b in zip(jax.tree.leaves(model), jax.tree.leaves(back)):
        assert np.asarray(a).tobytes() == np.asarray(b).tobytes()


def test_training_and_calibration_of_the_third_family(small_db, rng):
    """Generic training fits the toy from the same moments (s2 = mean of the
    diagonal variances); generic calibration (its default scaled_log_density)
    recovers the factors the Gaussian closed form finds on the equivalent model."""
    from jaxrecog.train import train_model

    with pytest.raises(ValueError, match="unknown likelihood 'nope'"):
        train_model(small_db, likelihood="nope")
    diag = train_model(small_db, kind="DB1", n_components=3, samples_per_image=6, var_floor=0.0)
    toy = train_model(small_db, kind="DB1", n_components=3, samples_per_image=6, var_floor=0.0,
                      likelihood="test-isotropic")
    # the summary names each family as it names itself (Likelihood.summary_words)
    assert "likelihood test-isotropic" in toy.summary() and "likelihood components (positions" in toy.summary()
    assert "covariance diag" in diag.summary() and " Gaussians (positions" in diag.summary()
    mixed = SensorModel((diag.cameras[0], toy.cameras[1]), diag.n_objects, diag.n_poses, diag.levels, diag.image_shape)
    assert "likelihood mixed" in mixed.summary() and "likelihood components" in mixed.summary()
    for a, b in zip(diag.cameras, toy.cameras):
        np.testing.assert_array_equal(a.mu, b.likelihood.mu)
        np.testing.assert_allclose(b.likelihood.s2, np.asarray(a.var, np.float64).mean(-1), rtol=1e-6)
    # the toy as an equivalent diagonal model, calibrated both ways
    plain_cams = tuple(CameraModel(c.mean_image, c.basis, c.eigenvalues, likelihood=K.gaussian(
                                   c.likelihood.mu, jnp.repeat(c.likelihood.s2[..., None], 3, axis=-1))) for c in toy.cameras)
    plain = SensorModel(plain_cams, toy.n_objects, toy.n_poses, toy.levels, toy.image_shape)
    feats = []
    for cam in toy.cameras:
        lik = cam.likelihood
        V, C, L = lik.s2.shape
        pos, cls = np.repeat(np.arange(V), C * 40), np.tile(np.repeat(np.arange(C), 40), V)
        sd = np.sqrt(3.0 * np.asarray(lik.s2, np.float64)[pos, cls, 0])
        feats.append(CameraFeatures(np.asarray(lik.mu, np.float64)[pos, cls, 0] + sd[:, None] * rng.normal(size=(pos.size, 3)),
                                    pos, cls))
    feats = CalibrationFeatures(tuple(feats))
    cal_toy, info_toy = calibrate_model(toy, feats)
    _, info_plain = calibrate_model(plain, feats)
    for a, b in zip(info_toy.factors, info_plain.factors):
        np.testing.assert_allclose(a, b, rtol=1e-4)
        assert np.all(a > 1.5)
    np.testing.assert_allclose(cal_toy.cameras[0].likelihood.s2,
                               toy.cameras[0].likelihood.s2 * info_toy.factors[0][:, None, :], rtol=1e-6)
    back = apply_calibration(cal_toy, [1.0 / f for f in info_toy.factors])
    np.testing.assert_allclose(back.cameras[0].likelihood.s2, toy.cameras[0].likelihood.s2, rtol=1e-5)
