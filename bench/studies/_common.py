"""Helpers shared by the studies: argument checks, plants and gains, random initial conditions,
markdown tables, and the atomic writer of a study's files (``STUDY_<name>.md``, ``study_<name>*.csv``,
``figures/study_<name>*.png``; :mod:`bench.outdir` publishes them whole, the markdown last).
"""

from __future__ import annotations

import functools
import inspect
import math
import os
import platform
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from bench import checks
from bench.errors import StudyError
from bench.search import largest_passing
from bench.report import format_cell as fmt, md_table, pyplot  # noqa: F401 (the studies import them from here)


@dataclass
class StudyResult:
    """What a study produced: its ``rows`` (the CSV), the ``settings`` it ran with and ``wall_s``; each
    study adds its own fields.
    """

    rows: list[dict]
    settings: dict
    wall_s: float


# -- argument checks (bench.checks, raising StudyError) --------------------------------------
def check_box(name: str, value: Any) -> float | None:
    """An initial-condition box half-width: finite and > 0 (None: the plant's default)."""
    return None if value is None else checks.real(name, value, lo=0.0, strict=True, error=StudyError)


#: A count ``>= 1``, a bisection's relative tolerance in (0, 1), a horizon (None: each plant's); StudyError if not.
check_count = functools.partial(checks.integer, lo=1, error=StudyError)
check_rtol = functools.partial(checks.real, "rtol", lo=0.0, strict=True, hi=1.0, error=StudyError)
check_horizon = functools.partial(checks.horizon, error=StudyError)


def check_levels(name: str, values: Any) -> list[float]:
    """Noise levels: a non-empty list of finite numbers > 0, sorted and unique."""
    vals = list(values)
    if not vals:
        raise StudyError(name, "at least one level is needed")
    return sorted({checks.real(name, v, lo=0.0, strict=True, error=StudyError) for v in vals})


def check_range(name: str, value: Any) -> tuple[float, float] | None:
    """Bisection bounds ``(lo, hi)`` with ``0 < lo < hi`` (None: automatic bracketing)."""
    if value is None:
        return None
    try:
        lo, hi = value
    except (TypeError, ValueError):
        raise StudyError(name, f"expected two numbers LO HI, got {value!r}") from None
    lo = checks.real(name, lo, lo=0.0, strict=True, error=StudyError)
    hi = checks.real(name, hi, error=StudyError)
    if not lo < hi:
        raise StudyError(name, f"bounds in the wrong order: LO = {lo:g} must be < HI = {hi:g}")
    return lo, hi


# -- bisection --------------------------------------------------------------------------------
def bisect_largest(
    check: Callable[[float], dict],
    default: float,
    *,
    bounds: tuple[float, float] | None = None,
    rtol: float = 0.01,
    max_doublings: int = 12,
) -> dict:
    """Largest value at which ``check(value)["ok"]`` holds (:func:`bench.search.largest_passing`).

    The bracket is found by doubling or halving from ``default`` (at most ``max_doublings`` moves; halving stops
    at a record with status "invalid"), or is ``bounds``; it is then bisected until ``hi / lo - 1 <= rtol``.
    Returns ``lo`` (largest passing, NaN if none), ``hi`` (smallest failing, NaN if none), ``kind``
    ("bracketed", "below_range", "above_range", "inapplicable") and ``evals`` (every record, in order).
    """
    bounds = check_range("bounds", bounds)
    evals, seen = [], {}

    def ok(value: float) -> bool:  # check, memoised; every record kept in evals
        if value not in seen:
            seen[value] = check(value)
            evals.append(seen[value])
        return bool(seen[value]["ok"])

    first = default if bounds is None else bounds[0]
    if not ok(first) and evals[0].get("status") == "inapplicable":  # no value of the knob changes that
        return {"lo": math.nan, "hi": math.nan, "kind": "inapplicable", "evals": evals}
    if bounds is not None:
        if not ok(bounds[0]):
            return {"lo": math.nan, "hi": bounds[0], "kind": "below_range", "evals": evals}
        if ok(bounds[1]):
            return {"lo": bounds[1], "hi": math.nan, "kind": "above_range", "evals": evals}
        out = largest_passing(ok, rtol=rtol, lo=bounds[0], hi=bounds[1])
    else:
        known = {"lo": default} if ok(default) else {"hi": default}
        out = largest_passing(ok, rtol=rtol, max_moves=max_doublings,
                              stop=lambda: evals[-1].get("status") == "invalid", **known)
    return {**out, "evals": evals}


# -- plants, gains, initial conditions --------------------------------------------------------
def default_box(plant) -> float:
    """The plant's own initial-condition scale: ``max(||x0||_inf, ||x_hat0||_inf)`` (1 if both are 0)."""
    s = float(max(np.abs(plant.x0).max(), np.abs(plant.x_hat0).max()))
    return s if s > 0 else 1.0


