"""The env with RL libraries: ap-gym's active-classification base
and its wrappers, the flat-action variant ``jaxrecog/ActiveRecognitionFlat-v0``
that stable-baselines3 and CleanRL take as it is (gymnasium's checker, a
random rollout, a CleanRL-style vector env), the episode rule (a declaration
stands for the steps it skips), a forked AsyncVectorEnv failing at once with a
line naming spawn, and the env without ap_gym."""

from __future__ import annotations

import json
import subprocess
import sys
import time
import warnings
from pathlib import Path

import ap_gym
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from jaxrecog import save_model, train_model, write_database
from jaxrecog.envs import AP_GYM, ENV_ID, FLAT_ENV_ID, ActiveRecognitionEnv, FlatActions
from jaxrecog.campaigns import Settings
from jaxrecog.hardware import DatasetRig
from builders import moving_database

SMALL = Settings(samples=64, min_per_stratum=2)
TESTS = Path(__file__).resolve().parent


@pytest.fixture(scope="module")
def moving(tmp_path_factory):
    """The one-camera database whose position 2 shows the object (3 positions,
    3 objects x 2 poses), as files, and its DB1 model."""
    root = tmp_path_factory.mktemp("moving-rl")
    db = moving_database()
    model = train_model(db, kind="DB1", n_components=2, samples_per_image=10)
    write_database(root / "db", db)
    save_model(root / "model.npz", model)
    return {"db": db, "model": model, "rig": f"dataset:{root / 'db'}", "path": str(root / "model.npz")}


def make(moving, env_id=ENV_ID, **kw):
    kw.setdefault("settings", SMALL)
    return gym.make(env_id, model=moving["path"], rig=moving["rig"], **kw)


def test_the_env_is_an_ap_gym_active_classification_env(moving):
    assert AP_GYM
    env = make(moving, prediction="logits").unwrapped
    assert isinstance(env, ap_gym.ActiveClassificationEnv)
    assert isinstance(env.action_space, ap_gym.ActivePerceptionActionSpace)
    assert isinstance(env.prediction_space, ap_gym.LogitSpace) and env.inner_action_space == gym.spaces.Discrete(3)
    assert env.prediction_target_space == gym.spaces.Discrete(6)
    assert ap_gym.ensure_active_perception_env(env) is env
    # ap-gym's own log wrapper runs it and reports its episode metrics
    logged = ap_gym.ActiveClassificationLogWrapper(env)
    obs, info = logged.reset(seed=1)
    logits = np.zeros(6, np.float32)
    for a in (1, 2):
        obs, reward, terminated, truncated, info = logged.step({"action": a, "prediction": logits})
    assert not (terminated or truncated)
    logits[info["prediction"]["target"]] = 10.0
    *_, terminated, _, info = logged.step({"action": 0, "prediction": logits})
    assert terminated and info["stats"]["scalar"]["final_accuracy"] == 1.0
    assert info["stats"]["scalar"]["avg_accuracy"] == pytest.approx(1 / 3)


@pytest.mark.parametrize("form", ["probabilities", "logits", "index"])
def test_ap_gym_loss_fn_is_the_rewards_loss(moving, form):
    env = make(moving, prediction=form).unwrapped
    _, info = env.reset(seed=4)
    target = info["prediction"]["target"]
    other = (target + 1) % 6
    pred = {"probabilities": np.eye(6, dtype=np.float32)[other] * 0.9 + 0.01,
            "logits": np.arange(6, dtype=np.float32) / 3, "index": np.int64(6)}[form]
    _, reward, terminated, _, info = env.step({"action": 1, "prediction": pred})
    assert not terminated and info["prediction"]["steps"] == 1
    assert reward == pytest.approx(-float(env.loss_fn(pred, np.int64(target))), rel=1e-5)


