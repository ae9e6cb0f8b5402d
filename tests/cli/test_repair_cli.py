"""A dataset with a corrupt chunk: ``info`` and ``map`` name it, ``repair`` keeps the rest."""

import json

import numpy as np

from tactojax.cli import main
from tactojax.io import open_dataset, save_shape_model

SMALL = ["--scale", "0.25", "--grid-mm", "30", "--yaws-deg", "0", "--turns-deg", "0", "90", "--no-progress"]


def test_info_and_map_name_the_corrupt_chunk_and_repair_keeps_the_rest(tmp_path, lookup_model, capsys):
    data = tmp_path / "data"
    assert main(["simulate", "cuboid", "--out", str(data), *SMALL]) == 0  # chunk 0
    assert main(["simulate", "cylinder", "--out", str(data), *SMALL]) == 0  # chunk 1
    ids = open_dataset(data).read(["object_id"])["object_id"]
    cuboids, cylinders = int(np.sum(ids == "cuboid")), int(np.sum(ids == "cylinder"))
    chunk = data / "chunks" / "chunk-000001.npz"
    chunk.write_bytes(chunk.read_bytes()[: chunk.stat().st_size // 2])  # truncated
    capsys.readouterr()

    assert main(["info", str(data)]) == 2
    error = capsys.readouterr().err
    assert "chunk-000001.npz" in error and "truncated" in error and f"tactojax repair {data}" in error
    model = save_shape_model(tmp_path / "lookup.msgpack", lookup_model)
    tactile_map = tmp_path / "cuboid.npz"
    assert main(["map", str(data), "--object", "cuboid", "--model", str(model), "--out", str(tactile_map),
                 "--no-progress"]) == 2
    assert "chunk-000001.npz" in capsys.readouterr().err and not tactile_map.exists()

    report = tmp_path / "repair.json"
    assert main(["repair", str(data), "--dry-run"]) == 0
    assert f"would lose {cylinders} records in 1 chunks" in capsys.readouterr().out
    assert main(["repair", str(data), "--json", str(report)]) == 0
    printed = capsys.readouterr().out
    assert "chunks/chunk-000001.npz" in printed and f"lost {cylinders} records" in printed
    assert f"kept {cuboids} records in 1 chunks" in printed
    assert json.loads(report.read_text())["lost"][0]["count"] == cylinders

    assert main(["info", str(data)]) == 0
    assert f"lost {cylinders} records (chunks/chunk-000001.npz)" in capsys.readouterr().out  # said, not hidden
    assert main(["map", str(data), "--model", str(model), "--out", str(tactile_map), "--no-progress"]) == 0
    assert main(["repair", str(data)]) == 0
    assert "every chunk is intact" in capsys.readouterr().out
