"""``python -m bench perf``: how design time grows with n, joint vs separated, and parallel speed-up.

Writes ``PERF.md``, ``perf.csv`` and ``figures/perf_scaling.png`` into the output folder
(default ``reports/``), atomically. Every figure is a measurement on this machine, printed as it
is taken:

- design time vs n (``random_lipschitz_v1`` plants, m = p = max(1, n // 4), c = 0.1, seed 0) for
  the corrected Theorem 1 joint LMI at a fixed phi1 (one solve) and separated (two solves),
  split into compile and solve seconds, with the peak memory of the process that ran it
  (each measurement runs in its own forked process; peak RSS is its high-water mark);
- the fitted growth exponent (least squares on log time vs log n, n >= 8);
- compile overhead of a parameter sweep (one compiled DPP problem, many solves), and of whole
  design calls in a sweep (a bisection over the scale of f, a random family over seeds) with
  the program cache and with every call rebuilding its problem;
- the default run's wall time with ``--jobs 1`` and ``--jobs 2`` (the parallel speed-up).
"""

from __future__ import annotations

import math
import multiprocessing
import os
import resource
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["measure_design", "perf_main"]


def _measure_child(design_id: str, n: int, kw: dict, queue) -> None:
    from bench.registry import DESIGNS, PLANTS
    from bench.lmi import clear_program_cache

    clear_program_cache()  # a cold design: programs compiled in the parent must not be inherited

    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    plant = PLANTS.create("random_lipschitz_v1", n=n, m=max(1, n // 4), p=max(1, n // 4), c=0.1, seed=0)
    t0 = time.perf_counter()
    r = DESIGNS.create(design_id, **kw).design(plant, plant.bounds)
    wall = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    queue.put({"design": design_id, "n": n, "status": r.status, "wall_s": wall, "compile_s": r.compile_s,
               "solve_s": r.solve_s, "n_solves": r.n_solves, "lmi_margin": r.margin,
               "peak_rss_mb": peak / 1024, "rss_increase_mb": (peak - base) / 1024})


def measure_design(design_id: str, n: int, kw: dict | None = None, *, timeout: float = 900.0) -> dict:
    """Time one design on the random Lipschitz plant of size n, in a forked process.

    Returns a dict with wall, compile and solve seconds, status and peak memory; status
    ``"timeout"`` if it took longer than ``timeout`` seconds.
    """
    ctx = multiprocessing.get_context("fork")
    q = ctx.Queue()
    proc = ctx.Process(target=_measure_child, args=(design_id, n, kw or {}, q))
    proc.start()
    proc.join(timeout)
    if proc.is_alive():
        proc.kill()
        proc.join()
        return {"design": design_id, "n": n, "status": "timeout", "wall_s": float("nan")}
    try:
        return q.get(timeout=5)
    except Exception:
        return {"design": design_id, "n": n, "status": f"worker exit {proc.exitcode}", "wall_s": float("nan")}


def _exponent(rows: list[dict], design: str) -> float:
    pts = [(r["n"], r["wall_s"]) for r in rows if r["design"] == design and r["n"] >= 8
           and isinstance(r.get("wall_s"), float) and math.isfinite(r["wall_s"])]
    if len(pts) < 2:
        return float("nan")
    x, y = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    return float(np.polyfit(x, y, 1)[0])


def _sweep_overhead(n: int = 8, count: int = 40) -> dict:
    """One compiled DPP problem (corrected Theorem 1, phi1 as a parameter) solved ``count`` times."""
    from bench.registry import DESIGNS, PLANTS
    from bench.lmi import clear_program_cache

    clear_program_cache()
    plant = PLANTS.create("random_lipschitz_v1", n=n, m=max(1, n // 4), p=max(1, n // 4), c=0.1, seed=0)
    design = DESIGNS.create("thm1")
    prog = design._program_convex(plant, plant.bounds)
    for phi in np.logspace(-3, 0, count):
        prog.solve(phi=phi, iphi=1 / phi)
    return {"n": n, "solves": count, "compile_s": prog.compile_s, "solve_s": prog.solve_s,
            "overhead": prog.compile_s / prog.solve_s if prog.solve_s > 0 else float("nan")}


#: Sweeps of whole design calls: (label, design, plant id, [factory keywords per call]).
DESIGN_SWEEPS = (
    ("bisection over c, flexible link (sparse A, B, C baked in)", "thm1", "flexible_link",
     [{"c": float(c)} for c in np.geomspace(0.05, 0.5, 10)]),
    ("bisection over c, random_lipschitz_v1 n = 8", "thm1", "random_lipschitz_v1",
     [{"n": 8, "m": 2, "p": 2, "seed": 0, "c": float(c)} for c in np.geomspace(0.01, 0.3, 10)]),
    ("bisection over c, random_lipschitz_v1 n = 32", "thm1_sep", "random_lipschitz_v1",
     [{"n": 32, "m": 8, "p": 8, "seed": 0, "c": float(c)} for c in np.geomspace(0.01, 0.3, 10)]),
    ("random family over seeds 0-9, n = 16", "thm1_sep", "random_lipschitz_v1",
     [{"n": 16, "m": 4, "p": 4, "seed": s, "c": 0.1} for s in range(10)]),
)


def design_sweeps(echo=print) -> list[dict]:
    """Compile vs solve of whole design calls in a sweep, with the program cache and without.

    ``cached``: the programs stay compiled between calls (what the studies and the harness do);
    ``rebuilt``: the cache is cleared before every call (every call builds and compiles its
    cvxpy problem, as the designs did before the cache).

    Returns
    -------
    list of dict
        One row per (sweep, mode): calls, compile, solve and wall seconds, overhead
        (compile / solve) and the statuses seen.
    """
    from bench.registry import DESIGNS, PLANTS
    from bench.lmi import clear_program_cache

    rows = []
    for label, did, pid, calls in DESIGN_SWEEPS:
        design = DESIGNS.create(did)
        plants = [PLANTS.create(pid, **kw) for kw in calls]
        design.design(plants[0], plants[0].bounds)  # warm-up: first-use costs of the solver interfaces
        for mode in ("rebuilt", "cached"):
            clear_program_cache()
            comps, solves = [], []
            statuses: dict[str, int] = {}
            t0 = time.perf_counter()
            for plant in plants:
                if mode == "rebuilt":
                    clear_program_cache()
                r = design.design(plant, plant.bounds)
                comps.append(r.compile_s)
                solves.append(r.solve_s)
                statuses[r.status] = statuses.get(r.status, 0) + 1
            wall = time.perf_counter() - t0
            comp, solve = sum(comps), sum(solves)
            later = sum(solves[1:])
            row = {"sweep": label, "design": did, "mode": mode, "calls": len(plants), "compile_s": comp,
                   "solve_s": solve, "wall_s": wall, "overhead": comp / solve if solve > 0 else float("nan"),
                   "first_compile_s": comps[0],
                   "later_overhead": sum(comps[1:]) / later if later > 0 else float("nan"),
                   "statuses": ", ".join(f"{k} {v}" for k, v in statuses.items())}
            rows.append(row)
            echo(f"sweep {label} [{did}, {mode}]: {len(plants)} calls, compile {comp:.3f} s, solve {solve:.3f} s, "
                 f"overhead {100 * row['overhead']:.1f} % (calls 2-{len(plants)}: "
                 f"{100 * row['later_overhead']:.1f} %), wall {wall:.2f} s")
    clear_program_cache()
    return rows


def _default_run_times(jobs_list=(1, 2)) -> dict[int, float]:
    from bench.harness import RunOptions, run
    from bench.registry import DESIGNS, PLANTS

    out = {}
    for jobs in jobs_list:
        t0 = time.perf_counter()
        run(PLANTS.ids(), DESIGNS.ids(), RunOptions(), jobs=jobs)
        out[jobs] = time.perf_counter() - t0
    return out


def _sweep_table(rows: list[dict]) -> str:
    """Markdown for :func:`design_sweeps` (rebuilt vs cached per sweep)."""
    if not rows:
        return "Design-call sweeps not measured (--no-sweeps)."
    out = ["Whole design calls in a sweep. *rebuilt*: every call builds and compiles its cvxpy problem (the cache "
           "cleared before each call); *cached*: one compiled problem per structure, the plant's matrices and "
           "constants set as cvxpy Parameters (`bench.lmi.cached_program`). Compile includes building the "
           "expression tree.", "",
           "| sweep | design | mode | calls | compile s | solve s | overhead % | first call compile s | "
           "overhead % of calls 2..N | wall s | statuses |",
           "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['sweep']} | {r['design']} | {r['mode']} | {r['calls']} | {r['compile_s']:.3f} | "
                   f"{r['solve_s']:.3f} | {100 * r['overhead']:.1f} | {r['first_compile_s']:.3f} | "
                   f"{100 * r['later_overhead']:.1f} | {r['wall_s']:.2f} | {r['statuses']} |")
    return "\n".join(out)


def _fmt(v) -> str:
    if isinstance(v, float):
        return "" if not math.isfinite(v) else f"{v:.3g}"
    return str(v)


def perf_main(out_dir: str, sizes: list[int], max_joint_n: int, with_run: bool, echo=print, *,
              with_sweeps: bool = True) -> Path:
    """Measure and write the performance report; returns the PERF.md path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pandas as pd

    from bench.executors import _warm_imports
    from bench.registry import DESIGNS, PLANTS

    _warm_imports()  # forked measurements must not pay for imports
    PLANTS.ids()
    DESIGNS.ids()
    rows = []
    for n in sizes:
        for did, kw, limit in (("thm1_sep", {}, None), ("thm1", {"phi1": 0.01}, max_joint_n)):
            if limit is not None and n > limit:
                rows.append({"design": did, "n": n, "status": f"skipped (n > --max-joint-n {limit})",
                             "wall_s": float("nan")})
                echo(f"n = {n:3d} {did:9s} skipped")
                continue
            r = measure_design(did, n, kw)
            r["form"] = "joint 6n LMI, one solve at phi1 = 0.01" if did == "thm1" else "separated, two 2n LMIs"
            rows.append(r)
            echo(f"n = {n:3d} {did:9s} {r['status']:10s} wall {_fmt(r['wall_s']):>8} s  compile "
                 f"{_fmt(r.get('compile_s', float('nan'))):>8} s  solve {_fmt(r.get('solve_s', float('nan'))):>8} s  "
                 f"peak {_fmt(r.get('peak_rss_mb', float('nan')))} MB")
    df = pd.DataFrame(rows)
    exp = {d: _exponent(rows, d) for d in ("thm1", "thm1_sep")}
    sweep = _sweep_overhead()
    echo(f"sweep: {sweep['solves']} solves at n = {sweep['n']}: compile {sweep['compile_s']:.3f} s, "
         f"solve {sweep['solve_s']:.3f} s, overhead {100 * sweep['overhead']:.1f} %")
    dsweeps = design_sweeps(echo) if with_sweeps else []
    runs = _default_run_times() if with_run else {}
    for j, w in runs.items():
        echo(f"default run, --jobs {j}: {w:.1f} s")

    ratio_lines = []
    for n in sizes:
        j = df[(df.design == "thm1") & (df.n == n)]["wall_s"]
        s = df[(df.design == "thm1_sep") & (df.n == n)]["wall_s"]
        if len(j) and len(s) and math.isfinite(j.iloc[0]) and math.isfinite(s.iloc[0]):
            ratio_lines.append(f"| {n} | {j.iloc[0]:.3g} | {s.iloc[0]:.3g} | {j.iloc[0] / s.iloc[0]:.3g} |")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".tmp-perf-", dir=out))
    try:
        (tmp / "figures").mkdir()
        fig, ax = plt.subplots(figsize=(6, 4), constrained_layout=True)
        for did, label in (("thm1", "joint (one solve)"), ("thm1_sep", "separated (two solves)")):
            sub = df[(df.design == did) & df.wall_s.notna()]
            ax.loglog(sub.n, sub.wall_s, "o-", label=f"{label}, slope {exp[did]:.2g}")
        ax.set(xlabel="n (states)", ylabel="design time [s]", title="Corrected Theorem 1: time vs n")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
        fig.savefig(tmp / "figures" / "perf_scaling.png", dpi=110)
        plt.close(fig)
        cols = ["design", "n", "status", "wall_s", "compile_s", "solve_s", "n_solves", "peak_rss_mb",
                "rss_increase_mb", "lmi_margin"]
        table = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
        for r in df.reindex(columns=cols).itertuples(index=False):
            table.append("| " + " | ".join(_fmt(v) for v in r) + " |")
        speed = ""
        if runs:
            speed = (f"| jobs | wall s |\n|---|---|\n" + "\n".join(f"| {j} | {w:.1f} |" for j, w in runs.items())
                     + (f"\n\nSpeed-up of --jobs 2 over --jobs 1: {runs[1] / runs[2]:.2f}x" if 1 in runs and 2 in runs else ""))
        md = "\n".join([
            "# oslbench performance",
            "",
            f"Machine: {os.cpu_count()} cores. Produced by `python -m bench perf`; each number is one measurement.",
            "",
            "## Design time vs n (random_lipschitz_v1, m = p = max(1, n // 4), c = 0.1, seed 0)",
            "",
            "\n".join(table),
            "",
            f"Fitted growth exponents (log time vs log n, n >= 8): joint {exp['thm1']:.2f}, "
            f"separated {exp['thm1_sep']:.2f}.",
            "",
            "| n | joint s | separated s | ratio |",
            "|---|---|---|---|",
            "\n".join(ratio_lines),
            "",
            "![time vs n](figures/perf_scaling.png)",
            "",
            "## Compile overhead in a sweep",
            "",
            f"One compiled DPP problem (corrected Theorem 1 with phi1 as a cvxpy parameter), n = {sweep['n']}, "
            f"{sweep['solves']} solves: compile {sweep['compile_s']:.3f} s, solve {sweep['solve_s']:.3f} s, "
            f"overhead {100 * sweep['overhead']:.1f} % of solve time.",
            "",
            _sweep_table(dsweeps),
            "",
            "## Default run",
            "",
            speed or "Not measured (--no-run).",
            "",
        ])
        (tmp / "PERF.md").write_text(md, encoding="utf-8")
        df.to_csv(tmp / "perf.csv", index=False)
        (out / "figures").mkdir(exist_ok=True)
        os.replace(tmp / "figures" / "perf_scaling.png", out / "figures" / "perf_scaling.png")
        os.replace(tmp / "perf.csv", out / "perf.csv")
        os.replace(tmp / "PERF.md", out / "PERF.md")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out / "PERF.md"
