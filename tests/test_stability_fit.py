"""The planner's stability weight fitted on held-out captures (jaxrecog/stability_fit.py):
the AUC test against brute-force pair counting, the batched profile scales against
one capture at a time, the gate on captures built to say yes / no, and the weight
carried by the model (planner, model file, recipe)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_view_stability import _mixture_model

from jaxrecog.calibration_data import CalibrationFeatures, CameraFeatures
from jaxrecog.kernels.adaptive_scale import adaptive_log_density, scale_grid
from jaxrecog.kernels.view_stability import expected_instability, view_instability
from jaxrecog.modelfile import ModelFileContentError, load_model, load_model_meta, save_model
from jaxrecog.planners import make_planner
from jaxrecog.recipes import AUTO, ROBUST, THESIS, Recipe, recipe_from_meta
from jaxrecog.sensor_model import SensorModel
from jaxrecog.stability_fit import StabilityFit, auc_test, capture_scales, fit_stability


def _brute_auc(u, e):
    return np.mean([(1.0 if a > b else 0.5 if a == b else 0.0) for a in u for b in e])


def test_auc_is_the_pair_count_with_half_ties_and_the_test_is_one_sided():
    rng = np.random.default_rng(0)
    u, e = rng.integers(0, 5, 23).astype(float), rng.integers(0, 5, 31).astype(float)   # many ties
    auc, p = auc_test(u, e)
    assert auc == pytest.approx(_brute_auc(u, e), abs=1e-12)
    hi, p_hi = auc_test(e + 10.0, e)
    lo, p_lo = auc_test(e - 10.0, e)
    assert hi == 1.0 and lo == 0.0 and p_hi < 1e-6 and p_lo > 0.99
    assert np.isnan(auc_test(np.array([]), e)[0]) and auc_test(u, np.array([]))[1] == 1.0


def test_capture_scales_are_the_one_capture_profile_in_padded_chunks():
    model = _mixture_model(positions=(3,), m=3)
    lik = model.cameras[0].likelihood
    rng = np.random.default_rng(1)
    n = 70                                               # one full chunk of 64 and a padded one
    pos = rng.integers(0, 3, n)
    mu = np.asarray(lik.mu)[pos, rng.integers(0, lik.mu.shape[1], n), 0, 0]
    g = (mu + rng.normal(size=mu.shape) * rng.choice([0.0, 1.0, 6.0], size=(n, 1))).astype(np.float32)
    got = capture_scales(lik, g, pos, 32.0)
    one = jax.jit(lambda lk, x, v: adaptive_log_density(lk.at(v), x, scale_grid(32.0))[1])   # one capture at a time
    want = [float(one(lik, jnp.asarray(x), int(v))) for x, v in zip(g, pos)]
    np.testing.assert_allclose(got, want, rtol=1e-6)
    assert len(set(np.round(got, 3))) > 1                # the captures span explained and unexplained


def _captures(model, *, unexplained_where: str, n=120, seed=2):
    """Held-out captures of camera 0: a capture at a component mean (explained)
    or far off every class (unexplained) at the views/classes of highest or
    lowest instability (``unexplained_where``: "unstable", "stable", "none")."""
    lik = model.cameras[0].likelihood
    d = np.asarray(view_instability(lik))                # [V, C]
    rng = np.random.default_rng(seed)
    order = np.argsort(d, axis=None)
    top, bottom = order[-len(order) // 4:], order[: len(order) // 2]
    g, pos, cls = [], [], []
    for i in range(n):
        bad = unexplained_where != "none" and i % 3 == 0
        pool = (top if unexplained_where == "unstable" else bottom) if bad else order
        v, c = np.unravel_index(rng.choice(pool), d.shape)
        x = np.asarray(lik.mu)[v, c, 0, 0] + (40.0 * rng.normal(size=lik.mu.shape[-1]) if bad else 0.0)
        g.append(x); pos.append(v); cls.append(c)
    cam = CameraFeatures(np.array(g, np.float64), np.array(pos), np.array(cls))
    empty = CameraFeatures(np.zeros((0, cam.g.shape[1])), np.zeros(0, int), np.zeros(0, int))
    return CalibrationFeatures((cam,) + (empty,) * (model.n_cameras - 1))


def test_the_gate_says_yes_only_where_instability_predicts_unexplained_captures():
    model = _mixture_model(positions=(6, 3), m=3)
    yes = fit_stability(model, _captures(model, unexplained_where="unstable"))
    assert yes.weight == 1.0 and yes.auc > 0.9 and yes.p_value < 0.01 and yes.n == 120 and yes.n_unexplained == 40
    no = fit_stability(model, _captures(model, unexplained_where="stable"))
    assert no.weight == 0.0 and no.auc < 0.5
    none = fit_stability(model, _captures(model, unexplained_where="none"))
    assert none.weight == 0.0 and none.n_unexplained == 0 and np.isnan(none.auc) and none.p_value == 1.0
    few = fit_stability(model, _captures(model, unexplained_where="unstable"), min_unexplained=41)
    assert few.weight == 0.0 and "too few unexplained" in few.summary()
    assert "weight 1" in yes.summary() and "AUC" in yes.summary() and yes.to_dict()["weight"] == 1.0
    assert none.to_dict()["auc"] is None
    empty = CalibrationFeatures(tuple(CameraFeatures(np.zeros((0, 4)), np.zeros(0, int), np.zeros(0, int))
                                      for _ in model.cameras))
    with pytest.raises(ValueError, match="no held-out captures"):
        fit_stability(model, empty)
    with pytest.raises(ValueError, match="alpha"):
        fit_stability(model, _captures(model, unexplained_where="unstable"), alpha=0.0)


def test_the_planner_takes_the_model_weight_unless_an_option_names_one(getkey):
    model = _mixture_model()
    prior_pc = jax.nn.log_softmax(jnp.arange(model.n_classes, dtype=jnp.float32))
    from jaxrecog import kernels as K
    prior = K.at_every_position(K.uniform_belief(model.n_classes, tuple(len(model.levels) for _ in model.positions)),
                                model.positions)._replace(log_pc=prior_pc)

    def scores(m, **opt):
        return np.asarray(make_planner("mi-class-pairwise-stable", m, key=getkey(), **opt).scores(prior, getkey()))

    inst = np.asarray(expected_instability(tuple(view_instability(lik) for lik in model.likelihoods), prior_pc))
    assert model.stability is None
    np.testing.assert_allclose(scores(model), scores(model, stability=1.0))           # not fitted: 1
    zero = dataclasses.replace(model, stability=0.0)
    np.testing.assert_allclose(scores(zero), scores(model, stability=0.0))            # the model's weight
    np.testing.assert_allclose(scores(zero) - scores(model), inst, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(scores(zero, stability=2.0), scores(model, stability=2.0))   # an option wins
    assert make_planner("mi-class-pairwise-stable", dataclasses.replace(model, stability=0.5), key=getkey()).stability == 0.5


def test_the_weight_round_trips_through_the_model_file_and_bad_values_are_one_line(tmp_path):
    model = _mixture_model()
    for w in (None, 0.0, 1.0):
        path = save_model(tmp_path / f"m{w}.npz", dataclasses.replace(model, stability=w))
        assert load_model(path).stability == w and load_model_meta(path)["stability"] == w
    with pytest.raises(ValueError, match="stability must be a finite number >= 0 or None"):
        dataclasses.replace(model, stability=-1.0)
    with pytest.raises(ValueError, match="stability must be"):
        SensorModel(model.cameras, model.n_objects, model.n_poses, model.levels, model.image_shape, stability=True)
    # a file whose metadata says -1 (written by hand): one line, not a model with a negative weight
    import json
    path = tmp_path / "m0.0.npz"
    with np.load(path) as f:
        arrays = dict(f)
    meta = json.loads(bytes(arrays["meta"]).decode())
    meta["stability"] = -1.0
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(ModelFileContentError, match="stability -1.0 must be a finite number >= 0"):
        load_model(tmp_path / "bad.npz")


def test_recipe_part_stability():
    assert ROBUST.stability == AUTO and ROBUST.version >= 5 and THESIS.stability == 1.0
    assert "stability = 'auto'" in ROBUST.describe()
    assert ROBUST.replace(stability=0.0).stability == 0.0
    for bad in (-1.0, float("inf"), "sometimes", True):
        with pytest.raises(ValueError, match="stability must be a finite number >= 0 or 'auto'"):
            Recipe("x", 1, "x", stability=bad)
    # a version-4 robust entry recorded no weight: it loads with 1, as it ran
    v4 = {k: v for k, v in ROBUST.to_dict().items() if k != "stability"}
    v4["version"] = 4
    assert recipe_from_meta({"recipe": v4}).stability == 1.0


def test_stability_fit_is_frozen_and_plain():
    fit = StabilityFit(1.0, 0.8, 1e-5, 10, 5)
    with pytest.raises(dataclasses.FrozenInstanceError):
        fit.weight = 0.0


def test_the_recognizer_takes_the_model_weight_then_the_recipe_number_then_1():
    from jaxrecog.recognizer_factory import make_recognizer

    model = _mixture_model()

    def weight(m, recipe):
        return make_recognizer(m, "mi-class-pairwise-stable", recipe=recipe).planner.stability

    assert weight(model, ROBUST) == 1.0                                   # auto, nothing fitted: 1
    assert weight(model, ROBUST.replace(stability=0.0)) == 0.0            # a model without a weight: the recipe's
    assert weight(dataclasses.replace(model, stability=1.0), ROBUST.replace(stability=0.0)) == 1.0   # the model's
    assert weight(dataclasses.replace(model, stability=0.0), THESIS.replace(planner="mi-class-pairwise-stable")) == 0.0


def test_the_fit_needs_an_adaptive_scale_that_can_mark_a_capture_unexplained():
    model = _mixture_model(positions=(6, 3), m=3)
    with pytest.raises(ValueError, match="needs an adaptive scale of at least 2"):
        fit_stability(model, _captures(model, unexplained_where="unstable"), max_scale=1.5)
    from types import SimpleNamespace

    from jaxrecog.cli.train import _resolve_stability

    recipe, m = _resolve_stability(ROBUST.replace(adaptive_scale=1.0), model, SimpleNamespace(split=np.array(["calib"])), {})
    assert recipe.stability == 1.0 == m.stability


def test_a_model_file_whose_weight_is_not_a_number_is_one_line(tmp_path):
    import json
    path = save_model(tmp_path / "m.npz", _mixture_model())
    with np.load(path) as f:
        arrays = dict(f)
    for bad in (True, "0.5"):
        meta = json.loads(bytes(arrays["meta"]).decode())
        meta["stability"] = bad
        arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
        np.savez(tmp_path / "bad.npz", **arrays)
        with pytest.raises(ModelFileContentError, match="is not a number"):
            load_model(tmp_path / "bad.npz")
