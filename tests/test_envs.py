"""The Gymnasium environment: gymnasium's own checker, the vector
env, our planners as policies reproducing run_campaign on the same trials,
bad input, and the package importing without gymnasium."""

from __future__ import annotations

import subprocess
import sys

import gymnasium as gym
import jax.random as jr
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from jaxrecog import save_model, train_model, write_database
from jaxrecog.campaign import plan_trials
from jaxrecog.envs import ENV_ID, ActiveRecognitionEnv, PlannerPolicy, confident_errors, env_vs_campaign
from jaxrecog.campaigns import Settings
from jaxrecog.hardware import Capture, DatasetRig
from builders import env_and_recognizer_beliefs, make_database, moving_database

#: a small Monte Carlo size: the planners' tables build in a moment
SMALL = Settings(samples=64, min_per_stratum=2)


@pytest.fixture(scope="module")
def moving(tmp_path_factory):
    """The one-camera database that needs a move, as files (the env's
    ``dataset:FOLDER`` and model-file paths), and its DB1 model."""
    root = tmp_path_factory.mktemp("moving")
    db = moving_database()
    model = train_model(db, kind="DB1", n_components=2, samples_per_image=10)
    write_database(root / "db", db)
    save_model(root / "model.npz", model)
    return {"db": db, "model": model, "rig": f"dataset:{root / 'db'}", "path": str(root / "model.npz")}


@pytest.fixture(scope="module")
def two_cameras():
    """Two cameras x 3 positions, 3 objects x 2 poses, two noisy test images per view."""
    db = make_database(positions=(3, 3), n_objects=3, n_poses=2, image_shape=(24, 32), n_test=2, seed=1)
    return db, train_model(db, kind="DB1", n_components=3, samples_per_image=10)


def make(moving, **kw):
    kw.setdefault("settings", SMALL)
    return gym.make(ENV_ID, model=moving["path"], rig=moving["rig"], **kw).unwrapped


@pytest.mark.parametrize("options", [
    {},
    {"render_mode": "rgb_array", "features": True, "belief": True},
    {"action": "per-camera", "prediction": "index", "belief": True, "scores": ("mi",)},
])
def test_check_env_passes_without_warnings(moving, options):
    # pytest turns every gymnasium warning into an error
    env = make(moving, **options)
    check_env(env)
    env.close()


def test_spaces_observation_and_info_follow_ap_gym(moving):
    env = make(moving, features=True, belief=True, render_mode="rgb_array", step_cost=0.1)
    assert set(env.action_space.spaces) == {"action", "prediction"}
    assert env.action_space["action"] == gym.spaces.Discrete(3)
    obs, info = env.reset(seed=3)
    assert obs["images"].shape == (1, 24, 32) and obs["images"].dtype == np.uint8
    assert obs in env.observation_space
    target = info["object"] * 3 + info["pose"]
    assert info["prediction"] == {"target": target}
    # a blind (uniform) prediction costs 1 on top of the step cost
    obs, reward, terminated, truncated, info = env.step({"action": 2, "prediction": np.full(6, 0.5, np.float32)})
    assert (terminated, truncated) == (False, False)
    assert info["base_reward"] == -0.1 and info["prediction"]["loss"] == pytest.approx(1.0)
    assert reward == pytest.approx(-1.1)
    assert env.configuration == (2,) and info["views"] == 2
    # the belief is the recognizer's: after position 2 (which shows the object) it knows the object
    assert obs["belief"].sum() == pytest.approx(1.0, abs=1e-5)
    assert int(np.argmax(obs["belief"])) // 3 == info["object"]
    # a confident right prediction: loss ~0, the episode terminates (the agent declared)
    sure = np.eye(6, dtype=np.float32)[target]
    _, reward, terminated, truncated, info = env.step({"action": 0, "prediction": sure})
    assert terminated and not truncated and info["prediction"]["loss"] == pytest.approx(0.0, abs=1e-9)
    assert info["views"] == 2  # declaring takes no new images
    frame = env.render()
    assert frame.shape == (24, 32, 3) and np.array_equal(frame[:, :, 1], obs["images"][0])


