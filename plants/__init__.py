"""Plants of oslbench: one module per plant, each registering its factories."""

import bench  # noqa: F401  (its __init__ sets the BLAS and Rayon threads, before numpy)

from plants._core import Channels, Constants, Plant, PlantError

__all__ = ["Channels", "Constants", "Plant", "PlantError"]
