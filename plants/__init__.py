"""Plants of oslbench: one module per plant, each registering its factories."""

from plants._core import Constants, Plant, PlantError

__all__ = ["Constants", "Plant", "PlantError"]
