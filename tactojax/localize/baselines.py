"""The paper's one-touch methods (``random``, ``cti``, ``cti-icp-N``, identification by the
closest imprint) and their pieces.

:func:`localize_baseline` runs a method by name; its steps are public for ablations:
retrieval of the closest imprints by feature (:func:`closest_imprints`), the touch's contact
points (:func:`contact_points`), and ICP from the retrieved poses (:func:`estimate_pose`).
:func:`identify` names the object whose map holds the imprint most similar to a touch (paper
section VII), over the maps' features stacked once in a :class:`MapLibrary`.
The library's answer is the belief (:func:`tactojax.localize.localize`); these stay as its
comparison (the paper's Table III).
"""

from tactojax.localize._baselines import PAPER_METHODS as PAPER_METHODS
from tactojax.localize._baselines import estimate_pose as estimate_pose
from tactojax.localize._baselines import localize_baseline as localize_baseline
from tactojax.localize._icp import IcpSettings as IcpSettings
from tactojax.localize._identify import MapLibrary as MapLibrary
from tactojax.localize._identify import identify as identify
from tactojax.localize._points import POINTS_PER_TOUCH as POINTS_PER_TOUCH
from tactojax.localize._points import contact_points as contact_points
from tactojax.localize._pose import PoseEstimate as PoseEstimate
from tactojax.localize._retrieval import MAX_OPENING_DIFFERENCE_MM as MAX_OPENING_DIFFERENCE_MM
from tactojax.localize._retrieval import closest_imprints as closest_imprints

__all__ = [
    "MAX_OPENING_DIFFERENCE_MM",
    "PAPER_METHODS",
    "POINTS_PER_TOUCH",
    "IcpSettings",
    "MapLibrary",
    "PoseEstimate",
    "closest_imprints",
    "contact_points",
    "estimate_pose",
    "identify",
    "localize_baseline",
]