def test_max_steps_truncates_and_reset_is_deterministic(moving):
    env = make(moving, max_steps=3)
    a, _ = env.reset(seed=11)
    b, _ = env.reset(seed=11)
    assert np.array_equal(a["images"], b["images"]) and a["configuration"] == b["configuration"]
    flags = []
    for v in range(3):
        flags.append(env.step({"action": v, "prediction": np.zeros(6, np.float32)})[2:4])
    assert flags == [(False, False), (False, False), (False, True)]


def test_sync_vector_env(moving):
    envs = gym.vector.SyncVectorEnv([lambda: make(moving, belief=True) for _ in range(3)])
    obs, info = envs.reset(seed=[1, 2, 3])
    assert obs["images"].shape == (3, 1, 24, 32) and obs["belief"].shape == (3, 6)
    envs.action_space.seed(0)
    ends = 0
    for _ in range(10):  # past max_steps: the vector env resets finished episodes itself
        obs, reward, terminated, truncated, info = envs.step(envs.action_space.sample())
        assert reward.shape == (3,) and np.all(np.isfinite(reward))
        assert obs in envs.observation_space
        ends += int(np.sum(terminated | truncated))
    assert ends >= 3
    envs.close()


def _assert_reproduced(cmp):
    via_env, campaign = cmp["env"], cmp["campaign"]
    n = len(campaign)
    rate = lambda rs: np.mean([r.correct for r in rs])  # noqa: E731
    views = lambda rs: np.mean([r.steps for r in rs])  # noqa: E731
    # same seeds, same scenes and keys: the same trials (up to float noise at a
    # threshold or a tie), and so within sampling error of each other
    assert cmp["same"] >= 0.9
    assert abs(rate(via_env) - rate(campaign)) <= 2 * np.sqrt(0.25 / n)
    assert abs(views(via_env) - views(campaign)) <= 2 * np.std([r.steps for r in campaign]) / np.sqrt(n) + 1e-9
    if cmp["same"] == 1.0:
        assert confident_errors(via_env) == confident_errors(campaign)


@pytest.mark.parametrize("planner", ["mi", "random"])
def test_planner_policy_reproduces_run_campaign_one_camera(moving, planner):
    env = make(moving)
    specs = plan_trials(2, 3, env.positions, 8, seed=4)
    cmp = env_vs_campaign(env, planner, specs, batch=4)
    _assert_reproduced(cmp)
    if planner == "mi":  # the MI planner finds the one informative position
        assert np.mean([r.correct for r in cmp["env"]]) >= 0.9


@pytest.mark.parametrize("planner", ["mi", "mi-class", "crlb", "random"])
def test_planner_policy_reproduces_run_campaign_two_cameras(two_cameras, planner):
    db, model = two_cameras
    env = ActiveRecognitionEnv(model, DatasetRig(db, seed=0), settings=SMALL, action="per-camera")
    specs = plan_trials(3, 2, env.positions, 6, seed=2)
    _assert_reproduced(env_vs_campaign(env, planner, specs, batch=4))


def test_info_scores_are_the_planners_scores(moving):
    env = make(moving, scores=("mi",))
    policy = PlannerPolicy("mi", env)
    obs, info = env.reset(seed=0)
    rec = policy.recognizer
    _, dec = rec.step(rec.init(config=env.configuration), obs["images"], jr.PRNGKey(0), trace=True)
    np.testing.assert_allclose(info["scores"]["mi"], np.asarray(dec.trace.scores), rtol=1e-5, atol=1e-6)


