"""Command line: ``python -m bench run``, ``report``, ``list``, ``study``, ``cache`` and ``perf`` (also installed as
``oslbench``).

Exit codes: 0 success, 1 a report that could not be written, a pair that is an error or a timeout under
``--strict`` (or an internal error, in one line), 2 bad usage, 130 interrupted; a run whose every pair is an
error or a timeout says so on its last line. ``run`` keeps finished pairs in a cache folder (default ``.bench-cache/`` beside the report
folder: ``--out /tmp/r`` caches in ``/tmp/.bench-cache``; ``--cache-dir`` chooses, ``--no-cache`` ignores it,
``cache clear`` empties it), so an interrupted run resumes when run again; the previous report stays
untouched until the new one is whole. The options a run shares with the studies are in
:mod:`bench.cli_common`.
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import sys
import time
from contextlib import contextmanager
from functools import partial
from pathlib import Path
from typing import Iterator

from bench.cli_common import (add_common, add_selection, error, nonneg_float, nonneg_int,  # noqa: F401
                              plain_summary, positive_float, positive_int, program)
from bench.registry import DESIGNS, PLANTS
from bench.selection import check_selection

__all__ = ["main", "summary_line"]


def _scheduler_address(text: str) -> str:
    """An argparse type: a Dask scheduler address ``[scheme://]host:port``."""
    if not re.fullmatch(r"([a-z][a-z0-9+.-]*://)?\S+:\d+", text):
        raise argparse.ArgumentTypeError(f"expected an address like tcp://host:8786, got {text!r}")
    return text


def version_text() -> str:
    """``oslbench <version>``, where the package is installed and the Python running it."""
    import platform

    import bench

    where = Path(bench.__file__).resolve().parents[1]
    return f"oslbench {bench.__version__} (packages bench, plants, designs in {where}; Python {platform.python_version()})"


class _Version(argparse.Action):
    """``--version``: :func:`version_text` on one line (argparse's own action wraps it), then exit 0."""

    def __init__(self, option_strings, dest, **kwargs):
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        print(version_text())
        parser.exit()


def _build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=program(), description="oslbench: observer-based control of OSL/Lipschitz systems")
    p.add_argument("--version", action=_Version, help="print the version, where the package is installed, and exit")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="run (plant, design) pairs and write the report")
    add_selection(r)
    add_common(r, seed_help="seed of the constants sampler and of the measurement noise")
    r.add_argument("--claimed-constants", action="store_true",
                   help="design with the constants the sources claim (the certificate still uses valid ones)")
    r.add_argument("--t-final", type=positive_float, default=None, metavar="SECONDS",
                   help="one simulation horizon for every pair (default: each pair's horizon follows its "
                        "certified rate, or its linearised rate when uncertified, from the plant's own "
                        "horizon up to ten times it)")
    r.add_argument("--noise", type=nonneg_float, default=0.0, metavar="SIGMA",
                   help="standard deviation of a seeded Gaussian measurement noise (default 0)")
    r.add_argument("--disturbance", type=nonneg_float, default=0.1, metavar="AMPLITUDE",
                   help="peak of a seeded L2 disturbance w (docs/results.md): each pair of a plant with "
                        "disturbance inputs is simulated again from z(0) = 0 with w, for the measured ratios "
                        "l2_measured_e, l2_measured_x beside the certified gains (default 0.1; 0: off)")
    r.add_argument("--figure-format", action="append", choices=("png", "pdf"), default=None,
                   help="figure format, repeatable (default png; the report links the PNG)")
    r.add_argument("--fail-fast", action="store_true", help="stop at the first exception (for debugging)")
    r.add_argument("--strict", action="store_true", help="exit 1 when any pair is an error or a timeout")
    r.add_argument("--scheduler", type=_scheduler_address, default=None, metavar="ADDRESS",
                   help="run on a Dask distributed cluster (needs pip install 'oslbench[dist]')")
    _cache_options(r, "folder of finished pairs (default: .bench-cache beside --out, e.g. /tmp/.bench-cache for "
                      "--out /tmp/r)")
    r.add_argument("--no-cache", action="store_true",
                   help="recompute every pair: neither read nor write the cache")
    rp = sub.add_parser("report", help="draw a report folder's REPORT.md, report.html, tables.tex and figures again "
                                       "from its results (results.csv, gains.json, run.json, figure_data.npz), "
                                       "computing nothing")
    rp.add_argument("folder", metavar="FOLDER", help="a report folder written by run")
    rp.add_argument("--out", default=None, metavar="DIR",
                    help="write into DIR, with the result files copied (default: FOLDER itself)")
    rp.add_argument("--no-figures", action="store_true", help="do not draw the figures")
    rp.add_argument("--figure-format", action="append", choices=("png", "pdf"), default=None,
                    help="figure format, repeatable (default: the formats the run drew)")
    rp.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")
    ls = sub.add_parser("list", help="list plants and designs")
    ls.add_argument("--plugin", action="append", metavar="PATH",
                    help="a Python file registering your own plants or designs (repeatable)")
    dp = sub.add_parser("docs-plants", help="print the plant catalogue page (docs/plants.md) from the registry")
    dp.add_argument("--out", default=None, metavar="FILE", help="write it to FILE (default: print it)")
    dp.add_argument("--plugin", action="append", metavar="PATH",
                    help="a Python file registering your own plants (repeatable): documented beside the catalogue")
    from bench.studies.cli import add_study_parser

    add_study_parser(sub)  # python -m bench study {admissible,sampling,montecarlo,noise}
    ca = sub.add_parser("cache", help="where the cache of finished pairs is, and clearing it")
    ca_sub = ca.add_subparsers(dest="action", required=True)
    for action, text in (("info", "print the cache folder, its entries and their size"),
                         ("clear", "delete the cache's entries (nothing else in the folder)")):
        c = ca_sub.add_parser(action, help=text)
        c.add_argument("--out", default="reports", metavar="DIR",
                       help="the report folder whose cache it is (default: reports; the cache is beside it)")
        _cache_options(c, "the cache folder itself (overrides --out)")
    pf = sub.add_parser("perf", help="measure design time vs n, joint vs separated, and the parallel speed-up")
    pf.add_argument("--out", default="reports", metavar="DIR", help="folder for PERF.md (default: reports)")
    pf.add_argument("--sizes", type=_sizes, default="4,8,16,32,64", metavar="N,N,...",
                    help="state dimensions (default 4,8,16,32,64)")
    pf.add_argument("--max-joint-n", type=positive_int, default=32, metavar="N",
                    help="largest n for the joint 6n LMI (default 32)")
    pf.add_argument("--no-run", action="store_true", help="skip timing the default run with --jobs 1 and 2")
    pf.add_argument("--no-sweeps", action="store_true",
                    help="skip the design-call sweeps (bisection over c, random family; compiled vs rebuilt)")
    pf.add_argument("--route-sizes", type=partial(_sizes, allow_empty=True), default="16,32,64,128,256,512,1024",
                    metavar="N,N,...",
                    help="chain sizes n for the structured design's Riccati and SDP routes ('' skips)")
    pf.add_argument("--no-sims", action="store_true", help="skip the n = 1000 trajectory and n = 100 batch")
    pf.add_argument("--repeats", type=positive_int, default=3, metavar="K",
                    help="runs per job count when timing the default run (default 3)")
    return p


