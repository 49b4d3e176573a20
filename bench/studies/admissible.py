"""Conservatism: the largest admissible scale of the nonlinearity for each LMI / Riccati design.

For a plant with a scale knob (the coefficient ``c`` of f, the region radius ``r`` of the moving object,
``g/l`` of the pendulum) and a design, the *admissible scale* is the largest knob value at which the design
is feasible **and** its gains are certified at some level of the ladder (:mod:`bench.certify`), judged by
:func:`bench.pipeline.evaluate_pair`. It is found by geometric bisection (:func:`bisect_largest`) and
reported as ``[lo, hi)``: ``lo`` the largest value verified to pass, ``hi`` the smallest verified to fail.
The LMIs' normalisation cap cuts the admissible range, so Theorem 1 and Corollary 1 are re-run with other
caps (:data:`CAP_DESIGNS`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench.studies._common import (StudyError, StudyResult, StudyRun, bisect_largest, bracket_cell, check_range,
                                   check_rtol, evaluate, fmt, md_table, pyplot, study, study_header, write_plant_study)
from bench.report import clip_words
from designs import GAIN_STATUSES

__all__ = ["run_admissible", "write_admissible"]

#: Scale knob of each catalog plant (keyword of its factory; f scales with it, A, B, C do not).
KNOBS = {
    "flexible_link": "c",
    "flexible_link_printed": "c",
    "flexible_joint_v1": "c",
    "pendulum_v1": "g_over_l",
    "random_lipschitz_v1": "c",
    "random_osl_v1": "c",
    "moving_object_v1": "r",
}

#: LMI and Riccati designs (the study's default selection).
DEFAULT_DESIGNS = ("thm1", "thm1_sep", "thm1_printed", "cor1", "cor1_sep", "cor1_printed", "structured",
                   "thm1_scaled", "cor1_scaled", "lqr+rajamani", "lqr+zhang_osl", "lqr+rh_riccati")

#: Designs re-run with other normalisation caps (they have a ``cap`` hyperparameter).
CAP_DESIGNS = ("thm1", "cor1")
#: Plants on which the normalisation sensitivity is measured (when selected).
CAP_PLANTS = ("flexible_link", "random_osl_v1")
#: Other sensitivity variants: (plant, design, overrides), run when the plant and design are selected
#: (a wider eps2 grid for the gamma < 0 form of Theorem 1).
EXTRA_VARIANTS = (("moving_object_v1", "thm1", {"eps2_range": (1e-6, 1e2)}),)


def _label(overrides: dict) -> str:
    """The variant label of a design's overrides."""
    if not overrides:
        return "default (cap = 1e3)"
    return ", ".join(f"{k} = {v:g}" if isinstance(v, float) else f"{k} = {v}" for k, v in overrides.items())


def small_gain_bound(plant_id: str, knob: str, K: np.ndarray, F: np.ndarray) -> float:
    """Knob value at which the channel small-gain test of fixed gains fails (NaN where it does not apply).

    For one channel with a symmetric slope sector ``[-r, r]`` whose half-width is linear in the knob, the
    structured certificate of fixed gains exists iff both sides pass the circle criterion (Khalil,
    *Nonlinear Systems*, Thm 7.1): ``r ||H (sI - A - BF)^-1 G||_inf < 1`` and ``r ||H (sI - A + KC)^-1 G||_inf < 1``.
    The bound is where the larger gain reaches 1 (an independent check on the bisection).
    """
    from bench.registry import PLANTS

    p1, p2 = PLANTS.create(plant_id, **{knob: 1.0}), PLANTS.create(plant_id, **{knob: 2.0})
    ch1, ch2 = p1.channels, p2.channels
    if ch1 is None or ch1.q != 1 or np.any(ch1.center != 0) or not np.allclose(ch2.spread, 2 * ch1.spread) \
            or ch1.spread[0] == 0:
        return math.nan
    peaks = [_siso_peak(M, ch1.G, ch1.H) for M in (p1.A + p1.B @ F, p1.A - K @ p1.C)]
    return 1.0 / (float(ch1.spread[0]) * max(peaks)) if all(map(math.isfinite, peaks)) else math.nan


