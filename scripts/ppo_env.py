"""PPO (stable-baselines3) on ``jaxrecog/ActiveRecognitionFlat-v0``, with its
learning curve against the random and the MI policies (docs/envs.md).

Needs the ``rl`` extra (``pip install -e '.[rl]'``: stable-baselines3 and
torch, a CPU build is enough).  No user wrapper: the registered flat variant
is what PPO trains on.  The agent picks the next camera configuration; the
prediction is the recognizer's belief (so every policy stops by the same
rule, P(c) >= P_th, or after max_steps image sets).  Every ``--eval-every``
steps the deterministic policy plays the same ``--episodes`` evaluation
scenes (seeds 10000, 10001, ...) as the random policy and the MI planner
(``PlannerPolicy("mi")``) did.

    python scripts/ppo_env.py                       # the docs' run (a few minutes)
    python scripts/ppo_env.py --steps 512 --eval-every 256 --episodes 4   # a smoke run

Writes ``WORKDIR/ppo_env.json`` (the curve, the baselines, wall times) and the
figure (``--figure``, default ``WORKDIR/ppo_env.png``; the docs' figure is
``--figure docs/figures/ppo_env.png``, a tracked file, so never the default).
Each printed rate carries its 95 % Wilson interval over the episodes.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def episode(env, act, seed):
    """One evaluation episode: (right, views, return)."""
    obs, info = env.reset(seed=seed)
    ret, done = 0.0, False
    while not done:
        obs, reward, terminated, truncated, info = env.step(act(obs))
        ret, done = ret + reward, terminated or truncated
    return float(info["belief_class"] == info["prediction"]["target"]), float(info["views"]), float(ret)


def evaluate(env, act, seeds):
    rows = np.array([episode(env, act, s) for s in seeds])
    n = len(rows)
    right, views, ret = rows.T
    return {"rate": float(right.mean()), "rate_se": float(np.sqrt(right.mean() * (1 - right.mean()) / n)),
            "views": float(views.mean()), "return": float(ret.mean()), "episodes": n}


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (the docs tests parse the docs' commands with it)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--case", default="occluded", choices=("clean", "occluded"))
    ap.add_argument("--stride", type=int, default=4, help="every stride-th position per camera (4: 8 x 2 = 16 configurations)")
    ap.add_argument("--steps", type=int, default=6144, help="PPO environment steps")
    ap.add_argument("--eval-every", type=int, default=1024)
    ap.add_argument("--episodes", type=int, default=48, help="evaluation episodes per point")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workdir", default="out/ppo-env", help="rendered database and model cache, and the JSON")
    ap.add_argument("--figure", default=None,
                    help="the learning-curve figure (default: WORKDIR/ppo_env.png, under out/)")
    ap.add_argument("--plot-only", metavar="JSON", help="redraw the figure from a run's ppo_env.json")
    return ap


def parse_args(argv=None) -> argparse.Namespace:
    """The options, ``--figure`` defaulting to ``WORKDIR/ppo_env.png``."""
    args = build_parser().parse_args(argv)
    if args.figure is None:
        args.figure = str(Path(args.workdir) / "ppo_env.png")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.plot_only:
        plot(json.loads(Path(args.plot_only).read_text()), args.figure)
        return 0

    import gymnasium as gym
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback

    from jaxrecog.envs import FLAT_ENV_ID, PlannerPolicy
    from jaxrecog.campaigns import Settings

    torch.set_num_threads(1)
    settings = Settings(workdir=args.workdir, stride=args.stride)
    t0 = time.perf_counter()
    make = lambda observation="belief": gym.make(FLAT_ENV_ID, case=args.case, settings=settings,  # noqa: E731
                                                observation=observation)
    env, eval_env = make(), make()
    setup_s = time.perf_counter() - t0
    seeds = [10_000 + i for i in range(args.episodes)]

    t = time.perf_counter()
    eval_env.action_space.seed(args.seed)
    random = evaluate(eval_env, lambda obs: eval_env.action_space.sample(), seeds)
    random["wall_s"] = time.perf_counter() - t
    t = time.perf_counter()
    mi_env = make("dict")  # the planner reads the images, as a campaign does
    mi_policy = PlannerPolicy("mi", mi_env)
    mi = evaluate(mi_env, lambda obs: mi_policy(obs)["action"], seeds)
    mi["wall_s"] = time.perf_counter() - t
    print(baselines_line(setup_s, random, mi), flush=True)

    model = PPO("MlpPolicy", env, n_steps=256, batch_size=64, n_epochs=4, learning_rate=3e-4, gamma=0.99,
                ent_coef=0.01, policy_kwargs={"net_arch": [64, 64]}, seed=args.seed, device="cpu", verbose=0)
    curve = []
    train_s = [0.0]

    def point(steps):
        t = time.perf_counter()
        r = evaluate(eval_env, lambda obs: model.predict(obs, deterministic=True)[0], seeds)
        r.update(steps=int(steps), eval_s=time.perf_counter() - t, train_s=train_s[0])
        curve.append(r)
        print(point_line(r), flush=True)

    class Every(BaseCallback):
        def _on_training_start(self):
            self._t = time.perf_counter()

        def _on_step(self):
            if self.num_timesteps % args.eval_every == 0:
                train_s[0] += time.perf_counter() - self._t
                point(self.num_timesteps)
                self._t = time.perf_counter()
            return True

    point(0)
    model.learn(total_timesteps=args.steps, callback=Every())
    out = {"case": args.case, "stride": args.stride, "positions": list(env.unwrapped.positions),
           "classes": env.unwrapped.n_classes, "setup_s": setup_s, "random": random, "mi": mi, "ppo": curve,
           "ppo_train_s": train_s[0], "steps": args.steps}
    Path(args.workdir).mkdir(parents=True, exist_ok=True)
    (Path(args.workdir) / "ppo_env.json").write_text(json.dumps(out, indent=1))
    plot(out, args.figure)
    print(done_line(out, args.figure))
    return 0


def baselines_line(setup_s: float, random: dict, mi: dict) -> str:
    """The first printed line: setup time and the two baseline policies."""
    return (f"setup {setup_s:.0f} s; random: {_rate(random)} %, {random['views']:.2f} views; "
            f"MI: {_rate(mi)} %, {mi['views']:.2f} views")


def _rate(r: dict) -> str:
    """An evaluation's rate (%) with its 95 % Wilson interval over its episodes."""
    from jaxrecog.results import format_rate, wilson_interval

    n = int(r["episodes"])
    lo, hi = wilson_interval(int(round(r["rate"] * n)), n)
    return format_rate(100 * r["rate"], (100 * lo, 100 * hi))


