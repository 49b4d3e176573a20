"""Digital implementation: the largest sample period h at which each design's loop still converges.

The controller and the observer run at period h, the plant stays continuous
(:func:`bench.batch.simulate_digital_batch`): the output is sampled at ``t_k = k h``, ``u_k = F x_hat_k``
is held, and the observer is advanced by its ``"zoh"`` or forward-Euler discretisation; the gains are the
continuous designs' own (emulation). Per pair: ``h_lin``, where the loop linearised at the origin loses
stability (spectral radius of the one-period matrix reaches 1), and ``h_max``, the largest h found by
bisection at which the nonlinear loop converges within the horizon from the plant's and ``n_ics`` seeded
random initial conditions (``h_max <= h_lin`` expected), with settling times vs h.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from bench.report import design_styles
from bench.studies._common import (StudyError, StudyResult, StudyRun, bisect_largest, bracket_cell, check_box,
                                   check_count, check_horizon, check_range, check_rtol, default_box, evaluate, fmt,
                                   map_tasks, md_table, pyplot, random_ics, skipped_lines, study, study_header,
                                   unsimulated_row, write_plant_study)

__all__ = ["run_sampling", "write_sampling"]

DEFAULT_PLANTS = ("flexible_link", "random_lipschitz_v1", "moving_object_v1")


def linear_h_bound(plant, K, F, discretisation: str = "zoh") -> float:
    """First sample period at which the sampled loop linearised at the origin loses stability: the first
    crossing of ``rho(Phi(h)) = 1`` on a log grid of 400 points in ``[1e-5, 10]`` s, refined by Brent's
    method; ``0.0`` if unstable at 1e-5 s, ``inf`` if stable on the whole grid.
    """
    from scipy.optimize import brentq

    from bench.batch import digital_matrix

    Alin = plant.A + plant.jacobian_at(np.zeros(plant.n))

    def rho(h: float) -> float:
        return float(np.abs(np.linalg.eigvals(digital_matrix(Alin, plant.B, plant.C, K, F, h, discretisation))).max())

    grid = np.logspace(-5, 1, 400)
    for i, h in enumerate(grid):
        if rho(h) >= 1.0:
            return 0.0 if i == 0 else float(brentq(lambda v: rho(v) - 1.0, grid[i - 1], h, rtol=1e-8))
    return math.inf


def _check_h(plant, prior, X, XH, h, disc, t_final, seed: int = 0) -> dict:
    """The digital loop at period ``h`` from every initial condition: the pipeline with a scenario."""
    from bench.pipeline import RunOptions, Scenario

    out = evaluate(plant, prior.record["design"], RunOptions(certificate="none", t_final=t_final, seed=seed), prior=prior,
                   scenario=Scenario(x0=X, x_hat0=XH, sample_period=h, discretisation=disc))
    m, rec = out.metrics, out.record
    if m is None:  # the pipeline recorded an error
        return {"h": float(h), "ok": False, "status": rec["status"], "n_converged": 0, "N": X.shape[1],
                "plant_ic_converged": False, "settling_x_plant": math.nan, "settling_e_plant": math.nan,
                "settling_x_median": math.nan, "worst_final_x": math.nan, "n_diverged": 0, "sim_s": math.nan,
                "horizon_s": rec["horizon_s"]}
    conv = m["converged"]
    sx = m["settling_x_s"][conv]
    return {"h": float(h), "ok": bool(conv.all()), "status": "converged" if conv.all() else "not converged",
            "n_converged": int(conv.sum()), "N": int(conv.size), "plant_ic_converged": bool(conv[0]),
            "settling_x_plant": float(m["settling_x_s"][0]) if conv[0] else math.nan,
            "settling_e_plant": float(m["settling_e_s"][0]) if conv[0] else math.nan,
            "settling_x_median": float(np.median(sx)) if sx.size else math.nan,
            "worst_final_x": float(np.nanmax(np.where(out.trajectory.diverged, np.inf, m["final_x"]))),
            "n_diverged": int(out.trajectory.diverged.sum()), "sim_s": rec["sim_s"], "horizon_s": rec["horizon_s"]}


def _design_task(plant_id: str, design_id: str, t_final: float | None, seed: int = 0):
    """The pair as the main table has it (design, certificate ladder, continuous simulation)."""
    from bench.pipeline import RunOptions
    from bench.registry import PLANTS

    out = evaluate(PLANTS.create(plant_id), design_id, RunOptions(t_final=t_final, seed=seed))
    return replace(out, trajectory=None, plant=None)


def _sampling_task(prior, n_ics: int, box: float | None, seed: int, disc: str, h_range, rtol: float,
                   t_final: float | None) -> dict:
    """One (plant, design with fixed gains): h_lin, the bisection of h_max, settling vs h."""
    from bench.registry import PLANTS

    t0 = time.perf_counter()
    plant_id, design_id = prior.record["plant"], prior.record["design"]
    plant = PLANTS.create(plant_id)
    K, F = prior.result.K, prior.result.F
    b = default_box(plant) if box is None else box
    X, XH = random_ics(plant, n_ics, b, seed)
    X = np.concatenate([plant.x0[:, None], X], axis=1)
    XH = np.concatenate([plant.x_hat0[:, None], XH], axis=1)
    h_lin = linear_h_bound(plant, K, F, disc)
    start = h_lin / 2 if 0 < h_lin < math.inf else (1e-3 if h_lin == 0 else 1.0)

    check = functools.partial(_check_h, plant, prior, X, XH, disc=disc, t_final=t_final, seed=seed)
    out = bisect_largest(check, start, bounds=h_range, rtol=rtol, max_doublings=6)
    evals = out["evals"]
    # settling time vs h: a few periods below the bound (not below 2e-4 s, for cost)
    if math.isfinite(out["lo"]):
        done = {e["h"] for e in evals}
        for frac in (1 / 8, 1 / 4, 1 / 2):
            h = out["lo"] * frac
            if h >= 2e-4 and h not in done:
                evals.append(check(h))
    for e in evals:
        e.update(plant=plant_id, design=design_id)
    rec = prior.record
    row = {"plant": plant_id, "design": design_id, "status": rec["status"], "certified": rec["certified"],
           "decay_rate": rec["decay_rate"], "h_max": out["lo"], "h_fail": out["hi"], "kind": out["kind"],
           "h_lin": h_lin, "n_evals": len(evals), "N_ics": X.shape[1], "box": b,
           "settling_x_cont": rec["settling_x_s"] if rec["converged"] else math.nan,
           "cont_converged": rec["converged"], "horizon_s": evals[0]["horizon_s"] if evals else math.nan,
           "wall_s": time.perf_counter() - t0, "reason": ""}
    at = [e for e in evals if e["h"] == out["lo"]]
    if at:
        row.update(settling_x_at_hmax=at[0]["settling_x_plant"], settling_x_median_at_hmax=at[0]["settling_x_median"])
    f = next((e for e in evals if e["h"] == out["hi"]), None)
    if f is not None:
        row["at_fail"] = (f"{f['n_converged']}/{f['N']} converged, {f['n_diverged']} diverged, worst final "
                          f"||x|| {fmt(f['worst_final_x'])}")
    return {"row": row, "evals": evals}


@dataclass
class SamplingResult(StudyResult):
    """What :func:`run_sampling` produced: the rows and every evaluation of the bisections."""

    evals: list[dict] = field(default_factory=list)


@study(DEFAULT_PLANTS)
def run_sampling(run: StudyRun, *, required: list[str] | tuple[str, ...] = (), n_ics: int = 20,
                 box: float | None = None, seed: int = 0, discretisation: str = "zoh",
                 h_range: tuple[float, float] | None = None, rtol: float = 0.01,
                 t_final: float | None = None) -> SamplingResult:
    """Largest sample period per (plant, design with fixed gains).

    Parameters
    ----------
    plant_ids : list of str, optional
        Default :data:`DEFAULT_PLANTS`.
    design_ids : list of str, optional
        Default: every registered design (those without fixed gains get a row with the reason).
    required : sequence of str
        Designs named explicitly: one without fixed gains raises :class:`StudyError`.
    n_ics : int
        Random initial conditions besides the plant's own (>= 1).
    box : float, optional
        Half-width of the initial-condition box (default: the plant's initial-condition scale).
    seed : int
    discretisation : {"zoh", "euler"}
    h_range : (float, float), optional
        Bisection bounds on h (default: bracketed from ``h_lin / 2``).
    rtol : float
    t_final : float, optional
    jobs, progress
        Worker processes; ``progress(done, total, label)``.

    Returns
    -------
    SamplingResult

    Raises
    ------
    StudyError
        Bad box, count, bounds, discretisation, or a required design without fixed gains.
    """
    from bench.batch import DISCRETISATIONS

    n_ics = check_count("n_ics", n_ics)
    box = check_box("box", box)
    h_range = check_range("h_range", h_range)
    if discretisation not in DISCRETISATIONS:
        raise StudyError("discretisation", f"must be one of {DISCRETISATIONS}, got {discretisation!r}")
    check_rtol(rtol)
    check_horizon(t_final)
    ordered, evals = _bisect_pairs(run, required, (n_ics, box, seed, discretisation, h_range, rtol, t_final))
    settings = {"n_ics": n_ics, "box": box if box is not None else "plant's initial-condition scale",
                "seed": seed, "discretisation": discretisation,
                "h_range": h_range or "automatic (from h_lin / 2)", "rtol": rtol,
                "t_final": t_final if t_final is not None else "plant's", "jobs": run.jobs}
    return SamplingResult(ordered, settings, run.wall_s(), evals=evals)


def _bisect_pairs(run: StudyRun, required, args: tuple) -> tuple[list[dict], list[dict]]:
    """Design every pair, then bisect h where there are fixed gains: rows (plant x design order), evaluations."""
    from bench.executors import executor

    t_final, seed, plant_ids, design_ids = args[-1], args[2], run.plant_ids, run.design_ids
    pairs = [(pid, did) for pid in plant_ids for did in design_ids]
    with executor(run.jobs) as ex:
        designed = map_tasks(ex, _design_task, [((pid, did), (pid, did, t_final, seed)) for pid, did in pairs])
        rows = {key: row for key in pairs if (row := unsimulated_row(*key, designed[key])) is not None}
        for (pid, did), row in rows.items():  # a design the caller named must have fixed gains on every plant
            if did in required and row["status"] == "no fixed gains":
                est = type(designed[(pid, did)].result.estimator).__name__
                raise StudyError("design", f"{did!r} has no fixed gains (K, F) on {pid!r} (its estimator is {est}): "
                                           "a sampling study needs fixed gains")
        tasks = [(key, (designed[key], *args)) for key in pairs if key not in rows]
        done = map_tasks(ex, _sampling_task, tasks, run.progress,
                         lambda key, r: f"{key[0]} x {key[1]}: h_max {fmt(r['row']['h_max'])}")
    evals: list[dict] = []
    for key, r in done.items():
        rows[key] = r["row"]
        evals.extend(r["evals"])
    evals.sort(key=lambda e: (plant_ids.index(e["plant"]), design_ids.index(e["design"]), e["h"]))
    return [rows[key] for key in pairs], evals


def _draw(pid: str, rows: list[dict], evals: list[dict]):
    """The figure of one plant: settling time vs h per design."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 4.2), constrained_layout=True)
    drawn = [x for x in rows if "h_max" in x]
    styles = design_styles(r["design"] for r in drawn)  # one colour per design, as in every figure of the suite
    for r in drawn:
        pts = sorted((e["h"], e["settling_x_plant"]) for e in evals
                     if e["plant"] == pid and e["design"] == r["design"] and math.isfinite(e["settling_x_plant"]))
        st = styles[r["design"]]
        color = st["color"]
        if pts:
            ax.plot([p[0] for p in pts], [p[1] for p in pts], marker=st["marker"], ls="-", color=color, ms=4,
                    label=r["design"])
        if math.isfinite(r.get("settling_x_cont", math.nan)):
            ax.axhline(r["settling_x_cont"], color=color, ls=":", lw=0.8)
        if math.isfinite(r.get("h_max", math.nan)):
            ax.axvline(r["h_max"], color=color, ls="--", lw=0.8)
    ax.set_xscale("log")
    ax.set(xlabel="sample period h [s] (log); dashed: largest converging h", ylabel="2 % settling time of ||x|| [s]",
           title=f"{pid}: settling time vs h (dotted: continuous loop)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    return fig


def write_sampling(result: SamplingResult, out_dir: str, command: str, *, figures: bool = True):
    """Write ``STUDY_sampling.md``, its CSVs and figures atomically; return the markdown's path."""
    rows = result.rows
    trows = [{**r, "h_max_s": bracket_cell(r.get("kind", ""), r.get("h_max"), r.get("h_fail"))} for r in rows]
    cols = ["plant", "design", "status", "h_max_s", "h_fail", "h_lin", "settling_x_cont", "settling_x_at_hmax",
            "settling_x_median_at_hmax", "at_fail", "n_evals", "wall_s"]
    heads = ["plant", "design", "status", "largest converging h [s]", "first failing h", "h_lin (rho = 1)",
             "settling, continuous [s]", "settling at h_max (plant IC)", "median settling at h_max (all ICs)",
             "at the first failing h", "sims", "wall s"]
    skipped = [r for r in rows if "h_max" not in r]
    disc = result.settings["discretisation"]
    lines = [
        study_header("Study: digital implementation (largest sample period)", command, result.settings, result.wall_s),
        "The controller and the observer run at period h, the plant is continuous: at `t_k = k h` the output is "
        "sampled, `u_k = F x_hat_k` is held and the observer is advanced by its "
        + ("**zoh** discretisation (its model integrated over the period, input and output injection held)"
           if disc == "zoh" else "**forward Euler** discretisation")
        + "; the gains are the continuous designs' own. The batch is integrated between samples by fixed-step RK4.",
        "",
        "- **largest converging h**: bisection (1 % relative) of the largest h at which *every* initial condition "
        "(the plant's and the seeded random ones) converges within the horizon (final `||x||`, `||e||` at most 1e-3 "
        "of their peaks);",
        "- **h_lin**: the first h at which the one-period matrix of the loop linearised at the origin reaches "
        "spectral radius 1 (`h_max <= h_lin` expected);",
        "- settling times: 2 % settling of `||x||` at the sample instants, from the plant's initial conditions.",
        "",
        "## Largest sample period per design",
        "",
        md_table([r for r in trows if "h_max" in r], cols, heads),
        "",
    ]
    slow = [r for r in rows if "h_max" in r and not r.get("cont_converged", True)]
    if slow:
        lines += ["The continuous loop itself does not converge within the horizon (same criterion) from the plant's "
                  "initial conditions, so no h can pass: " + ", ".join(f"{r['plant']} x {r['design']}" for r in slow)
                  + ".", ""]
    lines += skipped_lines(skipped, width=300)
    tables = {"study_sampling": rows, "study_sampling_evaluations": result.evals}
    return write_plant_study(out_dir, "sampling", lines, tables, rows, _draw, result.evals,
                             heading="## Settling time vs h", figures=figures)
