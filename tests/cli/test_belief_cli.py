"""The pose belief from the command line: ``calibrate-belief``, then ``eval-localization --test``."""

import json

import numpy as np
import pytest

from tactojax.cli import main
from tactojax.io import load_tactile_map, save_shape_model, save_tactile_map, tactile_map_metadata

GRASPS = ["--protocol", "grasps", "--grasps-per-episode", "2", "--fingers", "2", "--scale", "0.25",
          "--turns-deg", "0", "--no-progress"]


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory, cylinder_map, lookup_model, tiny_encoder_path):
    """The cylinder's map calibrated on grasps of its own (seed 11), and a separate test set (seed 12)."""
    folder = tmp_path_factory.mktemp("belief")
    map_path = str(save_tactile_map(folder / "cylinder.npz", cylinder_map))
    model = str(save_shape_model(folder / "lookup.msgpack", lookup_model))
    for name, seed, episodes in (("calibration", 11, 4), ("test", 12, 3)):
        assert main(["simulate", "cylinder", "--out", str(folder / name), *GRASPS, "--episodes", str(episodes),
                     "--seed", str(seed)]) == 0
    fits = folder / "fits.json"
    assert main(["calibrate-belief", map_path, "--grasps", str(folder / "calibration"), "--model", model,
                 "--encoder", str(tiny_encoder_path), "--rounds", "1", "--json", str(fits)]) == 0
    return folder, map_path, model, json.loads(fits.read_text())


def test_calibration_is_stored_with_the_map(calibrated, cylinder_map, capsys):
    _, map_path, _, fits = calibrated
    stored = tactile_map_metadata(map_path)["metadata"]["belief_calibration"]
    assert stored == fits["cylinder"]
    # Only the header changed: the map keeps its images (features from another encoder need them).
    np.testing.assert_array_equal(np.asarray(load_tactile_map(map_path, images=True).images),
                                  np.asarray(cylinder_map.images))
    # Per episode: a belief after every touch (grasps x fingers), and the second grasp's first finger alone.
    assert stored["beliefs"] == 4 * (2 * 2 + 1)
    assert stored["temperature"] > 0 and stored["fusion_exponent"] >= 0 and np.isfinite(stored["loss"])
    assert 0.0 <= stored["accuracy"] <= 1.0


def test_new_grasps_fuse_with_the_calibrated_belief(calibrated, tiny_encoder_path, tmp_path, capsys):
    folder, map_path, model, _ = calibrated
    report = tmp_path / "new.json"
    assert main(["eval-localization", map_path, "--test", str(folder / "test"), "--fingers", "2", "--methods",
                 "cti,belief", "--model", model, "--encoder", str(tiny_encoder_path), "--json", str(report),
                 "--figure", str(tmp_path / "new.png")]) == 0
    captured = capsys.readouterr()
    assert "holds no belief calibration" not in captured.err
    assert "belief calibration: predicted P(error <= 2 mm)" in captured.out
    result = json.loads(report.read_text())["objects"]["cylinder"]
    assert result["calibrated"]  # the belief ran with the map's stored fit
    rows = {(r["method"], r["grasps"], r["fused"]): r for r in result["results"]}
    assert rows[("cti", 1, False)]["count"] == 3 * 2 and rows[("belief", 1, False)]["count"] == 3 * 2
    assert rows[("belief", 1, True)]["count"] == 3 and rows[("belief", 2, True)]["count"] == 3
    for row in result["results"]:
        assert np.isfinite(row["median_rmse_mm"]) and row["median_symmetric_rmse_mm"] <= row["median_rmse_mm"] + 1e-6
    bins = result["calibration"]["bins"]
    assert sum(b["count"] for b in bins) == 3 * 2 + 3 * 2  # single touches and fused episodes, every grasp count
    assert all(0.0 <= b["predicted"] <= 1.0 for b in bins if b["count"])
    for row in result["results"]:  # every localization's error, for a paired comparison of two runs
        errors = np.asarray(row["per_localization"]["symmetric_rmse_mm"])
        assert len(errors) == row["count"]
        assert np.isclose(np.mean(errors <= 2.0), row["within_mm"]["2"])
        low, high = row["within_2mm_interval"]
        assert low <= row["within_mm"]["2"] <= high
        assert ("p_within_2mm" in row["per_localization"]) == (row["method"] == "belief")
    # A run compared with itself: every row present, no episode gained or lost.
    assert main(["compare", str(report), str(report), "--json", str(tmp_path / "same.json")]) == 0
    assert "p (McNemar)" in capsys.readouterr().out
    same = json.loads((tmp_path / "same.json").read_text())["rows"]
    assert len(same) == len(result["results"])
    assert all(r["within_2mm"]["gained"] == r["within_2mm"]["lost"] == 0 and r["within_2mm"]["p"] == 1.0
               for r in same)


