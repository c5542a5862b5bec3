"""Neighbouring views of the thesis rig as training samples
(``Settings.view_jitter``): ``prepare`` renders the ``jitter`` split into its
own database folder (the object turned a few degrees off each training pose)
and trains on it; the default keeps the thesis's database and model names."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from jaxrecog.campaigns import Settings, model_path, prepare
from jaxrecog.hardware.render.render_db import jitter_offsets
from jaxrecog.modelfile import load_model_meta


def test_offsets_alternate_and_reach_the_bound():
    assert jitter_offsets(0, 10.0) == ()
    assert jitter_offsets(4, 10.0) == (5.0, -5.0, 10.0, -10.0)
    assert jitter_offsets(1, 8.0) == (8.0,)
    for n, d in ((-1, 10.0), (2, 0.0), (2, 180.0), (2, float("nan"))):
        with pytest.raises(ValueError):
            jitter_offsets(n, d)


@pytest.mark.parametrize("field,value", [("view_jitter", -1), ("view_jitter", 1.5), ("view_jitter_deg", 0.0),
                                         ("view_jitter_deg", float("nan"))])
def test_bad_settings_name_the_field(field, value, unchecked):
    with unchecked(), pytest.raises(ValueError, match=field):
        Settings(**{field: value, **({} if field == "view_jitter" else {"view_jitter": 2})})


def test_prepare_renders_the_jitter_split_and_trains_on_it(tmp_path):
    settings = Settings(workdir=tmp_path, stride=8, view_jitter=2, view_jitter_deg=8.0, n_components=3,
                        samples_per_image=4)
    prepared = prepare(settings, databases=("DB1",))
    assert prepared.database == tmp_path / "database-stride8-vj2x8"
    with open(prepared.database / "manifest.csv") as f:
        rows = list(csv.DictReader(f))
    splits = [r["split"] for r in rows]
    assert splits.count("train") == 5 * 8 * 4 and splits.count("jitter") == 2 * 5 * 8 * 4
    # each jitter image is a different render of its labelled view, near it
    from PIL import Image

    one = [r for r in rows if (r["camera"], r["position"], r["object"], r["pose"]) == ("0", "1", "2", "3")]
    imgs = {r["split"] + r["path"][-6:]: np.asarray(Image.open(prepared.database / r["path"]), float) for r in one}
    train = next(v for k, v in imgs.items() if k.startswith("train"))
    jit = [v for k, v in imgs.items() if k.startswith("jitter")]
    assert len(jit) == 2 and all(0 < np.abs(j - train).mean() < 40 for j in jit)
    path = model_path(settings, "DB1")
    assert prepared.models["DB1"] == path and path.name.startswith("model-db1-stride8-K3-S4-seed0-gaussian-diag-")
    vj = load_model_meta(path)["training"]["params"]["view_jitter"]
    assert vj["images"] == 2 * 5 * 8 * 4 and vj["mode"] == "added"
    # the default: no jitter folder, the thesis's model name
    assert model_path(Settings(workdir=tmp_path, stride=8, n_components=3, samples_per_image=4), "DB1").name == \
        "model-db1-stride8-K3-S4-seed0.npz"