def _siso_peak(M: np.ndarray, G: np.ndarray, H: np.ndarray) -> float:
    """``sup_w |H (j w I - M)^-1 G|`` (python-control's H-infinity norm); ``inf`` if M is not Hurwitz."""
    import control

    if float(np.linalg.eigvals(M).real.max()) >= 0:
        return math.inf
    return float(control.norm(control.ss(M, G, H, 0), "inf", tol=1e-10))


def knob_of(plant_id: str) -> str | None:
    """The scale knob of a plant: from :data:`KNOBS`, else ``"c"`` if its params have one, else None."""
    if plant_id in KNOBS:
        return KNOBS[plant_id]
    from bench.registry import PLANTS

    try:
        return "c" if "c" in PLANTS.create(plant_id).params else None
    except Exception:
        return None


def evaluate_at(plant_id: str, knob: str, value: float, design_id: str, overrides: dict | None = None,
                seed: int = 0) -> dict:
    """Design and certify ``design_id`` (with ``overrides``) on ``PLANTS.create(plant_id, **{knob: value})``
    without simulating: a record with ``value``, ``ok`` (gains designed and certified), ``status`` (``invalid``
    when the plant cannot be built there), ``feasible``, ``certified``, ``cert_level``, margins, timings, ``reason``.
    """
    from bench.pipeline import RunOptions
    from bench.registry import PLANTS
    from plants import PlantError

    rec: dict[str, Any] = {"value": float(value), "ok": False, "status": "", "feasible": False, "certified": False,
                           "cert_level": "", "lmi_margin": math.nan, "cert_margin": math.nan, "compile_s": 0.0,
                           "solve_s": 0.0, "n_solves": 0, "design_s": 0.0, "cert_s": 0.0, "reason": ""}
    try:
        plant = PLANTS.create(plant_id, **{knob: value})
    except PlantError as exc:
        rec.update(status="invalid", reason=f"plant cannot be built at {knob} = {value:.4g}: {exc}")
        return rec
    row = evaluate(plant, design_id, RunOptions(certificate="verdict", simulate=False, seed=seed),
                   overrides=overrides).record
    rec.update({k: row[k] for k in rec if k in row and k not in ("value", "ok")})
    for k in ("compile_s", "solve_s", "design_s", "cert_s"):
        rec[k] = 0.0 if not math.isfinite(rec[k]) else rec[k]
    rec["n_solves"] = 0 if not math.isfinite(rec["n_solves"]) else int(rec["n_solves"])
    rec["ok"] = bool(rec["status"] in GAIN_STATUSES and rec["certified"])  # designed (solved or computed) and certified
    return rec


def _pair_task(plant_id: str, knob: str, design_id: str, overrides: dict, bounds, rtol: float, seed: int = 0) -> dict:
    from bench.registry import PLANTS

    t0 = time.perf_counter()
    default = float(PLANTS.create(plant_id).params[knob])
    out = bisect_largest(lambda v: evaluate_at(plant_id, knob, v, design_id, overrides, seed), default, bounds=bounds,
                         rtol=rtol)
    ev = out["evals"]
    row = {"plant": plant_id, "knob": knob, "default": default, "design": design_id,
           "variant": _label(overrides), "admissible_lo": out["lo"], "failing_hi": out["hi"],
           "kind": out["kind"], "n_evals": len(ev),
           **{k: sum(e[k] for e in ev) for k in ("compile_s", "solve_s", "n_solves", "cert_s")},
           "wall_s": time.perf_counter() - t0}
    fail = [e for e in ev if not e["ok"] and (e["value"] == out["hi"] or out["kind"] == "inapplicable")]
    row["fails_by"] = _outcome(fail[-1]) if fail else ""
    row["fail_reason"] = clip_words(fail[-1]["reason"], 300) if fail else ""
    row["at_default"] = next((_outcome(e) for e in ev if e["value"] == default), "")
    if math.isfinite(out["lo"]):
        b = PLANTS.create(plant_id, **{knob: out["lo"]}).bounds
        row.update(alpha_at_lo=b.alpha, rho_at_lo=b.rho, beta_at_lo=b.beta, gamma_at_lo=b.gamma)
    for e in ev:
        e.update(plant=plant_id, design=design_id, knob=knob, variant=row["variant"])
    if design_id == "lqr+lqe" and not overrides:  # neither gain depends on the knob
        from bench.registry import DESIGNS

        plant = PLANTS.create(plant_id)
        res = DESIGNS.create(design_id).design(plant, plant.bounds)
        row["small_gain"] = small_gain_bound(plant_id, knob, res.K, res.F) if res.has_gains else math.nan
    return {"row": row, "evals": ev}


