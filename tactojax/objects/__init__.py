"""Objects: analytic solids (JAX SDFs), triangle meshes, ray casting and the catalog."""

from tactojax.objects._catalog import CALIBRATION_SHAPES as CALIBRATION_SHAPES
from tactojax.objects._catalog import CATALOG as CATALOG
from tactojax.objects._catalog import CATALOG_YCB_SCANS as CATALOG_YCB_SCANS
from tactojax.objects._catalog import EVALUATION_YCB_SCANS as EVALUATION_YCB_SCANS
from tactojax.objects._catalog import HOUSEHOLD_OBJECTS as HOUSEHOLD_OBJECTS
from tactojax.objects._catalog import TABLE2_SHAPES as TABLE2_SHAPES
from tactojax.objects._catalog import YCB_ATTRIBUTION as YCB_ATTRIBUTION
from tactojax.objects._catalog import get_object as get_object
from tactojax.objects._catalog import object_from_mesh as object_from_mesh
from tactojax.objects._catalog import object_symmetry as object_symmetry
from tactojax.objects._catalog import resolve_object as resolve_object
from tactojax.objects._catalog import ycb_object as ycb_object
from tactojax.objects._catalog import ycb_scans as ycb_scans
from tactojax.objects._mesh import MeshSolid as MeshSolid
from tactojax.objects._mesh import mount_mesh as mount_mesh
from tactojax.objects._object import TactileObject as TactileObject
from tactojax.objects._symmetry import NO_SYMMETRY as NO_SYMMETRY
from tactojax.objects._symmetry import SYMMETRY_TOLERANCE_MM as SYMMETRY_TOLERANCE_MM
from tactojax.objects._symmetry import ObjectSymmetry as ObjectSymmetry
from tactojax.objects._symmetry import detect_symmetry as detect_symmetry
from tactojax.objects._symmetry import symmetry_residual as symmetry_residual
from tactojax.objects._primitives import Box as Box
from tactojax.objects._primitives import Cylinder as Cylinder
from tactojax.objects._primitives import Difference as Difference
from tactojax.objects._primitives import Frustum as Frustum
from tactojax.objects._primitives import Placed as Placed
from tactojax.objects._primitives import Solid as Solid
from tactojax.objects._primitives import Sphere as Sphere
from tactojax.objects._primitives import SquareFrustum as SquareFrustum
from tactojax.objects._primitives import Union as Union
from tactojax.objects._primitives import placed as placed
from tactojax.objects._raycast import RayHits as RayHits
from tactojax.objects._raycast import raycast as raycast

__all__ = [
    "CALIBRATION_SHAPES", "CATALOG", "CATALOG_YCB_SCANS", "EVALUATION_YCB_SCANS", "HOUSEHOLD_OBJECTS", "NO_SYMMETRY", "SYMMETRY_TOLERANCE_MM", "TABLE2_SHAPES", "YCB_ATTRIBUTION",
    "Box", "Cylinder", "Difference", "Frustum", "MeshSolid", "ObjectSymmetry", "Placed", "RayHits", "Solid",
    "Sphere", "SquareFrustum", "TactileObject", "Union", "detect_symmetry", "get_object", "mount_mesh",
    "object_from_mesh", "object_symmetry", "placed", "raycast", "resolve_object", "symmetry_residual", "ycb_object",
    "ycb_scans",
]
