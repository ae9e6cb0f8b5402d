"""Figures (matplotlib, saved as PNG). Outside the numerical core."""

from tactojax.viz._figures import imprint_figure as imprint_figure
from tactojax.viz._figures import stitched_points as stitched_points

__all__ = ["imprint_figure", "stitched_points"]
