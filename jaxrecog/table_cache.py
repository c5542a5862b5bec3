"""The planners' offline tables, built once per model in a process.

:func:`~jaxrecog.kernels.pairwise_tables` is the costly part of building a
pairwise planner (every pair of components at every position: for a view
mixture of the tutorial's 8 x 4 table 2.2 s of the test run's CPU, more than
a whole ``jaxrecog plan`` besides), and it depends on the model's
likelihoods and the divergence only.  The planners that share it
(``mi-pairwise``, ``mi-class-pairwise``, ``-robust``, ``-stable``, the
lookahead) each built it again: a campaign of two of them on one model, an
env and its policies, or one process that loads the same model file twice
paid it twice.  :func:`divergence_tables` keeps the last
:data:`KEEP` results, keyed by the divergence and the likelihoods' contents
(class, shapes, dtypes and a SHA-1 of the bytes: a model loaded again from
its file hits, a retrained or recalibrated one misses).  Under a JAX trace
(likelihoods as tracers) nothing is cached.

The Monte Carlo planners' sample tables (:func:`~jaxrecog.kernels.mi_tables`,
shared by ``mi``, ``mi-class`` and ``crlb``: 2.9 s to build for the thesis's
DB2 model, most of it compiling) are kept the same way by
:func:`sample_tables`, keyed also by the PRNG key, J and what is stored: a
thesis case builds them once for its three planners, and
``reproduce_thesis.py --case all`` once per model.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict

import jax
import numpy as np

from . import kernels as K

__all__ = ["KEEP", "divergence_tables", "sample_tables", "clear"]

#: how many table sets are kept (each is a few times the model's size)
KEEP = 2

_cache: OrderedDict[tuple, K.PairwiseTables] = OrderedDict()
_samples: OrderedDict[tuple, K.MITables] = OrderedDict()


def _key(arrays, *parts) -> tuple | None:
    """``parts``, the settings a build depends on beyond its inputs (64-bit
    floats, the default PRNG) and the contents of ``arrays`` (a pytree; a
    typed PRNG key by its implementation and bits), or ``None`` under a trace."""
    leaves, treedef = jax.tree.flatten(arrays)
    if any(isinstance(x, jax.core.Tracer) for x in leaves):
        return None
    digest = hashlib.sha1()
    for x in leaves:
        if jax.dtypes.issubdtype(getattr(x, "dtype", None), jax.dtypes.prng_key):
            digest.update(str(x.dtype).encode())
            x = jax.random.key_data(x)
        a = np.ascontiguousarray(np.asarray(x))
        digest.update(f"{a.dtype.str}{a.shape}".encode())
        digest.update(a.tobytes())
    settings = (bool(jax.config.jax_enable_x64), str(jax.config.jax_default_prng_impl))
    return parts, settings, str(treedef), digest.hexdigest()


def _kept(cache: OrderedDict, key: tuple | None, build):
    """``build()``, or what ``cache`` keeps under ``key`` (the :data:`KEEP`
    latest); a build that came out traced (called inside a transform) is
    not kept."""
    if key is None:
        return build()
    if key in cache:
        cache.move_to_end(key)
        return cache[key]
    value = build()
    if any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(value)):
        return value
    cache[key] = value
    while len(cache) > KEEP:
        cache.popitem(last=False)
    return value


def divergence_tables(likelihoods, kind: str = "bhattacharyya") -> K.PairwiseTables:
    """``K.pairwise_tables(likelihoods, kind=kind)``, from the cache when the
    same likelihoods (by content) and ``kind`` were built lately."""
    return _kept(_cache, _key(tuple(likelihoods), kind), lambda: K.pairwise_tables(likelihoods, kind=kind))


def sample_tables(likelihoods, *, key, samples_per_stratum: int, store: str) -> K.MITables:
    """``K.mi_tables(likelihoods, key=key, samples_per_stratum=..., store=store)``,
    from the cache when the same likelihoods (by content), key, J and
    ``store`` were built lately (the tables are a function of these)."""
    j = int(samples_per_stratum)
    return _kept(_samples, _key((tuple(likelihoods), key), "samples", j, store),
                 lambda: K.mi_tables(likelihoods, key=key, samples_per_stratum=j, store=store))


def clear() -> None:
    """Forget every kept table set."""
    _cache.clear()
    _samples.clear()
