"""``tactojax eval-localization``, ``identify`` and ``localize`` end to end on two small maps."""

import json

import cv2
import numpy as np
import pytest

from tactojax.cli import main
from tactojax.io import save_shape_model, save_tactile_map


@pytest.fixture(scope="module")
def map_files(tmp_path_factory, cylinder_map, gum_box_map):
    folder = tmp_path_factory.mktemp("maps")
    return [str(save_tactile_map(folder / "cylinder.npz", cylinder_map)),
            str(save_tactile_map(folder / "gum_box.npz", gum_box_map))]


def test_eval_localization_runs_the_belief_beside_the_papers_baselines(map_files, tiny_encoder_path, tmp_path,
                                                                       capsys):
    from tactojax.cli._eval_localization import DEFAULT_METHODS

    assert DEFAULT_METHODS.split(",") == ["belief", "random", "cti", "cti-icp-1", "cti-icp-5"]
    report, figure = tmp_path / "loc.json", tmp_path / "loc.png"
    assert main(["eval-localization", map_files[1], "--methods", "belief,cti", "--encoder", str(tiny_encoder_path),
                 "--queries", "8", "--figure", str(figure), "--json", str(report)]) == 0
    captured = capsys.readouterr()
    assert "median RMSE (mm)" in captured.out and "calibration gap" in captured.out
    assert "holds no belief calibration" in captured.err  # said, and the belief runs uncalibrated
    payload = json.loads(report.read_text())
    assert payload["methods"] == ["belief", "cti"]
    result = payload["objects"]["gum_box"]
    assert result["queries"] == 8 and result["symmetric"] and not result["calibrated"]
    methods = result["methods"]
    for summary in methods.values():  # the symmetry-aware error never exceeds the plain one
        assert summary["symmetric_rmse_mm"]["median"] <= summary["rmse_mm"]["median"] + 1e-6
        assert sum(summary["histogram"]["counts"]) == 8
    belief = methods["belief"]
    assert 0.0 <= belief["mean_probability_within_2mm"] <= 1.0
    assert sum(b["count"] for b in belief["calibration"]["bins"]) == 8
    assert "calibration" not in methods["cti"]  # the baselines predict nothing
    assert figure.stat().st_size > 10_000


def test_identify_confusion(map_files, tiny_encoder_path, tmp_path, capsys):
    report, figure = tmp_path / "id.json", tmp_path / "id.png"
    assert main(["identify", *map_files, "--encoder", str(tiny_encoder_path), "--figure", str(figure),
                 "--json", str(report)]) == 0
    result = json.loads(report.read_text())
    confusion = np.asarray(result["confusion"])
    assert confusion.shape == (2, 2) and confusion.sum() == result["queries"]
    assert "identification top-1" in capsys.readouterr().out
    assert figure.exists()


@pytest.fixture(scope="module")
def touches(mapping_dataset, lookup_model, tmp_path_factory):
    """Two grasps of the cylinder while it stayed put (one turn of the mapping protocol), as
    image files, with their openings, gripper poses and the object's true pose; and the model."""
    from tactojax.io import read_grasps

    folder = tmp_path_factory.mktemp("touches")
    grasps = read_grasps(mapping_dataset)
    images = np.asarray(grasps["images"])
    T_world_object, T_world_gripper = (np.asarray(grasps[k].wxyz_xyz) for k in ("T_world_object", "T_world_gripper"))
    turn = np.all(np.isclose(T_world_object, T_world_object[0], atol=1e-6), axis=1)
    contact = np.abs(images.astype(np.float32) - np.median(images, axis=0)).sum(axis=(1, 2, 3))
    chosen = np.flatnonzero(turn)[np.argsort(-contact[turn])[:2]]
    paths = []
    for k, index in enumerate(chosen):
        paths.append(str(folder / f"touch{k}.png"))
        cv2.imwrite(paths[-1], cv2.cvtColor(images[index], cv2.COLOR_RGB2BGR))
    return {"paths": paths, "openings": [str(float(grasps["openings"][i])) for i in chosen],
            "poses": [[str(float(v)) for v in T_world_gripper[i]] for i in chosen],
            "T_world_object": T_world_object[chosen[0]],
            "model": str(save_shape_model(folder / "lookup.msgpack", lookup_model))}


def test_localize_fuses_several_grasps_into_the_belief(map_files, touches, tiny_encoder_path, tmp_path, capsys):
    import jaxlie

    from tactojax.objects import get_object

    report = tmp_path / "belief.json"
    assert main(["localize", *map_files, *touches["paths"], "--opening", *touches["openings"],
                 "--gripper-pose", *touches["poses"][0], "--gripper-pose", *touches["poses"][1],
                 "--model", touches["model"], "--encoder", str(tiny_encoder_path), "--json", str(report)]) == 0
    printed = capsys.readouterr().out
    assert "pose belief over 2 touches of 2 grasps" in printed and "P(within 2 mm)" in printed
    result = json.loads(report.read_text())
    assert result["method"] == "belief" and result["frame"] == "world"
    assert result["object_id"] == "cylinder"
    assert sum(result["object_probabilities"].values()) == pytest.approx(1.0)
    assert result["object_probabilities"]["cylinder"] > 0.5
    assert 0.0 <= result["probability_within_2mm"] <= 1.0 and result["objects"]["cylinder"]["touches"] == 2
    modes = result["modes"]
    assert 1 <= len(modes) <= 3 and modes[0]["probability"] >= modes[-1]["probability"]
    # The object where it was, up to the cylinder's symmetry (turns about its axis, x) and to where
    # along its axis the touches are (a cylinder's side looks the same all along it).
    T_estimate = jaxlie.SE3(np.asarray(result["T_world_object_wxyz_xyz"]))
    copies = jaxlie.SE3(np.asarray(touches["T_world_object"])) @ get_object("cylinder").symmetry.transforms()
    offsets = np.asarray((copies.inverse() @ T_estimate).translation())  # object frame, mm
    assert np.min(np.linalg.norm(offsets[:, 1:], axis=-1)) < 3.0


