"""``tactojax record --simulate`` -> ``tactojax map`` -> ``tactojax localize-live`` on a video."""

import json

import jaxlie
import numpy as np
import pytest

from tactojax.cli import main
from tactojax.hardware import PoseLog, write_pose_log, write_video
from tactojax.io import open_dataset, save_shape_model
from tactojax.objects import get_object

FPS = 30.0


@pytest.fixture(scope="module")
def recorded(tmp_path_factory, lookup_model):
    """The gum box recorded through the simulated cell and mapped from the recording."""
    folder = tmp_path_factory.mktemp("live")
    recording, tactile_map = folder / "recording", folder / "gum_box.npz"
    assert main(["record", "--simulate", "gum_box", "--scale", "0.25", "--grid-mm", "30", "--yaws-deg", "0",
                 "--out", str(recording)]) == 0
    model = save_shape_model(folder / "lookup.msgpack", lookup_model)
    # --keep-images: the tests localize with the tiny encoder, whose features are computed from them
    assert main(["map", str(recording), "--model", str(model), "--out", str(tactile_map), "--points", "256",
                 "--keep-images", "--no-progress"]) == 0
    records = open_dataset(recording).read(["image", "opening_mm", "T_world_gripper", "T_world_object"])
    assert len(records["opening_mm"]) == 16  # 4 turns x 4 grasps of the 30 mm grid
    return folder, str(tactile_map), str(model), records


def test_record_map_and_localize_live(recorded, tiny_encoder_path, tmp_path, capsys):
    """One grasp across the box's thin side, held for 4 frames: it settles on its third frame (the
    belief's update) and the next frame is tracked from there."""
    folder, tactile_map, model, records = recorded
    images = records["image"].astype(np.float32)
    contact = np.abs(images - np.median(images, axis=0)).sum(axis=(1, 2, 3))
    grasp = int(np.argmax(np.where(records["opening_mm"] < 40, contact, -1)))
    video = write_video(tmp_path / "touches.mkv", np.stack([records["image"][grasp]] * 4), fps=FPS)
    report = tmp_path / "live.json"
    assert main(["localize-live", "--camera", str(video), "--map", tactile_map,
                 "--opening", str(float(records["opening_mm"][grasp])), "--model", model,
                 "--encoder", str(tiny_encoder_path), "--json", str(report)]) == 0
    printed = capsys.readouterr().out
    assert "sustained rate (Hz)" in printed and "recompilations" in printed and "P(within 2 mm)" in printed
    result = json.loads(report.read_text())
    assert result["method"] == "belief" and result["tracking"] and result["pose_source"] is None
    assert result["summary"]["frames"] == 4 and result["summary"]["recompilations"] == 0
    estimates = result["estimates"]
    assert [e["frame"] for e in estimates] == [0, 1, 2, 3] and all(e["contact"] for e in estimates)
    assert [e["updated"] for e in estimates] == [False, False, True, False]
    assert [e["tracked"] for e in estimates] == [False, False, False, True]
    assert all(e["object_id"] is None and e["T_object_sensor_wxyz_xyz"] is None for e in estimates[:2])
    for e in estimates[2:]:
        assert e["object_id"] == "gum_box" and e["object_probabilities"] == {"gum_box": 1.0} and e["grasps"] == 1
        assert 0.0 <= e["probability_within_2mm"] <= 1.0 and np.all(np.isfinite(e["T_object_sensor_wxyz_xyz"]))


def test_localize_live_fuses_grasps_by_the_robots_poses(recorded, lookup_model, tiny_encoder_path, tmp_path,
                                                         capsys):
    """Two grasps of the box where it stayed put, held 4 frames each with a release between them,
    and a pose log of the gripper: the belief fuses both, and the box is where it was."""
    folder, tactile_map, model, records = recorded
    turn = np.all(np.isclose(records["T_world_object"], records["T_world_object"][0], atol=1e-6), axis=1)
    first, second = np.flatnonzero(turn)[:2]
    background = np.round(np.clip(np.asarray(lookup_model.background), 0, 1) * 255).astype(np.uint8)
    frames = [records["image"][first]] * 4 + [background] + [records["image"][second]] * 4
    poses = [records["T_world_gripper"][first]] * 5 + [records["T_world_gripper"][second]] * 4
    video = write_video(tmp_path / "grasps.mkv", np.stack(frames), fps=FPS)
    # Two samples around every frame's time, so that a frame never interpolates across a move.
    times = np.sort(np.concatenate([np.arange(len(frames)) / FPS - 0.004, np.arange(len(frames)) / FPS + 0.004]))
    log = write_pose_log(tmp_path / "poses.csv", PoseLog(times, np.repeat(np.asarray(poses, np.float64), 2, axis=0)))
    report = tmp_path / "live.json"
    opening = float(np.mean(records["opening_mm"][[first, second]]))
    assert main(["localize-live", "--camera", str(video), "--map", tactile_map, "--opening", str(opening),
                 "--pose", str(log), "--max-skew-ms", "10", "--no-tracking", "--model", model,
                 "--encoder", str(tiny_encoder_path), "--json", str(report)]) == 0
    assert "grasps fused into the belief" in capsys.readouterr().out
    result = json.loads(report.read_text())
    assert result["pose_source"] == str(log) and result["summary"]["stale_poses"] == 0
    estimates = result["estimates"]
    assert all(e["T_world_gripper_wxyz_xyz"] is not None for e in estimates)
    assert [e["frame"] for e in estimates if e["updated"]] == [2, 7]  # each grasp settles once, on its 3rd frame
    last = estimates[-1]
    assert last["grasps"] == 2 and last["object_id"] == "gum_box" and 0.0 <= last["probability_within_2mm"] <= 1.0
    # The box where it was, up to its symmetry (a rotation about its centre: the position is one).
    T_true = jaxlie.SE3(np.asarray(records["T_world_object"][first]))
    copies = T_true @ get_object("gum_box").symmetry.transforms()
    offsets = np.asarray((copies.inverse() @ jaxlie.SE3(np.asarray(last["T_world_object_wxyz_xyz"]))).translation())
    assert np.min(np.linalg.norm(offsets, axis=-1)) < 5.0


def test_a_real_recording_names_what_is_missing(tmp_path, capsys):
    assert main(["record", "--out", str(tmp_path / "r"), "--camera", "0"]) == 2
    assert "needs --gripper, --pose, --object-id" in capsys.readouterr().err
