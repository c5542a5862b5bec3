"""A soak of the Gymnasium env on the synthetic (pybullet) rig:
many steps with a random agent and with the MI planner's policy, checking
that nothing turns NaN, that resident memory stays flat after the warm-up and
that no pybullet client leaks (one per rig while the env lives, none after
``close``).

Run by hand (the figures of docs/results.md)::

    .venv/bin/python tests/soak_env.py --steps 10000

``tests/test_soak_env.py`` runs the same code for a few hundred steps.

The scene: the thesis table at stride 8 (4 x 1 positions, two cameras),
thesis objects 1, 5 and 6 (:data:`OBJECTS`) x 2 poses, 120 x 160 images with the campaigns'
capture noise and, per episode, their cardboard occluders (``case="occluded"``:
boards are added and removed at every reset); a DB1 model trained on its
rendered train split; ``p_threshold`` :data:`P_THRESHOLD`.  The random
agent moves anywhere and declares a random class in one step of five
(otherwise a uniform prediction: it runs to ``max_steps``); the MI policy is
:class:`jaxrecog.envs.PlannerPolicy` ("mi").  Each env is built on a fresh
rig and closed at the end.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # run as a script from anywhere

SETTINGS = dict(samples=64, min_per_stratum=2, stride=8)
#: the duck and the look-alike pair (thesis objects 1, 5 and 6: 5 and 6 differ
#: by a sticker seen from few views), so that episodes take several views
OBJECTS = (0, 4, 5)
#: the thesis's stop probability
P_THRESHOLD = 0.95


def rss_mb() -> float:
    """Resident memory now (not the peak), MB."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def pybullet_clients(upto: int = 256) -> int:
    """How many pybullet clients this process has connected."""
    import pybullet

    return sum(1 for i in range(upto) if pybullet.getConnectionInfo(physicsClientId=i)["isConnected"])


def make_rig(seed: int = 0):
    from jaxrecog.campaigns import Settings, rig_table
    from jaxrecog.scene import CAPTURE_NOISE
    from jaxrecog.hardware import Noise, SyntheticRig, default_objects

    b, p, s = CAPTURE_NOISE
    return SyntheticRig(rig_table(Settings(**SETTINGS)), objects=[default_objects()[i] for i in OBJECTS], n_poses=2,
                        noise=Noise(brightness=b, pixel=p, max_shift=int(s)), seed=seed)


def train(folder: Path):
    """The rig's train split rendered into ``folder`` and its DB1 model."""
    from jaxrecog import load_database, train_model
    from jaxrecog.hardware.render.render_db import render_database

    rig = make_rig()
    try:
        render_database(folder, rig=rig)
    finally:
        rig.close()
    return train_model(load_database(folder), kind="DB1", n_components=2, samples_per_image=10)


def random_policy(env, rng):
    def act(obs):
        C = env.n_classes
        if rng.random() < 0.2:
            pred = np.zeros(C, np.float32)
            pred[rng.integers(C)] = 1.0
        else:
            pred = np.full(C, 1.0 / C, np.float32)
        return {"action": np.int64(rng.integers(env.n_configs)), "prediction": pred}
    return act


def soak(model, policy: str, steps: int, seed: int = 0) -> dict:
    """``steps`` env steps with ``policy`` ("random" or a planner name):
    counts of episodes, NaNs, and memory / pybullet clients along the way."""
    from jaxrecog.envs import ActiveRecognitionEnv, PlannerPolicy
    from jaxrecog.campaigns import Settings

    clients0 = pybullet_clients()
    env = ActiveRecognitionEnv(model, make_rig(seed), case="occluded", settings=Settings(**SETTINGS),
                               p_threshold=P_THRESHOLD, features=True, belief=True)
    act = random_policy(env, np.random.default_rng(seed)) if policy == "random" else PlannerPolicy(policy, env)
    clients_live = pybullet_clients()
    nan = episodes = declared = 0
    rss: dict[str, float] = {}
    clients_seen = set()
    warm = max(1, steps // 10)
    t0 = time.perf_counter()
    obs, info = env.reset(seed=seed)
    for k in range(steps):
        obs, reward, terminated, truncated, info = env.step(act(obs))
        vals = [reward, info["belief_probability"], info["prediction"]["loss"], *obs["belief"],
                *np.concatenate([np.ravel(g) for g in obs["features"]])]
        nan += int(not np.all(np.isfinite(vals)))
        if terminated or truncated:
            episodes += 1
            declared += int(terminated)
            obs, info = env.reset()
            clients_seen.add(pybullet_clients())
        if k + 1 == warm:
            rss["after_warmup"] = rss_mb()
            t_warm = time.perf_counter()
        if k + 1 == steps // 2:
            rss["half"] = rss_mb()
    rss["end"] = rss_mb()
    dt = time.perf_counter() - t_warm if steps > warm else float("nan")
    env.close()
    return {
        "policy": policy, "steps": steps, "episodes": episodes, "declared": declared, "nan_steps": nan,
        "rss_mb": {k: round(v, 1) for k, v in rss.items()},
        "rss_growth_after_warmup": round(rss["end"] / rss["after_warmup"] - 1.0, 4),
        "pybullet_clients": {"before": clients0, "while_live": clients_live,
                             "at_resets": sorted(clients_seen), "after_close": pybullet_clients()},
        "steps_per_s": round((steps - warm) / dt, 1) if dt == dt and dt > 0 else None,
        "seconds": round(time.perf_counter() - t0, 1),
    }


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=10_000, help="env steps per policy")
    ap.add_argument("--policies", nargs="+", default=["random", "mi"])
    ap.add_argument("--out", help="also write the figures as JSON here")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        model = train(Path(tmp) / "db")
    res = [soak(model, p, args.steps) for p in args.policies]
    text = json.dumps(res, indent=2)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
