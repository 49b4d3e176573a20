"""Measurement noise: RMS estimation error and final state norm vs noise level, Luenberger vs EKF.

For each plant and noise level sigma, every design with a controller is simulated by the harness's noisy
path (:func:`bench.simulate.simulate_controller`, seeded noise ``v ~ N(0, sigma^2 I)`` on ``y = C x + v``);
the EKF is also run with its measurement variance matched to the noise (``r = sigma^2``, :data:`MATCHED_EKF`).
The gains are designed once per pair and reused at every level; the numbers equal those of
``python -m bench run --noise SIGMA --seed SEED``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from bench import checks
from bench.report import design_styles
from bench.studies._common import (StudyError, StudyResult, StudyRun, check_horizon, check_levels, evaluate, fmt,
                                   md_table, pyplot, skipped_lines, study, study_header, unsimulated_row,
                                   write_plant_study)

__all__ = ["run_noise", "write_noise"]

DEFAULT_LEVELS = tuple(float(v) for v in np.logspace(-4, -1, 7))
DEFAULT_PLANTS = ("flexible_link", "random_osl_v1")
#: Label of the EKF whose measurement variance r is matched to the noise level.
MATCHED_EKF = "lqr+ekf (r = sigma^2)"


def _noise_task(prior, label: str, sigma: float, seed: int, noise_dt: float, t_final: float | None) -> dict:
    """One pair at one noise level: the pipeline with ``noise = sigma``, design and certificate re-used."""
    from bench.pipeline import RunOptions
    from bench.registry import PLANTS

    plant = PLANTS.create(prior.record["plant"])
    options = RunOptions(noise=sigma, seed=seed, noise_dt=noise_dt, t_final=t_final, certificate="none")
    rec = evaluate(plant, label, options, prior=prior).record
    est = "EKF" if prior.result.estimator is not None else "fixed K"
    keep = ("sim_status", "converged", "rms_e", "final_x", "final_e", "settling_x_s", "peak_u", "horizon_s", "sim_s")
    return {"plant": rec["plant"], "design": label, "noise": sigma, "estimator": est, **{k: rec[k] for k in keep}}


def _priors(plant_ids, design_ids, levels, matched_ekf: bool, t_final, seed: int = 0) -> tuple[list, list]:
    """Design and certify each pair once (the pipeline without simulation); the jobs per level."""
    from bench.pipeline import RunOptions
    from bench.registry import PLANTS

    skipped, jobs_list = [], []
    for pid in plant_ids:
        plant = PLANTS.create(pid)
        for did in design_ids:
            prior = evaluate(plant, did, RunOptions(simulate=False, t_final=t_final, seed=seed))
            skip = unsimulated_row(pid, did, prior, need_gains=False)
            if skip is not None:
                skipped.append(skip)
                continue
            res = prior.result
            prior.plant = None
            for sig in levels:
                jobs_list.append((prior, did, sig))
                if res.estimator is not None and matched_ekf:
                    matched = replace(prior, result=replace(res, estimator=replace(res.estimator, r=sig * sig)))
                    jobs_list.append((matched, MATCHED_EKF, sig))
    return skipped, jobs_list


@dataclass
class NoiseResult(StudyResult):
    """What :func:`run_noise` produced: the rows and the pairs not simulated (with why)."""

    skipped: list[dict] = field(default_factory=list)


@study(DEFAULT_PLANTS)
def run_noise(run: StudyRun, *, levels: tuple[float, ...] = DEFAULT_LEVELS, seed: int = 0, matched_ekf: bool = True,
              noise_dt: float = 0.01, t_final: float | None = None) -> NoiseResult:
    """RMS estimation error and final state norm vs noise level for every design with a controller.

    Parameters
    ----------
    plant_ids, design_ids : list of str, optional
        Default :data:`DEFAULT_PLANTS` and every registered design (those without a controller are listed).
    levels : sequence of float
        Noise standard deviations (each finite and > 0).
    seed : int
        Seed of the noise (the same sequence for every design and level, scaled by sigma).
    matched_ekf : bool
        Also run the EKF with ``r = sigma^2``.
    noise_dt : float
        Hold interval of the noise for fixed-gain observers.
    t_final : float, optional
    jobs, progress
        Worker processes; ``progress(done, total, label)``.

    Returns
    -------
    NoiseResult

    Raises
    ------
    StudyError
        A bad noise level, ``noise_dt`` or horizon.
    """
    levels = check_levels("levels", levels)
    checks.real("noise_dt", noise_dt, lo=0.0, strict=True, error=StudyError)
    check_horizon(t_final)
    skipped, jobs_list = _priors(run.plant_ids, run.design_ids, levels, matched_ekf, t_final, seed)
    tasks = [((prior.record["plant"], label, s), (prior, label, s, seed, noise_dt, t_final))
             for prior, label, s in jobs_list]
    rows = run.map(_noise_task, tasks, lambda key, r: f"{r['plant']} x {r['design']} sigma {r['noise']:g}: "
                                                      f"rms_e {fmt(r['rms_e'])}")
    ordered = [rows[(prior.record["plant"], label, s)] for prior, label, s in jobs_list]
    settings = {"levels": ", ".join(f"{v:.3g}" for v in levels), "seed": seed, "noise_dt": noise_dt,
                "matched EKF": matched_ekf, "t_final": t_final if t_final is not None else "plant's", "jobs": run.jobs}
    return NoiseResult(ordered, settings, run.wall_s(), skipped=skipped)


def _draw(pid: str, rows: list[dict]):
    """The figure of one plant: RMS error and final ||x|| vs the noise level per design."""
    plt = pyplot()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.3), constrained_layout=True)
    designs = list(dict.fromkeys(r["design"] for r in rows))
    styles = design_styles(designs)  # distinct hues, line styles and markers (no light/dark pairs of one hue)
    for did in designs:
        sub = sorted((r for r in rows if r["design"] == did), key=lambda r: r["noise"])
        st = styles[did]
        kw = dict(ls=st["linestyle"], marker=st["marker"], ms=4, color=st["color"], label=did)
        a1.loglog([r["noise"] for r in sub], [r["rms_e"] for r in sub], **kw)
        a2.loglog([r["noise"] for r in sub], [r["final_x"] for r in sub], **kw)
    a1.set(xlabel="noise standard deviation sigma", ylabel="RMS ||e|| (second half of the horizon)",
           title=f"{pid}: estimation error")
    a2.set(xlabel="noise standard deviation sigma", ylabel="final ||x||", title=f"{pid}: final state norm")
    for a in (a1, a2):
        a.grid(True, which="both", alpha=0.3)
    a2.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    return fig


def _plant_section(pid: str, sub: list[dict], levels: list[float]) -> list[str]:
    """The markdown of one plant: a table per metric, the best estimator per level, its figure, notes."""
    designs = list(dict.fromkeys(r["design"] for r in sub))
    by = {(r["design"], r["noise"]): r for r in sub}
    lines = []
    for metric, title in (("rms_e", "RMS estimation error"), ("final_x", "final ||x||")):
        rows = [{"design": did, **{s: by[(did, s)][metric] for s in levels if (did, s) in by}} for did in designs]
        heads = ["design", *(f"sigma {s:.3g}" for s in levels)]
        lines += [f"## {pid}: {title}", "", md_table(rows, ["design", *levels], heads), ""]
    lines += [f"## {pid}: best estimator per level", "",
              md_table(_best_per_level(sub, levels), ["noise", "best", "best_rms_e", "best_luenberger",
                                                      "luenberger_rms_e", "best_ekf", "ekf_rms_e"],
                       ["sigma", "lowest RMS ||e||", "its RMS", "best Luenberger-type", "its RMS", "best EKF",
                        "its RMS"]), "",
              f"![{pid}](figures/study_noise_{pid}.png)", ""]
    slow = _transient_dominated(by, designs, levels)
    if slow:
        lines += ["RMS not proportional to sigma at the smallest level (RMS / sigma more than 3 x its value at the "
                  "largest level): the transient has not died out by mid-horizon, so the error there is the slow "
                  "convergence, not the noise: " + ", ".join(slow) + ".", ""]
    nc = [r for r in sub if not r["converged"]]
    if nc:
        lines += ["Not settled (2 % settling of `||x||` or `||e||` not reached within the horizon): "
                  + ", ".join(f"{r['design']} at sigma {r['noise']:.3g}" for r in nc) + ".", ""]
    return lines


def _best_per_level(sub: list[dict], levels: list[float]) -> list[dict]:
    """Per level: the design of lowest RMS error overall, among fixed-gain observers and among EKFs."""
    best = []
    for s in levels:
        cand = [r for r in sub if r["noise"] == s and math.isfinite(r["rms_e"])]
        row = {"noise": s}
        for name, rms, kind in (("best", "best_rms_e", None), ("best_luenberger", "luenberger_rms_e", "fixed K"),
                                ("best_ekf", "ekf_rms_e", "EKF")):
            b = min((r for r in cand if kind in (None, r["estimator"])), key=lambda r: r["rms_e"],
                    default={"design": "", "rms_e": math.nan})
            row.update({name: b["design"], rms: b["rms_e"]})
        if cand:
            best.append(row)
    return best


def _transient_dominated(by: dict, designs: list[str], levels: list[float]) -> list[str]:
    """Designs whose RMS / sigma at the smallest level exceeds 3 x its value at the largest (none with one level)."""
    slow = []
    for did in designs:
        if did == MATCHED_EKF:  # its tuning r = sigma^2 changes with the level: not comparable
            continue
        lo, hi = by.get((did, levels[0])), by.get((did, levels[-1]))
        if lo and hi and all(math.isfinite(v) for v in (lo["rms_e"], hi["rms_e"])) and hi["rms_e"] > 0 and \
                lo["rms_e"] / levels[0] > 3 * hi["rms_e"] / levels[-1]:
            slow.append(did)
    return slow


def write_noise(result: NoiseResult, out_dir: str, command: str, *, figures: bool = True):
    """Write ``STUDY_noise.md``, its CSV and figures atomically; return the markdown's path."""
    rows = result.rows
    plants = list(dict.fromkeys(r["plant"] for r in rows))
    levels = sorted({r["noise"] for r in rows})
    lines = [
        study_header("Study: measurement noise (Luenberger-type observers vs EKF)", command, result.settings,
                     result.wall_s),
        "Seeded Gaussian measurement noise of standard deviation sigma on `y = C x + v`, simulated by the harness's "
        "noisy path (`bench.simulate.simulate_controller`): fixed-gain observers continuous with the noise held over "
        f"{result.settings['noise_dt']} s, the EKF at its own sample time with `u_k` held. `rms_e`: RMS of "
        "`||x - x_hat||` over the second half of the horizon; `final_x`: final `||x||`. Same numbers as "
        "`python -m bench run --noise SIGMA --seed SEED`. "
        f"`{MATCHED_EKF}` is the EKF with its measurement variance set to the noise variance (default r = 1e-4).",
        "",
    ]
    for pid in plants:
        lines += _plant_section(pid, [r for r in rows if r["plant"] == pid], levels)
    lines += skipped_lines(result.skipped, heading="## Not simulated", width=250)
    return write_plant_study(out_dir, "noise", lines, {"study_noise": rows}, rows, _draw, heading=None, figures=figures)
