"""Plants of oslbench: one module per plant, each registering its factories."""

import bench  # noqa: F401  (importing bench sets the BLAS and Rayon threads, before numpy)

from plants._core import Channels, Constants, Plant, PlantError, jacobian_mismatch

__all__ = ["Channels", "Constants", "Plant", "PlantError", "jacobian_mismatch"]
