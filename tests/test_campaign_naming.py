"""The campaigns' cache names are files on disk: existing databases, models
and trial stores stay valid only while every name is byte-identical.  The
values below were computed by ``jaxrecog/experiments.py`` on main before the
campaigns package split it; a change here orphans users' caches."""

from __future__ import annotations

from pathlib import Path

import pytest

from jaxrecog.campaigns import Settings, naming

#: (settings, run id with the model file below, DB2 model path, database folder, turntable model path)
PINS = {
    "default": ({}, "edfb17bde9", "W/model-db2-K20-S100-seed0.npz", "W/database",
                "W/turntable-n50-c1-p4-s20-occ-o7/model-db2-K20-S100-seed0-cal.npz"),
    "stride8": ({"stride": 8, "n_components": 12, "samples_per_image": 30}, "ff4fd79f36",
                "W/model-db2-stride8-K12-S30-seed0.npz", "W/database-stride8",
                "W/turntable-n50-c1-p4-s20-occ-o7/model-db2-K12-S30-seed0-cal.npz"),
    "stop rule": ({"p_threshold": 0.9, "min_views": 2, "exclude_visited_positions": True, "adaptive_scale": 32.0,
                   "motion_cost": 0.5}, "d8a2a14970", "W/model-db2-K20-S100-seed0.npz", "W/database",
                  "W/turntable-n50-c1-p4-s20-occ-o7/model-db2-K20-S100-seed0-cal.npz"),
    "training": ({"likelihood": "gaussian-lowrank", "likelihood_options": {"rank": 2}, "blur_sigma": 1.0,
                  "max_shift": 2, "occluder_gray": (10, 20)}, "c22e552d8e",
                 "W/model-db2-K20-S100-seed0-gaussian-lowrank-636f06cd.npz", "W/database",
                 "W/turntable-n50-c1-p4-s20-occ-o7/model-db2-K20-S100-seed0-gaussian-lowrank-636f06cd-cal.npz"),
    "mixture": ({"likelihood": "view-mixture", "view_jitter": 2, "view_jitter_deg": 5.0, "interpolate": 1,
                 "interpolation": "flow", "off_grid_deg": 10.0}, "3d13a64a6c",
                "W/model-db2-K20-S100-seed0-view-mixture-fb874b16.npz", "W/database-vj2x5",
                "W/turntable-n50-c1-p4-s20-occ-o7-vj2x5/model-db2-K20-S100-seed0-view-mixture-fb874b16-cal.npz"),
    "student": ({"likelihood": "student-t", "likelihood_options": (("nu", "auto"),), "max_rotation": 2.0,
                 "gain_amplitude": 0.1, "seed": 3, "trials_per_object": 5}, "267e747da9",
                "W/model-db2-K20-S100-seed3-student-t-d7f6d5cb.npz", "W/database",
                "W/turntable-n50-c1-p4-s20-occ-o7/model-db2-K20-S100-seed3-student-t-d7f6d5cb-cal.npz"),
}


@pytest.fixture(scope="module")
def model_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("naming") / "m.npz"
    path.write_bytes(b"pinned model bytes")  # the run id hashes the model file's bytes
    return path


@pytest.mark.parametrize("name", PINS)
def test_cache_names_are_those_of_main(name, model_file):
    fields, rid, db2, database, turntable = PINS[name]
    s = Settings(workdir="W", **fields)
    assert naming.run_id(s, model_file) == rid
    assert str(naming.model_path(s, "DB2")) == db2
    assert str(naming.model_path(s, "DB1")) == db2.replace("model-db2", "model-db1")
    assert str(naming.database_dir(s)) == database
    tt = naming.turntable_dir(s, 50, 1, True, 4, 20, 7)
    assert str(naming.turntable_model_path(s, tt, "DB2")) == turntable
    assert str(naming.results_dir(s)) == ("W/results-stride8" if name == "stride8" else "W/results")


def test_run_options_do_not_change_the_run_id(model_file):
    base = naming.run_id(Settings(workdir="W"), model_file)
    for k, v in (("workdir", "elsewhere"), ("batch", 3), ("devices", 1), ("render_workers", 2)):
        assert naming.run_id(Settings(**{"workdir": "W", k: v}), model_file) == base, k
    assert naming.run_id(Settings(workdir="W", seed=1), model_file) != base


def test_training_params_of_the_default_and_a_changed_training():
    assert naming.training_params(Settings(), "DB1") == {"kind": "DB1", "K": 20, "samples_per_image": 100, "seed": 0}
    params = naming.training_params(Settings(likelihood="gaussian-lowrank", likelihood_options={"rank": 2},
                                             blur_sigma=1.0, max_shift=2, occluder_gray=(10, 20)), "DB2")
    assert params["augment"] == {"max_rotation": 0.0, "max_scale": 0.0, "blur_sigma": [0.0, 1.0],
                                 "gain_amplitude": 0.0, "gain_cells": 3, "occluder_gray": [10.0, 20.0], "max_shift": 2}
    assert params["likelihood"] == "gaussian-lowrank" and params["likelihood_options"] == {"rank": 2}
