"""benchmarks/bench_recognizer.py's paired timing: two models' steps timed
alternately, both medians and the ratios, finite."""

from __future__ import annotations

import numpy as np
from builders import random_sensor_model
from clirun import script

from jaxrecog.campaigns import Settings


def test_paired_step_ratio_times_both_models_alternately():
    bench = script("bench_recognizer", "benchmarks")
    a, b = random_sensor_model(seed=0), random_sensor_model(seed=1)
    images = np.random.default_rng(0).integers(1, 255, (2, 6, 8)).astype(np.uint8)
    out = bench.paired_step_ratio(a, b, "mi-class-pairwise", Settings(), images, repeat=5)
    assert out["steps_each"] == 5 and len(out["median_ms"]) == 2
    assert all(np.isfinite(x) and x > 0 for x in out["median_ms"])
    assert out["ratio_of_medians"] == out["median_ms"][1] / out["median_ms"][0]
    assert np.isfinite(out["median_pair_ratio"]) and out["median_pair_ratio"] > 0
