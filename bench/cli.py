"""Command line: ``python -m bench run``, ``list``, ``perf`` and ``study``.

Exit codes: 0 success, 1 a report that could not be written (or an internal error, in one line), 2 bad
usage, 130 interrupted. ``run`` keeps finished pairs in ``.bench-cache/`` next to the report folder
(:mod:`bench.cache`), so an interrupted run resumes when run again (``--no-cache`` ignores it); the
previous report stays untouched until the new one is whole.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import time
from contextlib import contextmanager
from functools import partial
from pathlib import Path
from typing import Iterator

from bench import checks
from bench.checks import argtype
from bench.registry import DESIGNS, PLANTS
from bench.selection import check_selection

__all__ = ["main"]


positive_float = argtype(checks.real, lo=0.0, strict=True)
nonneg_float = argtype(checks.real, lo=0.0)
positive_int = argtype(checks.integer, lo=1)
nonneg_int = argtype(checks.integer, lo=0)


def _scheduler_address(text: str) -> str:
    """An argparse type: a Dask scheduler address ``[scheme://]host:port``."""
    import re

    if not re.fullmatch(r"([a-z][a-z0-9+.-]*://)?\S+:\d+", text):
        raise argparse.ArgumentTypeError(f"expected an address like tcp://host:8786, got {text!r}")
    return text


def _build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m bench", description="oslbench: observer-based control of OSL/Lipschitz systems")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="run (plant, design) pairs and write the report")
    r.add_argument("--plant", action="append", metavar="GLOB", help="plant id or glob (repeatable; default all)")
    r.add_argument("--design", action="append", metavar="GLOB", help="design id or glob (repeatable; default all)")
    r.add_argument("--out", default="reports", metavar="DIR", help="report folder (default: reports)")
    r.add_argument("--seed", type=nonneg_int, default=0, help="seed of the constants sampler (default 0)")
    r.add_argument("--claimed-constants", action="store_true",
                   help="design with the constants the sources claim (the certificate still uses valid ones)")
    r.add_argument("--t-final", type=positive_float, default=None, metavar="SECONDS",
                   help="one simulation horizon for every pair (default: each pair's horizon follows its "
                        "certified rate, or its linearised rate when uncertified, from the plant's own "
                        "horizon up to ten times it)")
    r.add_argument("--noise", type=nonneg_float, default=0.0, metavar="SIGMA",
                   help="standard deviation of a seeded Gaussian measurement noise (default 0)")
    r.add_argument("--disturbance", type=nonneg_float, default=0.0, metavar="AMPLITUDE",
                   help="peak of a seeded L2 disturbance w (docs/results.md): each pair of a plant with "
                        "disturbance inputs is simulated again from z(0) = 0 with w, for the measured ratios "
                        "l2_measured_e, l2_measured_x (default 0: off)")
    r.add_argument("--no-figures", action="store_true", help="skip the figures")
    r.add_argument("--figure-format", action="append", choices=("png", "pdf"), default=None,
                   help="figure format, repeatable (default png; the report links the PNG)")
    r.add_argument("--fail-fast", action="store_true", help="stop at the first exception (for debugging)")
    r.add_argument("-j", "--jobs", type=positive_int, default=None, metavar="N",
                   help="local worker processes (default: all cores; 1 = serial)")
    r.add_argument("--scheduler", type=_scheduler_address, default=None, metavar="ADDRESS",
                   help="run on a Dask distributed cluster (pip install '.[dist]')")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary")
    r.add_argument("--timeout", type=positive_float, default=None, metavar="SECONDS",
                   help="wall-clock limit per pair; a pair that exceeds it becomes a 'timeout' row (default: none)")
    r.add_argument("--no-cache", action="store_true",
                   help="recompute every pair: neither read nor write the cache (.bench-cache/ next to --out)")
    ls = sub.add_parser("list", help="list plants and designs")
    for sp in (r, ls):
        sp.add_argument("--plugin", action="append", metavar="PATH",
                        help="a Python file registering your own plants or designs (repeatable)")
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
    from bench.studies.cli import add_study_parser

    add_study_parser(sub)  # python -m bench study {admissible,sampling,montecarlo,noise}
    return p


def _cmd_list() -> int:
    for kind, registry in (("plants", PLANTS), ("designs", DESIGNS)):
        print(f"{kind}:")
        for i in registry.ids():
            extra = "" if registry[i].default else " [on request: not in the default run]"
            print(f"  {i:<24} {registry[i].summary}{extra}")
    return 0


def _cmd_run(args, argv: list[str]) -> int:
    """``python -m bench run``: :func:`bench.api.run`, then :meth:`bench.api.Results.write`."""
    selected = check_selection("python -m bench run", args.plant, args.design, args.out, keep_order=True)
    if selected is None:
        return 2
    plant_ids, design_ids = selected
    from bench.api import run
    from bench.cache import default_cache_dir
    from bench.executors import ExecutorError

    t0 = time.perf_counter()
    cache = None if args.no_cache else default_cache_dir(args.out)
    try:
        results = run(plant_ids, design_ids, seed=args.seed, claimed_constants=args.claimed_constants,
                      t_final=args.t_final, noise=args.noise, disturbance=args.disturbance, timeout=args.timeout,
                      jobs=args.jobs,
                      scheduler=args.scheduler, cache=cache, progress=not args.quiet, fail_fast=args.fail_fast,
                      command="python -m bench " + shlex.join(argv))
    except ExecutorError as exc:
        print(f"python -m bench run: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        kept = (f"finished pairs are kept in {cache}: run the same command again to resume" if cache is not None
                else "nothing was cached (--no-cache)")
        print(f"python -m bench run: interrupted; the previous report in {args.out!r}, if any, is unchanged; {kept}",
              file=sys.stderr)
        return 130
    except Exception as exc:  # --fail-fast re-raises the first failure: show where, then one line
        if not args.fail_fast:
            raise
        import traceback

        traceback.print_exc()
        print(f"python -m bench run: error (--fail-fast): {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    return _write_run(results, args, t0)


def _write_run(results, args, t0: float) -> int:
    """Write a finished run's report (Ctrl-C deferred until it is whole) and print the summary."""
    path = None
    try:
        with _sigint_deferred("python -m bench run: finishing the report before stopping (Ctrl-C again to abort "
                              "at once)"):
            path = results.write(args.out, figures=not args.no_figures, figure_format=args.figure_format or ("png",))
    except KeyboardInterrupt:
        where = (f"after writing {path}" if path is not None else
                 f"while writing the report; the previous report in {args.out!r}, if any, is unchanged")
        print(f"python -m bench run: interrupted {where}", file=sys.stderr)
        return 130
    except Exception as exc:  # the previous report stays intact (whole or nothing)
        print(f"python -m bench run: error: could not write the report to {args.out!r} "
              f"({type(exc).__name__}: {exc}); the previous report, if any, is unchanged", file=sys.stderr)
        return 1
    if not args.quiet:
        rr = results.run_result
        cached = f"; {rr.cache_hits} from the cache" if rr.cache_dir else ""
        print(f"{summary_line(results.table)}{cached}; {time.perf_counter() - t0:.1f} s", file=sys.stderr)
        for msg in results.info.get("cache_errors", [])[:3]:
            print(f"python -m bench run: warning: {msg}", file=sys.stderr)
        print(f"wrote {path}", file=sys.stderr)
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
    if with_gains:
        line += (f"; of the {with_gains} with gains, {int(df['certified'].sum())} certified and "
                 f"{int(df['converged'].sum())} converged")
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
        print("python -m bench perf: error: perf is a developer command, run from a checkout of oslbench "
              f"(no {_BENCHMARKS_DIR / 'perf_report.py'} beside this bench package)", file=sys.stderr)
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
    prog = f"python -m bench {next((a for a in argv if not a.startswith('-')), '')}".rstrip()
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
            print(f"python -m bench {args.command}: error: {exc}", file=sys.stderr)
            return 2
    if args.command == "perf":
        return _cmd_perf(args)
    if args.command == "study":
        from bench.studies.cli import run_study

        return run_study(args, argv)
    if args.command == "list":
        return _cmd_list()
    return _cmd_run(args, argv)
