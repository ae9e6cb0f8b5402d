"""Training pairs for the image -> heightmap models, and the paper's splits (section IV)."""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class ShapeData:
    """N (tactile image, heightmap, mask) pairs held in host memory.

    Images stay uint8 until a batch is drawn, so a few thousand full-resolution pairs fit.
    """

    images: np.ndarray
    """(N, H, W, 3) uint8 RGB."""
    heightmaps: np.ndarray
    """(N, H, W) float32 gel indentation, mm."""
    masks: np.ndarray
    """(N, H, W) bool contact masks."""
    object_ids: np.ndarray
    """(N,) str: the touched object."""
    mm_per_px: float
    """Pixel pitch, mm."""
    sensor: str = ""
    """Sensor name from the dataset metadata."""

    def __len__(self) -> int:
        return len(self.images)

    @property
    def objects(self) -> list[str]:
        """Object ids in order of first appearance."""
        return list(dict.fromkeys(self.object_ids.tolist()))

    def take(self, indices) -> ShapeData:
        """The pairs at ``indices`` (an index array or boolean mask)."""
        return dataclasses.replace(
            self, images=self.images[indices], heightmaps=self.heightmaps[indices],
            masks=self.masks[indices], object_ids=self.object_ids[indices],
        )

    def images_float(self, indices=slice(None)) -> np.ndarray:
        """Images at ``indices`` as float32 in [0, 1]."""
        return self.images[indices].astype(np.float32) / 255.0


def split_held_out(data: ShapeData, test_per_object: int = 100) -> tuple[ShapeData, ShapeData]:
    """(train, test): the last ``test_per_object`` pairs of every object are held out (paper: 100 of 600)."""
    test = np.zeros(len(data), bool)
    for name in data.objects:
        rows = np.flatnonzero(data.object_ids == name)
        if len(rows) <= test_per_object:
            raise ValueError(f"object {name!r} has {len(rows)} pairs, need more than {test_per_object}")
        test[rows[len(rows) - test_per_object:]] = True
    return data.take(~test), data.take(test)


def balanced_subset(data: ShapeData, count: int) -> ShapeData:
    """The first ``count`` pairs taken round-robin over objects (so every object is equally used)."""
    if count > len(data):
        raise ValueError(f"asked for {count} training pairs but only {len(data)} are available")
    per_object = [np.flatnonzero(data.object_ids == name) for name in data.objects]
    order = [rows[i] for i in range(max(map(len, per_object))) for rows in per_object if i < len(rows)]
    return data.take(np.sort(np.asarray(order[:count])))


def estimate_background(data: ShapeData, max_images: int = 512) -> np.ndarray:
    """The no-contact frame, (H, W, 3) float32 in [0, 1], from the pairs themselves.

    Each pixel averages the images in which the gel there is undeformed (true height below
    1 micrometre), which also averages the camera noise away; a pixel that is deformed in every
    image takes the per-pixel median. A captured background frame can be used instead.
    """
    step = max(1, len(data) // max_images)
    images = data.images[::step].astype(np.float32) / 255.0
    undeformed = (data.heightmaps[::step] < 1e-3)[..., None]
    counts = undeformed.sum(axis=0)
    mean = (images * undeformed).sum(axis=0) / np.maximum(counts, 1)
    return np.where(counts > 0, mean, np.median(images, axis=0)).astype(np.float32)
