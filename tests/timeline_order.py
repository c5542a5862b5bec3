"""The test files in the order the workers should take them: slowest first.

``make test`` runs the suite on one xdist worker per core with ``--dist
loadfile --no-loadscope-reorder``: a worker takes a whole file, the next file
in collection order when it is done.  xdist's own order (most tests first) put
a 27-second file last on one worker while the other had finished; handing the
slowest files out first (longest-processing-time scheduling) leaves only short
files for the end, where they even out the two workers.

``conftest.py`` sorts the collected tests by the ranks in
``tests/slowest_files.txt`` (files not listed keep their order, after the
listed ones).  To refresh the list from a timed run::

    JAXRECOG_TEST_TIMELINE=/tmp/tl make test    # a new folder: the files append
    python tests/timeline_order.py /tmp/tl      # rewrites tests/slowest_files.txt
"""

from __future__ import annotations

import sys
from collections import defaultdict
from pathlib import Path

LIST = Path(__file__).with_name("slowest_files.txt")
#: files at or above this many seconds of one worker are listed
MIN_SECONDS = 3.0


def listed() -> dict[str, int]:
    """``{test file: rank}`` from :data:`LIST` (rank 0: the slowest)."""
    if not LIST.is_file():
        return {}
    names = [line.split()[-1] for line in LIST.read_text().splitlines() if line.strip() and not line.startswith("#")]
    return {name: rank for rank, name in enumerate(names)}


def file_seconds(folder: Path) -> dict[str, float]:
    """Seconds per test file (setup, call and teardown of its tests) from the
    ``<worker>.tsv`` files of ``JAXRECOG_TEST_TIMELINE``."""
    seconds: dict[str, float] = defaultdict(float)
    for tsv in Path(folder).glob("*.tsv"):
        if "." in tsv.stem:  # <worker>.programs.tsv, <worker>.events.tsv
            continue
        for line in tsv.read_text().splitlines():
            start, stop, _, nodeid = line.split("\t", 3)
            seconds[nodeid.split("::")[0]] += float(stop) - float(start)
    return dict(seconds)


def write(folder: Path) -> list[tuple[str, float]]:
    ranked = sorted(((f, s) for f, s in file_seconds(folder).items() if s >= MIN_SECONDS), key=lambda x: -x[1])
    LIST.write_text("# seconds (one worker, 2 cores)  file -- written by tests/timeline_order.py\n"
                    + "".join(f"{s:6.1f}  {f}\n" for f, s in ranked))
    return ranked


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python tests/timeline_order.py TIMELINE_FOLDER")
    for name, s in write(Path(sys.argv[1])):
        print(f"{s:6.1f}  {name}")