def test_the_index_rule_a_declaration_stands_for_the_steps_it_skips(moving):
    """Return = minus the steps without the right answer: a blind guess at once
    costs what never answering costs (max_steps); it used to cost 1, as one
    "not yet", so PPO learned to guess at once."""
    env = make(moving, prediction="index", max_steps=5).unwrapped

    def run(predictions):
        _, info = env.reset(seed=7)
        t = info["prediction"]["target"]
        total, out = 0.0, None
        for p in predictions:
            out = env.step({"action": 2, "prediction": np.int64({"right": t, "wrong": (t + 1) % 6, "wait": 6}[p])})
            total += out[1]
            if out[2] or out[3]:
                break
        return total, out[2], out[3], out[4]["prediction"]

    assert run(["wrong"])[:3] == (-5.0, True, False)  # at the first view: stands for all 5 steps
    assert run(["right"])[:3] == (0.0, True, False)
    total, terminated, _, pred = run(["wait", "wait", "wrong"])
    assert (total, terminated, pred["steps"], pred["loss"]) == (-5.0, True, 3, 3.0)
    assert run(["wait", "right"])[:2] == (-1.0, True)
    assert run(["wait"] * 5)[:3] == (-5.0, False, True)  # never answering: truncated after 5
    # class weights too: a confident wrong declaration at view 1 counts 5 times
    env = make(moving, max_steps=5).unwrapped
    _, info = env.reset(seed=7)
    wrong = np.eye(6, dtype=np.float32)[(info["prediction"]["target"] + 1) % 6]
    _, reward, terminated, _, info = env.step({"action": 0, "prediction": wrong})
    assert terminated and info["prediction"]["steps"] == 5
    assert reward == pytest.approx(-5 * np.log(1e12) / np.log(6))


def _no_wrapper_warning():
    # check_env warns that a wrapper is not the raw env: FlatActions is one on purpose
    warnings.filterwarnings("ignore", message=".*is different from the unwrapped version")


@pytest.mark.parametrize("options", [{}, {"action": "per-camera", "prediction": "index"},
                                     {"observation": "dict", "prediction": "logits"}])
def test_flat_variant_passes_check_env_and_a_random_rollout(moving, options):
    env = make(moving, FLAT_ENV_ID, **options)
    with warnings.catch_warnings():
        _no_wrapper_warning()
        check_env(env)
    base = env.unwrapped
    expected = gym.spaces.MultiDiscrete([3]) if options.get("action") == "per-camera" else gym.spaces.Discrete(3)
    assert env.action_space == expected
    if "observation" not in options:
        assert env.observation_space == gym.spaces.Box(0.0, 1.0, (6 + 3 + 1,), np.float32)
    env.action_space.seed(0)
    obs, info = env.reset(seed=0)
    ends = steps = 0
    while ends < 4:
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        steps += 1
        assert obs in env.observation_space and np.isfinite(reward)
        if terminated:  # the recognizer's rule: the belief reached P_th
            assert info["belief_probability"] >= base.p_threshold
        if terminated or truncated:
            ends += 1
            obs, info = env.reset()
    assert steps <= 4 * base.max_steps
    if "observation" not in options:  # the observation: P(c), a one-hot position, views / max_steps
        np.testing.assert_allclose(obs[:6], base.class_belief)
        assert obs[6:9].tolist() == np.eye(3)[base.configuration[0]].tolist() and obs[9] == pytest.approx(1 / 7)
    with pytest.raises(gym.error.InvalidAction, match="outside"):
        FlatActions(base).step(0.5)
    env.close()


def test_flat_variant_in_a_cleanrl_style_vector_env(moving):
    """CleanRL's ppo.py: SyncVectorEnv of gym.make + RecordEpisodeStatistics, Box obs, Discrete action."""
    envs = gym.vector.SyncVectorEnv(
        [lambda: gym.wrappers.RecordEpisodeStatistics(make(moving, FLAT_ENV_ID)) for _ in range(2)])
    assert isinstance(envs.single_action_space, gym.spaces.Discrete)
    assert isinstance(envs.single_observation_space, gym.spaces.Box)
    obs, _ = envs.reset(seed=0)
    envs.action_space.seed(1)
    returns = []
    for _ in range(12):
        obs, reward, terminated, truncated, info = envs.step(envs.action_space.sample())
        assert obs.shape == (2, 10) and reward.shape == (2,)
        if "episode" in info:
            returns += list(info["episode"]["r"][info["_episode"]])
    assert returns and all(np.isfinite(returns))
    envs.close()


