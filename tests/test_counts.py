"""One counts check wherever a model meets a database or a rig: without it,
``recognize --rig dataset:`` on a 4-pose database with a 3 x 2
model printed "correct, P = 1.000" for the wrong pose."""

from __future__ import annotations

import pytest
from builders import make_database, random_sensor_model

from jaxrecog import save_model, write_database
from jaxrecog.counts import CountsMismatchError, check_counts

#: 3 objects x 2 poses, one camera of 3 positions, 6 x 8 images
MODEL = dict(positions=(3,), n_objects=3, n_poses=2, hw=(6, 8))


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    root = tmp_path_factory.mktemp("counts")
    model = random_sensor_model(**MODEL)
    save_model(root / "m.npz", model)
    four = make_database(positions=(3,), n_objects=3, n_poses=4, image_shape=(6, 8), n_test=1, n_calib=1)
    write_database(root / "db4", four)
    return {"root": root, "model": model, "four": four}


def test_the_message_names_every_count_that_differs_in_one_line(files):
    model = files["model"]
    other = make_database(positions=(3, 2), n_objects=4, n_poses=2, image_shape=(12, 16))
    with pytest.raises(CountsMismatchError) as e:
        check_counts(model, other, model_name="m.npz", other_name="database db")
    assert str(e.value) == ("database db does not match model m.npz: positions (3, 2) per camera vs the model's (3,); "
                            "4 objects vs the model's 3; images 12x16 vs the model's 6x8")
    check_counts(model, make_database(positions=(3,), n_objects=3, n_poses=2, image_shape=(6, 8)))  # fits
    # a count one side does not know is not checked; ``only`` narrows the check
    class Rig:
        positions, image_shape = (3,), (6, 8)
    check_counts(model, Rig())
    check_counts(model, files["four"], only=("positions", "image"))


def test_recognize_on_a_database_with_other_poses_is_refused_before_any_step(files, capsys):
    from jaxrecog import cli

    rig = f"dataset:{files['root'] / 'db4'}"
    code = cli.main(["recognize", str(files["root"] / "m.npz"), "--rig", rig, "--object", "1", "--pose", "1",
                     "--samples", "16", "--min-per-stratum", "1"])
    out, err = capsys.readouterr()
    assert code == 1 and "result:" not in out
    assert err.splitlines() == [f"jaxrecog: error: rig {rig} does not match model {files['root'] / 'm.npz'}: "
                                "4 poses vs the model's 2"]


def test_a_database_campaign_the_env_a_feature_bank_and_calibration_use_the_same_check(files):
    from jaxrecog import campaigns as ex
    from jaxrecog.calibration import CalibrationError, features_from_database
    from jaxrecog.envs import ActiveRecognitionEnv
    from jaxrecog.envs.functional import bank_from_database
    from jaxrecog.hardware import DatasetRig

    model, four, root = files["model"], files["four"], files["root"]
    tail = "does not match model {}: 4 poses vs the model's 2"
    with pytest.raises(CountsMismatchError, match="^database .*db4 " + tail.format(".*m.npz") + "$"):
        ex.run_dataset(root / "db4", root / "m.npz", ex.Settings(workdir=root / "work"))
    with pytest.raises(CountsMismatchError, match="^rig DatasetRig " + tail.format("").replace("model :", "the model:")):
        ActiveRecognitionEnv(model, DatasetRig(four), settings=ex.Settings(samples=16, min_per_stratum=1))
    with pytest.raises(CountsMismatchError, match="^database <in memory> does not match the model: 4 poses"):
        bank_from_database(model, four)
    with pytest.raises(CalibrationError, match="^database <in memory> does not match the model: 4 poses vs the model's 2$"):
        features_from_database(model, four)
