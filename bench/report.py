"""Reports: markdown tables and figures rendered from a run's records, written atomically.

``write_report`` renders everything into a temporary folder next to the destination and only
then moves the files into place (``os.replace``), REPORT.md last: an exception while rendering
leaves the previous report untouched.
"""

from __future__ import annotations

import json
import math
import os
import platform
import shutil
import sys
import tempfile
from importlib import metadata
from pathlib import Path

import numpy as np

from bench.harness import RunResult

__all__ = ["git_revision", "package_versions", "render_markdown", "write_report"]

#: Plants that get per-design figures of states, estimates and errors (like the paper's Figures
#: 2-5); every plant gets the norm comparison figure.
FIGURE_PLANTS = ("flexible_link",)

_PACKAGES = ("numpy", "scipy", "cvxpy", "clarabel", "scs", "control", "filterpy", "pandas", "matplotlib", "tabulate")


def package_versions() -> dict[str, str]:
    """Versions of Python and of the packages a run depends on."""
    out = {"python": platform.python_version()}
    for name in _PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def git_revision() -> dict[str, object]:
    """``{"commit": sha or None, "dirty": bool or None}`` of the checkout holding this package.

    None when the package is not in a git checkout (an installed wheel) or git is missing;
    ``dirty`` is True when tracked files differ from the commit (then the commit alone does not
    reproduce the run). Read-only: ``git rev-parse`` and ``git status`` without optional locks.
    """
    import subprocess

    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "GIT_OPTIONAL_LOCKS": "0"}

    def git(*args: str) -> str | None:
        try:
            done = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, timeout=10,
                                  env=env, check=False)
        except (OSError, subprocess.SubprocessError):
            return None
        return done.stdout.strip() if done.returncode == 0 else None

    top = git("rev-parse", "--show-toplevel")
    if top is None or Path(top).resolve() != root:
        return {"commit": None, "dirty": None}
    status = git("status", "--porcelain", "--untracked-files=no")
    return {"commit": git("rev-parse", "HEAD"), "dirty": None if status is None else bool(status)}


def format_cell(v, spec: str = ".3g") -> str:
    """Format a markdown table cell: floats with ``spec`` (blank if NaN, +-inf shown), bools as
    yes/no, text with ``|`` escaped and newlines flattened."""
    if v is None:
        return ""
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        v = float(v)
        if math.isnan(v):
            return ""
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return format(v, spec)
    return str(v).replace("|", "\\|").replace("\n", " ")


_fmt = format_cell


def _table(df, columns: list[str], headers: list[str] | None = None) -> str:
    rows = [[_fmt(v) for v in row] for row in df[columns].itertuples(index=False)]
    headers = headers or columns
    out = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out)


def _cell(rec) -> str:
    s = rec["status"]
    if s == "feasible":
        tags = ["cert" if rec["certified"] else "not cert", "conv" if rec["converged"] else "no conv"]
        return f"feasible ({', '.join(tags)})"
    return s


def _feasibility(df) -> str:
    plants = list(dict.fromkeys(df["plant"]))
    designs = list(dict.fromkeys(df["design"]))
    lines = ["| plant | " + " | ".join(designs) + " |", "|---|" + "|".join("---" for _ in designs) + "|"]
    for p in plants:
        sub = df[df["plant"] == p].set_index("design")
        cells = [_cell(sub.loc[d]) if d in sub.index else "" for d in designs]
        lines.append(f"| {p} | " + " | ".join(cells) + " |")
    reasons = df[(df["reason"] != "") & df["reason"].notna()]
    if len(reasons):
        lines += ["", "Reasons:", ""]
        for r in reasons.itertuples(index=False):
            lines.append(f"- **{r.plant} x {r.design}** ({r.status}): {_fmt(r.reason)}")
    return "\n".join(lines)


