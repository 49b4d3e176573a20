"""oslbench: a benchmark suite for observer-based control of Lipschitz and one-sided Lipschitz systems.

``python -m bench run`` writes ``reports/REPORT.md``; from Python::

    from bench import run
    r = run(plants=["flexible_link"], designs=["thm1"])
    r.table        # one row per pair (pandas)
    r.write("out") # the same report files as the command

Public names: :func:`run`, :class:`Results` (:mod:`bench.api`); :class:`Plant`, :class:`Constants`,
:class:`Channels`, :func:`register_plant` (:mod:`plants`); :class:`Design`, :class:`DesignResult`,
:func:`register_design` (:mod:`designs`); :class:`OslbenchError` and the errors beneath it
(:mod:`bench.errors`). They are imported on first use.
"""

from . import _env, errors  # noqa: F401  (_env: BLAS threads, before numpy; errors imports nothing)

__version__ = "0.1.0"

#: Public name -> the module that defines it (imported on first use).
_PUBLIC = {
    "run": "bench.api",
    "Results": "bench.api",
    "register_design": "bench.registry",
    "register_plant": "bench.registry",
    "Plant": "plants",
    "Constants": "plants",
    "Channels": "plants",
    "Design": "designs",
    "DesignResult": "designs",
}
_PUBLIC.update(dict.fromkeys(errors.__all__, "bench.errors"))

__all__ = sorted(_PUBLIC)


def __getattr__(name: str):
    if name in _PUBLIC:
        import importlib

        value = getattr(importlib.import_module(_PUBLIC[name]), name)
        globals()[name] = value  # later look-ups skip this function
        return value
    raise AttributeError(f"module 'bench' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_PUBLIC))
