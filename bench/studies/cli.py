"""Command line of the studies: ``python -m bench study {admissible,scale,sampling,montecarlo,noise}``.

:func:`add_study_parser` adds the ``study`` subcommand to the main parser (:mod:`bench.cli` calls it);
:func:`run_study` runs one study from the parsed arguments. The options a study shares with ``run``
(``--seed``, ``--jobs``, ``--start-method``, ``--no-figures``, ``--quiet``, ``--plugin``) come from
:mod:`bench.cli_common` and mean the same. Exit codes: 0 success, 1 the files could not be written (the
previous ones stay intact), 2 bad usage (unknown id, bad option value: the message names the option).
"""

from __future__ import annotations

import argparse
import importlib
import shlex
import sys
import time

from bench import checks
from bench.checks import argtype
from bench.cli_common import (add_common, add_selection, error, positive_float as _positive,
                              positive_int as _count, program)

__all__ = ["add_study_parser", "run_study"]

_number = argtype(checks.real)


def _float_list(*, allow_empty: bool):
    """An argparse type: comma-separated finite numbers > 0 (none if ``allow_empty``)."""
    def fail(name: str, message: str) -> Exception:
        return argparse.ArgumentTypeError(f"each value {message}")

    def parse(text: str) -> list[float]:
        parts = [p.strip() for p in text.split(",") if p.strip()]
        if not parts and not allow_empty:
            raise argparse.ArgumentTypeError("expected a comma-separated list of numbers, got nothing")
        try:
            values = [float(p) for p in parts]
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected numbers like 1e-3,1e-2, got {text!r}") from None
        return [checks.real("value", v, lo=0.0, strict=True, error=fail) for v in values]

    return parse


def add_study_parser(sub) -> None:
    """Add ``study`` and its sub-subcommands to the main parser's subparsers ``sub``."""
    st = sub.add_parser("study", help="studies after the tables: admissible, scale, sampling, montecarlo, noise")
    ss = st.add_subparsers(dest="study", required=True, parser_class=type(st))

    def common(p, simulates: bool = True):
        add_selection(p, default_all=False)
        add_common(p, timeout=False, seed_help="seed of the constants sampler" + (
            " and of the random draws (initial conditions, noise)" if simulates else ""))
        if simulates:
            p.add_argument("--t-final", type=_positive, default=None, metavar="SECONDS",
                           help="horizon (default: each plant's)")

    a = ss.add_parser("admissible", help="largest scale of f at which each LMI/Riccati design is feasible and "
                                         "certified (bisection)")
    common(a, simulates=False)
    a.add_argument("--range", nargs=2, type=_number, default=None, metavar=("LO", "HI"),
                   help="bisection bounds on the plant's scale knob (default: bracket from its default value)")
    a.add_argument("--rtol", type=_positive, default=0.01, help="relative tolerance of the bisection (default 0.01)")
    a.add_argument("--caps", type=_float_list(allow_empty=True), default=[10.0, 100.0, 1e4],
                   metavar="CAP,CAP,...", help="other normalisation caps for thm1/cor1 (default 10,100,10000; '' skips)")
    _add_scale(ss, common)

    s = ss.add_parser("sampling", help="largest sample period of a digital implementation (ZOH, discrete observer)")
    common(s)
    s.add_argument("--n-ics", type=_count, default=20, metavar="N",
                   help="random initial conditions besides the plant's own (default 20)")
    s.add_argument("--box", type=_positive, default=None, metavar="B",
                   help="half-width of the initial-condition box (default: the plant's initial-condition scale)")
    s.add_argument("--discretisation", choices=("zoh", "euler"), default="zoh",
                   help="observer discretisation (default zoh)")
    s.add_argument("--h-range", nargs=2, type=_number, default=None, metavar=("LO", "HI"),
                   help="bisection bounds on h in seconds (default: bracket from h_lin / 2)")
    s.add_argument("--rtol", type=_positive, default=0.01, help="relative tolerance of the bisection (default 0.01)")

    m = ss.add_parser("montecarlo", help="region of convergence: N seeded random initial conditions, one batch ODE")
    common(m)
    m.add_argument("--n", type=_count, default=1000, metavar="N", help="initial conditions per plant (default 1000)")
    m.add_argument("--box", type=_positive, default=None, metavar="B",
                   help="half-width of the initial-condition box (default: the plant's initial-condition scale)")
    m.add_argument("--method", default="auto", choices=("auto", "RK45", "DOP853", "RK23", "BDF", "Radau"),
                   help="solve_ivp method of the batch (default auto: DOP853, BDF when the loop is stiff)")

    n = ss.add_parser("noise", help="RMS estimation error and final ||x|| vs measurement noise, Luenberger vs EKF")
    common(n)
    n.add_argument("--levels", type=_float_list(allow_empty=False), default=None,
                   metavar="SIGMA,SIGMA,...", help="noise standard deviations (default: 7 points from 1e-4 to 1e-1)")
    n.add_argument("--no-matched-ekf", action="store_true", help="skip the EKF with r = sigma^2")


