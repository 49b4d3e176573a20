"""Monte Carlo speed: one vectorised ODE over the whole batch vs a loop of ``solve_ivp`` calls.

Usage: ``python benchmarks/montecarlo_speed.py [--design D ...] [--n 1000] [--t-final 20] [--loop-n N]``
(defaults: flexible link, designs ``lqr+lqe``, ``thm1`` and ``paper_gains``, 1000 initial conditions
from the study's seeded box, 20 s). For each design it prints the batch time (best of 3 after one
warm-up; ``bench.batch.simulate_batch``, ``--method`` (default DOP853, the study's
non-stiff choice), rtol 1e-6, atol 1e-9, 401 output points),
the time of looping ``solve_ivp`` over the same initial conditions with the same settings
(:func:`simulate_loop`; ``--loop-n`` loops over the first N only and extrapolates, labelled so), the
speed-up, and the largest difference between the two (relative to the largest state), plus whether
they agree on which initial conditions converge. Targets (issue 5): batch <= 1 s, speed-up >= 40x.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # run from a checkout

import bench  # noqa: E402,F401  (importing bench sets the BLAS threads, before numpy)
import numpy as np  # noqa: E402

from bench.registry import DESIGNS, PLANTS  # noqa: E402
from bench.studies._common import default_box, random_ics  # noqa: E402
from bench.batch import BATCH_OPTIONS, BatchTrajectory, simulate_batch  # noqa: E402
from bench.simulate import SimOptions, simulate  # noqa: E402


def simulate_loop(plant, K, F, X: np.ndarray, XH: np.ndarray, t_final: float, options: SimOptions):
    """The loop a batch replaces: one :func:`bench.simulate.simulate` (one ``solve_ivp``) per column of
    ``X``, ``XH`` (n, N). Returns ``t``, ``x`` and ``x_hat`` (n, N, T) padded with NaN after a failed
    member's last point, and the seconds spent."""
    n, N = X.shape
    xs = np.full((n, N, options.n_points), np.nan)
    xhs = np.full_like(xs, np.nan)
    t0 = time.perf_counter()
    for j in range(N):
        tr = simulate(plant, K, F, t_final=t_final, x0=X[:, j], x_hat0=XH[:, j], options=options)
        k = tr.t.size
        xs[:, j, :k] = tr.x
        xhs[:, j, :k] = tr.x_hat
    return np.linspace(0.0, t_final, options.n_points), xs, xhs, time.perf_counter() - t0


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--plant", default="flexible_link")
    p.add_argument("--design", action="append", help="repeatable (default: lqr+lqe, thm1, paper_gains)")
    p.add_argument("--n", type=int, default=1000)
    p.add_argument("--t-final", type=float, default=20.0)
    p.add_argument("--loop-n", type=int, default=None, help="loop over the first N only and extrapolate")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--method", default="DOP853", help="solve_ivp method for the batch and the loop (default DOP853)")
    a = p.parse_args()
    plant = PLANTS.create(a.plant)
    X, XH = random_ics(plant, a.n, default_box(plant), a.seed)
    opts = replace(BATCH_OPTIONS, method=a.method)  # the batch's settings, and the loop's
    print(f"{a.plant}: {a.n} initial conditions in [-{default_box(plant):g}, {default_box(plant):g}]^{plant.n} "
          f"(seed {a.seed}), {a.t_final:g} s, {a.method} rtol {opts.rtol:g} atol {opts.atol:g}, "
          f"{opts.n_points} output points; "
          f"{os.cpu_count()} cores")
    print(f"{'design':<14} {'batch s':>8} {'nfev':>6} {'loop s':>8} {'speed-up':>9} {'max rel diff':>12} "
          f"{'same verdicts':>13} {'converged':>9}")
    for did in a.design or ["lqr+lqe", "thm1", "paper_gains"]:
        r = DESIGNS.create(did).design(plant, plant.bounds)
        if r.K is None or r.F is None:
            print(f"{did:<14} no fixed gains ({r.status}: {r.reason[:60]})")
            continue
        simulate_batch(plant, r.K, r.F, X[:, :10], XH[:, :10], t_final=a.t_final, options=opts)  # warm-up
        best = None
        for _ in range(3):
            tr = simulate_batch(plant, r.K, r.F, X, XH, t_final=a.t_final, options=opts)
            if best is None or tr.wall_s < best.wall_s:
                best = tr
        m = a.n if a.loop_n is None else min(a.loop_n, a.n)
        t, xs, xhs, loop_s = simulate_loop(plant, r.K, r.F, X[:, :m], XH[:, :m], a.t_final, opts)
        loop_full = loop_s * a.n / m
        diff = float(np.nanmax(np.abs(best.x[:, :m] - xs)) / np.nanmax(np.abs(xs)))
        ref = BatchTrajectory(t, xs, xhs, np.zeros(m, dtype=bool), "ok", "", loop_s, 0)
        same = bool(np.array_equal(ref.metrics()["converged"], best.metrics()["converged"][:m]))
        conv = float(best.metrics()["converged"].mean())
        label = f"{loop_full:8.2f}" + ("*" if m < a.n else " ")
        print(f"{did:<14} {best.wall_s:8.3f} {best.nfev:6d} {label} {loop_full / best.wall_s:8.0f}x {diff:12.2e} "
              f"{str(same):>13} {conv:9.3f}")
    if a.loop_n is not None and a.loop_n < a.n:
        print(f"* loop time extrapolated from the first {a.loop_n} initial conditions")


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    print(f"total {time.perf_counter() - t0:.1f} s")
