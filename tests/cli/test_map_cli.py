"""``tactojax map``, ``fit-shape`` and ``show`` end to end on a small cylinder dataset."""

import json

import trimesh

from tactojax.cli import main
from tactojax.io import encoder_label, load_tactile_map, resolve_encoder, save_shape_model, tactile_map_metadata
from tactojax.objects import get_object


def test_map_fit_and_show(mapping_dataset, lookup_model, tiny_encoder_path, tmp_path, capsys):
    model_path = save_shape_model(tmp_path / "lookup.msgpack", lookup_model)
    map_path, ply, figure, report = (tmp_path / "map.npz", tmp_path / "map.ply", tmp_path / "map.png",
                                     tmp_path / "fit.json")
    assert main(["map", str(mapping_dataset), "--model", str(model_path), "--out", str(map_path),
                 "--points", "256", "--ply", str(ply), "--voxel-mm", "1.0", "--encoder", str(tiny_encoder_path),
                 "--no-progress"]) == 0
    tactile_map = load_tactile_map(map_path)
    assert tactile_map.object_id == "cylinder" and tactile_map.points.shape[1] == 256
    # The object's symmetry came with the simulated data and is stored with the map.
    assert tactile_map.symmetry == get_object("cylinder").symmetry
    metadata = tactile_map_metadata(map_path)["metadata"]
    assert metadata["model"] == str(model_path)
    # The features are the given encoder's, and the map says so (the commands encode new touches with it).
    assert metadata["features_encoder"] == encoder_label(tiny_encoder_path)
    assert tactile_map.features.shape[1] == resolve_encoder(tiny_encoder_path).feature_dim
    assert len(trimesh.load(ply).vertices) > 100
    printed = capsys.readouterr().out
    assert "distance to true surface" in printed

    assert main(["fit-shape", str(map_path), "--kind", "cylinder", "--json", str(report)]) == 0
    result = json.loads(report.read_text())
    assert result["converged"] and result["errors"]["radius_mm"]["true"] == 25.0
    assert result["errors"]["radius_mm"]["relative_error"] < 0.03
    assert "relative error" in capsys.readouterr().out

    assert main(["show", str(map_path), "--out", str(figure), "--examples", "2"]) == 0
    assert figure.stat().st_size > 20_000


def test_map_rejects_a_model_for_another_sensor(mapping_dataset, tmp_path, capsys):
    # The bundled model is for gelslim at 0.2 mm/px; the dataset is at 0.4 mm/px.
    assert main(["map", str(mapping_dataset), "--out", str(tmp_path / "map.npz")]) == 2
    assert "pixel pitch" in capsys.readouterr().err
    assert not (tmp_path / "map.npz").exists()
    assert main(["map", str(mapping_dataset), "--out", str(tmp_path / "map.npz"),
                 "--kinematic-noise", "wobbly"]) == 2
    assert main(["fit-shape", str(tmp_path / "missing.npz"), "--kind", "cylinder"]) == 2


def test_fit_shape_kinds_match_the_library():
    # The CLI lists the kinds without importing JAX at start-up; they must stay the library's.
    from tactojax.cli._fit_shape import KINDS
    from tactojax.mapping import SHAPE_KINDS

    assert KINDS == SHAPE_KINDS
