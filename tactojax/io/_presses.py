"""Read annotated ball presses (GelSight calibration frames) from disk.

Three sources, picked by :func:`load_ball_presses`:

* ``taxim:gelsight`` / ``taxim:gelsight_mini``: the real frames shipped by the ``taxim``
  package (see :mod:`tactojax.storage._taxim`), with their pixel pitch.
* an ``.npz`` in taxim's ``dataPack`` layout: ``f0`` (H, W, 3) BGR uint8 background, ``imgs``
  (N, H, W, 3) BGR uint8 presses, ``touch_center`` (N, 2) disc centres (x = column, y = row)
  and ``touch_radius`` (N,) disc radii, pixels.
* a directory with ``background.png``, the press images and ``presses.csv`` with a header
  ``image,center_x_px,center_y_px,radius_px`` (image paths relative to the directory).

The last two need the pixel pitch (``mm_per_px``).
"""

from __future__ import annotations

import csv
import pickle
import zipfile
from pathlib import Path

import numpy as np

from tactojax.shape import BallPresses

TAXIM_PREFIX = "taxim:"
CSV_NAME = "presses.csv"
BACKGROUND_NAME = "background.png"
CSV_COLUMNS = ("image", "center_x_px", "center_y_px", "radius_px")
NPZ_KEYS = ("f0", "imgs", "touch_center", "touch_radius")


def load_ball_presses(source, *, mm_per_px: float | None = None) -> BallPresses:
    """Annotated ball presses from taxim, a dataPack ``.npz`` or a directory (module docstring).

    Args:
        source: ``"taxim:<name>"``, a ``.npz`` path or a directory.
        mm_per_px: pixel pitch, mm; required for ``.npz`` and directories, overrides taxim's.

    Returns:
        :class:`tactojax.shape.BallPresses` (RGB images), validated.
    """
    if mm_per_px is not None and not (np.isfinite(mm_per_px) and mm_per_px > 0):
        raise ValueError(f"mm_per_px must be positive, got {mm_per_px}")
    text = str(source)
    if text.startswith(TAXIM_PREFIX):
        return _from_taxim(text[len(TAXIM_PREFIX):], mm_per_px)
    path = Path(source)
    if not path.exists():
        raise FileNotFoundError(f"no ball presses at {path} (give a .npz, a directory with {CSV_NAME}, "
                                "or taxim:gelsight / taxim:gelsight_mini)")
    if mm_per_px is None:
        raise ValueError(f"{path}: give the pixel pitch (mm_per_px, --mm-per-px) of these frames")
    try:
        if path.is_dir():
            return _from_directory(path, mm_per_px)
        if path.suffix.lower() == ".npz":
            return _from_npz(path, mm_per_px)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None
    raise ValueError(f"{path}: not a .npz file or a directory")


def _from_taxim(name: str, mm_per_px: float | None) -> BallPresses:
    from tactojax.storage._taxim import load_taxim_calibration

    calibration = load_taxim_calibration(name)
    return BallPresses(background=calibration.background_rgb, images=calibration.ball_frames_rgb,
                       centers_px=calibration.ball_centers_px, radii_px=calibration.ball_radii_px,
                       mm_per_px=calibration.mm_per_px if mm_per_px is None else mm_per_px, sensor=name)


def _from_npz(path: Path, mm_per_px: float) -> BallPresses:
    if not zipfile.is_zipfile(path):
        raise ValueError("not a .npz archive (corrupt or another format)")
    try:
        pack = np.load(path, allow_pickle=False)
        missing = [key for key in NPZ_KEYS if key not in pack.files]
        if missing:
            raise ValueError(f"missing arrays {missing} (a taxim dataPack holds {list(NPZ_KEYS)})")
        arrays = {key: pack[key] for key in NPZ_KEYS}
    except (OSError, EOFError, zipfile.BadZipFile, pickle.UnpicklingError) as error:
        raise ValueError(f"not a readable .npz file ({error})") from None
    background, images = arrays["f0"], arrays["imgs"]
    for key, array, rank in (("f0", background, 3), ("imgs", images, 4)):
        if array.ndim != rank or array.shape[-1] != 3:
            layout = "(H, W, 3)" if rank == 3 else "(N, H, W, 3)"
            raise ValueError(f"{key} must be {layout} BGR, got shape {array.shape}")
        if array.dtype != np.uint8:
            raise ValueError(f"{key} must be uint8, got {array.dtype}")
    return BallPresses(background=background[..., ::-1].astype(np.float32) / 255.0,
                       images=np.ascontiguousarray(images[..., ::-1]),
                       centers_px=np.asarray(arrays["touch_center"], np.float32),
                       radii_px=np.asarray(arrays["touch_radius"], np.float32),
                       mm_per_px=mm_per_px, sensor=path.stem)


def _from_directory(path: Path, mm_per_px: float) -> BallPresses:
    table = path / CSV_NAME
    if not table.is_file():
        raise FileNotFoundError(f"{path}: no {CSV_NAME} (columns {','.join(CSV_COLUMNS)})")
    background = _read_png(path / BACKGROUND_NAME)
    names, centers, radii = [], [], []
    with table.open(newline="") as stream:
        reader = csv.DictReader(stream)
        missing = [c for c in CSV_COLUMNS if c not in (reader.fieldnames or [])]
        if missing:
            raise ValueError(f"{CSV_NAME} lacks columns {missing} (header: {','.join(CSV_COLUMNS)})")
        for line, row in enumerate(reader, start=2):
            try:
                centers.append((float(row["center_x_px"]), float(row["center_y_px"])))
                radii.append(float(row["radius_px"]))
            except (TypeError, ValueError):
                raise ValueError(f"{CSV_NAME} line {line}: centre and radius must be numbers, got "
                                 f"{row['center_x_px']!r}, {row['center_y_px']!r}, {row['radius_px']!r}") from None
            names.append(row["image"])
    if not names:
        raise ValueError(f"{CSV_NAME} lists no presses")
    images = []
    for name in names:
        image = _read_png(path / name)
        if image.shape != background.shape:
            raise ValueError(f"{name} is {image.shape[1]} x {image.shape[0]} px but {BACKGROUND_NAME} is "
                             f"{background.shape[1]} x {background.shape[0]} px")
        images.append(image)
    return BallPresses(background=background.astype(np.float32) / 255.0, images=np.stack(images),
                       centers_px=np.asarray(centers, np.float32), radii_px=np.asarray(radii, np.float32),
                       mm_per_px=mm_per_px, sensor=path.name)


def _read_png(path: Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB image (8-bit colour only)."""
    import cv2

    if not path.is_file():
        raise FileNotFoundError(f"image {path} is missing")
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"cannot read image {path.name} (corrupt or not an image)")
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"{path.name} must be an 8-bit colour (BGR) image, got shape {image.shape} {image.dtype}")
    return np.ascontiguousarray(image[..., ::-1])
