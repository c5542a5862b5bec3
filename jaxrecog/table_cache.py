"""The pairwise-distance planners' divergence tables, built once per model in a process.

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
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict

import jax
import numpy as np

from . import kernels as K

__all__ = ["KEEP", "divergence_tables", "clear"]

#: how many table sets are kept (each is a few times the model's size)
KEEP = 2

_cache: OrderedDict[tuple, K.PairwiseTables] = OrderedDict()


def _key(likelihoods, kind: str) -> tuple | None:
    leaves, treedef = jax.tree.flatten(tuple(likelihoods))
    if any(isinstance(x, jax.core.Tracer) for x in leaves):
        return None
    digest = hashlib.sha1()
    for x in leaves:
        a = np.ascontiguousarray(np.asarray(x))
        digest.update(f"{a.dtype.str}{a.shape}".encode())
        digest.update(a.tobytes())
    return kind, str(treedef), digest.hexdigest()


def divergence_tables(likelihoods, kind: str = "bhattacharyya") -> K.PairwiseTables:
    """``K.pairwise_tables(likelihoods, kind=kind)``, from the cache when the
    same likelihoods (by content) and ``kind`` were built lately."""
    key = _key(likelihoods, kind)
    if key is None:
        return K.pairwise_tables(likelihoods, kind=kind)
    if key in _cache:
        _cache.move_to_end(key)
        return _cache[key]
    tables = K.pairwise_tables(likelihoods, kind=kind)
    _cache[key] = tables
    while len(_cache) > KEEP:
        _cache.popitem(last=False)
    return tables


def clear() -> None:
    """Forget every kept table set."""
    _cache.clear()