def _cache_options(p: argparse.ArgumentParser, text: str) -> None:
    p.add_argument("--cache-dir", default=None, metavar="DIR", help=text)


def cache_dir(args) -> Path:
    """The cache folder of a ``run`` or ``cache`` command: ``--cache-dir``, else ``.bench-cache`` beside ``--out``."""
    from bench.cache import default_cache_dir

    return Path(os.path.abspath(args.cache_dir)) if args.cache_dir else default_cache_dir(args.out)


#: The cache's entries inside its folder (bench.cache): pairs and constants, plus temporary files of a write.
_CACHE_ENTRIES = ("pairs", "constants")


def _cache_files(root: Path) -> list[Path]:
    return [f for sub in _CACHE_ENTRIES if (root / sub).is_dir() for f in sorted((root / sub).iterdir())
            if f.is_file() and (f.suffix == ".npz" or f.name.startswith(".tmp-"))]


def _cmd_cache(args) -> int:
    """``cache info``: the folder, its entries and size; ``cache clear``: delete the entries, then the empty folders."""
    root = cache_dir(args)
    files = _cache_files(root)
    size = sum(f.stat().st_size for f in files)
    if args.action == "info":
        count = {sub: sum(f.parent.name == sub and f.suffix == ".npz" for f in files) for sub in _CACHE_ENTRIES}
        pairs, plants = count["pairs"], count["constants"]
        state = "does not exist" if not root.exists() else (
            f"{pairs} pair{'s' * (pairs != 1)}, the constants of {plants} plant{'s' * (plants != 1)}, "
            f"{size / 1e6:.1f} MB")
        print(f"{root}: {state}")
        return 0
    if root.exists() and not root.is_dir():
        error("cache clear", f"{root} is not a folder")
        return 2
    for f in files:
        f.unlink(missing_ok=True)
    for folder in (*(root / sub for sub in _CACHE_ENTRIES), root):
        try:
            folder.rmdir()  # only when empty: a folder holding anything else stays
        except OSError:
            pass
    left = " (the folder holds other files, left alone)" if root.exists() else ""
    print(f"{root}: removed {len(files)} entries, {size / 1e6:.1f} MB{left}")
    return 0


