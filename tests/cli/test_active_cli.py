"""``tactojax eval-active`` on a tiny case: one episode, two grasps, the cylinder's small map; and
``tactojax record --active`` (slow): one active episode on the simulated cell."""

import json

import numpy as np
import pytest

from tactojax.cli import main
from tactojax.io import save_shape_model, save_tactile_map


def test_eval_active_runs_the_closed_loop(cylinder_map, lookup_model, tiny_encoder_path, tmp_path, capsys):
    map_path = str(save_tactile_map(tmp_path / "cylinder.npz", cylinder_map))
    model = str(save_shape_model(tmp_path / "lookup.msgpack", lookup_model))
    report = tmp_path / "active.json"
    assert main(["eval-active", map_path, "--object", "cylinder", "--episodes", "2", "--max-grasps", "2",
                 "--policies", "active,random", "--candidates", "8", "--hypotheses", "2", "--model", model,
                 "--encoder", str(tiny_encoder_path), "--seed", "3", "--json", str(report),
                 "--figure", str(tmp_path / "active.png"), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "stopping rule" in out and "ranking 8 candidates" in out
    result = json.loads(report.read_text())["objects"]["cylinder"]
    rows = {(r["policy"], r["grasps"]): r for r in result["results"]}
    assert set(rows) == {(p, k) for p in ("active", "random") for k in (1, 2)}
    for row in rows.values():
        assert row["count"] == 2 and row["fingers"] == 2
        assert set(row["within_mm"]) == {"1", "2", "5"}
        assert np.isfinite(row["median_rmse_mm"]) and row["median_symmetric_rmse_mm"] <= row["median_rmse_mm"] + 1e-6
    # Both policies start from the same random grasp; they part at the second.
    assert rows[("active", 1)]["median_rmse_mm"] == rows[("random", 1)]["median_rmse_mm"]
    for policy in ("active", "random"):
        stop = result["stop"][policy]
        assert 0.0 <= stop["stopped_share"] <= 1.0 and stop["threshold"] == 0.95
    assert (tmp_path / "active.png").stat().st_size > 0


@pytest.mark.slow  # compiles a full-size live localizer (tens of seconds); tests/hardware/test_active.py runs the loop
def test_record_runs_an_active_episode_on_the_simulated_cell(cylinder_map, lookup_model, tiny_encoder_path, tmp_path,
                                                             capsys):
    from tactojax.io import open_dataset

    map_path = str(save_tactile_map(tmp_path / "cylinder.npz", cylinder_map))
    model = str(save_shape_model(tmp_path / "lookup.msgpack", lookup_model))
    report, recording = tmp_path / "episode.json", tmp_path / "recording"
    assert main(["record", "--simulate", "cylinder", "--scale", "0.25", "--active", map_path, "--model", model,
                 "--encoder", str(tiny_encoder_path), "--max-grasps", "2", "--candidates", "8", "--seed", "3",
                 "--out", str(recording), "--json", str(report), "--figure", str(tmp_path / "episode.png")]) == 0
    out = capsys.readouterr().out
    assert "expected gain" in out and "recorded" in out
    rows = json.loads(report.read_text())["grasps"]
    fused = [row for row in rows if row["fused"]]
    assert rows[0]["chosen"] == "first" and rows[-1]["grasp"] <= 2
    assert all(row["chosen"] == "active" for row in rows if row["grasp"] == 2)
    assert all(np.isfinite(row["error_mm"]) and 0.0 <= row["probability_within_2mm"] <= 1.0 for row in fused)
    # Both fingers' touches of every fused grasp are on disk, sensor jaw first.
    fingers = open_dataset(recording).read(["finger"])["finger"]
    assert fingers.tolist() == [0, 1] * len(fused) and len(fused) >= 1
    assert (tmp_path / "episode.png").stat().st_size > 0
