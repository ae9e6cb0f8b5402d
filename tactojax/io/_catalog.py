"""Map catalogs: a directory of tactile maps with an index, as ``tactojax map-catalog`` writes it.

The index (``catalog.json``) lists every object the catalog was asked for, with the map file
of those built and the error of those that could not be (an object the gripper cannot grasp, a
mesh that does not load). The commands that take maps take a catalog directory too
(:func:`expand_catalogs`): it stands for the maps of its built objects.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

from tactojax.storage import atomic_write_bytes

INDEX = "catalog.json"
"""The index file inside a catalog directory."""

VERSION = 1
"""Version of the index layout."""


def is_catalog(path) -> bool:
    """Whether ``path`` is a catalog directory (it holds an index)."""
    return (Path(path) / INDEX).is_file()


def catalog_slug(object_name: str) -> str:
    """A file-name-safe name of an object (``ycb:011_banana`` -> ``ycb_011_banana``)."""
    return re.sub(r"[^\w.-]+", "_", object_name).strip("_")


def read_catalog(path) -> dict:
    """A catalog's index: ``{"version", "settings", "objects": {name: entry}}``; every entry has a
    ``status`` (``"built"`` with its ``map`` file, imprints, bytes and seconds, or ``"failed"``
    with its ``error``). An empty index for a directory that holds none yet."""
    index_path = Path(path) / INDEX
    if not index_path.exists():
        return {"version": VERSION, "settings": {}, "objects": {}}
    try:
        index = json.loads(index_path.read_text())
    except json.JSONDecodeError as error:
        raise ValueError(f"{index_path} is not a readable catalog index ({error})") from error
    if index.get("version") != VERSION or not isinstance(index.get("objects"), dict):
        raise ValueError(f"{index_path} is not a version-{VERSION} catalog index")
    return index


def write_catalog(path, index: dict) -> None:
    """Write a catalog's index atomically (an interrupted build keeps the last complete one)."""
    atomic_write_bytes(Path(path) / INDEX, (json.dumps(index, indent=2) + "\n").encode())


def catalog_maps(path) -> list[Path]:
    """The map files of a catalog's built objects, in the index's order."""
    if not is_catalog(path):
        raise FileNotFoundError(f"{path} is not a map catalog (no {INDEX}; build one with `tactojax map-catalog`)")
    index = read_catalog(path)
    maps = [Path(path) / entry["map"] for entry in index["objects"].values() if entry.get("status") == "built"]
    missing = [str(m) for m in maps if not m.is_file()]
    if missing:
        raise FileNotFoundError(f"the catalog {path} lists maps that are not there: {', '.join(missing)}")
    if not maps:
        raise ValueError(f"the catalog {path} holds no built map")
    return maps


def expand_catalogs(paths) -> list[str]:
    """Map paths with every catalog directory among them replaced by its maps (others as given)."""
    out: list[str] = []
    for path in paths:
        if Path(path).is_dir():
            out.extend(str(m) for m in catalog_maps(path))
        else:
            out.append(str(path))
    return out