def _cmd_report(args) -> int:
    """``python -m bench report FOLDER``: :func:`bench.report.redraw`."""
    from bench.errors import OutDirError
    from bench.report import redraw

    try:
        path = redraw(args.folder, args.out, figures=not args.no_figures, figure_format=args.figure_format)
    except OutDirError as exc:
        error("report", str(exc))
        return 2
    except ValueError as exc:
        error("report", str(exc))
        return 1
    if not args.quiet:
        print(f"wrote {path} (and report.html, tables.tex{'' if args.no_figures else ', figures'})", file=sys.stderr)
    return 0


def _cmd_docs_plants(args) -> int:
    """``docs-plants``: :func:`bench.plantdoc.plants_markdown`, printed or written to ``--out``."""
    from bench.plantdoc import plants_markdown

    text = plants_markdown()
    if args.out is None:
        sys.stdout.write(text)
        return 0
    Path(args.out).write_text(text, encoding="utf-8")
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


def _cmd_list() -> int:
    for kind, registry in (("plants", PLANTS), ("designs", DESIGNS)):
        print(f"{kind}:")
        for i in registry.ids():
            extra = "" if registry[i].default else " [on request: not in the default run]"
            print(f"  {i:<24} {plain_summary(registry[i].summary)}{extra}")
    return 0