def test_calibration_needs_the_objects_grasps(calibrated, tiny_encoder_path, tmp_path, capsys):
    folder, map_path, model, _ = calibrated
    other = tmp_path / "other"
    assert main(["simulate", "cuboid", "--out", str(other), *GRASPS, "--episodes", "1", "--seed", "3"]) == 0
    assert main(["calibrate-belief", map_path, "--grasps", str(other), "--model", model, "--encoder",
                 str(tiny_encoder_path)]) == 2
    assert "no calibration grasps of 'cylinder'" in capsys.readouterr().err
    # The default's scales belong to the default encoder's features: --search-only keeps them, so not here.
    assert main(["calibrate-belief", map_path, "--grasps", str(folder / "calibration"), "--model", model,
                 "--encoder", str(tiny_encoder_path), "--search-only"]) == 2
    assert "--search-only keeps the default's scales" in capsys.readouterr().err


def test_identify_fuses_the_grasps_of_each_episode(calibrated, gum_box_map, tiny_encoder_path, tmp_path, capsys):
    folder, map_path, model, _ = calibrated
    gum_box = str(save_tactile_map(tmp_path / "gum_box.npz", gum_box_map))
    gum_box_test = tmp_path / "test-gum_box"
    assert main(["simulate", "gum_box", "--out", str(gum_box_test), *GRASPS, "--episodes", "2", "--seed", "5"]) == 0
    report = tmp_path / "id.json"
    assert main(["identify", map_path, gum_box, "--test", str(folder / "test"), str(gum_box_test), "--model", model,
                 "--encoder", str(tiny_encoder_path), "--json", str(report), "--figure", str(tmp_path / "id.png")]) == 0
    assert "P(object) from the pose beliefs of the maps in play" in capsys.readouterr().out
    assert (tmp_path / "id.png").stat().st_size > 0
    result = json.loads(report.read_text())
    assert result["objects"] == ["cylinder", "gum_box"]
    # The shared calibration: the median of the maps' own (only the cylinder has one).
    assert result["calibration"]["temperature"] == pytest.approx(
        tactile_map_metadata(map_path)["metadata"]["belief_calibration"]["temperature"])
    assert [(r["grasps"], r["fingers"], r["count"]) for r in result["results"]] == [(1, 2, 5), (2, 2, 5)]
    for row in result["results"]:
        assert 0.0 <= row["top1"] <= 1.0 and 0.0 <= row["mean_probability_of_truth"] <= 1.0
        assert set(row["per_object_top1"]) == {"cylinder", "gum_box"}
        assert 1.0 <= row["mean_maps_weighed"] <= 2.0
    assert result["results"][0]["mean_maps_weighed"] == 2.0  # the first grasp weighs every map
    # The confusion after the last grasp: one row per true object, its diagonal the top-1 hits.
    confusion = np.array(result["confusion"]["true_by_identified"])
    assert result["confusion"]["grasps"] == 2 and confusion.sum() == 5
    assert np.trace(confusion) / confusion.sum() == pytest.approx(result["results"][-1]["top1"])
