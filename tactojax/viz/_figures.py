"""Figures of simulated imprints and stitched contact clouds."""

from __future__ import annotations

from pathlib import Path

import jax.numpy as jnp
import jaxlie
import numpy as np

from tactojax.geometry import heightmap_to_points


def stitched_points(records: dict, mm_per_px: float, *, max_points: int = 20000, seed: int = 0) -> np.ndarray:
    """Contact points of many imprints stitched in the object frame, mm.

    Each imprint's points (sensor frame) are placed with ``T_object_sensor =
    T_world_object^-1 T_world_sensor`` (the robot kinematics), then subsampled.

    Args:
        records: dataset records with ``heightmap`` (N, H, W), ``mask``, ``T_world_sensor`` and
            ``T_world_object`` (N, 7).
        mm_per_px: the sensor's pixel pitch.

    Returns:
        (M, 3) points, M <= max_points.
    """
    clouds = []
    for heightmap, mask, T_ws, T_wo in zip(records["heightmap"], records["mask"],
                                           records["T_world_sensor"], records["T_world_object"]):
        points = np.asarray(heightmap_to_points(jnp.asarray(heightmap), mm_per_px))[mask]
        T_object_sensor = jaxlie.SE3(jnp.asarray(T_wo)).inverse() @ jaxlie.SE3(jnp.asarray(T_ws))
        clouds.append(np.asarray(T_object_sensor @ jnp.asarray(points)))
    cloud = np.concatenate(clouds) if clouds else np.zeros((0, 3))
    if len(cloud) > max_points:
        cloud = cloud[np.random.default_rng(seed).choice(len(cloud), max_points, replace=False)]
    return cloud


def imprint_figure(per_object: dict[str, dict], mm_per_px: float, path: str | Path, *, examples: int = 2) -> Path:
    """Save a figure: per object, example tactile images and heightmaps and the stitched cloud.

    Args:
        per_object: object name -> dataset records (see :func:`stitched_points`) with ``image``.
        mm_per_px: the sensor's pixel pitch.
        path: output PNG.
    """
    from matplotlib.figure import Figure  # no pyplot: leaves a notebook's backend alone

    from tactojax.viz._save import save_png

    names = list(per_object)
    columns = 2 * examples + 1
    fig = Figure(figsize=(3.0 * columns, 2.8 * len(names)))
    for row, name in enumerate(names):
        records = per_object[name]
        contact_area = records["mask"].sum(axis=(1, 2))
        picks = np.argsort(-contact_area)[np.linspace(0, len(contact_area) // 2, examples).astype(int)]
        for j, index in enumerate(picks):
            ax = fig.add_subplot(len(names), columns, row * columns + 2 * j + 1)
            ax.imshow(records["image"][index])
            ax.set_title(f"{name}: image #{index}", fontsize=8)
            ax.axis("off")
            ax = fig.add_subplot(len(names), columns, row * columns + 2 * j + 2)
            shown = ax.imshow(records["heightmap"][index], cmap="viridis")
            fig.colorbar(shown, ax=ax, fraction=0.046, label="indentation (mm)")
            ax.set_title(f"heightmap #{index}", fontsize=8)
            ax.axis("off")
        cloud = stitched_points(records, mm_per_px)
        ax = fig.add_subplot(len(names), columns, row * columns + columns, projection="3d")
        ax.scatter(cloud[:, 0], cloud[:, 1], cloud[:, 2], s=0.2, c=cloud[:, 2], cmap="viridis")
        ax.set_title(f"{name}: {len(records['image'])} imprints stitched", fontsize=8)
        ax.set_xlabel("x (mm)", fontsize=7)
        ax.set_ylabel("y (mm)", fontsize=7)
        ax.set_zlabel("z (mm)", fontsize=7)
        ax.set_box_aspect(np.ptp(cloud, axis=0) + 1e-3 if len(cloud) else (1, 1, 1))
    return save_png(fig, path, dpi=110)
