"""``tactojax eval-active`` on a tiny case: one episode, two grasps, the cylinder's small map."""

import json

import numpy as np

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
