"""Command line: ``python -m bench run`` and ``python -m bench list``.

Exit codes: 0 success, 1 a run that could not write its report, 2 bad usage (unknown id,
bad option value).
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time

from bench.registry import DESIGNS, PLANTS, UnknownIdError

__all__ = ["main"]


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # exit 2 with a one-line message, argparse-style
        self.print_usage(sys.stderr)
        self.exit(2, f"{self.prog}: error: {message}\n")


def _number(kind: type, lo: float, *, strict: bool):
    """An argparse type: a finite ``kind`` (int or float) above ``lo`` (``> lo`` if strict, else ``>=``)."""
    word = "an integer" if kind is int else "a number"
    bound = f"> {lo:g}" if strict else f">= {lo:g}"

    def parse(text: str):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {word}, got {text!r}") from None
        if not (v < float("inf") and (v > lo if strict else v >= lo)):
            raise argparse.ArgumentTypeError(f"must be {word} {bound}, finite, got {text!r}")
        return v

    return parse


_positive_float = _number(float, 0, strict=True)
_nonneg_float = _number(float, 0, strict=False)
_positive_int = _number(int, 1, strict=False)
_nonneg_int = _number(int, 0, strict=False)


def _build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="python -m bench", description="oslbench: observer-based control of OSL/Lipschitz systems")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)
    r = sub.add_parser("run", help="run (plant, design) pairs and write the report")
    r.add_argument("--plant", action="append", metavar="GLOB", help="plant id or glob (repeatable; default all)")
    r.add_argument("--design", action="append", metavar="GLOB", help="design id or glob (repeatable; default all)")
    r.add_argument("--out", default="reports", metavar="DIR", help="report folder (default: reports)")
    r.add_argument("--seed", type=_nonneg_int, default=0, help="seed of the constants sampler (default 0)")
    r.add_argument("--claimed-constants", action="store_true",
                   help="design with the constants the sources claim (the certificate still uses valid ones)")
    r.add_argument("--t-final", type=_positive_float, default=None, metavar="SECONDS",
                   help="simulation horizon (default: each plant's)")
    r.add_argument("--noise", type=_nonneg_float, default=0.0, metavar="SIGMA",
                   help="standard deviation of a seeded Gaussian measurement noise (default 0)")
    r.add_argument("--no-figures", action="store_true", help="skip the figures")
    r.add_argument("--fail-fast", action="store_true", help="stop at the first exception (for debugging)")
    r.add_argument("-j", "--jobs", type=_positive_int, default=None, metavar="N",
                   help="local worker processes (default: all cores; 1 = serial)")
    r.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run on a Dask distributed cluster (pip install '.[dist]')")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary")
    ls = sub.add_parser("list", help="list plants and designs")
    for sp in (r, ls):
        sp.add_argument("--plugin", action="append", metavar="PATH",
                        help="a Python file registering your own plants or designs (repeatable)")
    pf = sub.add_parser("perf", help="measure design time vs n, joint vs separated, and the parallel speed-up")
    pf.add_argument("--out", default="reports", metavar="DIR", help="folder for PERF.md (default: reports)")
    pf.add_argument("--sizes", default="4,8,16,32,64", metavar="N,N,...", help="state dimensions (default 4,8,16,32,64)")
    pf.add_argument("--max-joint-n", type=_positive_int, default=32, metavar="N",
                    help="largest n for the joint 6n LMI (default 32; n = 50 took ~800 s here)")
    pf.add_argument("--no-run", action="store_true", help="skip timing the default run with --jobs 1 and 2")
    return p


def _cmd_list() -> int:
    print("plants:")
    for pid in PLANTS.ids():
        print(f"  {pid:<24} {PLANTS[pid].summary}")
    print("designs:")
    for did in DESIGNS.ids():
        print(f"  {did:<24} {DESIGNS[did].summary}")
    return 0


def _cmd_run(args, argv: list[str]) -> int:
    try:
        plant_ids = PLANTS.select(args.plant)
        design_ids = DESIGNS.select(args.design)
    except UnknownIdError as exc:
        print(f"python -m bench run: error: {exc}", file=sys.stderr)
        return 2
    from bench.executors import ExecutorError, default_jobs
    from bench.harness import ProgressBar, RunOptions, run
    from bench.report import write_report

    options = RunOptions(seed=args.seed, use_claimed=args.claimed_constants, fail_fast=args.fail_fast,
                         t_final=args.t_final, noise=args.noise)
    t0 = time.perf_counter()
    jobs = args.jobs or default_jobs()
    bar = None if args.quiet else ProgressBar()
    try:
        result = run(plant_ids, design_ids, options, progress=bar, jobs=jobs, scheduler=args.scheduler)
    except ExecutorError as exc:
        print(f"python -m bench run: error: {exc}", file=sys.stderr)
        return 2
    finally:
        if bar is not None:
            bar.close()
    info = {"command": "python -m bench " + shlex.join(argv), "plants": plant_ids, "designs": design_ids,
            "jobs": jobs, "scheduler": args.scheduler}
    try:
        path = write_report(result, args.out, info, figures=not args.no_figures)
    except Exception as exc:  # the previous report stays intact (atomic write)
        print(f"python -m bench run: error: could not write the report to {args.out!r} "
              f"({type(exc).__name__}: {exc}); the previous report, if any, is unchanged", file=sys.stderr)
        return 1
    df = result.frame()
    if not args.quiet:
        n_feas = int(df["feasible"].sum())
        n_cert = int(df["certified"].sum())
        n_conv = int(df["converged"].sum())
        n_err = int((df["status"] == "error").sum())
        print(f"{len(df)} pairs: {n_feas} feasible, {n_cert} certified, {n_conv} converged, {n_err} errors; "
              f"{time.perf_counter() - t0:.1f} s", file=sys.stderr)
        print(f"wrote {path}", file=sys.stderr)
    return 0


def _cmd_perf(args) -> int:
    try:
        sizes = [int(x) for x in args.sizes.split(",") if x.strip()]
    except ValueError:
        print(f"python -m bench perf: error: --sizes: expected integers like 4,8,16, got {args.sizes!r}", file=sys.stderr)
        return 2
    if not sizes or min(sizes) < 2:
        print(f"python -m bench perf: error: --sizes: each n must be >= 2, got {args.sizes!r}", file=sys.stderr)
        return 2
    from bench.perf import perf_main

    path = perf_main(args.out, sizes, args.max_joint_n, not args.no_run,
                     echo=lambda line: print(line, file=sys.stderr, flush=True))
    print(f"wrote {path}", file=sys.stderr)
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code.

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name (default ``sys.argv[1:]``).
    """
    argv = list(sys.argv[1:] if argv is None else argv)
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
    if args.command == "list":
        return _cmd_list()
    return _cmd_run(args, argv)