def _constants_table(result: RunResult) -> str:
    lines = [
        "| plant | constant | claimed | analytic | sampled (lower bound) | used | flag |",
        "|---|---|---|---|---|---|---|",
    ]
    region = lambda r: "everywhere" if r is None else f"\\|\\|x\\|\\| <= {r:g}"  # noqa: E731
    for pid, rep in result.constants.items():
        for name in ("alpha", "rho", "beta", "gamma"):
            claimed = getattr(rep.claimed, name)
            analytic = getattr(rep.analytic, name) if rep.analytic is not None else None
            sampled = getattr(rep.sampled, name)
            used = getattr(rep.valid, name)
            src = rep.source.get(name, "") if name != "gamma" else ""
            v = rep.violated(name)
            flags = [f"VIOLATED: {v.describe()}"] if v else []
            # a sample above an analytic bound means the plant's bound is wrong (beta only when
            # it was sampled at the analytic gamma)
            comparable = name != "gamma" and (name != "beta" or (rep.analytic is not None
                                                                 and rep.analytic.gamma == rep.sampled.gamma))
            if comparable and analytic is not None and sampled is not None and math.isfinite(sampled) and \
                    sampled > analytic + 1e-7 * max(1.0, abs(analytic)):
                flags.append(f"ANALYTIC BOUND EXCEEDED by a sample ({sampled:.4g} > {analytic:.4g})")
            if name == "gamma":
                sampled_s = f"{_fmt(sampled)} (fixed)"
            else:
                sampled_s = _fmt(sampled)
            lines.append(
                f"| {pid} | {name} | {_fmt(claimed)} | {_fmt(analytic)} | {sampled_s} | "
                f"{_fmt(used)}{f' ({src})' if src else ''} | {'; '.join(flags)} |"
            )
        a_radius = rep.analytic.radius if rep.analytic is not None else None
        has_claims = any(getattr(rep.claimed, k) is not None for k in ("alpha", "rho", "beta"))
        if rep.claimed.radius is not None or rep.valid.radius is not None or a_radius is not None:
            lines.append(
                f"| {pid} | region | {region(rep.claimed.radius) if has_claims else ''} | "
                f"{region(a_radius) if rep.analytic is not None else ''} | {region(rep.sampled.radius)} | "
                f"{region(rep.valid.radius)} | |"
            )
    for pid, err in result.constants_errors.items():
        lines.append(f"| {pid} | (error) | | | | | {_fmt(err)} |")
    return "\n".join(lines)


