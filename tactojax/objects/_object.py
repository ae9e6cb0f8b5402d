"""TactileObject: a solid (analytic or mesh) with a name, a catalog group and its bounds."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tactojax.objects._mesh import MeshSolid
from tactojax.objects._primitives import Solid
from tactojax.objects._symmetry import NO_SYMMETRY, ObjectSymmetry


@dataclass(frozen=True, eq=False)
class TactileObject:
    """An object the simulator can touch, in its canonical object frame (mm)."""

    name: str
    solid: Solid | MeshSolid
    """Analytic solid (JAX, differentiable) or a triangle mesh (Embree ray casting)."""
    bounds: np.ndarray
    """(2, 3) axis-aligned bounds (min, max) in the object frame, mm."""
    group: str = "custom"
    """'calibration' (paper section IV), 'table2' (section V), 'household' (section VI) or 'custom'."""
    description: str = ""
    attribution: str = ""
    parameters: dict = field(default_factory=dict)
    """True dimensions of parametric shapes (mm, radians), for shape recovery checks."""
    symmetry: ObjectSymmetry = NO_SYMMETRY
    """Rotations that map the object onto itself (symmetry-aware localization errors)."""
    mesh_repair: dict | None = None
    """What loading changed to make the scanned mesh a closed solid (``MeshRepair.as_dict()`` of
    ``tactojax.io``, with its one-line ``"summary"``); None when the mesh was used as read."""

    @property
    def is_mesh(self) -> bool:
        return isinstance(self.solid, MeshSolid)

    @property
    def extents(self) -> np.ndarray:
        """(3,) size along x, y, z, mm."""
        return self.bounds[1] - self.bounds[0]
