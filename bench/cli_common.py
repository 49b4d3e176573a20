"""What the command lines of the runs (:mod:`bench.cli`) and of the studies (:mod:`bench.studies.cli`) share:
the program's name, the argparse types, and the options that mean the same in both (``--seed``,
``--timeout``, ``--jobs``, ``--start-method``, ``--no-figures``, ``--plugin``, ...). Both import this module;
neither imports the other's helpers (:mod:`bench.cli` adds the ``study`` subcommand from :mod:`bench.studies.cli`).
"""

from __future__ import annotations

import argparse
import os
import re
import sys

from bench import checks
from bench.checks import argtype

__all__ = ["add_common", "add_selection", "error", "nonneg_float", "nonneg_int", "plain_summary", "positive_float",
           "positive_int", "program"]

positive_float = argtype(checks.real, lo=0.0, strict=True)
nonneg_float = argtype(checks.real, lo=0.0)
positive_int = argtype(checks.integer, lo=1)
nonneg_int = argtype(checks.integer, lo=0)


def program() -> str:
    """The command as the user typed it: ``oslbench`` for the installed script, else ``python -m bench``."""
    name = os.path.basename(sys.argv[0] if sys.argv and sys.argv[0] else "")
    stem = name[:-4] if name.lower().endswith(".exe") else name.removesuffix("-script.py")
    return "oslbench" if stem == "oslbench" else "python -m bench"


def error(command: str, message: str) -> None:
    """Print ``<program> <command>: error: <message>`` on one line of stderr."""
    print(f"{program()}{' ' + command if command else ''}: error: {message}", file=sys.stderr)


def add_selection(p: argparse.ArgumentParser, *, default_all: bool = True) -> None:
    """``--plant``, ``--design`` (globs, repeatable) and ``--out``."""
    default = "; default all" if default_all else "; default: the study's own"
    p.add_argument("--plant", action="append", metavar="GLOB", help=f"plant id or glob (repeatable{default})")
    p.add_argument("--design", action="append", metavar="GLOB", help=f"design id or glob (repeatable{default})")
    p.add_argument("--out", default="reports", metavar="DIR", help="report folder (default: reports)")


def add_common(p: argparse.ArgumentParser, *, seed_help: str, timeout: bool = True) -> None:
    """The options a run and every study share, each with the same meaning: ``--seed``, ``--timeout`` (when
    ``timeout``), ``--no-figures``, ``--jobs``, ``--start-method``, ``--quiet`` and ``--plugin``."""
    p.add_argument("--seed", type=nonneg_int, default=0, help=f"{seed_help} (default 0)")
    if timeout:
        p.add_argument("--timeout", type=positive_float, default=None, metavar="SECONDS",
                       help="wall-clock limit per pair; a pair that exceeds it becomes a 'timeout' row (default: none)")
    p.add_argument("--no-figures", action="store_true", help="skip the figures")
    p.add_argument("-j", "--jobs", type=positive_int, default=None, metavar="N",
                   help="local worker processes (default: all cores; 1 = serial)")
    p.add_argument("--start-method", choices=("fork", "forkserver", "spawn"), default=None,
                   help="how worker processes start (default: spawn on Windows and macOS; elsewhere fork, or "
                        "forkserver once this process runs threads); results are the same")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary")
    p.add_argument("--plugin", action="append", metavar="PATH",
                   help="a Python file registering your own plants or designs (repeatable)")


#: Sphinx roles in a docstring's first line (``:func:`~mod.name```): shown as the name alone.
_ROLE = re.compile(r":(?:[a-z]+:)?[a-z]+:`~?([^`<]*?)(?: <[^`]*>)?`")


def plain_summary(text: str) -> str:
    """A docstring's summary without reStructuredText markup: roles as their target, ````literals```` as is."""
    text = _ROLE.sub(lambda m: m.group(1).rsplit(".", 1)[-1] if m.group(0).find("~") >= 0 else m.group(1), text)
    return text.replace("``", "`")
