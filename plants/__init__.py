"""Plants of oslbench: one module per plant, each registering its factories."""

import bench._env  # noqa: F401  (the BLAS and Rayon threads, set before numpy)

from plants._core import Channels, Constants, Plant, PlantError

__all__ = ["Channels", "Constants", "Plant", "PlantError"]
