"""The one compile counter of the tests and the benchmarks: XLA compilations
inside a block, by function name, read from ``jax.log_compiles``.

It sees every compilation (not only one wrapped function's traces), so "a
second run compiles nothing" is ``sum(counter.values()) == 0``.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import re
from collections.abc import Iterator

import jax

__all__ = ["count_compiles", "assert_steps_never_recompile"]


class _CompileLog(logging.Handler):
    def __init__(self):
        super().__init__(logging.DEBUG)
        self.names: collections.Counter[str] = collections.Counter()

    def emit(self, record):
        m = re.match(r"Compiling (?:jit\()?([\w<>.-]+)", record.getMessage())
        if m:
            self.names[m.group(1)] += 1


@contextlib.contextmanager
def count_compiles() -> Iterator[collections.Counter[str]]:
    """Count the XLA compilations inside the block by function name
    (``jax.log_compiles``): yields a ``Counter`` filled as they happen."""
    log, logger = _CompileLog(), logging.getLogger("jax")
    logger.addHandler(log)
    try:
        with jax.log_compiles():
            yield log.names
    finally:
        logger.removeHandler(log)


def assert_steps_never_recompile(rec, getkey, n_configs: int, image_shape=(2, 6, 8), steps: int = 12) -> None:
    """One warm-up step of ``rec`` on random images, then ``steps`` more
    (a new trial after each stop): no XLA compilation, every decision valid,
    its next configuration in range and its trace's scores free of NaN."""
    import jax.numpy as jnp
    import jax.random as jr
    import numpy as np

    def images():
        return jr.randint(getkey(), image_shape, 1, 255).astype(jnp.uint8)

    state = rec.init(getkey())
    state, dec = rec.step(state, images(), getkey(), trace=True)
    jax.block_until_ready(dec)
    with count_compiles() as later:
        for _ in range(steps):
            if bool(dec.stop):
                state = rec.init(getkey())
            state, dec = rec.step(state, images(), getkey(), trace=True)
            assert bool(dec.valid) and 0 <= int(dec.next_index) < n_configs
            assert not np.any(np.isnan(np.asarray(dec.trace.scores)))
    assert sum(later.values()) == 0, dict(later)