def test_bad_input_raises_a_clear_error_and_reset_still_works(moving):
    env = make(moving)
    with pytest.raises(gym.error.ResetNeeded, match="reset"):
        env.step({"action": 0, "prediction": np.zeros(6, np.float32)})
    env.reset(seed=0)
    bad = [
        ({"action": 3, "prediction": np.zeros(6, np.float32)}, r"action\['action'\] = 3 is outside Discrete\(3\)"),
        ({"action": -1, "prediction": np.zeros(6, np.float32)}, "outside"),
        ({"action": 0.5, "prediction": np.zeros(6, np.float32)}, "outside"),
        ({"action": 0, "prediction": np.zeros(5, np.float32)}, r"shape \(6,\).*got \(5,\)"),
        ({"action": 0, "prediction": np.full(6, 2.0, np.float32)}, r"\[0, 1\]"),
        ({"action": 0, "prediction": np.full(6, np.nan, np.float32)}, r"\[0, 1\]"),
        ({"action": 0}, "keys 'action' and 'prediction'"),
        (3, "keys 'action' and 'prediction'"),
    ]
    for action, msg in bad:
        with pytest.raises(gym.error.InvalidAction, match=msg):
            env.step(action)
    assert env.configuration == tuple(np.unravel_index(int(env._configuration_obs()), env.positions))
    # nothing was lost: the episode goes on from where it was
    _, _, term, trunc, info = env.step({"action": 1, "prediction": np.zeros(6, np.float32)})
    assert info["views"] == 2
    target = info["prediction"]["target"]
    env.step({"action": 0, "prediction": np.eye(6, dtype=np.float32)[target]})  # declares: the episode ends
    with pytest.raises(gym.error.ResetNeeded, match="episode has ended"):
        env.step({"action": 0, "prediction": np.zeros(6, np.float32)})
    obs, _ = env.reset(seed=0)
    assert obs in env.observation_space
    # a wrong-shaped index prediction and a bad per-camera action
    env = make(moving, action="per-camera", prediction="index")
    env.reset(seed=0)
    with pytest.raises(gym.error.InvalidAction, match=r"outside Discrete\(7\)"):
        env.step({"action": np.array([0]), "prediction": 7})
    with pytest.raises(gym.error.InvalidAction, match="one position per camera"):
        env.step({"action": np.array([0, 1]), "prediction": 6})
    with pytest.raises(gym.error.InvalidAction, match="one position per camera"):
        env.step({"action": np.array([3]), "prediction": 6})
    assert env.step({"action": np.array([1]), "prediction": 6})[4]["views"] == 2


def test_a_model_rig_layout_mismatch_is_named(moving, two_cameras):
    db, model = two_cameras
    with pytest.raises(ValueError, match=r"does not match the model: positions \(3,\) per camera vs the model's \(3, 3\)"):
        ActiveRecognitionEnv(model, moving["rig"], settings=SMALL)
    other = make_database(positions=(3, 3), n_objects=3, n_poses=2, image_shape=(12, 16), n_test=1)
    with pytest.raises(ValueError, match=r"does not match the model: images 12x16 vs the model's 24x32"):
        ActiveRecognitionEnv(model, DatasetRig(other), settings=SMALL)
    with pytest.raises(ValueError, match="unknown rig 'nope'"):
        ActiveRecognitionEnv(model, "nope")
    with pytest.raises(ValueError, match="case must be one of clean, occluded"):
        ActiveRecognitionEnv(model, DatasetRig(db), case="foggy")
    with pytest.raises(ValueError, match="needs a rendered scene"):
        ActiveRecognitionEnv(model, DatasetRig(db), case="occluded")
    with pytest.raises(ValueError, match="a model .* is required"):
        ActiveRecognitionEnv(None, DatasetRig(db))
    env = ActiveRecognitionEnv(model, DatasetRig(db), settings=SMALL)
    with pytest.raises(ValueError, match=r"^unknown reset option\(s\) 'trail'; known: 'trial', 'capture_seed'$"):
        env.reset(options={"trail": 1})
    with pytest.raises(ValueError, match=r"initial configuration \(5, 0\) outside"):
        env.reset(options={"trial": plan_trials(3, 2, (3, 3), 1)[0].__class__(0, 0, 0, (5, 0))})
    assert env.reset(seed=1)[0] in env.observation_space