def test_localize_one_touch_by_a_baseline(map_files, touches, tiny_encoder_path, tmp_path, capsys):
    report = tmp_path / "pose.json"
    code = main(["localize", *map_files, touches["paths"][0], "--opening", touches["openings"][0],
                 "--model", touches["model"], "--encoder", str(tiny_encoder_path), "--method", "cti-icp-2",
                 "--json", str(report)])
    assert code in (0, 1)  # 1: ICP did not converge (reported, not an error)
    result = json.loads(report.read_text())
    assert result["method"] == "cti-icp-2" and result["object_id"] in ("cylinder", "gum_box")
    assert np.all(np.isfinite(result["T_object_sensor_wxyz_xyz"]))
    assert "a one-touch baseline" in capsys.readouterr().out


def test_localize_rejects_bad_input(map_files, touches, lookup_model, tmp_path, capsys):
    broken = tmp_path / "broken.png"
    broken.write_bytes(b"not an image")
    assert main(["localize", *map_files, str(broken), "--opening", "20"]) == 2
    assert "not a readable image" in capsys.readouterr().err
    wrong = tmp_path / "wrong.png"
    cv2.imwrite(str(wrong), np.zeros((10, 12, 3), np.uint8))
    assert main(["localize", *map_files, str(wrong), "--opening", "20", "--model", touches["model"]]) == 2
    assert "shape" in capsys.readouterr().err
    assert main(["localize", *map_files, str(wrong), "--opening", "-3"]) == 2
    blank = tmp_path / "blank.png"  # the gel untouched: the model's background
    background = np.round(np.clip(np.asarray(lookup_model.background), 0, 1) * 255).astype(np.uint8)
    cv2.imwrite(str(blank), cv2.cvtColor(background, cv2.COLOR_RGB2BGR))
    assert main(["localize", *map_files, str(blank), "--opening", "20", "--model", touches["model"]]) == 2
    assert "shows no contact" in capsys.readouterr().err
    two = [*map_files, *touches["paths"], "--opening", "20"]
    assert main(["localize", *two]) == 2
    assert "2 images need their gripper poses" in capsys.readouterr().err
    assert main(["localize", *two, "--gripper-pose", *touches["poses"][0]]) == 2
    assert "2 images but 1 --gripper-pose" in capsys.readouterr().err
    assert main(["localize", *two, "--gripper-pose", "2", "0", "0", "0", "0", "0", "0", "--gripper-pose",
                 *touches["poses"][1]]) == 2
    assert "unit norm" in capsys.readouterr().err
    assert main(["localize", *two, "--opening", "20", "21", "22"]) == 2
    assert "one per image" in capsys.readouterr().err
    assert main(["localize", *map_files, touches["paths"][0], "--opening", "20", "--second-image",
                 touches["paths"][1], "--method", "cti"]) == 2
    assert "one-touch baselines" in capsys.readouterr().err
    assert main(["localize", touches["paths"][0], map_files[0], "--opening", "20"]) == 2
    assert "maps (.npz) first" in capsys.readouterr().err


def test_histogram_panel_shows_the_symmetry_aware_error_of_symmetric_objects():
    from types import SimpleNamespace

    from tactojax.cli._maps import histogram_panel
    from tactojax.objects import NO_SYMMETRY, ObjectSymmetry

    def tactile_map(object_id, symmetry):  # what the panel reads of a map
        return SimpleNamespace(object_id=object_id, object_symmetry=symmetry)

    results = {"cti": SimpleNamespace(rmse=np.array([80.0]), symmetric_rmse=np.array([0.1]))}
    title, panel = histogram_panel(tactile_map("gum_box", ObjectSymmetry(axis="z", fold=2)), results)
    assert title == "gum_box (symmetry-aware)" and panel["cti"][0] == 0.1
    title, panel = histogram_panel(tactile_map("scissors", NO_SYMMETRY), results)  # identity only
    assert title == "scissors" and panel["cti"][0] == 80.0
    # A group measured from a mesh (not exact) counts as well.
    title, _ = histogram_panel(tactile_map("my_part", ObjectSymmetry(axis="x", exact=False)), results)
    assert title == "my_part (symmetry-aware)"
    assert histogram_panel(tactile_map("my_part", ObjectSymmetry(exact=False)), results) == (
        "my_part", {"cti": results["cti"].rmse})
