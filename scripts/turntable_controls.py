#!/usr/bin/env python
"""Controls of the 50-object turntable campaign (docs/results.md, "Turntable set"):
the same objects and model with the test views ON the training grid (offset 0),
and the uncalibrated model off and on the grid.  Run after
``scripts/reproduce_thesis.py --case turntable --objects 50 --workdir out/turntable``."""
import time, os
from pathlib import Path
from jaxrecog.campaigns import Settings, run_dataset
from jaxrecog.hardware.render.random_objects import random_objects
from jaxrecog.hardware.render.turntable import render_turntable
from jaxrecog.metrics import campaign_metrics
from jaxrecog.results import format_rate
from jaxrecog.calibration import uncalibrated
from jaxrecog.modelfile import load_model, save_model
work = Path("out/turntable")
base = work / "turntable-n50-c1-p4-s20"
ongrid = work / "turntable-n50-c1-p4-s20-ongrid"
cal = base / "model-db1-K20-S100-seed0-cal.npz"
unc = base / "model-db1-K20-S100-seed0-uncal.npz"
if not unc.exists():
    save_model(unc, uncalibrated(load_model(cal)))
t = time.perf_counter()
if not (ongrid / "manifest.csv").exists():
    render_turntable(ongrid, random_objects(50), test_per_view=2, calib_per_view=0, test_offset=0.0)
print("render", time.perf_counter() - t, flush=True)
s = Settings(workdir=work, trials_per_object=10)
for name, folder, model in (("on-grid, calibrated", ongrid, cal), ("off-grid, uncalibrated", base, unc),
                            ("on-grid, uncalibrated", ongrid, unc)):
    r = run_dataset(folder, model, s, planners=("mi-class-pairwise", "random"))
    for p, res in r.results.items():
        m = campaign_metrics(res)
        print(f"| {name} | {p} | {m['trials']} | {format_rate(m['recognition_rate'], m['recognition_rate_ci'])} | {m['mean_views']:.2f} | {format_rate(m['confident_error_pct_of_trials'], m['confident_error_pct_of_trials_ci'])} | {m['ece']:.3f} | {r.seconds[p]:.0f} |", flush=True)
