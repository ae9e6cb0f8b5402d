"""tactojax: tactile mapping and localization from high-resolution tactile imprints, in JAX.

Pipeline stages (one subpackage each): ``sensor`` (specs, contact, optics), ``geometry``
(heightmaps -> points, kinematics), ``objects`` (analytic shapes and meshes), ``simulate``
(grasps and exploration protocols), ``io`` (all disk I/O), ``cli``.
"""

from tactojax.sensor import Imprint as Imprint
from tactojax.sensor import SensorSpec as SensorSpec

__version__ = "0.1.0"
__all__ = ["Imprint", "SensorSpec", "__version__"]