def _figures(result: RunResult, figdir: Path) -> list[tuple[str, str]]:
    """Draw the figures; return (caption, relative path) pairs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    made: list[tuple[str, str]] = []
    by_plant: dict[str, list] = {}
    for o in result.outcomes:
        if o.trajectory is not None and o.record["converged"] and o.plant is not None:
            by_plant.setdefault(o.plant.id, []).append(o)
    for pid, outs in by_plant.items():
        # comparison of norms across designs
        fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), constrained_layout=True)
        for o in outs:
            tr = o.trajectory
            axes[0].semilogy(tr.t, np.maximum(np.linalg.norm(tr.x, axis=0), 1e-16), label=o.record["design"])
            axes[1].semilogy(tr.t, np.maximum(np.linalg.norm(tr.e, axis=0), 1e-16), label=o.record["design"])
        axes[0].set(title=f"{pid}: ||x(t)||", xlabel="t [s]")
        axes[1].set(title=f"{pid}: ||e(t)|| = ||x - x_hat||", xlabel="t [s]")
        for ax in axes:
            ax.grid(True, which="both", alpha=0.3)
        axes[0].legend(fontsize=8)
        name = f"{pid}__norms.png"
        fig.savefig(figdir / name, dpi=110)
        plt.close(fig)
        made.append((f"{pid}: state and error norms of every converging design (log scale)", f"figures/{name}"))
        if pid not in FIGURE_PLANTS:
            continue
        for o in outs:
            tr, did = o.trajectory, o.record["design"]
            n = tr.x.shape[0]
            settle = [o.record["settling_x_s"], o.record["settling_e_s"]]
            settle = [s for s in settle if isinstance(s, float) and math.isfinite(s)]
            t_show = min(float(tr.t[-1]), max(1.0, 2.0 * max(settle))) if settle else float(tr.t[-1])
            fig, axes = plt.subplots(2, n, figsize=(3.2 * n, 5.2), constrained_layout=True, squeeze=False)
            for i in range(n):
                ax = axes[0, i]
                ax.plot(tr.t, tr.x[i], label=f"x{i + 1}")
                ax.plot(tr.t, tr.x_hat[i], "--", label=f"x_hat{i + 1}")
                ax.set(title=f"x{i + 1} and its estimate", xlabel="t [s]", xlim=(0, t_show))
                ax.legend(fontsize=8)
                ax.grid(True, alpha=0.3)
                ax = axes[1, i]
                ax.plot(tr.t, tr.e[i], color="C3")
                ax.set(title=f"estimation error e{i + 1}", xlabel="t [s]", xlim=(0, t_show))
                ax.grid(True, alpha=0.3)
            fig.suptitle(f"{pid} with {did} (cf. the paper's Figures 2-5; first {t_show:.3g} s of {tr.t[-1]:.3g} s)")
            name = f"{pid}__{did}.png"
            fig.savefig(figdir / name, dpi=100)
            plt.close(fig)
            made.append((f"{pid} with {did}: states, estimates (dashed) and estimation errors", f"figures/{name}"))
    return made


def _uncertified(df) -> str:
    sub = df[df["converged"] & ~df["certified"]]
    if not len(sub):
        return "Every converging pair is also certified."
    pairs = ", ".join(f"{r.plant} x {r.design}" for r in sub.itertuples(index=False))
    return (f"**Converge without a certificate** ({len(sub)}): {pairs}. Simulation from one initial condition "
            "is evidence, not proof: these gains have no quadratic certificate of (20) with the valid constants "
            "(or, for the EKF, none applies).")


def render_markdown(result: RunResult, figures: list[tuple[str, str]], run_info: dict) -> str:
    """The REPORT.md text (tables from the DataFrame only, no timestamps in table bodies)."""
    df = result.frame()
    o = result.options
    conv_cols = ["plant", "design", "stabilizing", "max_re_eig_x", "max_re_eig_e", "certified", "decay_rate",
                 "converged", "sim_status", "settling_x_s", "settling_e_s", "final_x", "final_e", "iae_e", "rms_e",
                 "peak_u"]
    time_cols = ["plant", "design", "solver", "solver_status", "n_solves", "lmi_size", "lmi_margin", "compile_s",
                 "solve_s", "design_s", "cert_s", "sim_s"]
    with_gains = df[df["max_re_eig_x"].notna()]
    parts = [
        "# oslbench report",
        "",
        f"Command: `{run_info['command']}`. Seed {o.seed}; measurement noise sigma = {o.noise:g}; "
        "constants used by designs: "
        f"{'claimed by the sources' if o.use_claimed else 'valid (analytic where known, else sampled)'}; "
        f"{len(df)} pairs. Package versions and settings are in `run.json`; one row per pair in "
        "`results.csv`; gains in `gains.json`.",
        "",
        "Observer gain K (n x p), feedback F (m x n), u = F x_hat. *Stabilizing*: A+BF and A-KC Hurwitz. "
        "*Certified*: the analysis LMI of the paper's (20) with K, F fixed has a verified negative margin with "
        "the valid constants (for a plant whose constants hold only on a region ||x|| <= r, the certificate is "
        "local: it holds while x and x_hat stay in that region); *decay_rate*: the largest certified lambda with "
        "V' <= -2 lambda V (bisection). "
        "*Converged*: the nonlinear closed loop (plant + observer (6)) from the plant's initial conditions ends "
        "with ||x|| and ||e|| below 1e-3 of their peaks. Settling times are 2 % of the peak norm. "
        "*lmi_margin* is the largest eigenvalue of the design LMI recomputed with numpy (negative = strictly "
        "feasible).",
        "",
        "## Feasibility",
        "",
        _feasibility(df),
        "",
        "## Convergence",
        "",
        _table(with_gains, conv_cols) if len(with_gains) else "No design produced gains.",
        "",
        _uncertified(df),
        "",
        "## Timing (seconds)",
        "",
        _table(df, time_cols),
        "",
        "## Constants",
        "",
        "Sampled values are lower bounds from seeded random pairs refined by local optimisation; a claimed "
        "constant that a sample exceeds is flagged with the violating pair. Beta is sampled at the gamma in use.",
        "",
        _constants_table(result),
        "",
        "## Figures",
        "",
    ]
    if figures:
        for caption, path in figures:
            parts += [f"![{caption}]({path})", "", f"*{caption}*", ""]
    else:
        parts.append("No converging pair to plot.")
    return "\n".join(parts).rstrip() + "\n"


def _gains(result: RunResult) -> list[dict]:
    out = []
    for o in result.outcomes:
        r = o.result
        if r is not None and r.has_controller:
            dr = o.record["decay_rate"]
            out.append({
                "plant": o.record["plant"],
                "design": o.record["design"],
                "K": None if r.K is None else np.asarray(r.K).tolist(),
                "F": np.asarray(r.F).tolist(),
                "estimator": None if r.estimator is None else repr(r.estimator),
                "certified": bool(o.record["certified"]),
                "decay_rate": None if not math.isfinite(dr) else float(dr),
            })
    return out


def write_report(result: RunResult, out_dir: str | os.PathLike, run_info: dict, *, figures: bool = True) -> Path:
    """Write REPORT.md, results.csv, gains.json, run.json and figures/ into ``out_dir``, atomically.

    Parameters
    ----------
    result : RunResult
    out_dir : path
    run_info : dict
        Must hold ``command``; extended with versions and settings into run.json.
    figures : bool
        Draw the figures.

    Returns
    -------
    Path
        The REPORT.md path.
    """
    from bench.outdir import publish, staged

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with staged(out, "report") as tmp:  # a folder of its own; stale ones are removed by publish
        (tmp / "figures").mkdir()
        figs = _figures(result, tmp / "figures") if figures else []
        md = render_markdown(result, figs, run_info)
        (tmp / "REPORT.md").write_text(md, encoding="utf-8")
        result.frame().to_csv(tmp / "results.csv", index=False)
        (tmp / "gains.json").write_text(json.dumps(_gains(result), indent=1) + "\n", encoding="utf-8")
        info = {
            **run_info,
            "seed": result.options.seed,
            "use_claimed_constants": result.options.use_claimed,
            "n_samples_constants": result.options.n_samples,
            "t_final_override": result.options.t_final,
            "noise": result.options.noise,
            "noise_dt": result.options.noise_dt,
            "timeout": result.options.timeout,
            "sim": {k: getattr(result.options.sim, k) for k in ("method", "rtol", "atol", "n_points", "blowup",
                                                                 "max_nfev")},
            **{f"git_{k}": v for k, v in git_revision().items()},
            "cache": {"dir": result.cache_dir, "hits": result.cache_hits, "misses": result.cache_misses},
            "versions": package_versions(),
            "platform": platform.platform(),
            "executable": sys.executable,
            "wall_s": round(result.wall_s, 3),
        }
        (tmp / "run.json").write_text(json.dumps(info, indent=1, default=str) + "\n", encoding="utf-8")
        # everything rendered: swap it in whole or not at all (bench.outdir), REPORT.md last; stale figures
        # of the main report (figures/*__*.png) go, the studies' and perf's stay
        files = [f"figures/{p.name}" for p in sorted((tmp / "figures").iterdir())]
        files += ["results.csv", "gains.json", "run.json", "REPORT.md"]
        publish(out, tmp, files, dirs=("figures",),
                owned=lambda rel: rel.startswith("figures/") and "__" in rel and rel.endswith(".png"))
    return out / "REPORT.md"
