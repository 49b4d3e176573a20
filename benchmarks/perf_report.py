"""``python -m bench perf``: how the designs scale with n, and how long the default run takes.

A developer script of the checkout, not part of the installed package: ``python -m bench perf``
(from a checkout) loads it from ``benchmarks/``.

Writes ``PERF.md``, ``perf.csv`` and ``figures/perf_scaling.png`` into the output folder
(default ``reports/``), whole or not at all. Every figure is a measurement on this machine,
printed as it is taken:

- the structured design on the chain family (n = 2N up to 2048): the Riccati route at every
  size and the SDP route up to n = 64, design plus certificate, with the certified rate beside
  the linearised rate of the same gains, peak memory and the fitted growth exponent, and at
  n >= 1024 an unordered Schur form of a random 2n x 2n matrix as the machine's reference;
- one closed-loop trajectory at n = 1024 over seven time constants of its certified rate, and a
  Monte Carlo batch at n = 100;
- design time vs n (``random_lipschitz_v1`` plants, m = p = max(1, n // 4), c = 0.1, seed 0) for
  the corrected Theorem 1 joint LMI at a fixed phi1 (one solve) and separated (two solves),
  split into compile and solve seconds, with the peak memory of the process that ran it
  (each measurement runs in its own forked process; peak RSS is its high-water mark);
- the fitted growth exponent (least squares on log time vs log n, n >= 8);
- compile overhead of a parameter sweep (one compiled DPP problem, many solves), and of whole
  design calls in a sweep (a bisection over the scale of f, a random family over seeds) with
  the program cache and with every call rebuilding its problem;
- the default run's wall time (a fresh ``python -m bench run --no-cache`` process) with
  ``--jobs 1`` and ``--jobs 2``, median, min and max over several runs, and where its CPU time
  goes (its work serially in one process, each part timed), with the floor that gives on 2 cores.
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

__all__ = ["default_run_breakdown", "default_run_times", "measure_design", "perf_main", "reference_rows", "route_rows",
           "sim_rows", "theorem1_rows"]


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


def _exponent(rows: list[dict], name: str, key: str = "design", n_min: int = 8) -> float:
    """Least-squares slope of log wall time vs log n over the rows with ``row[key] == name`` and n >= n_min."""
    pts = [(r["n"], r["wall_s"]) for r in rows if r.get(key) == name and r["n"] >= n_min
           and isinstance(r.get("wall_s"), float) and math.isfinite(r["wall_s"]) and r["wall_s"] > 0]
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
    prog = design.joint_program(plant, plant.bounds)
    for phi in np.logspace(-3, 0, count):
        prog.solve(phi=phi, iphi=1 / phi)
    return {"n": n, "solves": count, "compile_s": prog.compile_s, "solve_s": prog.solve_s,
            "overhead": prog.compile_s / prog.solve_s if prog.solve_s > 0 else float("nan")}


#: Sweeps of whole design calls: (label, design, plant id, [factory keywords per call]).
DESIGN_SWEEPS = (
    ("bisection over c, flexible link (sparse A, B, C by sparsity pattern)", "thm1", "flexible_link",
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


#: The structured design on the chain family, per route: sizes n = 2N and a per-measurement limit.
ROUTE_SIZES = (16, 32, 64, 128, 256, 512, 1024, 2048)
#: The SDP route is measured up to this n (interior-point cost grows like n^4 - n^6).
SDP_MAX_N = 64


def _route_child(route: str, n: int, queue) -> None:
    """One structured design + certificate on the chain of n = 2N states (in a forked process), with the
    certified rate beside the linearised loop's rate of the same gains."""
    from bench.certify import linearised_rate
    from bench.constants import compute_constants
    from bench.lmi import clear_program_cache
    from bench.pipeline import RunOptions, evaluate_pair
    from designs.structured import Structured
    from plants.chain import chain_plant

    clear_program_cache()
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    plant = chain_plant(N=n // 2)
    t0 = time.perf_counter()
    report = compute_constants(plant, n_samples=200, n_refine=0)
    t1 = time.perf_counter()
    out = evaluate_pair(plant, Structured(route=route), report, RunOptions(simulate=False, certificate="own"),
                        design_id=f"structured ({route})")
    rec = out.record
    wall = time.perf_counter() - t1
    res = out.result
    lin = linearised_rate(plant, res.K, res.F) if res is not None and res.K is not None else float("nan")
    queue.put({"route": route, "n": n, "status": rec["status"], "certified": bool(rec["certified"]),
               "cert_level": rec["cert_level"], "decay_rate": rec["decay_rate"], "linearised_rate": lin,
               "decay_target": (res.params or {}).get("decay_target", float("nan")) if res is not None else float("nan"),
               "ares_or_sdps": rec["n_solves"], "wall_s": wall, "design_s": rec["design_s"],
               "search_s": (res.params or {}).get("search_s", float("nan")) if res is not None else float("nan"),
               "joint_cert_s": (res.params or {}).get("certificate_s", float("nan")) if res is not None else float("nan"),
               "checks_s": wall - rec["design_s"], "constants_s": t1 - t0,
               "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
               "rss_increase_mb": (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - base) / 1024,
               "reason": rec["reason"][:200]})


def _schur_child(n: int, threads: int, queue) -> None:
    """The reference: an unordered real Schur form of a random 2n x 2n matrix with ``threads`` BLAS threads."""
    import scipy.linalg as sla
    from threadpoolctl import threadpool_limits

    M = np.random.default_rng(0).standard_normal((2 * n, 2 * n))
    with threadpool_limits(limits=threads, user_api="blas"):
        t0 = time.perf_counter()
        sla.schur(M, output="real", overwrite_a=True, check_finite=False)
    queue.put({"n": n, "threads": threads, "status": "ok", "wall_s": time.perf_counter() - t0})


def reference_rows(sizes=(1024,), echo=print) -> list[dict]:
    """The Schur reference at each size (:func:`_schur_child`), measured beside the route rows with one BLAS
    thread (the suite's setting) and with one per core (the route runs its two sides on two cores)."""
    rows = []
    for n in sizes:
        for threads in dict.fromkeys((1, os.cpu_count() or 1)):
            r = _forked(_schur_child, (n, threads), 1800.0, {"n": n, "threads": threads})
            rows.append(r)
            echo(f"reference: unordered scipy.linalg.schur of a random {2 * n} x {2 * n} matrix, {threads} BLAS "
                 f"thread(s): {_fmt(r['wall_s'])} s")
    return rows


def _forked(target, args: tuple, timeout: float, label: dict) -> dict:
    """Run ``target(*args, queue)`` in a forked process; its result, or a ``timeout`` row."""
    ctx = multiprocessing.get_context("fork")
    q = ctx.Queue()
    proc = ctx.Process(target=target, args=(*args, q))
    proc.start()
    proc.join(timeout)
    if proc.is_alive():
        proc.kill()
        proc.join()
        return {**label, "status": f"timeout (> {timeout:g} s)", "wall_s": float("nan")}
    try:
        return q.get(timeout=5)
    except Exception:
        return {**label, "status": f"worker exit {proc.exitcode}", "wall_s": float("nan")}


def route_rows(sizes=ROUTE_SIZES, *, sdp_max_n: int = SDP_MAX_N, timeout: float = 3600.0, echo=print) -> list[dict]:
    """The structured design on the chain family, Riccati route at every size, SDP route up to ``sdp_max_n``.

    Each row: route, n, status, certified, level, decay rate, wall seconds (design + certificate),
    peak memory of the forked process.
    """
    rows = []
    for n in sizes:
        for route in ("sdp", "riccati"):
            if route == "sdp" and n > sdp_max_n:
                rows.append({"route": route, "n": n, "status": f"skipped (n > {sdp_max_n})", "wall_s": float("nan")})
                continue
            r = _forked(_route_child, (route, n), timeout, {"route": route, "n": n})
            rows.append(r)
            echo(f"structured, {route:7s} n = {n:5d}: {r['status']:12s} certified {r.get('certified')} rate "
                 f"{_fmt(r.get('decay_rate', float('nan')))} (linearised {_fmt(r.get('linearised_rate', float('nan')))}) "
                 f"wall {_fmt(r['wall_s'])} s peak {_fmt(r.get('peak_rss_mb', float('nan')))} MB")
    return rows


def _sim_child(kind: str, n: int, queue) -> None:
    """A closed-loop trajectory (or a Monte Carlo batch) of the chain of n states with Riccati-route gains.

    The trajectory runs for ``7 / rate`` seconds (at least the plant's horizon), the certified rate's
    time constant seven times over: ``V`` falls by ``e^-14`` and the state by about ``e^-7 sqrt(cond P)``.
    """
    from bench.batch import simulate_batch
    from bench.simulate import SimOptions, simulate
    from designs.structured import Structured
    from plants.chain import chain_plant

    plant = chain_plant(N=n // 2)
    res = Structured(route="riccati").design(plant, plant.bounds)
    rate = res.certificate["decay_rate"] if res.certificate else float("nan")
    t0 = time.perf_counter()
    row = {"n": n, "rate": rate}
    if kind == "trajectory":
        T = max(plant.t_final, 7.0 / rate) if rate > 0 else plant.t_final
        tr = simulate(plant, res.K, res.F, t_final=T, options=SimOptions(n_points=401))
        x, xh = tr.x, tr.x_hat
        row.update(kind="one trajectory from x0, horizon 7 / rate", horizon_s=T, status=tr.status,
                   x0_norm=float(np.linalg.norm(plant.x0)), final_x=float(np.linalg.norm(x[:, -1])),
                   final_e=float(np.linalg.norm(x[:, -1] - xh[:, -1])), peak_x=float(np.linalg.norm(x, axis=0).max()))
    else:
        rng = np.random.default_rng(0)
        X = rng.uniform(-0.5, 0.5, (n, 200))
        tr = simulate_batch(plant, res.K, res.F, X, np.zeros_like(X))
        row.update(kind="Monte Carlo batch, 200 initial conditions, 20 s", status=tr.status)
    row["wall_s"] = time.perf_counter() - t0
    queue.put(row)


def sim_rows(echo=print) -> list[dict]:
    """One n = 1024 closed-loop trajectory over its certified rate's horizon and an n = 100 Monte Carlo batch."""
    rows = []
    for kind, n in (("trajectory", 1024), ("batch", 100)):
        r = _forked(_sim_child, (kind, n), 3600.0, {"kind": kind, "n": n})
        rows.append(r)
        echo(f"simulation {r.get('kind', kind)} n = {n}: {r['status']} horizon {_fmt(r.get('horizon_s', float('nan')))} s, "
             f"final |x| {_fmt(r.get('final_x', float('nan')))}, |e| {_fmt(r.get('final_e', float('nan')))}, "
             f"{_fmt(r['wall_s'])} s")
    return rows


def default_run_times(jobs_list=(1, 2), repeats: int = 3) -> list[dict]:
    """``python -m bench run --no-cache`` (cold: a fresh process, imports, constants, figures, report),
    ``repeats`` times per job count; rows with the median, min and max wall seconds."""
    import statistics
    import subprocess
    import sys

    rows = []
    for jobs in jobs_list:
        walls = []
        for _ in range(repeats):
            out = tempfile.mkdtemp(prefix="oslbench-perf-")
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "bench", "run", "--no-cache", "-q", "--jobs", str(jobs), "--out",
                            out], check=True, capture_output=True)
            walls.append(time.perf_counter() - t0)
            shutil.rmtree(out, ignore_errors=True)
        rows.append({"jobs": jobs, "runs": repeats, "median_s": statistics.median(walls), "min_s": min(walls),
                     "max_s": max(walls)})
    return rows