def test_flat_actions_rejects_what_it_cannot_wrap(moving):
    with pytest.raises(ValueError, match="observation must be one of 'belief', 'dict'"):
        make(moving, FLAT_ENV_ID, observation="pixels")
    with pytest.raises(TypeError, match="wraps an ActiveRecognitionEnv"):
        FlatActions(gym.make("CartPole-v1"))


def _script(body: str) -> str:
    return (f"import sys; sys.path.insert(0, {str(TESTS)!r})\n"
            "from builders import moving_database\n"
            "from jaxrecog import train_model\n"
            "from jaxrecog.campaigns import Settings\n"
            "from jaxrecog.hardware import DatasetRig\n"
            "db = moving_database()\n"
            "model = train_model(db, kind='DB1', n_components=2, samples_per_image=10)\n"
            "S = Settings(samples=64, min_per_stratum=2)\n" + body)


def test_async_vector_env_with_fork_fails_at_once_naming_spawn(moving, capfd):
    """A forked worker used to hang in its first JAX call (JAX has started in
    this process: the vector env builds one env here first); now the env
    refuses to start in it, and the vector env fails within seconds."""
    mk = lambda: ActiveRecognitionEnv(moving["model"], DatasetRig(moving["db"], seed=0), settings=SMALL)  # noqa: E731
    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # JAX's own "os.fork() was called" warning
        with pytest.raises((EOFError, BrokenPipeError, ConnectionError, RuntimeError)):
            envs = gym.vector.AsyncVectorEnv([mk, mk], context="fork")  # Linux's default start method
            envs.reset(seed=0)
    assert time.perf_counter() - t < 30  # at once, not a hang
    err = capfd.readouterr().err
    assert "RuntimeError: ActiveRecognitionEnv cannot run in a process forked after JAX started" in err
    assert "context='spawn'" in err


def test_without_ap_gym_the_env_is_a_plain_gymnasium_env_with_the_same_rewards(moving):
    """The ap_gym base is optional: without it the env (and the flat variant)
    passes gymnasium's checker and gives the rewards it gives on ap-gym."""
    body = ("import sys as _s, json, warnings; _s.modules['ap_gym'] = None\n"
            "warnings.simplefilter('error')\n"
            "warnings.filterwarnings('ignore', message='.*is different from the unwrapped version')\n"
            "import gymnasium as gym\n"
            "from gymnasium.utils.env_checker import check_env\n"
            "from jaxrecog.envs import AP_GYM, ENV_ID, FLAT_ENV_ID\n"
            "from jaxrecog.envs.active_recognition import AP_GYM_MISSING\n"
            "env = gym.make(ENV_ID, model=model, rig=DatasetRig(db, seed=0), settings=S)\n"
            "check_env(env.unwrapped)\n"
            "flat = gym.make(FLAT_ENV_ID, model=model, rig=DatasetRig(db, seed=0), settings=S)\n"
            "check_env(flat)\n"
            "flat.reset(seed=5)\n"
            "rewards = [flat.step(a)[1] for a in (0, 1)]\n"
            "mro = [c.__name__ for c in type(env.unwrapped).__mro__]\n"
            "print(json.dumps({'ap_gym': AP_GYM, 'missing': AP_GYM_MISSING, 'mro': mro, 'rewards': rewards}))\n")
    p = subprocess.run([sys.executable, "-c", _script(body)], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout.strip().splitlines()[-1])
    assert out["ap_gym"] is False and "ap_gym" in out["missing"]
    assert "ActiveClassificationEnv" not in out["mro"] and "Env" in out["mro"]
    flat = gym.make(FLAT_ENV_ID, model=moving["model"], rig=DatasetRig(moving["db"], seed=0), settings=SMALL)
    flat.reset(seed=5)
    np.testing.assert_allclose(out["rewards"], [flat.step(a)[1] for a in (0, 1)], rtol=1e-5)
