"""Designs of oslbench: one module per design, each registering itself."""

import bench  # noqa: F401  (importing bench sets the BLAS and Rayon threads, before numpy)

from designs._core import GAIN_STATUSES, STATUSES, Design, DesignError, DesignResult

__all__ = ["GAIN_STATUSES", "STATUSES", "Design", "DesignError", "DesignResult"]