def _import_seconds() -> float:
    """Seconds a fresh process spends importing what ``bench run`` imports before its workers fork."""
    import subprocess
    import sys

    code = ("import time; t0 = time.perf_counter(); import bench.api, bench.report; "
            "from bench.executors import warm_imports; warm_imports(); print(time.perf_counter() - t0)")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    return float(out.stdout.strip().splitlines()[-1])


def _breakdown_child(plant_ids, design_ids, queue) -> None:
    """The default run's work, serially in one process, each part timed (see :func:`default_run_breakdown`)."""
    from bench.constants import compute_constants
    from bench.harness import RunResult
    from bench.lmi import clear_program_cache, reset_solve_tally, solve_tally
    from bench.pipeline import RunOptions, evaluate_pair
    from bench.registry import DESIGNS, PLANTS
    from bench.report import draw_figures

    clear_program_cache()  # cold, like a fresh run: every program compiled here
    reset_solve_tally()
    plant_ids = PLANTS.defaults() if plant_ids is None else plant_ids
    design_ids = DESIGNS.defaults() if design_ids is None else design_ids
    options = RunOptions()
    t0 = time.perf_counter()
    plants = {pid: PLANTS.create(pid) for pid in plant_ids}
    reports = {pid: compute_constants(plants[pid], seed=options.seed, n_samples=options.n_samples)
               for pid in plant_ids}
    t1 = time.perf_counter()
    outcomes, parts = [], {"design_s": 0.0, "cert_s": 0.0, "sim_s": 0.0}
    for pid in plant_ids:
        for did in design_ids:
            o = evaluate_pair(plants[pid], did, reports[pid], options)
            o.plant = plants[pid]
            outcomes.append(o)
            for k in parts:
                v = o.record.get(k)
                parts[k] += float(v) if isinstance(v, (int, float)) and math.isfinite(v) else 0.0
    t2 = time.perf_counter()
    tally = solve_tally()
    with tempfile.TemporaryDirectory(prefix="oslbench-perf-") as tmp:
        figs = draw_figures(RunResult(outcomes, reports, {}, options, t2 - t0), Path(tmp), ("png",), jobs=1)
    t3 = time.perf_counter()
    queue.put({"pairs": len(outcomes), "figures": len(figs), "constants_s": t1 - t0, "pairs_s": t2 - t1,
               "figures_s": t3 - t2, **parts, "n_solves": tally["n"], "compile_s": tally["compile_s"],
               "solver_s": tally["solver_s"], "cvxpy_solve_s": tally["solve_s"] - tally["solver_s"],
               "status": "ok", "wall_s": t3 - t0})