def _outcome(e: dict) -> str:
    """An evaluation's outcome: ``ok``, ``not certified`` (gains designed) or its status."""
    return "ok" if e["ok"] else "not certified" if e["status"] in GAIN_STATUSES else e["status"]


@dataclass
class AdmissibleResult(StudyResult):
    """What :func:`run_admissible` produced: the rows, the cap variants' rows and every evaluation."""

    variant_rows: list[dict] = field(default_factory=list)
    evals: list[dict] = field(default_factory=list)


@study(KNOBS, DEFAULT_DESIGNS)
def run_admissible(run: StudyRun, *, bounds: tuple[float, float] | None = None, rtol: float = 0.01,
                   caps: tuple[float, ...] = (10.0, 100.0, 1e4), seed: int = 0) -> AdmissibleResult:
    """Bisect the admissible scale of every (plant, design) pair.

    Parameters
    ----------
    plant_ids : list of str, optional
        Plants with a scale knob (default: :data:`KNOBS`).
    design_ids : list of str, optional
        Default :data:`DEFAULT_DESIGNS`.
    bounds : (float, float), optional
        Bisection bounds on the knob (default: bracketing from each plant's default value).
    rtol : float
        Relative tolerance of the bisection.
    caps : tuple of float
        Other normalisation caps for :data:`CAP_DESIGNS` on :data:`CAP_PLANTS` (empty: skip).
    seed : int
        Seed of the constants sampler (as ``python -m bench run --seed``).
    jobs, progress
        Worker processes; ``progress(done, total, label)``.

    Returns
    -------
    AdmissibleResult

    Raises
    ------
    StudyError
        A plant without a scale knob, bad bounds, rtol or cap.
    """
    bounds = check_range("bounds", bounds)
    check_rtol(rtol)
    for c in caps:
        if not (math.isfinite(c) and c > 0):
            raise StudyError("caps", f"each cap must be finite and > 0, got {c!r}")
    tasks = _tasks(run.plant_ids, run.design_ids, caps)
    results = run.map(_pair_task, [((pid, did, _label(ov)), (pid, k, did, ov, bounds, rtol, seed))
                                   for pid, k, did, ov in tasks],
                      lambda key, r: f"{key[0]} x {key[1]} ({key[2]}): "
                                     f"[{fmt(r['row']['admissible_lo'])}, {fmt(r['row']['failing_hi'])})")
    rows, variant_rows, evals = _gather(tasks, results)
    settings = {"rtol": rtol, "bounds": bounds or "automatic (doubling/halving from the plant's default)",
                "cap": 1e3, "other caps": tuple(caps),
                "certificate": "the pipeline's ladder at lam = 0 (strongest level first), trusted constants",
                "seed": seed, "jobs": run.jobs}
    return AdmissibleResult(rows, settings, run.wall_s(), variant_rows=variant_rows, evals=evals)


def _tasks(plant_ids: list[str], design_ids: list[str], caps) -> list[tuple[str, str, str, dict]]:
    """The bisections ``(plant, knob, design, overrides)``: every pair, then the cap and the extra variants."""
    knobs = {}
    for pid in plant_ids:
        k = knob_of(pid)
        if k is None:
            raise StudyError("plant", f"{pid!r} has no scale knob (a factory keyword c, or one of {sorted(KNOBS)})")
        knobs[pid] = k
    tasks = [(pid, knobs[pid], did, {}) for pid in plant_ids for did in design_ids]
    tasks += [(pid, knobs[pid], did, {"cap": float(c)}) for pid in plant_ids if pid in CAP_PLANTS
              for did in design_ids if did in CAP_DESIGNS for c in caps if float(c) != 1e3]
    tasks += [(pid, knobs[pid], did, dict(ov)) for pid, did, ov in EXTRA_VARIANTS
              if pid in plant_ids and did in design_ids]
    return tasks


