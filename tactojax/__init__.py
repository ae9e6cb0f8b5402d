"""tactojax: tactile mapping and localization from high-resolution tactile imprints, in JAX.

Layers, bottom to top; each imports only those below it, also inside functions (``lint-imports``
checks the contract in ``pyproject.toml``; details in :mod:`tactojax.storage`):

- ``storage``: file formats (atomic writes, datasets, meshes, taxim packs, torch weights,
  checkpoint containers); imports no stage.
- the stages, in order: ``geometry`` (heightmaps -> points, kinematics), ``sensor`` (specs,
  contact, optics), ``objects`` (analytic shapes and meshes), ``simulate`` (grasps, protocols,
  datasets), ``shape`` (image -> heightmap), ``mapping`` (tactile maps), ``features`` (encoders),
  ``localize`` (pose beliefs, evaluation).
- ``io``: stage-specific load and save, and every public file function in one place.
- ``hardware`` and ``viz``, then ``cli``.
"""

from tactojax._compilation import CompilationCounter as CompilationCounter
from tactojax._compilation import kernel_count as kernel_count
from tactojax._compilation import use_compilation_cache as use_compilation_cache
from tactojax.sensor import Imprint as Imprint
from tactojax.sensor import SensorSpec as SensorSpec

__version__ = "0.1.0"
__all__ = ["CompilationCounter", "Imprint", "SensorSpec", "__version__", "kernel_count", "use_compilation_cache"]
