"""oslbench: a benchmark suite for observer-based control of Lipschitz and one-sided Lipschitz systems.

Run ``python -m bench run`` to produce ``reports/REPORT.md``; ``python -m bench list`` lists
the registered plants and designs.
"""

from bench import _env  # noqa: F401  (BLAS threads, before numpy)

__version__ = "0.1.0"