def _gather(tasks: list, results: dict) -> tuple[list[dict], list[dict], list[dict]]:
    """The default rows, the variant rows (each variant's pair with its default row beside, sorted) and every
    evaluation, in the order of ``tasks``."""
    rows, variant_rows, evals = [], [], []
    for pid, k, did, ov in tasks:
        r = results[(pid, did, _label(ov))]
        (variant_rows if ov else rows).append(r["row"])
        evals.extend(r["evals"])
    for pair in dict.fromkeys((r["plant"], r["design"]) for r in list(variant_rows)):
        variant_rows += [r for r in rows if (r["plant"], r["design"]) == pair]
    variant_rows.sort(key=lambda r: (r["plant"], r["design"], not r["variant"].startswith("default"),
                                     float(r["variant"].split("= ")[1]) if r["variant"].startswith("cap") else 0.0,
                                     r["variant"]))
    return rows, variant_rows, evals


def _interval(r: dict) -> str:
    """The admissible value of a row in words, with its first failure."""
    lo, hi, kind = r["admissible_lo"], r["failing_hi"], r["kind"]
    if kind == "inapplicable":
        return "n/a (inapplicable)"
    if kind == "below_range":
        return f"< {fmt(hi, '.4g')} (fails at every value tried)"
    if kind == "above_range":
        return f">= {fmt(lo, '.4g')} (passes at every value tried)"
    return f"{fmt(lo, '.4g')} (fails at {fmt(hi, '.4g')})"