def default_run_breakdown(plant_ids=None, design_ids=None, *, cores: int = 2, timeout: float = 900.0) -> dict:
    """Where the default run's CPU time goes: its work done serially in one forked process, each part timed.

    The parts: the imports before the workers fork (a fresh process), every plant's constants,
    every pair (design, certificate ladder, simulation; the SDP solves split into the solver's
    own time, cvxpy's compile and cvxpy's per-solve work), and the figures.

    Parameters
    ----------
    plant_ids, design_ids : list of str, optional
        The selection (default: the default run's ids, as ``python -m bench run``; on-request plants left out).
    cores : int
        For the floor: the run's parallel work spread perfectly over this many cores.
    timeout : float
        Seconds before the measurement is abandoned (a ``timeout`` status).

    Returns
    -------
    dict
        The parts in CPU seconds, and ``floor_s``: the imports plus the constants, the solver's
        own time, the simulations and the figures divided by ``cores``. It is a lower bound on
        the run's wall time on ``cores`` cores with the work as it is computed today (those
        parts at today's cost, and cvxpy and everything else free).
    """
    out = _forked(_breakdown_child, (plant_ids, design_ids), timeout, {})
    if out.get("status") != "ok":
        return out
    out["imports_s"] = _import_seconds()
    out["cores"] = cores
    out["other_s"] = out["design_s"] + out["cert_s"] - out["compile_s"] - out["solver_s"] - out["cvxpy_solve_s"]
    out["floor_s"] = out["imports_s"] + (out["constants_s"] + out["solver_s"] + out["sim_s"] + out["figures_s"]) / cores
    return out


