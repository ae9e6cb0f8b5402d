"""Public names that moved: the old import path keeps working, with a DeprecationWarning, until
the next release."""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Callable


def moved_names(package: str, moved: dict[str, str]) -> Callable[[str], object]:
    """A module ``__getattr__`` for ``package`` whose names ``moved`` maps to their new modules
    (``{"load_test_episodes": "tactojax.localize.evaluation"}``)."""
    def __getattr__(name: str):
        if name in moved:
            warnings.warn(f"{package}.{name} moved to {moved[name]}.{name}; the old path goes in the next release",
                          DeprecationWarning, stacklevel=2)
            return getattr(importlib.import_module(moved[name]), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return __getattr__
