"""Benchmark the functional environment: env steps per second under ``vmap``.

A thesis-sized problem (32 x 7 positions, 32 classes, 6 occlusion levels per
camera, K = 20) with random Gaussians and a feature bank of ``--samples``
draws per (camera, position, class) from them; ``--envs`` environments
stepped together (``jax.vmap``), ``--steps`` steps per call inside a
``lax.scan`` with a random policy whose prediction is the belief it observes
(so episodes end by declaring as well as by truncation, and auto-reset runs).
The call is compiled once (timed apart), then the median of ``--repeat`` timed
calls under ``block_until_ready``.  Target: >= 10,000 env steps
per second on the 2-core CPU.  Writes JSON (default out/bench/env.json).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import jax.random as jr
import numpy as np

from jaxrecog.envs import FeatureBank, FunctionalEnv
from jaxrecog.kernels import gaussian
from jaxrecog.sensor_model import CameraModel, SensorModel


def thesis_sized(rng, positions=(32, 7), n_objects=8, n_poses=4, levels=6, dim=20, samples=16):
    """A random model of the thesis's sizes and a bank drawn from its Gaussians."""
    C = n_objects * n_poses
    cams, bank = [], []
    for v in positions:
        mu = rng.normal(scale=0.3, size=(v, C, levels, dim)).astype(np.float32)
        var = rng.uniform(0.005, 0.02, size=(v, C, levels, dim)).astype(np.float32)
        cams.append(CameraModel(jnp.zeros((v, 1), jnp.float32), jnp.zeros((v, 1, dim), jnp.float32),
                                jnp.ones((v, dim), jnp.float32), gaussian(jnp.asarray(mu), jnp.asarray(var))))
        k = rng.integers(levels, size=(v, C, samples))
        idx = np.arange(v)[:, None, None], np.arange(C)[None, :, None], k
        g = mu[idx] + np.sqrt(var[idx]) * rng.standard_normal((v, C, samples, dim)).astype(np.float32)
        bank.append(jnp.asarray(g))
    model = SensorModel(tuple(cams), n_objects, n_poses, tuple(float(x) for x in np.linspace(0, 0.25, levels)), (1, 1))
    return model, FeatureBank(tuple(bank))


def rollout_fn(env: FunctionalEnv, n_envs: int, n_steps: int):
    """``(states, obs, key) -> (states, obs, rewards [T, B])``: ``n_steps``
    vmapped steps of a random policy that predicts its observed belief."""
    step = jax.vmap(env.step)

    def body(carry, key):
        states, obs = carry
        k_act, k_step = jr.split(key)
        action = {"action": jr.randint(k_act, (n_envs,), 0, env.n_configs), "prediction": obs["belief"]}
        states, obs, reward, done, _ = step(states, action, jr.split(k_step, n_envs))
        return (states, obs), (reward, done)

    @jax.jit
    def rollout(states, obs, key):
        (states, obs), (rewards, dones) = jax.lax.scan(body, (states, obs), jr.split(key, n_steps))
        return states, obs, rewards, dones

    return rollout


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="out/bench/env.json")
    p.add_argument("--envs", type=int, default=1024, help="environments stepped together under vmap")
    p.add_argument("--steps", type=int, default=32, help="steps per timed call (a lax.scan)")
    p.add_argument("--samples", type=int, default=16, help="bank draws per (camera, position, class)")
    p.add_argument("--repeat", type=int, default=10)
    args = p.parse_args(argv)

    model, bank = thesis_sized(np.random.default_rng(0), samples=args.samples)
    env = FunctionalEnv(model, bank)
    states, obs = jax.jit(jax.vmap(env.reset))(jr.split(jr.PRNGKey(0), args.envs))
    rollout = rollout_fn(env, args.envs, args.steps)
    t0 = time.perf_counter()
    states, obs, rewards, dones = jax.block_until_ready(rollout(states, obs, jr.PRNGKey(1)))
    compile_s = time.perf_counter() - t0
    times, episodes = [], 0
    for i in range(args.repeat):
        t0 = time.perf_counter()
        states, obs, rewards, dones = jax.block_until_ready(rollout(states, obs, jr.PRNGKey(2 + i)))
        times.append(time.perf_counter() - t0)
        episodes += int(np.sum(dones))
    median = float(np.median(times))
    steps_per_s = args.envs * args.steps / median
    assert np.all(np.isfinite(np.asarray(rewards)))
    print(f"functional env, thesis sizes: {args.envs} envs x {args.steps} steps per call: median {1e3 * median:.1f} ms "
          f"= {steps_per_s:,.0f} env steps/s (min {args.envs * args.steps / min(times):,.0f}); compile {compile_s:.1f} s; "
          f"{episodes} episodes ended in the timed calls")
    out = {
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "jax": jax.__version__,
                    "backend": jax.default_backend(), "note": "shared machine: other processes ran beside this one"},
        "settings": vars(args) | {"positions": list(model.positions), "classes": model.n_classes,
                                  "levels": model.n_levels, "K": model.n_components},
        "compile_s": compile_s,
        "median_s": median,
        "min_s": float(np.min(times)),
        "env_steps_per_s": steps_per_s,
        "episodes_ended": episodes,
        "target_steps_per_s": 10_000,
        "ratio_vs_target": steps_per_s / 10_000,
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
