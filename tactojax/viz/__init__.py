"""Figures (matplotlib, saved as PNG) and interactive 3-D views (rerun, imported lazily).

Outside the numerical core. The rerun functions (``log_*``, ``new_recording``, ``open_recording``,
``read_estimates``) import ``rerun`` only when called (optional extra ``viz``).
"""

from tactojax.viz._active import active_episode_figure as active_episode_figure
from tactojax.viz._belief import belief_figure as belief_figure
from tactojax.viz._belief import new_grasps_figure as new_grasps_figure
from tactojax.viz._figures import imprint_figure as imprint_figure
from tactojax.viz._figures import stitched_points as stitched_points
from tactojax.viz._localize import confusion_figure as confusion_figure
from tactojax.viz._localize import localization_histogram_figure as localization_histogram_figure
from tactojax.viz._localize import map_size_figure as map_size_figure
from tactojax.viz._map import tactile_map_figure as tactile_map_figure
from tactojax.viz._rerun import height_colors as height_colors
from tactojax.viz._rerun import log_belief as log_belief
from tactojax.viz._rerun import log_estimate as log_estimate
from tactojax.viz._rerun import log_live_estimate as log_live_estimate
from tactojax.viz._rerun import log_maps as log_maps
from tactojax.viz._rerun import log_touch as log_touch
from tactojax.viz._rerun import log_view as log_view
from tactojax.viz._rerun import new_recording as new_recording
from tactojax.viz._rerun import open_recording as open_recording
from tactojax.viz._rerun import read_estimates as read_estimates
from tactojax.viz._rerun import read_test_touches as read_test_touches
from tactojax.viz._save import save_png as save_png
from tactojax.viz._shape import shape_examples_figure as shape_examples_figure

__all__ = [
    "active_episode_figure", "belief_figure", "confusion_figure", "imprint_figure", "localization_histogram_figure", "map_size_figure", "new_grasps_figure", "save_png",
    "shape_examples_figure", "stitched_points", "tactile_map_figure",
    "height_colors", "log_belief", "log_estimate", "log_live_estimate", "log_maps", "log_touch", "log_view", "new_recording",
    "open_recording", "read_estimates", "read_test_touches",
]
