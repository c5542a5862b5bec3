"""The thesis's published results (chapter 7), for comparison tables and plots.

Each table is per object (objects 1..8) plus the average, as printed.  Table 7.3
(random camera movement) is garbled in the extracted text; the rows for objects
6-8 were reassembled from the scattered columns and check out against the
printed average (the mean of the eight rates is 90.75 %, printed 90.8 %).
"""

from __future__ import annotations

import math
from typing import NamedTuple

__all__ = ["ThesisTable", "TABLES", "SINGLE_CAMERA", "TABLE_7_8", "published"]


class ThesisTable(NamedTuple):
    name: str
    case: str  # "i", "ii", "iii"
    planner: str  # "mi", "crlb", "random"
    rate: tuple[float, ...]  # recognition rate, percent, per object
    exit_prob: tuple[float, ...]
    views: tuple[float, ...]
    average: tuple[float, float, float]  # rate %, exit prob, views


TABLES: dict[tuple[str, str], ThesisTable] = {
    ("i", "mi"): ThesisTable(
        "Table 7.1", "i", "mi",
        (100.0, 100.0, 100.0, 100.0, 100.0, 100.0, 100.0, 97.9),
        (0.98, 0.99, 0.99, 0.98, 0.97, 0.97, 0.83, 0.86),
        (1.6, 1.9, 2.2, 1.6, 3.5, 3.6, 4.3, 4.7),
        (99.7, 0.95, 2.9),
    ),
    ("i", "crlb"): ThesisTable(
        "Table 7.2", "i", "crlb",
        (100.0, 100.0, 100.0, 100.0, 100.0, 100.0, 100.0, 99.0),
        (0.99, 0.98, 0.98, 0.97, 0.97, 0.96, 0.84, 0.81),
        (1.8, 1.8, 2.3, 1.9, 3.8, 4.2, 4.9, 4.5),
        (99.9, 0.94, 3.2),
    ),
    ("i", "random"): ThesisTable(
        "Table 7.3", "i", "random",
        (100.0, 100.0, 90.6, 96.9, 90.6, 89.6, 82.3, 76.0),
        (0.96, 0.99, 0.98, 0.91, 0.83, 0.92, 0.80, 0.79),
        (2.8, 3.3, 4.7, 2.8, 5.5, 6.6, 5.9, 6.5),
        (90.8, 0.90, 4.8),
    ),
    ("ii", "mi"): ThesisTable(
        "Table 7.4", "ii", "mi",
        (45.8, 39.6, 53.1, 51.0, 42.7, 57.3, 58.3, 49.0),
        (0.97, 0.98, 0.96, 0.99, 0.97, 0.95, 0.92, 0.86),
        (4.2, 4.1, 3.6, 2.1, 3.9, 3.7, 3.3, 4.4),
        (49.6, 0.95, 3.7),
    ),
    ("ii", "crlb"): ThesisTable(
        "Table 7.5", "ii", "crlb",
        (43.8, 34.4, 47.9, 58.3, 49.0, 51.0, 52.1, 47.9),
        (0.99, 0.98, 0.99, 0.98, 0.99, 0.99, 0.89, 0.94),
        (3.0, 3.3, 2.9, 3.2, 2.9, 3.5, 3.9, 4.1),
        (48.1, 0.97, 3.4),
    ),
    ("iii", "mi"): ThesisTable(
        "Table 7.6", "iii", "mi",
        (100.0, 100.0, 100.0, 100.0, 95.8, 100.0, 96.9, 97.9),
        (0.95, 0.96, 0.91, 0.97, 0.85, 0.81, 0.87, 0.75),
        (3.7, 3.5, 4.3, 4.2, 4.4, 5.9, 5.3, 5.7),
        (98.8, 0.88, 4.6),
    ),
    ("iii", "crlb"): ThesisTable(
        "Table 7.7", "iii", "crlb",
        (100.0, 100.0, 99.0, 100.0, 97.1, 97.9, 95.8, 99.0),
        (0.95, 0.96, 0.83, 0.94, 0.81, 0.88, 0.86, 0.71),
        (3.6, 3.3, 4.1, 2.9, 4.9, 5.2, 5.3, 6.1),
        (98.6, 0.87, 4.4),
    ),
}

#: Section 7.4: MI with camera 1 only.  (rate %, views, exit prob or None)
SINGLE_CAMERA = {
    "clean": (97.8, 5.1, None),
    "occluded": (66.6, 5.8, 0.74),
}

#: Table 7.8: object probabilities (summed over poses) per step, object 6 occluded.
TABLE_7_8 = (
    (0.1250, 0.1250, 0.1250, 0.1250, 0.1250, 0.1250, 0.1250, 0.1250),
    (0.1065, 0.0333, 0.0090, 0.2062, 0.3722, 0.2553, 0.0086, 0.0088),
    (0.0040, 0.0007, 0.0000, 0.0791, 0.3912, 0.5250, 0.0000, 0.0000),
    (0.0001, 0.0000, 0.0000, 0.0062, 0.1993, 0.7944, 0.0000, 0.0000),
    (0.0000, 0.0000, 0.0000, 0.0008, 0.0119, 0.9873, 0.0000, 0.0000),
)


def published(case: str, planner_key: str | None, n_objects: int = 8) -> ThesisTable | None:
    """The thesis's numbers for a case and a planner's thesis column (``"mi"``,
    ``"crlb"``, ``"random"``: ``planners.PLANNERS[name].thesis``), or ``None``
    where the thesis has none.

    Cases ``i``, ``ii``, ``iii``: Tables 7.1-7.7.  ``single-clean`` and
    ``single-occluded`` (section 7.4, MI only): the average alone, the
    ``n_objects`` per-object values NaN (and the clean case's exit
    probability, which the thesis does not give).
    """
    table = TABLES.get((case, planner_key))
    if table is not None:
        return table
    scene = case.removeprefix("single-")
    if planner_key != "mi" or scene == case or scene not in SINGLE_CAMERA:
        return None
    rate, views, exit_prob = SINGLE_CAMERA[scene]
    nan = (math.nan,) * n_objects
    return ThesisTable("Section 7.4", case, "mi", nan, nan, nan,
                       (rate, math.nan if exit_prob is None else exit_prob, views))