def test_bad_reset_option_types_are_named_and_change_nothing(moving, unchecked):
    """Bad ``reset(options=...)`` types gave IndexError / 'dictionary update
    sequence' messages."""
    from jaxrecog.driver import TrialSpec

    env = make(moving)
    obs, info = env.reset(seed=2)
    with unchecked():  # what a caller without the run-time type checker builds
        cases = _bad_reset_options(TrialSpec)
    for options, kind, match in cases:
        with unchecked(), pytest.raises(kind, match=match):
            env.reset(options=options)
        # nothing changed: the episode goes on where it was
        assert env.views == 1 and env._info()["object"] == info["object"]
    out = env.step({"action": 1, "prediction": np.full(6, 1 / 6, np.float32)})
    assert out[4]["views"] == 2
    obs, info = env.reset(options={"trial": TrialSpec(0, 1, 1, (2,)), "capture_seed": np.int64(4)})
    assert (info["object"], info["pose"], env.configuration) == (1, 1, (2,))


def _bad_reset_options(TrialSpec):
    return [
        (["trial"], TypeError, r"^reset\(options=\.\.\.\) must be a dict with keys 'trial' and/or 'capture_seed' \(or None\), got list$"),
        ("trial", TypeError, r"must be a dict .* got str$"),
        ({1: 2, "x": 3}, ValueError, r"^unknown reset option\(s\) 'x', 1; known"),
        ({"trial": (0, 0, 0, (1,))}, TypeError, r"^options\['trial'\] must be a jaxrecog.campaign.TrialSpec, got tuple$"),
        ({"trial": TrialSpec(0, 0, 0, 1)}, TypeError, r"^options\['trial'\].initial must be a tuple of integers .* got 1$"),
        ({"trial": TrialSpec(0, 0, 0, ("1",))}, TypeError, r"^options\['trial'\].initial must be a tuple of integers"),
        ({"trial": TrialSpec(0, "0", 0, (1,))}, TypeError, r"^options\['trial'\].object must be an integer, got '0'$"),
        ({"trial": TrialSpec(0, 0, 1.5, (1,))}, TypeError, r"^options\['trial'\].pose must be an integer, got 1.5$"),
        ({"trial": TrialSpec(0, 0, 0, (1,), yaw_offset="x")}, TypeError, r"yaw_offset must be a finite number"),
        ({"trial": TrialSpec(0, 0, 0, (1,)), "capture_seed": "abc"}, TypeError,
         r"^options\['capture_seed'\] must be an integer, got 'abc'$"),
        ({"trial": TrialSpec(0, 0, 0, (1,)), "capture_seed": 1.5}, TypeError, r"capture_seed'\] must be an integer"),
        ({"capture_seed": 3}, ValueError, r"give it with options\['trial'\]$"),
    ]


