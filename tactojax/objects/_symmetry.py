"""Rotational symmetries of objects, for symmetry-aware localization errors and beliefs.

A touch on a tape roll cannot tell where around the roll it is; a localizer that returns a
pose rotated about the roll's axis has found the contact exactly. The symmetry-aware error of
issue 5 takes the minimum of the plain error over the object's symmetry group, sampled as a
batch of object-frame transforms ``T_object_object'``.

Catalog objects declare their group; an object made from a mesh (a YCB scan, a CAD file) has
it measured from its surface (:func:`detect_symmetry`).
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import jax.numpy as jnp
import jaxlie
import numpy as np
import trimesh
from scipy.spatial import cKDTree

_AXES = {"x": np.array([1.0, 0.0, 0.0]), "y": np.array([0.0, 1.0, 0.0]), "z": np.array([0.0, 0.0, 1.0])}


@dataclass(frozen=True)
class ObjectSymmetry:
    """A symmetry group: rotations about one axis (continuous or n-fold) times half-turn flips.

    Attributes:
        axis: ``"x"``, ``"y"`` or ``"z"``: the object-frame axis through ``centre`` that the
            object is (approximately) symmetric about; None for no rotational symmetry.
        fold: 0 for a continuous symmetry (sampled every ``step_deg``), else n for n-fold.
        flips: axes of extra half-turn symmetries (e.g. a roll that looks the same upside down).
        centre: (3,) a point on the axis, mm.
        exact: False where the symmetry is only approximate (a scanned marker's cap, a
            screwdriver's fluted handle).
    """

    axis: str | None = None
    fold: int = 0
    flips: tuple[str, ...] = ()
    centre: tuple[float, float, float] = (0.0, 0.0, 0.0)
    exact: bool = True

    def transforms(self, *, step_deg: float = 2.0) -> jaxlie.SE3:
        """The group as a batch of object-frame transforms, identity first.

        Args:
            step_deg: sampling step of a continuous symmetry, degrees.

        Returns:
            (S,) ``jaxlie.SE3``: every rotation maps the object onto itself (about ``centre``).
        """
        rotations = [np.eye(3)]
        if self.axis is not None:
            count = self.fold if self.fold > 0 else int(round(360.0 / step_deg))
            angles = np.arange(1, count) * (2 * np.pi / count)
            rotations += [_axis_angle(_AXES[self.axis], angle) for angle in angles]
        for flip in self.flips:
            half_turn = _axis_angle(_AXES[flip], np.pi)
            rotations += [half_turn @ rotation for rotation in rotations]
        matrices = np.stack(rotations)
        centre = np.asarray(self.centre, np.float64)
        translations = centre - matrices @ centre  # rotate about the centre, not the origin
        return jaxlie.SE3.from_rotation_and_translation(
            jaxlie.SO3.from_matrix(jnp.asarray(matrices, jnp.float32)), jnp.asarray(translations, jnp.float32))

    def copies(self) -> jaxlie.SE3:
        """The group's distinct copies once all turns about a continuous axis count as one (its
        quotient by those turns), identity first: the flips alone for a continuous symmetry, the
        whole group otherwise. With :meth:`continuous_axis` they give a symmetry-aware distance
        exactly (the closest turn is found in closed form), from 1-4 copies instead of the
        hundreds that :meth:`transforms` samples.

        Returns:
            (S,) ``jaxlie.SE3`` object-frame transforms (about ``centre``).
        """
        if self.axis is None or self.fold > 0:
            return self.transforms()
        return dataclasses.replace(self, axis=None).transforms()

    @property
    def symmetric(self) -> bool:
        """Whether the group holds more than the identity."""
        return self.axis is not None or bool(self.flips)

    def describe(self) -> str:
        """One line: ``"none"``, ``"continuous about x, flipped about y"``, ``"2-fold about z"``..."""
        if not self.symmetric:
            return "none"
        parts = [] if self.axis is None else [f"{'continuous' if self.fold == 0 else f'{self.fold}-fold'} about {self.axis}"]
        parts += [f"flipped about {flip}" for flip in self.flips]
        return ", ".join(parts)

    @staticmethod
    def parse(text: str) -> ObjectSymmetry:
        """A group from a short spec: ``"none"``; an axis, continuous (``"x"``) or n-fold
        (``"z2"``, ``"x4"``); and optionally a half-turn flip (``"y,flip=z"``, ``"x2,flip=y"``;
        ``"flip=x"`` alone). The turns are about the object frame's axes through its origin.

        Raises:
            ValueError: a spec that is none of these, naming what is wrong.
        """
        spec = text.strip().lower()
        if spec == "none":
            return NO_SYMMETRY
        axis, fold, flips = None, 0, ()
        for part in (p.strip() for p in spec.split(",")):
            if part.startswith("flip="):
                flip = part.removeprefix("flip=")
                if flip not in _AXES:
                    raise ValueError(f"symmetry {text!r}: flip about {flip!r}; axes are x, y, z")
                flips += (flip,)
            elif part[:1] in _AXES and axis is None and (part[1:] == "" or part[1:].isdigit()):
                axis, fold = part[0], int(part[1:] or 0)
                if fold == 1:
                    raise ValueError(f"symmetry {text!r}: a 1-fold turn is no symmetry (give 'none', or n >= 2)")
            else:
                raise ValueError(f"symmetry {text!r}: expected 'none', an axis x/y/z with an optional fold "
                                 "(x, z2) and an optional ',flip=AXIS'")
        if len(flips) > 1 or (axis is not None and axis in flips):
            raise ValueError(f"symmetry {text!r}: at most one flip, about an axis other than the turns'")
        return ObjectSymmetry(axis=axis, fold=fold, flips=flips)

    def to_json(self) -> dict:
        """The group as a JSON object (a map file's header): :meth:`from_json` reads it back."""
        return {"axis": self.axis, "fold": self.fold, "flips": list(self.flips),
                "centre": [float(c) for c in self.centre], "exact": self.exact}

    @staticmethod
    def from_json(data: dict) -> ObjectSymmetry:
        """The group :meth:`to_json` wrote."""
        return ObjectSymmetry(axis=data.get("axis"), fold=int(data.get("fold", 0)), flips=tuple(data.get("flips", ())),
                              centre=tuple(float(c) for c in data.get("centre", (0.0, 0.0, 0.0))),
                              exact=bool(data.get("exact", True)))

    def continuous_axis(self) -> tuple[np.ndarray, np.ndarray]:
        """(3,) the unit axis of a continuous rotational symmetry and (3,) a point on it (object
        frame, mm); zeros for an object without one (none, or n-fold)."""
        if self.axis is None or self.fold > 0:
            return np.zeros(3, np.float32), np.zeros(3, np.float32)
        return _AXES[self.axis].astype(np.float32), np.asarray(self.centre, np.float32)


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix (Rodrigues)."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


NO_SYMMETRY = ObjectSymmetry()

SYMMETRY_TOLERANCE_MM = 0.5
"""How far (RMS over any touch-sized patch) a turned copy of a surface may lie from the surface
and still count as the same object: about the depth error of a predicted heightmap (90th
percentile 0.54 mm on the catalog maps, docs/mapping.md), below which a touch cannot tell the
copies apart."""

PATCH_RADIUS_MM = 3.0
"""Radius of the smallest patch a touch reads (a pinpoint contact): a feature that large that
the copy does not share breaks the symmetry, however small a share of the surface it is."""

_CONTINUOUS_TEST_DEG = (23.0, 59.0, 97.0, 137.0, 180.0)
"""Turns that all leave the surface in place only under a continuous symmetry (no n-fold group
with n <= 6 holds more than one of them)."""
_FOLDS = (6, 5, 4, 3, 2)


@dataclass(frozen=True)
class _SurfaceSample:
    """What every residual of one mesh reads: two independent uniform draws of its surface with
    their normals, the reference draw's k-d tree, and each query's patch (the queries within the
    patch radius of it)."""

    reference: np.ndarray
    reference_normals: np.ndarray
    tree: cKDTree
    queries: np.ndarray
    query_normals: np.ndarray
    patches: list


def _surface_sample(mesh: trimesh.Trimesh, samples: int, seed: int, patch_radius_mm: float) -> _SurfaceSample:
    rng = np.random.default_rng(seed)
    reference, reference_faces = trimesh.sample.sample_surface(mesh, samples, seed=rng)
    queries, query_faces = trimesh.sample.sample_surface(mesh, samples // 4, seed=rng)
    return _SurfaceSample(reference, mesh.face_normals[reference_faces], cKDTree(reference), queries,
                          mesh.face_normals[query_faces], cKDTree(queries).query_ball_point(queries, patch_radius_mm))


def _residual(sample: _SurfaceSample, rotation: np.ndarray, centre) -> float:
    """:func:`symmetry_residual` of a drawn surface."""
    centre = np.asarray(centre, np.float64)
    turned = (sample.queries - centre) @ rotation.T + centre
    turned_normals = sample.query_normals @ rotation.T
    gap, nearest = sample.tree.query(turned, k=8)  # (Q, 8)
    offset = turned[:, None, :] - sample.reference[nearest]
    normals = sample.reference_normals[nearest]
    along_normal = np.abs(np.sum(offset * normals, axis=-1))
    agree = np.sum(turned_normals[:, None, :] * normals, axis=-1) > 0.5
    distance = np.where(np.any(agree, axis=1), np.min(np.where(agree, along_normal, np.inf), axis=1), gap[:, 0])
    squared = distance ** 2
    return float(np.sqrt(max(np.mean(squared[patch]) for patch in sample.patches)))


def symmetry_residual(mesh: trimesh.Trimesh, rotation: np.ndarray, *, centre=(0.0, 0.0, 0.0),
                      patch_radius_mm: float = PATCH_RADIUS_MM, samples: int = 20000, seed: int = 0) -> float:
    """How far the mesh's surface turned by ``rotation`` (3 x 3, about ``centre``) lies from the
    surface itself, where it lies farthest: the largest RMS distance, mm, over patches of radius
    ``patch_radius_mm`` (~0 for a symmetry of the mesh).

    Points drawn uniformly over the surface are turned and measured against an independent draw:
    along the normal of the nearest of their 8 nearest points whose normal agrees with theirs (a
    plane's sampling leaves no error, nor does an edge), else to the nearest point (a copy that
    lands on nothing, or on the other side of a thin wall)."""
    return _residual(_surface_sample(mesh, samples, seed, patch_radius_mm), rotation, centre)


def detect_symmetry(mesh: trimesh.Trimesh, *, tolerance_mm: float = SYMMETRY_TOLERANCE_MM,
                    samples: int = 20000) -> ObjectSymmetry:
    """The largest group of turns about the object frame's axes that maps the mesh onto itself
    within ``tolerance_mm`` on every touch-sized patch (:func:`symmetry_residual`), as an
    :class:`ObjectSymmetry`. A scan's noise can hide a symmetry the object has: declare it then.

    The mesh is in its object frame (:func:`~tactojax.objects.mount_mesh`: the axes of its
    oriented bounding box, centred), so a symmetry axis of the object is one of x, y, z through
    the origin. Per axis: continuous if every turn of a spread set leaves the surface in place,
    else the largest n <= 6 whose turns all do. The axis with the largest group is kept (a
    continuous one first, then by fold, then x before y before z), with a half-turn flip about
    another axis if one holds too (a box: 2-fold about x and flipped about z; a can: about its
    axis, and upside down).

    Args:
        mesh: a closed surface, mm, in its object frame.
        tolerance_mm: the largest RMS distance of a copy from the surface that still counts.
        samples: surface points drawn per test.

    Returns:
        the group (the identity alone when no turn holds); ``exact`` is False (measured to the
        tolerance, not declared).
    """
    sample = _surface_sample(mesh, samples, 0, PATCH_RADIUS_MM)  # drawn once: every turn reads it

    @functools.cache
    def holds(axis: str, angle_deg: float) -> bool:  # cached: the half turn is asked up to three times
        rotation = _axis_angle(_AXES[axis], np.deg2rad(angle_deg))
        return _residual(sample, rotation, (0.0, 0.0, 0.0)) <= tolerance_mm

    groups = {}
    for axis in "xyz":
        if not holds(axis, 180.0) and not holds(axis, 120.0) and not holds(axis, 72.0):
            continue  # no n-fold group (n <= 6) and no continuous one: each holds one of these
        if all(holds(axis, angle) for angle in _CONTINUOUS_TEST_DEG):
            groups[axis] = 0
            continue
        fold = next((n for n in _FOLDS if all(holds(axis, 360.0 * j / n) for j in range(1, n))), None)
        if fold is not None:
            groups[axis] = fold
    if not groups:
        return ObjectSymmetry(exact=False)
    axis = max(groups, key=lambda a: (groups[a] == 0, groups[a], -"xyz".index(a)))
    flip = next((other for other in "xyz" if other != axis and holds(other, 180.0)), None)
    return ObjectSymmetry(axis=axis, fold=groups[axis], flips=(flip,) if flip else (), exact=False)
