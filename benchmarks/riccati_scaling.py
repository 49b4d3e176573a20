"""Scaling of the Riccati route (designs/_riccati_route.py) on the chain family, n = 2N states.

Usage::

    python benchmarks/riccati_scaling.py [--sizes 16 32 ... 1024] [--method schur] [--lam 0]
                                         [--threads T] [--solvers]

For each n: the chain ``chain_plant(N=n/2)`` (pendula, forces and sensors at every fifth mass) is
built (timed apart), then :func:`designs._riccati_route.structured_riccati` designs K and F by two
AREs and certifies the pair by one 2n x 2n eigenvalue test. Printed per n: the wall time of the
route (design + joint certificate) and of each step, the status, the verified margin, the grid
points tried, and the peak resident memory of the process so far (``ru_maxrss``; sizes run in
increasing order, so it is the peak of the largest n so far). Last, the growth exponent: the
least-squares slope of log(time) on log(n), over all sizes and over n >= 128.

``--solvers`` times one ARE (the x-side's, tau = 10 tau0, eps = 1e-2 sigma) by each method:
ordered Hamiltonian Schur, matrix sign function, scipy's ``solve_continuous_are`` (n <= 512) and
Newton-Kleinman from X0 = 0 (A is Hurwitz for the chain; n <= 512).

``--threads T`` sets the BLAS threads (the suite's default is 1: ``bench/_env.py``).
"""

from __future__ import annotations

import argparse
import math
import os
import resource
import sys
import time


def _args():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[16, 32, 64, 128, 256, 512, 1024],
                    help="state dimensions n (even)")
    ap.add_argument("--method", default="schur", choices=["schur", "sign", "scipy"])
    ap.add_argument("--lam", type=float, default=0.0, help="decay target")
    ap.add_argument("--threads", type=int, default=None, help="BLAS threads (default: the suite's, 1)")
    ap.add_argument("--solvers", action="store_true", help="compare the ARE solvers instead")
    return ap.parse_args()


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _fit(ns, ts):
    import numpy as np

    if len(ns) < 2:
        return math.nan
    return float(np.polyfit(np.log(ns), np.log(ts), 1)[0])


def run_route(args) -> None:
    import numpy as np

    from designs._riccati_route import structured_riccati
    from plants.chain import chain_plant

    print(f"Riccati route on chain_plant(N = n/2): method={args.method}, lam={args.lam}, "
          f"BLAS threads={os.environ.get('OPENBLAS_NUM_THREADS', '?')}")
    hdr = (f"{'n':>5} {'q':>4} {'m=p':>4} {'build_s':>8} {'route_s':>8} {'x_side':>7} {'e_side':>7} {'mu':>6} "
           f"{'joint':>7} {'status':>10} {'margin':>10} {'tries':>5} {'methods':>13} {'peak_MB':>8}")
    print(hdr)
    ns, ts = [], []
    for n in args.sizes:
        t0 = time.perf_counter()
        p = chain_plant(N=n // 2)
        t_build = time.perf_counter() - t0
        ch = p.channels
        t0 = time.perf_counter()
        res = structured_riccati(p.A, p.B, p.C, ch.G, ch.H, ch.lo, ch.hi, lam=args.lam, method=args.method)
        t_route = time.perf_counter() - t0
        tm = res.timings
        joint = tm.get("joint_build", 0.0) + tm.get("joint_eig", 0.0)
        print(f"{p.n:>5} {ch.q:>4} {p.m:>4} {t_build:>8.2f} {t_route:>8.2f} {tm.get('x_side', 0):>7.2f} "
              f"{tm.get('e_side', 0):>7.2f} {tm.get('mu', 0):>6.2f} {joint:>7.2f} {res.status:>10} "
              f"{res.margin:>10.3g} {len(res.tries):>5} {'/'.join(res.methods) or '-':>13} {_peak_mb():>8.0f}",
              flush=True)
        if res.status != "feasible":
            print(f"      reason: {res.reason}")
        ns.append(p.n)
        ts.append(t_route)
    big = [(n, t) for n, t in zip(ns, ts) if n >= 128]
    print(f"growth exponent (least squares, log time on log n): all sizes {_fit(ns, ts):.2f}; "
          f"n >= 128: {_fit([n for n, _ in big], [t for _, t in big]):.2f}")
    _ = np


def run_solvers(args) -> None:
    import numpy as np
    from scipy.linalg import solve_continuous_lyapunov

    from designs._riccati_route import _norm2, solve_are
    from plants.chain import chain_plant

    print(f"one ARE (x-side of the chain, tau = 10 tau0, eps = 1e-2 sigma); "
          f"BLAS threads={os.environ.get('OPENBLAS_NUM_THREADS', '?')}")
    print(f"{'n':>5} {'method':>8} {'seconds':>8} {'residual':>9} {'max_re':>10} {'iters':>5}  note")
    for n in args.sizes:
        p = chain_plant(N=n // 2)
        ch = p.channels
        DH = ch.spread[:, None] * ch.H
        sigma = _norm2(ch.G) * _norm2(DH)
        s = _norm2(DH) / _norm2(ch.G)
        tau = 10 * sigma / _norm2(p.B) ** 2
        eps = 1e-2 * sigma
        b = np.hstack([p.B, ch.G])
        rr = np.concatenate([np.full(p.m, 1 / (2 * tau)), np.full(ch.q, -1 / s)])
        q = DH.T @ DH / s + eps * np.eye(p.n)
        for method in ("schur", "sign", "scipy"):
            if method == "scipy" and p.n > 512:
                continue
            X, info = solve_are(p.A, b, rr, q, method=method, fallback=False)
            print(f"{p.n:>5} {method:>8} {info.seconds:>8.2f} {info.residual:>9.1e} {info.closed_loop_max_re:>10.3g} "
                  f"{'':>5}  {info.reason}", flush=True)
        if p.n <= 512:  # Newton-Kleinman: X_{k+1} from (a - M X_k)' X + X (a - M X_k) + X_k M X_k + q = 0
            M = (b / rr) @ b.T
            t0 = time.perf_counter()
            X = np.zeros((p.n, p.n))
            for k in range(1, 101):
                Ak = p.A - M @ X
                Xn = solve_continuous_lyapunov(Ak.T, -(X @ M @ X + q))
                Xn = (Xn + Xn.T) / 2
                done = np.abs(Xn - X).max() <= 1e-12 * max(1.0, np.abs(Xn).max())
                X = Xn
                if done:
                    break
            sec = time.perf_counter() - t0
            R = p.A.T @ X + X @ p.A - X @ M @ X + q
            nX = np.abs(X).sum(0).max()
            res = np.abs(R).sum(0).max() / (2 * np.abs(p.A).sum(0).max() * nX + np.abs(M).sum(0).max() * nX**2
                                             + np.abs(q).sum(0).max())
            mre = float(np.linalg.eigvals(p.A - M @ X).real.max())
            print(f"{p.n:>5} {'newton':>8} {sec:>8.2f} {res:>9.1e} {mre:>10.3g} {k:>5}  from X0 = 0", flush=True)


def main() -> None:
    args = _args()
    if args.threads is not None:
        if "numpy" in sys.modules:
            raise SystemExit("--threads must be set before numpy is imported")
        for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ[var] = str(args.threads)
    import bench._env  # noqa: F401  (the suite's BLAS default when --threads is not given)

    if any(n < 2 or n % 2 for n in args.sizes):
        raise SystemExit("--sizes: every n must be even and >= 2 (n = 2N)")
    (run_solvers if args.solvers else run_route)(args)


if __name__ == "__main__":
    main()