def _cmd_run(args, argv: list[str]) -> int:
    """``python -m bench run``: :func:`bench.api.run`, then :meth:`bench.api.Results.write`."""
    prog = f"{program()} run"
    selected = check_selection(prog, args.plant, args.design, args.out, keep_order=True)
    if selected is None:
        return 2
    plant_ids, design_ids = selected
    from bench.api import progress_label, run
    from bench.executors import ExecutorError, use_start_method
    from bench.progress import Progress

    t0 = time.perf_counter()
    cache = None if args.no_cache else cache_dir(args)
    bar = False if args.quiet else Progress(desc=progress_label(len(plant_ids), len(plant_ids) * len(design_ids)))
    try:
        with use_start_method(args.start_method):
            results = run(plant_ids, design_ids, seed=args.seed, claimed_constants=args.claimed_constants,
                          t_final=args.t_final, noise=args.noise, disturbance=args.disturbance,
                          timeout=args.timeout, jobs=args.jobs,
                          scheduler=args.scheduler, cache=cache, progress=bar, fail_fast=args.fail_fast,
                          command=f"{program()} {shlex.join(argv)}")
    except ExecutorError as exc:
        error("run", str(exc))
        return 2
    except KeyboardInterrupt:
        kept = (f"finished pairs are kept in {cache}: run the same command again to resume" if cache is not None
                else "nothing was cached (--no-cache)")
        print(f"{prog}: interrupted; the previous report in {args.out!r}, if any, is unchanged; {kept}",
              file=sys.stderr)
        return 130
    except Exception as exc:  # --fail-fast re-raises the first failure: show where, then one line
        if not args.fail_fast:
            raise
        import traceback

        traceback.print_exc()
        print(f"{prog}: error (--fail-fast): {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    return _write_run(results, args, t0)


def _write_run(results, args, t0: float) -> int:
    """Write a finished run's report (Ctrl-C deferred until it is whole), print the summary; the exit code."""
    from bench.executors import use_start_method

    prog = f"{program()} run"
    path = None
    if not args.quiet:
        n_fig = "" if args.no_figures else ", figures"
        print(f"writing the report into {args.out} (tables{n_fig}) ...", file=sys.stderr, flush=True)
    try:
        with _sigint_deferred(f"{prog}: finishing the report before stopping (Ctrl-C again to abort at once)"), \
                use_start_method(args.start_method):
            path = results.write(args.out, figures=not args.no_figures, figure_format=args.figure_format or ("png",))
    except KeyboardInterrupt:
        where = (f"after writing {path}" if path is not None else
                 f"while writing the report; the previous report in {args.out!r}, if any, is unchanged")
        print(f"{prog}: interrupted {where}", file=sys.stderr)
        return 130
    except Exception as exc:  # the previous report stays intact (whole or nothing)
        error("run", f"could not write the report to {args.out!r} ({type(exc).__name__}: {exc}); the previous "
                     "report, if any, is unchanged")
        return 1
    df = results.table
    if not args.quiet:
        rr = results.run_result
        cached = f"; {rr.cache_hits} from the cache in {rr.cache_dir}" if rr.cache_dir else ""
        print(f"{summary_line(df)}{cached}; {time.perf_counter() - t0:.1f} s", file=sys.stderr)
        for msg in results.info.get("cache_errors", [])[:3]:
            print(f"{prog}: warning: {msg}", file=sys.stderr)
        print(f"wrote {path}", file=sys.stderr)
    failed = df[df["status"].isin(("error", "timeout"))]
    if len(df) and len(failed) == len(df):  # the last line, even with -q: nothing was computed
        first = str(failed["reason"].iloc[0])
        kind = "error" if args.strict else "warning"
        print(f"{prog}: {kind}: every pair is an error or a timeout ({len(df)} of {len(df)}; the first: {first}); "
              f"see the reason column of {Path(args.out) / 'results.csv'}"
              + ("" if args.strict else " (--strict makes this exit 1)"), file=sys.stderr)
        return 1 if args.strict else 0
    if args.strict and len(failed):
        error("run", f"--strict: {len(failed)} of {len(df)} pairs are errors or timeouts: "
                     + ", ".join(f"{r.plant} x {r.design}" for r in failed.head(5).itertuples())
                     + (", ..." if len(failed) > 5 else ""))
        return 1
    return 0


def summary_line(df) -> str:
    """What a run's results table gave, in one line: pairs with gains and how, pairs without and why, and
    how many with gains are certified and converged.
    """
    from designs import GAIN_STATUSES, STATUSES

    count = {k: int((df["status"] == k).sum()) for k in STATUSES}
    with_gains = sum(count[k] for k in GAIN_STATUSES)
    gains = ", ".join(f"{count[k]} {k}" for k in GAIN_STATUSES if count[k])
    plural = {"error": "errors", "timeout": "timeouts"}
    without = ", ".join(f"{count[k]} {plural.get(k, k) if count[k] != 1 else k}" for k in STATUSES
                        if k not in GAIN_STATUSES and count[k])
    other = len(df) - sum(count.values())
    if other:
        without += (", " if without else "") + f"{other} other"
    line = f"{len(df)} pairs: {with_gains} with gains" + (f" ({gains})" if gains else "")
    if len(df) - with_gains:
        line += f", {len(df) - with_gains} without ({without})"
    if with_gains:  # converged is blank (None) for a pair without gains: count the True ones
        line += (f"; of the {with_gains} with gains, {int(df['certified'].eq(True).sum())} certified and "
                 f"{int(df['converged'].eq(True).sum())} converged")
    return line


@contextmanager
def _sigint_deferred(message: str) -> Iterator[None]:
    """Hold a Ctrl-C until the block is done, then raise it (a second one aborts at once); main thread only."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield
        return
    pending: list[int] = []

    def hold(signum, frame):
        if pending:
            raise KeyboardInterrupt
        pending.append(signum)
        print(message, file=sys.stderr, flush=True)

    signal.signal(signal.SIGINT, hold)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if pending:
        raise KeyboardInterrupt


def _sizes(text: str, *, allow_empty: bool = False) -> list[int]:
    """An argparse type: comma-separated state dimensions, each >= 2."""
    try:
        sizes = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected integers like 4,8,16, got {text!r}") from None
    if (not sizes and not allow_empty) or any(n < 2 for n in sizes):
        raise argparse.ArgumentTypeError(f"each n must be >= 2, got {text!r}")
    return sizes


#: Where ``python -m bench perf`` finds its report code: the ``benchmarks/`` folder of the checkout
#: this package was imported from (a developer command; an installed package has no such folder).
_BENCHMARKS_DIR = Path(__file__).resolve().parents[1] / "benchmarks"


def _cmd_perf(args) -> int:
    """``python -m bench perf``: ``perf_main`` of ``benchmarks/perf_report.py`` with the checked sizes."""
    if not (_BENCHMARKS_DIR / "perf_report.py").is_file():
        error("perf", "perf is a developer command, run from a checkout of oslbench "
                      f"(no {_BENCHMARKS_DIR / 'perf_report.py'} beside this bench package)")
        return 2
    if str(_BENCHMARKS_DIR) not in sys.path:
        sys.path.insert(0, str(_BENCHMARKS_DIR))
    from perf_report import perf_main

    path = perf_main(args.out, args.sizes, args.max_joint_n, not args.no_run,
                     echo=lambda line: print(line, file=sys.stderr, flush=True), with_sweeps=not args.no_sweeps,
                     route_sizes=args.route_sizes, with_sims=not args.no_sims, repeats=args.repeats)
    print(f"wrote {path}", file=sys.stderr)
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code and never raises (a Ctrl-C gives 130, an exception 1, in one line).

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name (default ``sys.argv[1:]``).
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    prog = f"{program()} {next((a for a in argv if not a.startswith('-')), '')}".rstrip()
    try:
        return _main(argv)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader left (`python -m bench list | head`): stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except Exception as exc:  # noqa: BLE001 - the CLI prints one line, never a bare traceback
        print(f"{prog}: error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1


def _main(argv: list[str]) -> int:
    parser = _build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    if getattr(args, "plugin", None):
        from bench.plugins import PluginError, load_plugins

        try:
            load_plugins(args.plugin)
        except PluginError as exc:
            error(args.command, str(exc))
            return 2
    if getattr(args, "start_method", None):
        from bench.executors import ExecutorError, check_start_method

        try:
            check_start_method(args.start_method)
        except ExecutorError as exc:
            error(args.command, f"--start-method: {exc}")
            return 2
    if args.command == "perf":
        return _cmd_perf(args)
    if args.command == "study":
        from bench.studies.cli import run_study

        return run_study(args, argv)
    if args.command == "list":
        return _cmd_list()
    if args.command == "cache":
        return _cmd_cache(args)
    if args.command == "docs-plants":
        return _cmd_docs_plants(args)
    if args.command == "report":
        return _cmd_report(args)
    return _cmd_run(args, argv)
