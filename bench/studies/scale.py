"""The largest admissible nonlinearity of any plant: the factor by which its class can be scaled.

For a plant (of the catalog or a plugin's) and a design, :meth:`plants.Plant.scaled` multiplies f by ``c``, so
the class's constants and channel slopes by ``c`` (Lipschitz ``c alpha``, OSL ``c rho``, QIB
``(c^2 beta, c gamma)``, slopes ``c [lo, hi]``) while A, B, C, the disturbance inputs and the initial
conditions stay. Two answers per pair, each the largest ``c`` found by geometric bisection on the grid of
:mod:`bench.search` (:func:`bench.studies._common.bisect_largest`, from ``c = 1``, the plant's own class):

(a) **designed**: the design, given the scaled class, returns gains it verified itself: status
    ``feasible``, ``computed`` or ``given`` with fixed gains K and F (a plugin design's ``unverified`` gains
    and a run-time estimator do not count: the pair is ``n/a`` for (a));
(b) **certified**: besides, the suite's certificate ladder (:mod:`bench.certify`, at rate 0, the strongest
    level first, trusted constants) certifies those gains over the scaled class (any gains the design
    returns, a plugin's unverified ones included: the ladder checks them itself).

Each is reported as a bracket ``[lo, hi)``: ``lo`` the largest factor verified to pass, ``hi`` the smallest
verified to fail. Neither answer need be monotone in ``c`` (a design's feasible set shrinks with ``c`` only if
its LMI says so), which is why the probes and their outcomes are all kept. The catalog's scale knobs keep
their own study (``python -m bench study admissible``); this one needs no knob and runs on every plant.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench.studies._common import (StudyError, StudyResult, StudyRun, bisect_largest, bracket_cell, check_range,
                                   check_rtol, evaluate, fmt, md_table, pyplot, study, study_header, write_study)

__all__ = ["run_scale", "write_scale", "bar_styles", "circle_bound"]

#: Statuses of a design's own verified gains (criterion (a)).
VERIFIED = ("feasible", "computed", "given")
#: Statuses that come with gains the ladder can check (criterion (b)).
WITH_GAINS = ("feasible", "computed", "given", "unverified")
#: The two criteria: key, column prefix, words.
CRITERIA = (("a", "designed", "the design returns verified gains"),
            ("b", "certified", "the ladder certifies those gains"))


class _NotApplicable(Exception):
    """Raised by a probe when no value of the factor can change the answer (the pair is n/a for a criterion)."""


def bar_styles(design_ids) -> dict[str, dict]:
    """The bar colour of each design: the suite's palette (:func:`bench.report.design_styles`, the same design has
    the same colour in the report and in every study), and a dotted hatch on a design whose colour an earlier
    one in ``design_ids`` already has (the palette has 18 colours)."""
    from bench.report import design_styles

    styles, seen = {}, set()
    for did, st in design_styles(design_ids).items():
        styles[did] = {"color": st["color"], "hatch": "..." if st["color"] in seen else None}
        seen.add(st["color"])
    return styles


def circle_bound(plant, K: np.ndarray, F: np.ndarray) -> float:
    """The factor at which fixed gains stop passing the circle criterion on a one-channel plant (NaN where it does
    not apply).

    For one channel ``f = G phi(H x)`` with a symmetric slope sector ``[-r, r]`` (``r`` the channel's half-width
    at ``c = 1``) of a continuous plant, the scaled class has ``[-c r, c r]``; a quadratic certificate of the
    gains over it exists iff both sides pass the circle criterion (Khalil, *Nonlinear Systems*, Thm 7.1),
    ``c r ||H (sI - A - BF)^-1 G||_inf < 1`` and ``c r ||H (sI - A + KC)^-1 G||_inf < 1``, so the bound is
    ``1 / (r max(...))`` (python-control's H-infinity norm); ``inf`` for a linear plant.
    """
    from bench.studies.admissible import _siso_peak

    ch = plant.channels
    if plant.discrete or ch is None or ch.q != 1 or np.any(ch.center != 0):
        return math.nan
    r = float(ch.spread[0])
    if r == 0:
        return math.inf
    peaks = [_siso_peak(M, ch.G, ch.H) for M in (plant.A + plant.B @ F, plant.A - K @ plant.C)]
    return 1.0 / (r * max(peaks)) if all(map(math.isfinite, peaks)) else 0.0


_BASE: dict[str, Any] = {}


def _base(plant_id: str):
    """The registered plant (built once per process)."""
    from bench.registry import PLANTS

    if plant_id not in _BASE:
        _BASE[plant_id] = PLANTS.create(plant_id)
    return _BASE[plant_id]


def _probe(plant_id: str, c: float, design_id: str, certify: bool, seed: int = 0) -> dict:
    """Design (and, with ``certify``, certify) ``design_id`` on the plant scaled by ``c``, without simulating: a
    record with the factor, the design's status, the gains, the certificate's outcome and the costs."""
    from bench.pipeline import LEVELS, RunOptions
    from plants import PlantError

    rec: dict[str, Any] = {"value": float(c), "status": "", "reason": "", "certified": False, "cert_level": "",
                           "cert_run": certify, "cert_applies": True, "cert_marginal": False, "has_gains": False,
                           "K": None, "F": None,
                           "design_s": 0.0, "cert_s": 0.0, "solve_s": 0.0, "n_solves": 0}
    try:
        plant = _base(plant_id).scaled(c)
    except PlantError as exc:
        rec.update(status="invalid", reason=f"the plant cannot be scaled by {c:.4g}: {exc}")
        return rec
    out = evaluate(plant, design_id, RunOptions(certificate="verdict" if certify else "none", simulate=False,
                                                seed=seed))
    row, res = out.record, out.result
    rec.update(status=row["status"], reason=str(row["reason"]), certified=bool(row["certified"]),
               cert_level=row["cert_level"] or "")
    for k in ("design_s", "cert_s", "solve_s", "n_solves"):
        rec[k] = row[k] if isinstance(row[k], (int, float)) and math.isfinite(row[k]) else rec[k]
    if res is not None and res.has_gains:
        rec.update(has_gains=True, K=np.array(res.K, dtype=float), F=np.array(res.F, dtype=float))
    if certify and rec["has_gains"] and row["status"] in WITH_GAINS:
        rec["cert_applies"] = any(row[f"cert_{lv}"] not in ("inapplicable", "") for lv in LEVELS)
        rec["cert_marginal"] = not rec["certified"] and any(row[f"cert_{lv}"] == "marginal" for lv in LEVELS)
    return rec


def _criterion(rec: dict, key: str) -> dict:
    """The record of one criterion at a probe: ``ok`` and an outcome; :class:`_NotApplicable` when no factor can
    change it (the design does not apply, has no fixed gains, or (a) is a plugin's unverified design, or (b) the
    ladder does not apply to the plant's gains)."""
    status = rec["status"]
    if status == "inapplicable":
        raise _NotApplicable(rec["reason"])
    if status in WITH_GAINS and not rec["has_gains"]:
        raise _NotApplicable("no fixed gains K, F (a run-time estimator): no quadratic certificate applies")
    if key == "a":
        if status == "unverified":
            raise _NotApplicable("unverified: a design from outside the suite says 'feasible', which the suite "
                                 "does not verify")
        ok = status in VERIFIED
        outcome = "ok" if ok else status
    else:
        if status in WITH_GAINS and not rec["cert_applies"]:
            raise _NotApplicable(_certificate_reason(rec["reason"]))
        ok = status in WITH_GAINS and rec["certified"]
        outcome = "ok" if ok else ("marginal certificate" if rec["cert_marginal"] else "not certified") \
            if status in WITH_GAINS else status
    return {"value": rec["value"], "ok": ok, "status": status, "outcome": outcome, "reason": rec["reason"]}


def _certificate_reason(reason: str) -> str:
    """The certificate's clause of a record's reason (the whole reason if none)."""
    clauses = [c for c in reason.split("; ") if c.startswith("certificate")]
    return clauses[0] if clauses else reason


def _bisect(probe, key: str, bounds, rtol: float) -> dict:
    """:func:`bisect_largest` of one criterion; ``kind = "inapplicable"`` with its ``why`` when a probe says so."""
    evals: list[dict] = []

    def check(c: float) -> dict:
        crit = _criterion(probe(c, key == "b"), key)
        evals.append(crit)
        return crit

    try:
        out = bisect_largest(check, 1.0, bounds=bounds, rtol=rtol)
    except _NotApplicable as exc:
        return {"lo": math.nan, "hi": math.nan, "kind": "inapplicable", "evals": evals, "why": str(exc)}
    out["why"] = ""
    return out


def _pair_task(plant_id: str, design_id: str, bounds, rtol: float, seed: int = 0) -> dict:
    """Both bisections of one pair; (b)'s probes (design and certificate) are re-used by (a)."""
    from bench.studies import _common

    t0 = time.perf_counter()
    full: dict[float, dict] = {}
    design_only: dict[float, dict] = {}
    known = set(_common._CONSTANTS)

    def probe(c: float, certify: bool) -> dict:
        if c in full:
            return full[c]
        if certify:
            full[c] = _probe(plant_id, c, design_id, True, seed)
            return full[c]
        if c not in design_only:
            design_only[c] = _probe(plant_id, c, design_id, False, seed)
        return design_only[c]

    try:
        base = _base(plant_id)
        outs = {"b": _bisect(probe, "b", bounds, rtol), "a": _bisect(probe, "a", bounds, rtol)}
    except Exception as exc:  # noqa: BLE001 - one failing pair never ends the study: a row with its error
        why = f"{type(exc).__name__}: {exc}"[:300]
        row = {"plant": plant_id, "design": design_id, "discrete": None, "circle_bound": math.nan, "n_probes": 0,
               **{f"{k}_at_lo": math.nan for k in ("alpha", "rho", "beta", "gamma")},
               "wall_s": time.perf_counter() - t0}
        for _, name, _ in CRITERIA:
            row.update({f"{name}_kind": "error", f"{name}_lo": math.nan, f"{name}_hi": math.nan,
                        f"{name}_at_1": "error", f"{name}_fails_by": "error", f"{name}_reason": why,
                        f"{name}_evals": 0})
        return {"row": row, "evals": []}
    finally:
        for k in set(_common._CONSTANTS) - known:  # the scaled plants' constants are not needed again
            _common._CONSTANTS.pop(k, None)
    probes = [*full.values(), *design_only.values()]
    row: dict[str, Any] = {"plant": plant_id, "design": design_id, "discrete": base.discrete}
    for key, name, _ in CRITERIA:
        o = outs[key]
        fail = [e for e in o["evals"] if not e["ok"] and e["value"] == o["hi"]]
        at_one = next((e["outcome"] for e in o["evals"] if e["value"] == 1.0), "")
        row.update({f"{name}_kind": o["kind"], f"{name}_lo": o["lo"], f"{name}_hi": o["hi"],
                    f"{name}_at_1": "n/a" if o["kind"] == "inapplicable" else at_one,
                    f"{name}_fails_by": fail[-1]["outcome"] if fail else "",
                    f"{name}_reason": (o["why"] or (fail[-1]["reason"] if fail else ""))[:300],
                    f"{name}_evals": len(o["evals"])})
    b = base.bounds
    lo = row["certified_lo"] if math.isfinite(row["certified_lo"]) else row["designed_lo"]
    for name, v, power in (("alpha", b.alpha if b else None, 1), ("rho", b.rho if b else None, 1),
                           ("beta", b.beta if b else None, 2), ("gamma", b.gamma if b else None, 1)):
        row[f"{name}_at_lo"] = v * lo**power if v is not None and math.isfinite(lo) else math.nan
    row["circle_bound"] = _fixed_gain_bound(base, probes)
    row.update(n_probes=len(probes), design_s=sum(p["design_s"] for p in probes),
               solve_s=sum(p["solve_s"] for p in probes), n_solves=sum(p["n_solves"] for p in probes),
               cert_s=sum(p["cert_s"] for p in probes), wall_s=time.perf_counter() - t0)
    evals = [{"plant": plant_id, "design": design_id, "factor": p["value"], "status": p["status"],
              "certificate_run": p["cert_run"], "certified": p["certified"] if p["cert_run"] else None,
              "marginal": p["cert_marginal"],
              "cert_level": p["cert_level"], "design_s": p["design_s"], "cert_s": p["cert_s"],
              "reason": p["reason"][:300]} for p in sorted(probes, key=lambda p: (p["value"], not p["cert_run"]))]
    return {"row": row, "evals": evals}


def _fixed_gain_bound(plant, probes: list[dict]) -> float:
    """:func:`circle_bound` of the gains when every probe with gains returned the same ones (a design whose gains
    do not depend on the factor: given, LQR/LQE); NaN otherwise."""
    gains = [(p["K"], p["F"]) for p in probes if p["has_gains"]]
    if len(gains) < 2 or not all(np.array_equal(K, gains[0][0]) and np.array_equal(F, gains[0][1])
                                 for K, F in gains):
        return math.nan
    return circle_bound(plant, *gains[0])


@dataclass
class ScaleResult(StudyResult):
    """What :func:`run_scale` produced: one row per pair and every probe."""

    evals: list[dict] = field(default_factory=list)


@study()
def run_scale(run: StudyRun, *, bounds: tuple[float, float] | None = None, rtol: float = 0.01,
              seed: int = 0) -> ScaleResult:
    """Bisect, for every (plant, design) pair, the largest factor of the plant's class at which (a) the design
    returns verified gains and (b) the ladder certifies them.

    Parameters
    ----------
    plant_ids : list of str, optional
        Plants, plugins' included (default: the registry's default selection).
    design_ids : list of str, optional
        Designs (default: every registered one).
    bounds : (float, float), optional
        Bisection bounds on the factor (default: doubling and halving from 1, at most 12 moves: 2^-12 to 2^12).
    rtol : float
        Relative tolerance of the bisection (the grid's step).
    seed : int
        Seed of the constants sampler (as ``python -m bench run --seed``).
    jobs, progress
        Worker processes; ``progress(done, total, label)``.

    Returns
    -------
    ScaleResult

    Raises
    ------
    StudyError
        Bad bounds or rtol.
    """
    bounds = check_range("bounds", bounds)
    check_rtol(rtol)
    tasks = [((pid, did), (pid, did, bounds, rtol, seed)) for pid in run.plant_ids for did in run.design_ids]
    results = run.map(_pair_task, tasks,
                      lambda key, r: f"{key[0]} x {key[1]}: designed {_cell(r['row'], 'designed')}, "
                                     f"certified {_cell(r['row'], 'certified')}")
    rows, evals = [], []
    for key, _ in tasks:
        rows.append(results[key]["row"])
        evals.extend(results[key]["evals"])
    _rank(rows)
    settings = {"rtol": rtol, "bounds": bounds or "automatic (doubling/halving from c = 1, at most 12 moves)",
                "cap": 1e3, "certificate": "the pipeline's ladder at lam = 0 (strongest level first), trusted "
                                           "constants of the scaled class", "seed": seed, "jobs": run.jobs}
    return ScaleResult(rows, settings, run.wall_s(), evals=evals)


def _cell(row: dict, name: str) -> str:
    """A criterion's bracket as a table cell (:func:`bracket_cell`; ``error`` for a pair that failed)."""
    if row[f"{name}_kind"] == "error":
        return "error"
    return bracket_cell(row[f"{name}_kind"], row[f"{name}_lo"], row[f"{name}_hi"]) or "?"


def _score(row: dict, name: str) -> float | None:
    """What ranks a pair for a criterion: ``lo`` (passes at least there), else ``hi / 2`` below the range (fails
    everywhere tried: behind every pair that passed somewhere), None when n/a."""
    kind = row[f"{name}_kind"]
    if kind in ("bracketed", "above_range"):
        return row[f"{name}_lo"]
    if kind == "below_range":
        return row[f"{name}_hi"] / 2
    return None


def _rank(rows: list[dict]) -> None:
    """Add ``designed_rank`` and ``certified_rank`` (1 = largest factor of the plant; ties share a rank, n/a
    none) to each row, in place."""
    for _, name, _ in CRITERIA:
        for pid in dict.fromkeys(r["plant"] for r in rows):
            mine = [r for r in rows if r["plant"] == pid]
            for r in mine:
                s = _score(r, name)
                r[f"{name}_rank"] = (1 + sum(1 for r2 in mine if (s2 := _score(r2, name)) is not None and s2 > s)
                                     if s is not None else math.nan)


def _interval(row: dict, name: str) -> str:
    """A criterion's answer in words, with its first failure."""
    kind, lo, hi = row[f"{name}_kind"], row[f"{name}_lo"], row[f"{name}_hi"]
    if kind in ("inapplicable", "error"):
        return "n/a" if kind == "inapplicable" else "error"
    if kind == "below_range":
        return f"< {fmt(hi, '.4g')} (fails at every factor tried)"
    if kind == "above_range":
        return f">= {fmt(lo, '.4g')} (passes at every factor tried)"
    return f"{fmt(lo, '.4g')} (fails at {fmt(hi, '.4g')})"


def _matrix(rows: list[dict], name: str) -> str:
    """The plant x design matrix of one criterion: the factor and, in parentheses, its rank on the plant."""
    designs = list(dict.fromkeys(r["design"] for r in rows))
    table = []
    for pid in dict.fromkeys(r["plant"] for r in rows):
        cells = {}
        for r in (r for r in rows if r["plant"] == pid):
            cell = _cell(r, name)
            rank = r[f"{name}_rank"]
            cells[r["design"]] = f"{cell} ({int(rank)})" if isinstance(rank, (int, float)) and math.isfinite(rank) \
                else cell
        table.append({"plant": pid, **cells})
    return md_table(table, ["plant", *designs], ["plant", *designs])


def _ranking(rows: list[dict]) -> list[str]:
    """One line per plant: its designs from the largest certified factor down (then those only designed)."""
    lines = []
    for pid in dict.fromkeys(r["plant"] for r in rows):
        mine = [r for r in rows if r["plant"] == pid]
        parts = []
        for name in ("certified", "designed"):
            ranked = sorted((r for r in mine if math.isfinite(r[f"{name}_rank"])), key=lambda r: r[f"{name}_rank"])
            shown = ", ".join(f"{int(r[f'{name}_rank'])}. {r['design']} {_cell(r, name)}" for r in ranked)
            parts.append(f"{name}: {shown or '(none)'}")
        lines.append(f"- **{pid}**: " + "; ".join(parts))
    return lines


def _draw(rows: list[dict], path) -> None:
    """Bars of the admissible factor per design, grouped by plant, log scale; (a) above, (b) below. A design that
    is n/a on every plant for both criteria is left out."""
    from matplotlib.patches import Patch

    plt = pyplot()
    plants = list(dict.fromkeys(r["plant"] for r in rows))
    designs = [d for d in dict.fromkeys(r["design"] for r in rows)
               if any(r[f"{name}_kind"] != "inapplicable" for r in rows if r["design"] == d for _, name, _ in CRITERIA)]
    styles = bar_styles(designs)
    width = 0.84 / max(1, len(designs))
    fig, axes = plt.subplots(2, 1, figsize=(min(18.0, 4.0 + 1.2 * len(plants) * max(1.0, len(designs) / 8)), 9.0),
                             sharex=True, constrained_layout=True)
    finite = [v for r in rows for _, k, _ in CRITERIA for v in (r[f"{k}_lo"], r[f"{k}_hi"])
              if isinstance(v, float) and math.isfinite(v) and v > 0]
    floor = min([*finite, 1.0]) / 2
    for ax, (key, name, words) in zip(axes, CRITERIA):
        for j, did in enumerate(designs):
            style = styles[did]
            for i, pid in enumerate(plants):
                r = next((r for r in rows if r["plant"] == pid and r["design"] == did), None)
                if r is None:
                    continue
                x = i - 0.42 + (j + 0.5) * width
                kind, lo, hi = r[f"{name}_kind"], r[f"{name}_lo"], r[f"{name}_hi"]
                if kind in ("bracketed", "above_range"):
                    ax.bar(x, lo - floor, width, bottom=floor, color=style["color"], edgecolor="white", linewidth=0.3,
                           hatch=style["hatch"])
                    if kind == "above_range":
                        ax.plot(x, lo * 1.6, "^", color=style["color"], ms=3.5)
                elif kind == "below_range":
                    ax.plot(x, hi, "v", color=style["color"], ms=4)
        for i in range(1, len(plants)):
            ax.axvline(i - 0.5, color="0.85", lw=0.6)
        ax.axhline(1.0, color="0.3", lw=0.9, ls="--")
        ax.set_yscale("log")
        ax.set_ylim(bottom=floor)
        ax.set_ylabel("admissible factor c (log)")
        ax.set_title(f"({key}) {name}: largest c at which {words}", fontsize=10)
        ax.grid(True, axis="y", which="major", alpha=0.3)
    axes[1].set_xticks(range(len(plants)), plants, rotation=20, ha="right")
    axes[1].set_xlim(-0.5, len(plants) - 0.5)
    axes[0].legend(handles=[Patch(facecolor=styles[d]["color"], hatch=styles[d]["hatch"],
                                  edgecolor="white", label=d) for d in designs],
                   fontsize=7, ncol=1, loc="upper left", bbox_to_anchor=(1.0, 1.0), title="design")
    fig.suptitle("Largest admissible scale of each plant's class (dashed: c = 1, the plant itself); ^ above a bar: "
                 "passes at every factor tried;\nv: fails at every factor tried (drawn at the smallest); no mark: n/a "
                 "(details in the report)", fontsize=9)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write_scale(result: ScaleResult, out_dir: str, command: str, *, figures: bool = True) -> "Path":  # noqa: F821
    """Write ``STUDY_scale.md``, ``study_scale.csv``, ``study_scale_probes.csv`` and ``figures/study_scale.png``
    (none with ``figures=False``) whole or not at all; return the markdown's path."""
    rows = result.rows
    checks = [r for r in rows if math.isfinite(r["circle_bound"])]
    lines = [
        study_header("Study: largest admissible scale of each plant's class", command, result.settings,
                     result.wall_s),
        _INTRO.format(percent=f"{100 * result.settings['rtol']:g}"),
        "",
        "## Normalisation (the answer depends on it)",
        "",
        _NORMALISATION,
        "",
        "## (a) Designed: largest factor at which the design returns verified gains",
        "",
        _matrix(rows, "designed"),
        "",
        "## (b) Certified: largest factor at which the ladder certifies the design's gains",
        "",
        _matrix(rows, "certified"),
        "",
        "Cells: the factor `lo` (the largest verified to pass) and, in parentheses, the design's rank on the plant "
        "(1 = largest; ties share a rank). `< v`: fails at every factor tried, down to v; `>= v`: passes at every "
        "factor tried, up to v; `n/a`: the criterion does not apply (reason in the details).",
        "",
        "## Ranking per plant",
        "",
        *_ranking(rows),
        "",
        *(["![largest admissible factor per design and plant](figures/study_scale.png)", ""] if figures else []),
        "## Fixed gains against the circle criterion",
        "",
        _CIRCLE,
        "",
        (md_table([{**r, "certified": _interval(r, "certified"), "inside": _inside(r)} for r in checks],
                  ["plant", "design", "circle_bound", "certified", "inside"],
                  ["plant", "design", "circle-criterion bound", "(b) certified", "bracket vs bound"])
         if checks else "(no pair with fixed gains on a one-channel symmetric-sector continuous plant)"),
        "",
        "## Details",
        "",
        md_table([{**r, "a": _interval(r, "designed"), "b": _interval(r, "certified"),
                   "why_a": fmt(r["designed_reason"])[:160], "why_b": fmt(r["certified_reason"])[:160]}
                  for r in rows],
                 ["plant", "design", "designed_at_1", "a", "designed_fails_by", "why_a", "certified_at_1", "b",
                  "certified_fails_by", "why_b", "alpha_at_lo", "rho_at_lo", "n_probes", "wall_s"],
                 ["plant", "design", "(a) at c = 1", "(a) designed", "(a) fails by", "(a) why", "(b) at c = 1",
                  "(b) certified", "(b) fails by", "(b) why", "alpha at lo", "rho at lo", "probes", "wall s"]),
        "",
        "`fails by`: the outcome at the first failing factor (`infeasible`, `marginal` = a design's margin within "
        "its tolerance, `undecided` = solver trouble, `not certified` = gains the ladder does not certify, "
        "`marginal certificate` = the ladder's best margin within its tolerance of zero). `why`: the reason of the "
        "first failure or of `n/a` (in full in `study_scale.csv`; every probe in `study_scale_probes.csv`). `alpha at lo`, "
        "`rho at lo`: the trusted constants of the class at the largest certified factor (designed where none).",
        "",
    ]
    tables = {"study_scale": rows, "study_scale_probes": result.evals}
    return write_study(out_dir, "scale", "\n".join(lines), tables,
                       {"study_scale": lambda p: _draw(rows, p)} if figures else {})


def _inside(r: dict) -> str:
    """Where a pair's certified bracket lies with respect to its circle-criterion bound."""
    bound, kind, lo, hi = r["circle_bound"], r["certified_kind"], r["certified_lo"], r["certified_hi"]
    if kind == "inapplicable" or not math.isfinite(bound):
        return ""
    if (kind in ("bracketed", "below_range") and bound > hi) and not math.isclose(bound, hi, rel_tol=1e-3):
        if r["certified_fails_by"] == "marginal certificate":
            return f"marginal from {fmt(hi, '.4g')}, {fmt(100 * (bound / hi - 1), '.2g')} % below the bound"
        return "FAILS BELOW the bound (contradicts the criterion's sufficiency)"
    if kind in ("bracketed", "above_range") and bound < lo:
        return "certified beyond the bound"
    return "contains it" if kind == "bracketed" else "consistent"


_INTRO = (
    "For every plant and design: the largest factor c by which the plant's class can be multiplied (f -> c f: "
    "Lipschitz c alpha, OSL c rho, QIB (c^2 beta, c gamma), channel slopes c [lo, hi]; A, B, C, the disturbance "
    "inputs and x0 fixed; `Plant.scaled`) such that (a) the design, given the scaled class, still returns gains it "
    "verified (status feasible, computed or given, with fixed K and F), and (b) the suite's certificate ladder "
    "(`bench.certify`, at rate 0, the strongest level first, over the trusted constants of the scaled class) "
    "certifies those gains. Geometric bisection from c = 1 (the plant itself) on a grid of step {percent} %; "
    "`lo` is the largest factor verified to pass, the value in parentheses the smallest that did not (a failure, "
    "or a marginal certificate: a margin within the verification tolerance of zero, undecided rather than "
    "failed; near the true limit a certificate's margin shrinks to zero, so (b) stops a little below it). "
    "Plants with a scale knob have the knob study too (`python -m bench study admissible`), which scales f through "
    "the plant's own parameter instead.")

_NORMALISATION = (
    "Every LMI design maximises a margin t with `M << -t I`, `Q, R >> t I`, **`Q, R << 1e3 I`** and `t <= 1` "
    "(`bench/lmi.py`); (a) is feasibility under that cap, so a design's factor can grow with the cap where its LMI "
    "is not homogeneous (the corrected Theorem 1 and Corollary 1, whose Young and Schur blocks are constant: "
    "`STUDY_admissible.md` measures their sensitivity to caps 10, 100 and 1e4). Designs whose gains do not "
    "depend on the class (given gains, LQR/LQE) pass (a) at every factor; their (b) is the largest class their "
    "fixed gains are certified over. A design with no fixed gain (the EKF) and a plugin's unverified gains have "
    "no (a); on a discrete-time plant (b) is the discrete-time ladder's (V(z_{k+1}) <= V(z_k)).")

_CIRCLE = (
    "For a pair whose gains do not depend on the factor, on a continuous plant with one channel and a symmetric "
    "slope sector `[-r, r]`: if both sides pass the circle criterion, `c r ||H (sI - A - BF)^-1 G||_inf < 1` and "
    "`c r ||H (sI - A + KC)^-1 G||_inf < 1` (Khalil, *Nonlinear Systems*, Thm 7.1; python-control's H-infinity "
    "norm), the two quadratic certificates combine into one for the cascade (x driven by e), so the ladder's "
    "structured level certifies every factor below `1 / (r max(...))`; the x-side's criterion is also necessary "
    "(at e = 0 the certificate is one for the x-side alone), and for one state both are (every slope in the "
    "sector is a linear member of the class: `tests/test_scaled_class.py`). An independent check on the "
    "bisection (b): a bracket that fails below the bound contradicts the criterion.")
