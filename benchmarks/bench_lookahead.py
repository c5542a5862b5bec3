"""Time one two-step lookahead planner call at thesis size, with the myopic
planners in the same run as the reference.

C = 32 classes, L = 6 levels per camera, K = 20, positions 32 x 7 (A = 224),
float32, a random predicted prior (a Dirichlet posterior moved by the uniform
transition from configuration (3, 2)).  Reports compile time and the median /
min of repeated calls (``block_until_ready``) of

- ``mi``: the Monte Carlo MI (belief levels, J = 8 per stratum: the campaigns'
  floor), the thesis planner;
- ``mi-pairwise``: the pairwise (Bhattacharyya) MI, the lookahead's one-step score;
- ``lookahead k=.. S=..``: :func:`jaxrecog.kernels.lookahead_information` with
  that one-step score, ``top_k`` first moves, ``S`` outcomes each.

Writes JSON (default out/bench/lookahead.json).  Numbers from a shared 2-core
machine are noisy.

    python benchmarks/bench_lookahead.py [--repeat 5] [--configs 8x16,4x8] [--out PATH]
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import jax.random as jr
import numpy as np

from jaxrecog import kernels as K


def _timeit(fn, repeat):
    t0 = time.perf_counter()
    jax.block_until_ready(fn())
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return {"compile_s": round(compile_s, 3), "median_ms": round(1e3 * float(np.median(times)), 2),
            "min_ms": round(1e3 * float(np.min(times)), 2)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--configs", default="8x16,4x8", help="comma-separated TOPKxOUTCOMES")
    ap.add_argument("--batch-size", type=int, default=32, help="one-step calls per lax.map chunk (0: one vmap)")
    ap.add_argument("--out", type=Path, default=Path("out/bench/lookahead.json"))
    args = ap.parse_args(argv)

    rng = np.random.default_rng(0)
    n_c, n_l, dim, positions = 32, 6, 20, (32, 7)
    mus = tuple(jnp.asarray(rng.normal(scale=0.3, size=(v, n_c, n_l, dim)), jnp.float32) for v in positions)
    vars = tuple(jnp.asarray(rng.uniform(0.005, 0.02, size=(v, n_c, n_l, dim)), jnp.float32) for v in positions)
    post = K.Belief(jnp.asarray(np.log(rng.dirichlet(np.ones(n_c))), jnp.float32),
                    tuple(jnp.asarray(np.log(rng.dirichlet(np.ones(n_l), size=n_c)), jnp.float32) for _ in positions))
    prior = K.transition_per_position(post, (3, 2), positions)

    liks = K.gaussian_likelihoods(mus, vars)
    tables = jax.block_until_ready(K.mi_tables(liks, key=jr.PRNGKey(0), samples_per_stratum=8, store="full"))
    pw = jax.block_until_ready(K.pairwise_tables(liks, kind="bhattacharyya"))
    outcome_tables = tables._replace(ld_max=None, ld_exp=None)
    j = tables.ld[0].shape[3]

    mi = jax.jit(lambda b: K.mutual_information(tables, b))
    pmi = jax.jit(lambda b: K.pairwise_mutual_information(pw, b))
    out = {
        "sizes": {"C": n_c, "L": n_l, "K": dim, "positions": positions, "J": j, "dtype": "float32"},
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "backend": jax.default_backend()},
        "mi (Monte Carlo, J=8)": _timeit(lambda: mi(prior), args.repeat),
        "mi-pairwise": _timeit(lambda: pmi(prior), args.repeat),
    }
    for spec in args.configs.split(","):
        k, s = (int(x) for x in spec.split("x"))
        draws = K.lookahead_draws(jr.PRNGKey(1), s, j, dtype=jnp.float32)

        @jax.jit
        def la(b, draws, k=k):
            score = functools.partial(K.pairwise_mutual_information, pw)
            return K.lookahead_information(outcome_tables, score, b, draws=draws, top_k=k, batch_size=args.batch_size or None)

        res = _timeit(lambda: la(prior, draws), args.repeat)
        res["one_step_calls"] = k * s + 1
        out[f"lookahead k={k} S={s} batch={args.batch_size}"] = res
        print(spec, res, flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=2))
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
