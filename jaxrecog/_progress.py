"""Progress bars for long jobs (rendering, training, campaigns).

A thin wrapper over ``tqdm``: a bar shows counts, rate and time left when the
output is a terminal; it stays silent when output goes to a file or pipe, or
when quiet mode is on (``--quiet``).  Library functions take plain callbacks
(``progress(n)`` or ``progress(done, total)``); :func:`bar` builds them.
"""

from __future__ import annotations

import contextlib
import sys
from typing import Iterator

__all__ = ["set_quiet", "enabled", "bar", "Bar"]

_QUIET = False


def set_quiet(quiet: bool) -> None:
    """Turn every bar off (``True``) or back to the terminal rule (``False``)."""
    global _QUIET
    _QUIET = bool(quiet)


def enabled(stream=None) -> bool:
    """Bars are drawn only on a terminal and when not quiet."""
    stream = sys.stderr if stream is None else stream
    if _QUIET:
        return False
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


class Bar:
    """A counter with a bar (or none).  ``update(n)`` adds ``n`` items;
    ``set(done, total)`` fits the ``progress(done, total)`` callbacks of
    :func:`jaxrecog.train_model`."""

    def __init__(self, total: int | None, desc: str, unit: str, stream=None):
        self.n = 0
        self.total = total
        self._tqdm = None
        if enabled(stream):
            from tqdm import tqdm

            self._tqdm = tqdm(total=total, desc=desc, unit=unit, file=stream or sys.stderr,
                              dynamic_ncols=True, leave=True)

    def update(self, n: int = 1) -> None:
        self.n += int(n)
        if self._tqdm is not None:
            self._tqdm.update(int(n))

    def set(self, done: int, total: int | None = None) -> None:
        if total is not None and self._tqdm is not None and self._tqdm.total != total:
            self._tqdm.total = total
            self._tqdm.refresh()
        self.update(int(done) - self.n)

    def close(self) -> None:
        if self._tqdm is not None:
            self._tqdm.close()
            self._tqdm = None


@contextlib.contextmanager
def bar(total: int | None, desc: str, unit: str = "it", stream=None) -> Iterator[Bar]:
    """``with bar(100, "render", "img") as b: ... b.update(1)``."""
    b = Bar(total, desc, unit, stream)
    try:
        yield b
    finally:
        b.close()
