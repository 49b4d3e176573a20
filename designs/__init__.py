"""Designs of oslbench: one module per design, each registering itself."""

from designs._core import Design, DesignError, DesignResult

__all__ = ["Design", "DesignError", "DesignResult"]
