"""Read the real GelSight calibrations shipped by the PyPI package ``taxim`` (MIT licence).

Folder ``taxim/calib/<name>/`` holds ``f0`` (background frame, BGR uint8) and ball presses in
``dataPack.npz``, the per-pixel polynomial colour table in ``polycalib.npz`` (``grad_r``,
``grad_g``, ``grad_b``: (bins, bins, 6) coefficients on 0-255 intensities; the file's red and
blue tables are swapped, as the taxim authors note) and ``params.json`` (``sensor.pixmm``,
``sensor.h``, ``sensor.w``).
"""

from __future__ import annotations

import importlib.util
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

TAXIM_SENSORS = ("gelsight", "gelsight_mini")


class MissingDataPackageError(ImportError):
    """An optional data package (``pip install 'tactojax[data]'``) is not installed."""


def taxim_calibration_dir(name: str) -> Path:
    """Folder of the taxim calibration ``name`` ('gelsight' or 'gelsight_mini')."""
    if name not in TAXIM_SENSORS:
        raise ValueError(f"unknown taxim sensor {name!r}; choose one of {TAXIM_SENSORS}")
    spec = importlib.util.find_spec("taxim")
    if spec is None or not spec.submodule_search_locations:
        raise MissingDataPackageError(
            f"sensor preset {name!r} reads the calibration shipped by the 'taxim' package: "
            "install it with  pip install 'tactojax[data]'"
        )
    folder = Path(next(iter(spec.submodule_search_locations))) / "calib" / name
    if not folder.is_dir():
        raise FileNotFoundError(f"taxim calibration folder {folder} is missing")
    return folder


@dataclass(frozen=True)
class TaximCalibration:
    """Arrays of one taxim calibration folder, at full resolution."""

    mm_per_px: float
    background_rgb: np.ndarray
    """(480, 640, 3) float32 in [0, 1]."""
    table_rgb: np.ndarray
    """(bins, bins, 6, 3) float32, colour change per unit intensity [0, 1]."""
    ball_frames_rgb: np.ndarray
    """(N, 480, 640, 3) uint8 real ball presses."""
    ball_centers_px: np.ndarray
    """(N, 2) annotated contact centres (column x, row y), pixels."""
    ball_radii_px: np.ndarray
    """(N,) annotated contact radii, pixels."""


def load_taxim_calibration(name: str) -> TaximCalibration:
    """Load one taxim calibration folder (see the module docstring for its files)."""
    folder = taxim_calibration_dir(name)
    params = json.loads((folder / "params.json").read_text())["sensor"]
    poly = np.load(folder / "polycalib.npz")
    # RGB order: the file's grad_b table drives red and grad_r drives blue.
    table = np.stack([poly["grad_b"], poly["grad_g"], poly["grad_r"]], axis=-1) / 255.0
    pack = np.load(folder / "dataPack.npz")
    background = pack["f0"][..., ::-1].astype(np.float32) / 255.0
    expected = (int(params["h"]), int(params["w"]), 3)
    if background.shape != expected:
        raise ValueError(f"{folder}: background frame is {background.shape}, expected {expected}")
    return TaximCalibration(
        mm_per_px=float(params["pixmm"]),
        background_rgb=background,
        table_rgb=table.astype(np.float32),
        ball_frames_rgb=np.ascontiguousarray(pack["imgs"][..., ::-1]),
        ball_centers_px=np.asarray(pack["touch_center"], dtype=np.float32),
        ball_radii_px=np.asarray(pack["touch_radius"], dtype=np.float32),
    )
