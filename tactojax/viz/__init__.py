"""Figures (matplotlib, saved as PNG). Outside the numerical core."""

from tactojax.viz._figures import imprint_figure as imprint_figure
from tactojax.viz._figures import stitched_points as stitched_points
from tactojax.viz._map import tactile_map_figure as tactile_map_figure
from tactojax.viz._shape import shape_examples_figure as shape_examples_figure

__all__ = ["imprint_figure", "shape_examples_figure", "stitched_points", "tactile_map_figure"]