def _breakdown_md(b: dict | None) -> str:
    """Markdown for :func:`default_run_breakdown`."""
    if not b:
        return "Not measured (--no-run)."
    if b.get("status") != "ok":
        return f"Not measured: {b.get('status')}."
    rows = [("imports before the workers fork (a fresh process)", b["imports_s"]),
            ("constants of every plant", b["constants_s"]),
            (f"SDP solver's own time ({b['n_solves']} solves, as the solver reports it)", b["solver_s"]),
            ("cvxpy's compile (first solve of each program)", b["compile_s"]),
            ("the rest of each solve (cvxpy: parameters in, solution out; the solver's setup)", b["cvxpy_solve_s"]),
            ("the rest of designs and certificates (Riccati, python-control, eigenvalue checks)", b["other_s"]),
            ("simulations (scipy integrators, the EKF's filterpy steps)", b["sim_s"]),
            (f"figures ({b['figures']}, matplotlib)", b["figures_s"])]
    total = sum(v for _, v in rows)
    out = [f"The default run's work ({b['pairs']} pairs) done serially in one process, each part timed "
           "(`benchmarks/perf_report.py`, `default_run_breakdown`), CPU seconds:", "", "| part | s |", "|---|---|"]
    out += [f"| {what} | {v:.1f} |" for what, v in rows]
    out += [f"| total | {total:.1f} |", "",
            f"Floor on {b['cores']} cores: the imports plus (constants + solver + simulations + figures) / "
            f"{b['cores']} = **{b['floor_s']:.1f} s**. With cvxpy's compile and per-solve work and the rest of the "
            "designs and certificates free, and the other parts at today's cost spread perfectly over the cores, "
            "the run could not be faster than this on this machine."]
    return "\n".join(out)


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


