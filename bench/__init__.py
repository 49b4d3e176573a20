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

The packages ``plants`` and ``designs`` are found beside this one: ``python -m bench`` leaves the working
folder off the module path (as ``python -P`` does, and as the ``oslbench`` command is anyway), so a local
``plants.py`` or ``designs.py`` cannot shadow them; elsewhere (a notebook, a script) importing :mod:`bench`
with such a file on the path raises an ImportError naming it. (A local ``bench.py`` is what ``python -m bench``
itself runs: use ``oslbench`` there.)
"""

from . import _env, errors  # noqa: F401  (_env: BLAS threads, before numpy; errors imports nothing)


def _run_as_module() -> bool:
    """Whether this interpreter was started as ``python [options] -m bench``."""
    import sys

    argv = list(getattr(sys, "orig_argv", [])[1:])
    while argv:
        tok = argv.pop(0)
        if tok == "-m":
            return bool(argv) and argv[0] == "bench"
        if tok.startswith("-m"):
            return tok[2:] == "bench"
        if tok in ("-X", "-W"):  # options that take a value
            argv[:1] = []
        elif tok == "-c" or not tok.startswith("-"):
            return False
    return False


def _own_packages() -> None:
    """Make sure ``plants`` and ``designs`` are the packages beside this one (see the module docstring)."""
    import importlib.util
    import os
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    cwd = Path.cwd().resolve()
    if _run_as_module() and cwd != root:  # the working folder -m put first: off the path, as python -P would
        sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != cwd]
    for name in ("plants", "designs"):
        module = sys.modules.get(name)
        try:
            origin = getattr(module, "__file__", None) if module is not None else \
                getattr(importlib.util.find_spec(name), "origin", None)
        except (ImportError, ValueError):
            origin = None
        if not origin or not os.path.exists(origin):
            continue
        found = Path(origin).resolve()
        if found != root / name / "__init__.py":
            what = f"folder {found.parent}" if found.name == "__init__.py" else f"file {found}"
            raise ImportError(f"a local {what} shadows the oslbench package {name!r} (installed in {root}): rename "
                              "it, or work in another folder")


_own_packages()

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