def point_line(r: dict) -> str:
    """The printed line of one evaluation of the PPO policy (a ``curve`` entry)."""
    return (f"PPO {r['steps']:6d} steps: {_rate(r)} %, {r['views']:.2f} views, return {r['return']:.2f} "
            f"(training so far {r['train_s']:.0f} s)")


def done_line(out: dict, figure: str) -> str:
    return f"PPO trained {out['steps']} steps in {out['ppo_train_s']:.0f} s; wrote {figure}"


def printed(out: dict, figure: str) -> str:
    """What a run printed, rebuilt from its ``ppo_env.json`` (``out``): the
    docs/envs.md output block is checked against the recorded run with it."""
    lines = [baselines_line(out["setup_s"], out["random"], out["mi"]), *map(point_line, out["ppo"]),
             done_line(out, figure)]
    return "\n".join(lines) + "\n"


def plot(out, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = [p["steps"] for p in out["ppo"]]
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.4))
    for ax, key, label in ((axes[0], "rate", "right at the end (%)"), (axes[1], "views", "views per episode"),
                           (axes[2], "return", "return per episode (PPO's objective)")):
        scale = 100 if key == "rate" else 1
        y = np.array([p[key] for p in out["ppo"]]) * scale
        ax.plot(steps, y, "o-", color="C0", label="PPO (deterministic)")
        if key == "rate":
            se = np.array([p["rate_se"] for p in out["ppo"]]) * 100
            ax.fill_between(steps, y - se, y + se, color="C0", alpha=0.2)
        for name, color in (("random", "C3"), ("mi", "C2")):
            b = out[name]
            ax.axhline(b[key] * scale, color=color, ls="--", label=f"{name.upper() if name == 'mi' else name} policy")
            if key == "rate":
                ax.axhspan((b[key] - b["rate_se"]) * 100, (b[key] + b["rate_se"]) * 100, color=color, alpha=0.1)
        ax.set_xlabel("PPO environment steps")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, loc="lower right")
    n = out["ppo"][0]["episodes"]
    fig.suptitle(f"PPO on ActiveRecognitionFlat-v0 ({out['case']}, {out['positions'][0]} x {out['positions'][1]} "
                 f"configurations, {out['classes']} classes; {n} evaluation episodes per point, rate ±1 s.e.; "
                 f"training {out['ppo_train_s']:.0f} s for {out['steps']} steps)", fontsize=9)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    raise SystemExit(main())