def _add_scale(ss, common) -> None:
    """``study scale``: the largest factor of any plant's class (:mod:`bench.studies.scale`)."""
    c = ss.add_parser("scale", help="largest factor of each plant's class (constants and slopes times c) at which "
                                    "each design returns verified gains, and the ladder certifies them (bisection)")
    common(c, simulates=False)
    c.add_argument("--range", nargs=2, type=_number, default=None, metavar=("LO", "HI"),
                   help="bisection bounds on the factor c (default: doubling/halving from c = 1)")
    c.add_argument("--rtol", type=_positive, default=0.01, help="relative tolerance of the bisection (default 0.01)")


def _options(args) -> dict:
    """The study's own options from the parsed arguments."""
    if args.study == "scale":
        return dict(bounds=tuple(args.range) if args.range else None, rtol=args.rtol, seed=args.seed)
    if args.study == "admissible":
        return dict(bounds=tuple(args.range) if args.range else None, rtol=args.rtol, caps=tuple(args.caps),
                    seed=args.seed)
    if args.study == "sampling":
        required = [p for p in (args.design or []) if not any(ch in p for ch in "*?[]")]  # ids named without a glob
        return dict(required=required, n_ics=args.n_ics, box=args.box, seed=args.seed,
                    discretisation=args.discretisation, h_range=tuple(args.h_range) if args.h_range else None,
                    rtol=args.rtol, t_final=args.t_final)
    if args.study == "montecarlo":
        return dict(n=args.n, box=args.box, seed=args.seed, t_final=args.t_final, method=args.method)
    levels = {"levels": tuple(args.levels)} if args.levels else {}  # none given: run_noise's DEFAULT_LEVELS
    return dict(**levels, seed=args.seed, matched_ekf=not args.no_matched_ekf, t_final=args.t_final)


def run_study(args, argv: list[str]) -> int:
    """Run the study named by ``args.study``; returns the exit code."""
    from bench.executors import ExecutorError, default_jobs, use_start_method
    from bench.progress import Progress
    from bench.selection import check_selection
    from bench.studies._common import StudyError

    command = f"study {args.study}"
    prog = f"{program()} {command}"
    selected = check_selection(prog, args.plant, args.design, args.out, all_by_default=False)
    if selected is None:
        return 2
    plant_ids, design_ids = selected
    jobs = args.jobs or default_jobs()
    recorded = f"{program()} {shlex.join(argv)}"
    t0 = time.perf_counter()
    try:
        module = importlib.import_module(f"bench.studies.{args.study}")
        run, write = getattr(module, f"run_{args.study}"), getattr(module, f"write_{args.study}")
        with Progress(desc=f"study {args.study}", delay=1.0, disable=True if args.quiet else None) as bar, \
                use_start_method(args.start_method):
            result = run(plant_ids, design_ids, jobs=jobs, progress=bar, **_options(args))
    except StudyError as exc:
        option = "--range" if exc.param == "bounds" else "--" + exc.param.replace("_", "-")  # the parameter's option
        error(command, f"{option}: {exc.message}")
        return 2
    except ExecutorError as exc:
        error(command, str(exc))
        return 2
    if not args.quiet:
        print(f"writing the study into {args.out} ...", file=sys.stderr, flush=True)
    try:
        path = write(result, args.out, recorded, figures=not args.no_figures)
    except Exception as exc:  # the previous files stay intact (atomic write)
        error(command, f"could not write the study to {args.out!r} ({type(exc).__name__}: {exc}); "
                       "the previous files, if any, are unchanged")
        return 1
    if not args.quiet:
        print(f"wrote {path} ({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
    return 0
