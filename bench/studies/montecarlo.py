"""Region of convergence: N seeded random initial conditions per (plant, design), simulated as one batch.

Per plant, N initial conditions (x and x_hat uniform in ``[-box, box]^n``) are drawn once; every design with
fixed gains is simulated from all of them by one ``solve_ivp`` call (:func:`bench.batch.simulate_batch`).
Per design: the fraction converging (the criterion of :mod:`bench.metrics`), the worst final ``||x||`` and
the distribution of the 2 % settling time of ``||x||``, beside the certificate (with local constants it
proves convergence only from its level set).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from bench.studies._common import (StudyResult, StudyRun, check_box, check_count, check_horizon, default_box, evaluate,
                                   fmt, md_table, pyplot, random_ics, skipped_lines, study, study_header,
                                   unsimulated_row, write_plant_study)

__all__ = ["run_montecarlo", "write_montecarlo"]


def _mc_task(plant_id: str, design_id: str, n: int, box: float | None, seed: int, t_final: float | None,
             method: str, rtol: float, atol: float) -> dict:
    """One (plant, design): the pipeline with a batch of ``n`` initial conditions."""
    from bench.batch import BATCH_OPTIONS
    from bench.pipeline import RunOptions, Scenario
    from bench.registry import PLANTS

    t0 = time.perf_counter()
    plant = PLANTS.create(plant_id)
    b = default_box(plant) if box is None else box
    row = {"plant": plant_id, "design": design_id, "N": n, "box": b, "seed": seed}
    X, XH = random_ics(plant, n, b, seed)
    first = evaluate(plant, design_id, RunOptions(t_final=t_final, simulate=False, seed=seed))
    skip = unsimulated_row(plant_id, design_id, first)
    if skip is not None:
        row.update(status=skip["status"], reason=skip["reason"])
        return {"row": row, "settling": np.array([])}
    scenario = Scenario(x0=X, x_hat0=XH, options=replace(BATCH_OPTIONS, method=method, rtol=rtol, atol=atol))
    out = evaluate(plant, design_id, RunOptions(t_final=t_final, seed=seed), prior=first, scenario=scenario)
    rec, m, tr = out.record, out.metrics, out.trajectory
    if m is None:
        row.update(status="error", reason=rec["reason"])
        return {"row": row, "settling": np.array([])}
    conv = m["converged"]
    sx = m["settling_x_s"][conv]
    q = (lambda p: float(np.quantile(sx, p))) if sx.size else (lambda p: math.nan)
    fx = np.where(tr.diverged, np.inf, m["final_x"])
    row.update(status=rec["status"], reason="" if tr.status == "ok" else f"integration {tr.status}: {tr.message}",
               certified=rec["certified"], cert_level=rec["cert_level"], decay_rate=rec["decay_rate"],
               region="global" if not math.isfinite(rec["cert_radius"]) else f"||x|| <= {rec['cert_radius']:g}",
               horizon_s=rec["horizon_s"], frac_converged=float(conv.mean()), n_converged=int(conv.sum()),
               n_diverged=int(tr.diverged.sum()), worst_final_x=float(np.nanmax(fx)),
               median_final_x=float(np.nanmedian(fx)), settling_min=q(0.0), settling_p10=q(0.1),
               settling_median=q(0.5), settling_p90=q(0.9), settling_max=q(1.0),
               peak_x_max=float(np.nanmax(m["peak_x"])), sim_s=tr.wall_s, nfev=tr.nfev, method=tr.method,
               design_s=rec["design_s"], wall_s=time.perf_counter() - t0)
    if rec["certified"] and math.isfinite(rec["cert_radius"]):
        # a local certificate proves convergence only from its level set V <= level_set: count those members
        Z = np.vstack([X, X - XH])
        inside = np.einsum("ij,ij->j", Z, first.certificate.best.P @ Z) <= first.record["level_set"]
        row.update(n_in_level_set=int(inside.sum()), frac_converged_in_level_set=float(conv[inside].mean())
                   if inside.any() else math.nan)
    return {"row": row, "settling": sx}


@dataclass
class MonteCarloResult(StudyResult):
    """What :func:`run_montecarlo` produced: the rows and the settling times per plant x design."""

    settling: dict = field(default_factory=dict)


@study()
def run_montecarlo(run: StudyRun, *, n: int = 1000, box: float | None = None, seed: int = 0,
                   t_final: float | None = None, method: str = "auto", rtol: float = 1e-6,
                   atol: float = 1e-9) -> MonteCarloResult:
    """Simulate N seeded random initial conditions per (plant, design) as one vectorised batch.

    Parameters
    ----------
    plant_ids, design_ids : list of str, optional
        Default: every registered plant and design (designs without fixed gains get a row saying so).
    n : int
        Initial conditions per plant (>= 1).
    box : float, optional
        Half-width of the box (default: each plant's initial-condition scale).
    seed : int
        Seed of the initial conditions (the same draws for every design of a plant).
    t_final : float, optional
        Horizon (default: each plant's).
    method, rtol, atol
        ``solve_ivp`` settings of the batch (``"auto"``: :func:`bench.simulate.choose_method`).
    jobs, progress
        Worker processes; ``progress(done, total, label)``.

    Returns
    -------
    MonteCarloResult

    Raises
    ------
    StudyError
        Bad ``n``, box or horizon.
    """
    n = check_count("n", n)
    box = check_box("box", box)
    check_horizon(t_final)
    pairs = [(pid, did) for pid in run.plant_ids for did in run.design_ids]
    out = run.map(_mc_task, [(key, (*key, n, box, seed, t_final, method, rtol, atol)) for key in pairs],
                  lambda key, r: f"{key[0]} x {key[1]}: {fmt(r['row'].get('frac_converged', math.nan))}")
    rows = [out[key]["row"] for key in pairs]
    settling = {key: out[key]["settling"] for key in pairs}
    settings = {"N": n, "box": box if box is not None else "plant's initial-condition scale", "seed": seed,
                "t_final": t_final if t_final is not None else "plant's", "method": method, "rtol": rtol,
                "atol": atol, "jobs": run.jobs}
    return MonteCarloResult(rows, settings, run.wall_s(), settling=settling)


def _draw(pid: str, sim: list[dict], settling: dict):
    """The figure of one plant: fraction converging and settling times per simulated design."""
    plt = pyplot()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 0.35 * max(len(sim), 3) + 1.8), constrained_layout=True,
                                 gridspec_kw={"width_ratios": [1, 2]})
    names = [r["design"] for r in sim]
    y = np.arange(len(sim))
    a1.barh(y, [r["frac_converged"] for r in sim], color=["tab:green" if r["certified"] else "tab:orange"
                                                            for r in sim])
    a1.set_yticks(y, names)
    a1.invert_yaxis()
    a1.set(xlim=(0, 1.05), xlabel="fraction converging", title="green: certified; orange: not")
    data = [settling[(pid, r["design"])] for r in sim]
    nonempty = [(i, d) for i, d in enumerate(data) if d.size]
    if nonempty:
        import matplotlib

        major, minor = (int(v) for v in matplotlib.__version__.split(".")[:2])
        horiz = {"orientation": "horizontal"} if (major, minor) >= (3, 10) else {"vert": False}
        a2.boxplot([d for _, d in nonempty], positions=[i for i, _ in nonempty], widths=0.6, whis=(0, 100),
                   **horiz)
    a2.set_yticks(y, names)
    a2.set_ylim(len(sim) - 0.5, -0.5)
    a2.set(xlabel="2 % settling time of ||x|| [s] (converging ICs; whiskers min-max)",
           title=f"{pid}: {sim[0]['N']} initial conditions in "
                 f"[-{fmt(sim[0]['box'])}, {fmt(sim[0]['box'])}]^n")
    a2.grid(True, axis="x", alpha=0.3)
    return fig


def write_montecarlo(result: MonteCarloResult, out_dir: str, command: str, *, figures: bool = True):
    """Write ``STUDY_montecarlo.md``, its CSV and figures atomically; return the markdown's path."""
    rows = result.rows
    sim = [r for r in rows if "frac_converged" in r]
    skipped = [r for r in rows if "frac_converged" not in r]
    cols = ["plant", "design", "certified", "region", "frac_converged", "n_diverged", "worst_final_x",
            "settling_min", "settling_median", "settling_p90", "settling_max", "method", "sim_s"]
    heads = ["plant", "design", "certified", "constants hold", "fraction converged within the horizon", "diverged",
             "worst final ||x||", "settling min [s]", "median", "p90", "max", "method", "batch sim s"]
    warn = [r for r in sim if r["certified"] and r["region"] == "global" and r["frac_converged"] < 1]
    lines = [
        study_header("Study: region of convergence (Monte Carlo)", command, result.settings, result.wall_s),
        "For each plant, N initial conditions (x and x_hat independent, uniform in `[-box, box]^n`, seeded; the same "
        "draws for every design) are simulated for each design with fixed gains as **one** vectorised ODE "
        "(`bench.batch.py`: DOP853, or BDF with the batch's block-diagonal Jacobian sparsity when the loop is "
        "stiff). Converged within the horizon: final `||x||` and `||e||` at most 1e-3 of their peaks (a slow but "
        "converging member counts as not converged). Settling: 2 % settling time of `||x||`, converging members only.",
        "",
        md_table(sim, cols, heads),
        "",
    ]
    if warn:
        lines += ["**Certified with global constants but not all converging** (a horizon too short for the slowest "
                  "initial conditions, or a numerical issue): " + ", ".join(f"{r['plant']} x {r['design']}"
                                                                             for r in warn), ""]
    lines += skipped_lines(skipped, width=250)
    return write_plant_study(out_dir, "montecarlo", lines, {"study_montecarlo": rows}, sim, _draw, result.settling, figures=figures)
