"""``tactojax train`` and ``eval-shape`` end to end on a small calibration dataset."""

import json

import numpy as np

from tactojax.cli import main
from tactojax.io import load_shape_model, shape_model_metadata


def test_train_lookup_then_evaluate(calibration_dataset, tmp_path, capsys):
    model_path = tmp_path / "lookup.msgpack"
    assert main(["train", str(calibration_dataset), "--preset", "lookup", "--out", str(model_path),
                 "--test-per-object", "8", "--exclude-object", "calib_semicone_1", "--no-progress"]) == 0
    metadata = shape_model_metadata(model_path)
    assert metadata["excluded"] == ["calib_semicone_1"] and metadata["pairs"] == 2 * 32
    assert load_shape_model(model_path).preset == "lookup"
    report_path, figure = tmp_path / "eval.json", tmp_path / "examples.png"
    assert main(["eval-shape", str(model_path), str(calibration_dataset), "--held-out", "8",
                 "--json", str(report_path), "--figure", str(figure)]) == 0
    report = json.loads(report_path.read_text())
    errors = report["errors"]
    assert set(errors) == {"calib_sphere", "calib_semicone_1", "calib_semipyramid", "all"}
    assert errors["all"]["count"] == 24 and errors["all"]["patch_rmse"] < 0.1
    assert figure.stat().st_size > 10_000
    printed = capsys.readouterr().out
    assert "patch RMSE" in printed and "calib_semicone_1" in printed


def test_train_tiny_writes_a_loadable_model(calibration_dataset, tmp_path):
    model_path = tmp_path / "tiny.msgpack"
    assert main(["train", str(calibration_dataset), "--preset", "tiny", "--out", str(model_path),
                 "--steps", "2", "--pixel-steps", "4", "--batch-size", "4", "--test-per-object", "8",
                 "--no-progress"]) == 0
    model = load_shape_model(model_path)
    assert model.preset == "tiny" and model.image_shape == (60, 80)
    assert not (tmp_path / "tiny.msgpack.train-state").exists()
    assert np.isfinite(shape_model_metadata(model_path)["test"]["all"]["image_rmse"])


def test_shape_commands_give_clear_errors(calibration_dataset, tmp_path, capsys):
    garbage = tmp_path / "garbage.msgpack"
    garbage.write_bytes(b"\x00" * 64)
    assert main(["eval-shape", str(garbage), str(calibration_dataset)]) == 2
    assert "not a" in capsys.readouterr().err
    assert main(["eval-shape", "bundled:nope", str(calibration_dataset)]) == 2
    assert "no bundled shape model" in capsys.readouterr().err
    assert main(["train", str(calibration_dataset), "--out", str(tmp_path / "m"), "--exclude-object", "ghost"]) == 2
    assert "ghost" in capsys.readouterr().err
