"""Figures (matplotlib, saved as PNG). Outside the numerical core."""

from tactojax.viz._belief import new_grasps_figure as new_grasps_figure
from tactojax.viz._figures import imprint_figure as imprint_figure
from tactojax.viz._figures import stitched_points as stitched_points
from tactojax.viz._localize import confusion_figure as confusion_figure
from tactojax.viz._localize import localization_histogram_figure as localization_histogram_figure
from tactojax.viz._localize import map_size_figure as map_size_figure
from tactojax.viz._map import tactile_map_figure as tactile_map_figure
from tactojax.viz._save import save_png as save_png
from tactojax.viz._shape import shape_examples_figure as shape_examples_figure

__all__ = [
    "confusion_figure", "imprint_figure", "localization_histogram_figure", "map_size_figure", "new_grasps_figure", "save_png",
    "shape_examples_figure", "stitched_points", "tactile_map_figure",
]
