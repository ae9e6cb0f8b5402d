"""``tactojax record --simulate`` -> ``tactojax map`` -> ``tactojax localize-live`` on a video."""

import json

import numpy as np

from tactojax.cli import main
from tactojax.hardware import write_video
from tactojax.io import open_dataset, save_shape_model


def test_record_map_and_localize_live(tmp_path, lookup_model, tiny_encoder_path, capsys):
    recording, tactile_map = tmp_path / "recording", tmp_path / "gum_box.npz"
    assert main(["record", "--simulate", "gum_box", "--scale", "0.25", "--grid-mm", "30", "--yaws-deg", "0",
                 "--out", str(recording)]) == 0
    assert "recorded 16 touches" in capsys.readouterr().out
    model = save_shape_model(tmp_path / "lookup.msgpack", lookup_model)
    assert main(["map", str(recording), "--model", str(model), "--out", str(tactile_map), "--points", "256",
                 "--no-progress"]) == 0
    records = open_dataset(recording).read(["image", "opening_mm"])
    thin = np.flatnonzero(records["opening_mm"] < 40)[:4]  # touches across the box's thin side
    video = write_video(tmp_path / "touches.mkv", records["image"][thin], fps=30.0)
    report = tmp_path / "live.json"
    assert main(["localize-live", "--camera", str(video), "--map", str(tactile_map),
                 "--opening", str(float(records["opening_mm"][thin[0]])), "--model", str(model),
                 "--encoder", str(tiny_encoder_path), "--method", "cti-icp-2", "--json", str(report)]) == 0
    printed = capsys.readouterr().out
    assert "sustained rate (Hz)" in printed and "recompilations" in printed
    result = json.loads(report.read_text())
    assert result["summary"]["frames"] == len(thin) and result["summary"]["recompilations"] == 0
    assert [e["frame"] for e in result["estimates"]] == list(range(len(thin)))
    touched = [e for e in result["estimates"] if e["contact"]]
    assert len(touched) >= 3  # a grasp may barely touch: no estimate for it (below)
    assert all(e["object_id"] == "gum_box" and np.all(np.isfinite(e["T_object_sensor_wxyz_xyz"])) for e in touched)
    assert all(e["object_id"] is None and e["T_object_sensor_wxyz_xyz"] is None
               for e in result["estimates"] if not e["contact"])


def test_a_real_recording_names_what_is_missing(tmp_path, capsys):
    assert main(["record", "--out", str(tmp_path / "r"), "--camera", "0"]) == 2
    assert "needs --gripper, --pose, --object-id" in capsys.readouterr().err
