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

__all__ = ["count_compiles"]


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