def test_import_jaxrecog_works_without_gymnasium():
    code = ("import sys; sys.modules['gymnasium'] = None\n"
            "import jaxrecog, jaxrecog.campaigns, jaxrecog.envs\n"
            "from jaxrecog.envs import FunctionalEnv\n"
            "try:\n    jaxrecog.envs.ActiveRecognitionEnv\nexcept ImportError as e:\n    print('ERR', e)\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert "ERR jaxrecog.envs.ActiveRecognitionEnv needs gymnasium" in p.stdout and "jaxrecog[gym]" in p.stdout


def test_logits_prediction_is_softmaxed(moving):
    # ap-gym's own form; unbounded, so check_env would warn about its Box bounds
    env = make(moving, prediction="logits")
    assert env.action_space["prediction"].shape == (6,) and np.all(np.isinf(env.action_space["prediction"].high))
    _, info = env.reset(seed=2)
    target = info["prediction"]["target"]
    logits = np.zeros(6, np.float32)
    _, reward, terminated, _, info = env.step({"action": 1, "prediction": logits})
    assert not terminated and info["prediction"]["loss"] == pytest.approx(1.0)
    logits[target] = 10.0  # softmax: p = e^10 / (e^10 + 5) > 0.95
    _, reward, terminated, _, info = env.step({"action": 2, "prediction": logits})
    assert terminated
    # declared at view 2 of 7: the loss stands for the 6 steps left (the episode rule)
    assert info["prediction"]["steps"] == 6
    assert info["prediction"]["loss"] == pytest.approx(-6 * np.log(np.exp(10) / (np.exp(10) + 5)) / np.log(6), rel=1e-6)
    env.reset(seed=2)
    with pytest.raises(gym.error.InvalidAction, match="NaN or \\+inf"):
        env.step({"action": 0, "prediction": np.full(6, np.nan, np.float32)})


def test_a_rig_error_mid_episode_loses_nothing(moving):
    from jaxrecog.hardware import RigError

    class Flaky(DatasetRig):
        fail = False

        def capture(self):
            if self.fail:
                self.fail = False
                raise RigError("camera 1 timed out")
            return super().capture()

    rig = Flaky(moving["db"])
    env = ActiveRecognitionEnv(moving["model"], rig, settings=SMALL, belief=True)
    obs, _ = env.reset(seed=0)
    before = (env.configuration, env.views, obs["belief"])
    rig.fail = True
    other = (int(obs["configuration"]) + 1) % 3
    with pytest.raises(RigError, match="timed out"):
        env.step({"action": other, "prediction": np.zeros(6, np.float32)})
    assert (env.configuration, env.views) == before[:2]
    assert np.array_equal(env._obs()["belief"], before[2])
    obs, *_ = env.step({"action": other, "prediction": np.zeros(6, np.float32)})
    assert env.configuration == (other,) and env.views == 2


class _FarRig:
    """The env's rig with every capture turned into an image no class explains
    (a quarter of the capture plus a ramp): the adaptive scale weakens its evidence."""

    def __init__(self, rig):
        self.rig = rig

    def __getattr__(self, name):
        return getattr(self.rig, name)

    def capture(self):
        cap = self.rig.capture()
        ramp = np.arange(cap.images.shape[-1])[None, None, :] * 6
        return Capture(np.clip(np.asarray(cap.images, np.int32) // 4 + ramp, 1, 255).astype(np.uint8), cap.occluded)


def test_the_env_belief_is_the_recognizers_with_the_adaptive_scale(moving):
    """The env's belief update is the recognizer's own, so
    ``settings.adaptive_scale`` weakens an unexplained capture's evidence in
    the env as in a campaign (it was ignored: the plain update)."""
    from jaxrecog.recipes import THESIS
    from jaxrecog.recognizer_factory import make_recognizer

    settings = Settings(samples=64, min_per_stratum=2, adaptive_scale=32.0)
    env = ActiveRecognitionEnv(moving["model"], _FarRig(DatasetRig(moving["db"], seed=0)), settings=settings)
    adaptive = make_recognizer(moving["model"], "random", recipe=THESIS.replace(adaptive_scale=32.0))
    got, want = env_and_recognizer_beliefs(env, adaptive)
    np.testing.assert_allclose(got, want, atol=1e-5)
    plain = make_recognizer(moving["model"], "random")
    _, thesis = env_and_recognizer_beliefs(env, plain)
    assert np.abs(thesis - want).max() > 0.05  # the scale changes the belief: the test can tell them apart
    # the policy's recognizer is built with the same settings
    assert PlannerPolicy("random", env).recognizer.adaptive_scale == 32.0