def _draw_plant(pid: str, rows: list[dict], evals: list[dict]):
    """The figure of one plant: every evaluation per design on the knob's log axis."""
    plt = pyplot()
    designs = [r["design"] for r in rows]
    fig, ax = plt.subplots(figsize=(7.5, 0.45 * len(designs) + 1.6), constrained_layout=True)
    styles = {"ok": ("o", "tab:green", "feasible and certified"),
              "nc": ("s", "tab:orange", "feasible, not certified"),
              "no": ("x", "tab:red", "infeasible / undecided / error"),
              "na": ("+", "tab:gray", "inapplicable / invalid value")}
    seen = set()
    for i, r in enumerate(rows):
        for e in (e for e in evals if e["plant"] == pid and e["design"] == r["design"] and e["variant"] == r["variant"]):
            key = {"ok": "ok", "not certified": "nc", "inapplicable": "na", "invalid": "na"}.get(_outcome(e), "no")
            m, c, lab = styles[key]
            ax.plot(e["value"], i, m, color=c, ms=6, label=None if key in seen else lab)
            seen.add(key)
        if math.isfinite(r["admissible_lo"]):
            ax.plot([r["admissible_lo"]] * 2, [i - 0.35, i + 0.35], "-", color="k", lw=2)
    ax.axvline(rows[0]["default"], ls="--", color="tab:blue", lw=1, label=f"default {rows[0]['knob']}")
    ax.set_xscale("log")
    ax.set_yticks(range(len(designs)), designs)
    ax.invert_yaxis()
    ax.set(xlabel=f"scale knob {rows[0]['knob']} of f (log)",
           title=f"{pid}: feasibility vs {rows[0]['knob']} (black bar: admissible value)")
    ax.grid(True, axis="x", which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    return fig


def write_admissible(result: AdmissibleResult, out_dir: str, command: str, *, figures: bool = True) -> "Path":  # noqa: F821
    """Write ``STUDY_admissible.md``, its CSVs and figures atomically; return the markdown's path."""
    rows = result.rows
    by_plant = {pid: {r["design"]: r for r in rows if r["plant"] == pid}  # plant -> design -> row, in order
                for pid in dict.fromkeys(r["plant"] for r in rows)}
    osl = _osl_rows(by_plant)
    lines = [
        study_header("Study: maximum admissible nonlinearity (conservatism)", command, result.settings, result.wall_s),
        _INTRO.format(percent=f"{100 * result.settings['rtol']:g}"),
        "",
        "## Normalisation (the answer depends on it)",
        "",
        _NORMALISATION,
        "",
        "## Admissible value, plant x design",
        "",
        _matrix(rows, by_plant),
        "",
        "`< v`: fails already at v (the smallest value tried); `>= v`: passes at every value tried; `n/a`: the "
        "design does not apply to the plant (reason in the details).",
        "",
        "## Details",
        "",
        _details_table(rows),
        "",
        _DETAILS_NOTE,
        "",
        "## Theorem 1 (OSL/QIB) vs Corollary 1 (Lipschitz)",
        "",
        _OSL_INTRO,
        "",
        md_table(osl, ["plant", "pair", "thm", "cor", "ratio", "alpha_thm", "alpha_cor", "rho_thm"],
                 ["plant", "pair", "Theorem 1 admissible", "Corollary 1 admissible", "ratio Thm/Cor",
                  "alpha at Thm's value", "alpha at Cor's value", "rho at Thm's value"]) if osl else "(not run)",
        "",
        _osl_verdict(osl),
        "",
        "## Sensitivity to the normalisation and to the designs' searches",
        "",
        (md_table([{**r, "admissible": _interval(r)} for r in result.variant_rows],
                  ["plant", "design", "variant", "admissible", "fails_by", "n_evals", "wall_s"],
                  ["plant", "design", "variant (design hyperparameters)", "admissible value", "fails by", "evals",
                   "wall s"])
         if result.variant_rows else "(not run: no variant's plant and design selected, or `--caps ''`)"),
        "",
        "A value that changes with the variant is set by the normalisation or the search, not by the theorem alone.",
        "",
        "## Compile vs solve",
        "",
        _compile_note(rows),
        "",
    ]
    tables = {"study_admissible": rows, "study_admissible_evaluations": result.evals}
    if result.variant_rows:
        tables["study_admissible_variants"] = result.variant_rows
    return write_plant_study(out_dir, "admissible", lines, tables, rows, _draw_plant, result.evals, figures=figures)


_INTRO = (
    "For each plant with a scale knob on f and each LMI / Riccati design: the largest knob value at which the "
    "design is **feasible and its gains are certified** (at some level of `bench.certify`'s ladder, by the "
    "pipeline of the main table), by geometric bisection to {percent} % relative. `lo` is the largest value "
    "verified to pass; the value in parentheses the smallest verified to fail.")

_NORMALISATION = (
    "Every LMI maximises a margin t with `M << -t I`, `Q, R >> t I`, **`Q, R << 1e3 I`** and `t <= 1` "
    "(`bench/lmi.py`). The corrected Theorem 1 and Corollary 1 contain constant identity blocks (the Young term "
    "and the Schur column), so they are not homogeneous: near the boundary the feasible set needs larger Q, R, and "
    "the cap cuts the admissible range (the observer LMIs are homogeneous: there the cap only fixes the scale). "
    "The sensitivity table below re-runs the joint Theorem 1 and Corollary 1 with other caps; the answer also "
    "depends on the designs' own searches (the gamma < 0 form of Theorem 1 fixes eps2 on a grid).")

_DETAILS_NOTE = (
    "`at default`: the outcome at the plant's default knob value. `fails by`: why the first failing value fails "
    "(`undecided` = solver trouble, `not certified` = feasible gains the ladder does not certify; the reasons are "
    "in `study_admissible.csv`, `fail_reason`). `small-gain bound`: for `lqr+lqe` on a plant with one channel "
    "and a symmetric slope sector `[-r, r]`, the knob value at which `r max(||H (sI - A - BF)^-1 G||_inf, "
    "||H (sI - A + KC)^-1 G||_inf) = 1`: the structured certificate of fixed gains exists iff both sides pass "
    "this circle criterion, so where the pair fails by `not certified` the bracket should contain it.")

_OSL_INTRO = (
    "The paper claims the one-sided Lipschitz condition (Theorem 1) is less conservative than the Lipschitz one "
    "(Corollary 1) when rho is much smaller than alpha. On `moving_object_v1` (knob r: rho = 0, alpha = 3 r^2, "
    "gamma = -3 r^2) and `random_osl_v1` (knob c: rho = 0, alpha = 3c, gamma = -3c) rho = 0 at every scale. On "
    "the other plants gamma = 0 and beta = alpha^2, so Theorem 1's state-feedback side is Corollary 1's and the "
    "two must agree up to the joint designs' phi search.")


def _matrix(rows: list[dict], by_plant: dict[str, dict[str, dict]]) -> str:
    """The markdown matrix plant x design of the admissible values (``by_plant``: plant -> design -> row)."""
    designs = list(dict.fromkeys(r["design"] for r in rows))
    table = []
    for pid, sub in by_plant.items():
        first = next(iter(sub.values()))
        table.append({"plant": f"{pid} ({first['knob']}, {fmt(first['default'])})",
                      **{d: bracket_cell(r["kind"], r["admissible_lo"], r["failing_hi"]) for d, r in sub.items()}})
    return md_table(table, ["plant", *designs], ["plant (knob, default)", *designs])


def _details_table(rows: list[dict]) -> str:
    """The markdown table of every pair: interval, reason, constants at ``lo``, small-gain bound, costs."""
    table_rows = [{**r, "admissible": _interval(r),
                   "alpha": r.get("alpha_at_lo", math.nan), "rho": r.get("rho_at_lo", math.nan),
                   "gamma": r.get("gamma_at_lo", math.nan), "small_gain": r.get("small_gain", math.nan)}
                  for r in rows]
    cols = ["plant", "knob", "default", "design", "at_default", "admissible", "fails_by", "alpha", "rho", "gamma",
            "small_gain", "n_evals", "compile_s", "solve_s", "cert_s", "wall_s"]
    heads = ["plant", "knob", "default", "design", "at default", "admissible value [lo] (first failure)",
             "fails by", "alpha at lo", "rho at lo", "gamma at lo", "small-gain bound (lqr+lqe)", "evals",
             "compile s", "solve s", "cert s", "wall s"]
    return md_table(table_rows, cols, heads)


def _osl_rows(by_plant: dict[str, dict[str, dict]]) -> list[dict]:
    """Theorem 1 vs Corollary 1 (joint and separated) per plant, the OSL plants (rho = 0, alpha > 0) first."""
    osl = []
    for pid, sub in by_plant.items():
        for a, b in (("thm1", "cor1"), ("thm1_sep", "cor1_sep")):
            if a in sub and b in sub:
                ra, rb = sub[a], sub[b]
                ratio = (ra["admissible_lo"] / rb["admissible_lo"]
                         if math.isfinite(ra["admissible_lo"]) and math.isfinite(rb["admissible_lo"]) else math.nan)
                osl.append({"plant": pid, "pair": f"{a} vs {b}", "thm": _interval(ra), "cor": _interval(rb),
                            "ratio": ratio, "alpha_thm": ra.get("alpha_at_lo", math.nan),
                            "alpha_cor": rb.get("alpha_at_lo", math.nan), "rho_thm": ra.get("rho_at_lo", math.nan)})
    osl.sort(key=lambda o: not (o["rho_thm"] == 0 and o["alpha_thm"] > 0))  # stable: plant order within each group
    return osl


def _compile_note(rows: list[dict]) -> str:
    """The compile, solve and certificate seconds summed over every evaluation."""
    total = {k: sum(r[k] for r in rows) for k in ("compile_s", "solve_s", "cert_s", "n_evals")}
    return (f"{total['n_evals']} evaluations (design + certificate at one knob value each): compile "
            f"{total['compile_s']:.2f} s, solve {total['solve_s']:.2f} s (design LMIs), certificate (compile + solve) "
            f"{total['cert_s']:.2f} s. Each "
            "design compiles its cvxpy problem once per structure and re-uses it across the bisection, the knob "
            "entering as parameter values (`bench.lmi.cached_program`).")


def _osl_verdict(osl: list[dict]) -> str:
    """What the Theorem 1 / Corollary 1 numbers say, in words (whichever way they go)."""
    def word(r: float) -> str:
        return "larger" if r > 1.01 else "smaller" if r < 0.99 else "about equal (within 1 %)"

    lines = []
    for o in osl:
        r = o["ratio"]
        osl_plant = o["rho_thm"] == 0 and o["alpha_thm"] > 0
        tag = "OSL plant, rho = 0" if osl_plant else "gamma = 0 plant"
        if math.isfinite(r):
            lines.append(f"- {o['plant']} ({tag}), {o['pair']}: Theorem 1's admissible value is {word(r)}: "
                         f"{fmt(r)} x Corollary 1's.")
        else:
            lines.append(f"- {o['plant']} ({tag}), {o['pair']}: Theorem 1 {o['thm']}; Corollary 1 {o['cor']}.")
    return "What the numbers say:\n\n" + "\n".join(lines) if lines else ""
