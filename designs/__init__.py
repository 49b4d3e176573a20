"""Designs of oslbench: one module per design, each registering itself."""

import bench._env  # noqa: F401  (the BLAS and Rayon threads, set before numpy)

from designs._core import GAIN_STATUSES, STATUSES, Design, DesignError, DesignResult

__all__ = ["GAIN_STATUSES", "STATUSES", "Design", "DesignError", "DesignResult"]