def random_ics(plant, n_ics: int, box: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``n_ics`` seeded initial conditions ``(x0, x_hat0)``, each uniform in ``[-box, box]^n``, shape (n, n_ics)."""
    rng = np.random.default_rng([int(seed), 5])
    return tuple(rng.uniform(-box, box, size=(plant.n, n_ics)) for _ in range(2))


#: Sampled pairs of a study's constants check (fewer than a run's: a bisection evaluates hundreds of scales of f).
STUDY_SAMPLES = 1000

_CONSTANTS: dict[tuple, object] = {}


def evaluate(plant, design_id: str, options=None, *, overrides: dict | None = None, prior=None, scenario=None):
    """One pair through :func:`bench.pipeline.evaluate_pair` with the study's constants (the plant's
    :func:`bench.constants.compute_constants` with :data:`STUDY_SAMPLES` pairs seeded by ``options.seed``, memoised
    per plant and seed); ``overrides``
    are the design's hyperparameters, ``prior`` an earlier outcome whose design and certificate are re-used.
    """
    from bench.constants import compute_constants
    from bench.pipeline import RunOptions, evaluate_pair
    from bench.registry import DESIGNS

    options = options or RunOptions()
    key = (plant.id, tuple(sorted(plant.params.items())), options.seed)
    if key not in _CONSTANTS:
        _CONSTANTS[key] = compute_constants(plant, seed=options.seed, n_samples=STUDY_SAMPLES, n_refine=2)
    design = design_id if not overrides else DESIGNS.create(design_id, **overrides)
    return evaluate_pair(plant, design, _CONSTANTS[key], options, design_id=design_id,
                         prior=prior, scenario=scenario)


def unsimulated_row(pid: str, did: str, outcome, *, need_gains: bool = True) -> dict | None:
    """The row of a pair that cannot be simulated (no controller, or no fixed gains when ``need_gains``); None when
    it can."""
    res, rec = outcome.result, outcome.record
    if res is None or not res.has_controller:
        return {"plant": pid, "design": did, "status": rec["status"], "reason": rec["reason"]}
    if need_gains and not res.has_gains:
        return {"plant": pid, "design": did, "status": "no fixed gains",
                "reason": f"estimator {type(res.estimator).__name__}: not a fixed gain K"}
    return None


def map_tasks(ex, fn: Callable, tasks: list[tuple[Any, tuple]], progress: Callable[[int, int, str], None] | None = None,
              describe: Callable[[Any, Any], str] | None = None) -> dict:
    """Run ``fn(*args)`` for every ``(key, args)`` of ``tasks`` on ``ex``; return ``{key: result}``.

    ``progress(done, total, describe(key, result))`` is called as each task finishes.
    """
    from concurrent.futures import as_completed

    futs = {ex.submit(fn, *args): key for key, args in tasks}
    out = {}
    for i, fut in enumerate(as_completed(futs), 1):
        key = futs[fut]
        out[key] = fut.result()
        if progress:
            progress(i, len(futs), describe(key, out[key]))
    return out


@dataclass
class StudyRun:
    """The pairs a study runs and how: ``plant_ids``, ``design_ids``, ``jobs`` worker processes and
    ``progress(done, total, label)``; :meth:`wall_s` counts from its creation."""

    plant_ids: list[str]
    design_ids: list[str]
    jobs: int = 1
    progress: Callable[[int, int, str], None] | None = None
    t_start: float = field(default_factory=time.perf_counter)

    def map(self, fn: Callable, tasks: list[tuple[Any, tuple]], describe: Callable[[Any, Any], str]) -> dict:
        """:func:`map_tasks` on a fresh :func:`bench.executors.executor` of ``jobs`` workers."""
        from bench.executors import executor

        with executor(self.jobs) as ex:
            return map_tasks(ex, fn, tasks, self.progress, describe)

    def wall_s(self) -> float:
        return time.perf_counter() - self.t_start


def study(default_plants=None, default_designs=None):
    """Decorator making ``fn(run: StudyRun, **options)`` a study's
    ``fn(plant_ids=None, design_ids=None, *, jobs=1, progress=None, start_method=None, **options)``; without ids,
    the defaults (None: the registry's default selection, :meth:`bench.registry.Registry.defaults`);
    ``start_method``: how worker processes start (:func:`bench.executors.use_start_method`)."""
    def deco(fn):
        def run(plant_ids=None, design_ids=None, *, jobs: int = 1, progress=None, start_method: str | None = None,
                **options):
            from bench.executors import use_start_method
            from bench.registry import DESIGNS, PLANTS

            def pick(ids, default, registry):
                return list(ids) if ids else (list(default) if default is not None else registry.defaults())

            pairs = StudyRun(pick(plant_ids, default_plants, PLANTS), pick(design_ids, default_designs, DESIGNS), jobs,
                             progress)
            with use_start_method(start_method):
                return fn(pairs, **options)

        functools.update_wrapper(run, fn)
        del run.__wrapped__
        # the signature a notebook shows: the wrapper's ids, jobs and progress, then the study's own options
        own = inspect.signature(run).parameters
        options = list(inspect.signature(fn).parameters.values())[1:]
        run.__signature__ = inspect.Signature([*(v for k, v in own.items() if k != "options"), *options],
                                              return_annotation=inspect.signature(fn).return_annotation)
        return run

    return deco


# -- rendering ---------------------------------------------------------------------------------
def bracket_cell(kind: str, lo: float, hi: float) -> str:
    """A bisection's answer (:func:`bisect_largest`) as a table cell: ``lo``, ``< hi``, ``>= lo`` or ``n/a``."""
    return {"bracketed": fmt(lo, ".3g"), "below_range": f"< {fmt(hi, '.3g')}", "above_range": f">= {fmt(lo, '.3g')}",
            "inapplicable": "n/a"}.get(kind, "")


def skipped_lines(rows: list[dict], *, heading: str = "Not simulated:", width: int = 250) -> list[str]:
    """Markdown lines: ``heading`` and one bullet per pair not simulated, with its status and reason."""
    if not rows:
        return []
    from bench.report import clip_words

    return [heading, "", *(f"- **{r['plant']} x {r['design']}** ({r['status']}): "
                           f"{clip_words(fmt(r.get('reason', '')), width)}" for r in rows), ""]


def study_header(title: str, command: str, settings: dict, wall_s: float) -> str:
    """The first lines of a study's markdown: title, command, settings and versions."""
    from bench.report import package_versions

    vers = package_versions()
    keep = ("python", "numpy", "scipy", "cvxpy", "clarabel", "control", "filterpy")
    settings_s = ", ".join(f"{k} = {v}" for k, v in settings.items())
    return "\n".join([
        f"# {title}",
        "",
        f"Produced by `{command}` in {wall_s:.1f} s on {os.cpu_count()} cores ({platform.machine()}). "
        "Every number below comes from a solve or a simulation of this run.",
        "",
        f"Settings: {settings_s}.",
        "",
        "Versions: " + ", ".join(f"{k} {vers.get(k, '?')}" for k in keep) + ".",
        "",
    ])


def write_study(out_dir: str | os.PathLike, name: str, markdown: str, tables: dict[str, Any],
                figures: dict[str, Callable[[Path], None]]) -> Path:
    """Write a study's files whole or not at all: ``STUDY_<name>.md``, each table (file stem -> DataFrame or
    row dicts) as CSV and each figure (file stem -> callable drawing into a path) as PNG (none: no figures
    folder); return the markdown's path."""
    import pandas as pd

    from bench.outdir import publish, staged

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    md_name = f"STUDY_{name}.md"
    with staged(out, f"study-{name}") as tmp:
        if figures:
            (tmp / "figures").mkdir()
        for stem, draw in figures.items():
            draw(tmp / "figures" / f"{stem}.png")
        for stem, table in tables.items():
            pd.DataFrame(table).to_csv(tmp / f"{stem}.csv", index=False)
        (tmp / md_name).write_text(markdown.rstrip("\n") + "\n", encoding="utf-8")
        publish(out, tmp, [*(f"figures/{stem}.png" for stem in figures), *(f"{stem}.csv" for stem in tables), md_name])
    return out / md_name


def write_plant_study(out_dir: str | os.PathLike, name: str, lines: list[str], tables: dict[str, Any],
                      rows: list[dict], draw: Callable[..., Any], *args, heading: str | None = "## Figures",
                      figures: bool = True) -> Path:
    """:func:`write_study` with a figure ``study_<name>_<plant>`` per plant of ``rows`` (in order): the figure
    ``draw(plant, its rows, *args)`` returns, saved at 100 dpi; ``heading`` and the figures' image lines end the
    markdown ``lines`` (None: the lines show them). ``figures=False``: no figure (and no image line)."""
    plants = list(dict.fromkeys(r["plant"] for r in rows)) if figures else []
    if not figures:
        lines = [ln for ln in lines if not ln.startswith("![")]
    elif heading is not None:
        lines = [*lines, heading, "", *(f"![{pid}](figures/study_{name}_{pid}.png)" for pid in plants), ""]
    figs = {f"study_{name}_{pid}": functools.partial(_save_figure, draw, pid, rows, args) for pid in plants}
    return write_study(out_dir, name, "\n".join(lines), tables, figs)


def _save_figure(draw: Callable[..., Any], pid: str, rows: list[dict], args: tuple, path: Path) -> None:
    """Save the figure ``draw(pid, the rows of pid, *args)`` at 100 dpi and close it."""
    fig = draw(pid, [r for r in rows if r["plant"] == pid], *args)
    fig.savefig(path, dpi=100)
    pyplot().close(fig)
