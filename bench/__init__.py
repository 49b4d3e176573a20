"""oslbench: a benchmark suite for observer-based control of Lipschitz and one-sided Lipschitz systems.

From the command line, ``python -m bench run`` writes ``reports/REPORT.md``; from Python::

    import bench
    r = bench.run(plants=["flexible_link"], designs=["thm1"])
    r.table        # one row per pair (pandas)
    r.write("out") # the same report files as the command

``bench.run`` and ``bench.Results`` are imported on first use (``python -m bench --help`` stays fast).
"""

from bench import _env  # noqa: F401  (BLAS threads, before numpy)

__version__ = "0.1.0"
__all__ = ["Results", "run"]


def __getattr__(name: str):
    if name in ("run", "Results"):
        from bench import api

        return getattr(api, name)
    raise AttributeError(f"module 'bench' has no attribute {name!r}")