def _md_table(rows: list[dict], cols: list[str]) -> str:
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    out += ["| " + " | ".join(_fmt(r.get(c, "")) for c in cols) + " |" for r in rows]
    return "\n".join(out)


def theorem1_rows(sizes: list[int], max_joint_n: int, echo=print) -> list[dict]:
    """Corrected Theorem 1, joint (one solve at phi1 = 0.01) vs separated, on random_lipschitz_v1 of size n."""
    rows = []
    for n in sizes:
        for did, kw, limit in (("thm1_sep", {}, None), ("thm1", {"phi1": 0.01}, max_joint_n)):
            if limit is not None and n > limit:
                rows.append({"design": did, "n": n, "status": f"skipped (n > --max-joint-n {limit})",
                             "wall_s": float("nan")})
                continue
            r = measure_design(did, n, kw)
            rows.append(r)
            echo(f"n = {n:3d} {did:9s} {r['status']:10s} wall {_fmt(r['wall_s']):>8} s")
    return rows


def _figure(path: Path, thm_rows: list[dict], routes: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    for did, label in (("thm1", "joint 6n LMI"), ("thm1_sep", "separated 2n LMIs")):
        pts = [(r["n"], r["wall_s"]) for r in thm_rows if r["design"] == did and math.isfinite(r["wall_s"])]
        if pts:
            axes[0].loglog(*zip(*pts), "o-", label=f"{label}, slope {_exponent(thm_rows, did, 'design'):.2g}")
    axes[0].set(xlabel="n", ylabel="design time [s]", title="corrected Theorem 1 (random_lipschitz_v1)")
    for route in ("sdp", "riccati"):
        pts = [(r["n"], r["wall_s"]) for r in routes if r["route"] == route and math.isfinite(r["wall_s"])]
        if pts:
            axes[1].loglog(*zip(*pts), "o-", label=f"{route}, slope {_exponent(routes, route, 'route'):.2g}")
    axes[1].set(xlabel="n", ylabel="design + certificate [s]", title="structured design (chain, n = 2N)")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _agreement(routes: list[dict]) -> str:
    """Where both routes ran: both certified rates, their ratio and each pair of gains' linearised rate."""
    by = {(r["route"], r["n"]): r for r in routes if "certified" in r}
    lines = ["| n | SDP rate | Riccati rate | Riccati / SDP | SDP linearised | Riccati linearised | verdicts |",
             "|---|---|---|---|---|---|---|"]
    for n in sorted({r["n"] for r in routes}):
        s, r = by.get(("sdp", n)), by.get(("riccati", n))
        if s is None or r is None:
            continue
        if bool(s["certified"]) == bool(r["certified"]):
            verdict = "both certified" if s["certified"] else "neither certified"
        else:
            verdict = f"only the {'SDP' if s['certified'] else 'Riccati'} route certifies"
        sr, rr = s.get("decay_rate", math.nan), r.get("decay_rate", math.nan)
        ratio = rr / sr if isinstance(sr, float) and sr > 0 else math.nan
        lines.append(f"| {n} | {_fmt(sr)} | {_fmt(rr)} | {_fmt(ratio)} | {_fmt(s.get('linearised_rate', math.nan))} | "
                     f"{_fmt(r.get('linearised_rate', math.nan))} | {verdict} |")
    return "\n".join(lines) if len(lines) > 2 else "No size where both routes ran."


def _targets(routes: list[dict], sims: list[dict], runs: list[dict], refs: list[dict] = ()) -> str:
    """The scale and speed targets of the issues beside what this run measured."""
    def row(n, key="wall_s"):
        r = next((r for r in routes if r["route"] == "riccati" and r["n"] == n), {})
        return r.get(key, float("nan"))

    traj = next((r["wall_s"] for r in sims if r.get("n") == 1024), float("nan"))
    run2 = next((r["median_s"] for r in runs if r["jobs"] == 2), float("nan"))
    rows = [("structured, Riccati route, n = 256, design + certificate", "<= 10 s", row(256, "design_s"))]
    for n, want in ((1024, "<= 15 s"), (2048, "-")) if any(r["n"] == 2048 for r in routes) else ((1024, "<= 15 s"),):
        rows.append((f"structured, Riccati route, n = {n}, design (rate searched) + certificate with its rate "
                     f"(rate {_fmt(row(n, 'decay_rate'))}, peak {_fmt(row(n, 'peak_rss_mb'))} MB)", want,
                     row(n, "design_s")))
        for ref in (r for r in refs if r.get("n") == n):
            rows.append((f"  the same, over an unordered scipy.linalg.schur of a random {2 * n} x {2 * n} matrix with "
                         f"{ref['threads']} BLAS thread(s) ({_fmt(ref['wall_s'])} s in this run)",
                         "<= 2.1" if n == 1024 and ref["threads"] == 1 else "-",
                         row(n, "design_s") / ref["wall_s"] if ref["wall_s"] > 0 else float("nan")))
        rows.append((f"  the same with the eigenvalue checks of A+BF and A-KC (the pair without simulation, `wall_s`)",
                     "-", row(n)))
    rows += [("growth exponent of the Riccati route (n >= 64)", "<= 3.2", _exponent(routes, "riccati", "route", 64)),
            ("one closed-loop trajectory, n = 1024, horizon 7 / certified rate", "-", traj),
            ("default run, cold, --jobs 2 (median)", "<= 20 s", run2)]
    out = ["| target | wanted | measured |", "|---|---|---|"]
    out += [f"| {what} | {want} | {_fmt(got)} |" for what, want, got in rows]
    return "\n".join(out)


def _markdown(thm_rows, routes, sweep, dsweeps, sims, runs, breakdown=None, refs=()) -> str:
    cert = [r for r in routes if r["route"] == "riccati" and "certified" in r]
    frac = sum(r["certified"] for r in cert) / len(cert) if cert else float("nan")
    run_md = _md_table(runs, ["jobs", "runs", "median_s", "min_s", "max_s"]) if runs else "Not measured (--no-run)."
    return "\n".join([
        "# oslbench performance",
        "",
        f"Machine: {os.cpu_count()} cores. Produced by `python -m bench perf`; every number is a measurement of "
        "this run (forked processes for the design timings, so peak memory is the measurement's own).",
        "",
        "## Targets",
        "",
        _targets(routes, sims, runs, refs),
        "",
        "## Structured design: Riccati route vs SDP route (chain family, n = 2N)",
        "",
        "Design (decay target searched within max_gain = 20) plus its own joint certificate (bench.joint: "
        "V = x'Px + mu e'Re, verified by the eigenvalues of the joint matrix; the ladder's SDPs are not run here). "
        "`decay_rate` is the rate the certificate proves (a generalised eigenvalue, on the 1 % rate grid), "
        "`linearised_rate` the rate of the same gains' loop linearised at the origin (no certificate beats it). "
        "The SDP route is skipped above n = 64. `wall_s` is the pair's evaluation without simulation: `design_s` "
        "(for the Riccati route `search_s`, the search and the verified sides, and `joint_cert_s`, the certificate "
        "with its rate; `ares_or_sdps` counts its Riccati equations, estimates and verified solves) and `checks_s`, "
        "the eigenvalues of the gains' closed loops. The Riccati route runs two Riccati equations at a time, one "
        "per core, each with one BLAS thread.",
        "",
        _md_table(routes, ["route", "n", "status", "certified", "decay_rate", "linearised_rate", "decay_target",
                           "ares_or_sdps", "wall_s", "design_s", "search_s", "joint_cert_s", "checks_s", "peak_rss_mb",
                           "reason"]),
        "",
        f"Growth exponent (log time vs log n, n >= 64): Riccati route {_exponent(routes, 'riccati', 'route', 64):.2f}; "
        f"SDP route {_exponent(routes, 'sdp', 'route', 16):.2f}. Certified Riccati rows: {100 * frac:.0f} %.",
        "",
        "Where both routes ran (certified rates, their ratio, and each pair of gains' linearised rate):",
        "",
        _agreement(routes),
        "",
        "![time vs n](figures/perf_scaling.png)",
        "",
        "## Simulation at scale",
        "",
        _md_table(sims, ["kind", "n", "status", "rate", "horizon_s", "x0_norm", "peak_x", "final_x", "final_e",
                         "wall_s"]),
        "",
        "## Corrected Theorem 1: time vs n (random_lipschitz_v1, m = p = max(1, n // 4), c = 0.1)",
        "",
        _md_table(thm_rows, ["design", "n", "status", "wall_s", "compile_s", "solve_s", "n_solves", "peak_rss_mb"]),
        "",
        f"Growth exponents (n >= 8): joint {_exponent(thm_rows, 'thm1', 'design'):.2f}, separated "
        f"{_exponent(thm_rows, 'thm1_sep', 'design'):.2f}.",
        "",
        "## Compile overhead in a sweep",
        "",
        f"One compiled DPP problem (corrected Theorem 1 with phi1 as a cvxpy parameter), n = {sweep['n']}, "
        f"{sweep['solves']} solves: compile {sweep['compile_s']:.3f} s, solve {sweep['solve_s']:.3f} s, overhead "
        f"{100 * sweep['overhead']:.1f} % of solve time.",
        "",
        _sweep_table(dsweeps),
        "",
        "## Default run",
        "",
        "`python -m bench run --no-cache` in a fresh process (imports, constants, every pair with the certificate "
        "ladder, figures, report), wall seconds over several runs:",
        "",
        run_md,
        "",
        "### Where the time goes",
        "",
        _breakdown_md(breakdown),
        "",
    ])


def perf_main(out_dir: str, sizes: list[int], max_joint_n: int, with_run: bool, echo=print, *,
              with_sweeps: bool = True, route_sizes=ROUTE_SIZES, with_sims: bool = True, repeats: int = 3) -> Path:
    """Measure and write the performance report (PERF.md, perf.csv, figures/perf_scaling.png); returns PERF.md."""
    import pandas as pd

    from bench.executors import warm_imports
    from bench.outdir import publish, staged
    from bench.registry import DESIGNS, PLANTS

    warm_imports()  # forked measurements must not pay for imports
    PLANTS.ids()
    DESIGNS.ids()
    routes, refs = [], []
    for n in route_sizes or ():  # the reference right after its route row: the same load on the machine
        routes += route_rows((n,), echo=echo)
        refs += reference_rows((n,) if n >= 1024 else (), echo=echo)
    sims = sim_rows(echo) if with_sims else []
    thm_rows = theorem1_rows(sizes, max_joint_n, echo)
    sweep = _sweep_overhead()
    dsweeps = design_sweeps(echo) if with_sweeps else []
    runs = default_run_times(repeats=repeats) if with_run else []
    for r in runs:
        echo(f"default run, --jobs {r['jobs']}: median {r['median_s']:.1f} s (min {r['min_s']:.1f}, max {r['max_s']:.1f})")
    breakdown = default_run_breakdown() if with_run else None
    if breakdown:
        echo(f"default run's work, serially: {_fmt(breakdown.get('wall_s'))} s; floor on {breakdown.get('cores', 2)} cores "
             f"{_fmt(breakdown.get('floor_s', float('nan')))} s ({breakdown.get('status')})")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with staged(out, "perf") as tmp:
        (tmp / "figures").mkdir()
        _figure(tmp / "figures" / "perf_scaling.png", thm_rows, routes)
        (tmp / "PERF.md").write_text(_markdown(thm_rows, routes, sweep, dsweeps, sims, runs, breakdown, refs),
                                     encoding="utf-8")
        pd.DataFrame([*({"section": "structured", **r} for r in routes), *({"section": "schur reference", **r} for r in refs),
                      *({"section": "theorem1", **r} for r in thm_rows),
                      *({"section": "simulation", **r} for r in sims), *({"section": "default run", **r} for r in runs),
                      *([{"section": "default run breakdown", **breakdown}] if breakdown else [])]
                     ).to_csv(tmp / "perf.csv", index=False)
        publish(out, tmp, ["figures/perf_scaling.png", "perf.csv", "PERF.md"])
    return out / "PERF.md"
