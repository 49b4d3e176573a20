"""Scaling of the Riccati route of the structured design on the chain family, n = 2N states.

Usage::

    python benchmarks/riccati_scaling.py [--sizes 16 32 ... 1024] [--method sign] [--lam LAM]
                                         [--threads T] [--no-reference]

For each n: the chain ``chain_plant(N=n/2)``, then
:func:`designs._riccati_route.structured_riccati` searches the decay target (or takes ``--lam``)
with ``max_gain = 20`` and certifies the pair by :func:`bench.joint.certify`. Printed per n: the
AREs solved, the seconds of the search and of the certificate, the total, the certified rate
and its exact bound, the linearised rate of the same gains, the peak resident memory so far, and
(unless ``--no-reference``) an unordered ``scipy.linalg.schur`` of a random 2n x 2n matrix timed
in the same process with the ratio total / reference.

``--threads T`` sets the BLAS threads (the suite's default is 1: ``bench/_env.py``).
"""

from __future__ import annotations

import argparse
import resource
import time


def _args():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[16, 32, 64, 128, 256, 512, 1024],
                    help="state dimensions n (even)")
    ap.add_argument("--method", default="sign", choices=["sign", "scipy"])
    ap.add_argument("--lam", type=float, default=None, help="a fixed decay target (default: searched)")
    ap.add_argument("--threads", type=int, default=1, help="BLAS threads (default 1, as the suite)")
    ap.add_argument("--no-reference", action="store_true", help="skip the Schur reference")
    return ap.parse_args()


def main() -> None:
    args = _args()
    if any(n < 2 or n % 2 for n in args.sizes):
        raise SystemExit("--sizes: every n must be even and >= 2 (n = 2N)")
    import numpy as np
    import scipy.linalg as sla
    from threadpoolctl import threadpool_limits

    from bench.certify import linearised_rate
    from designs._riccati_route import structured_riccati
    from plants.chain import chain_plant

    threadpool_limits(limits=args.threads, user_api="blas")
    print(f"Riccati route on chain_plant(N = n/2): method={args.method}, decay target "
          f"{'searched' if args.lam is None else args.lam}, max_gain 20, BLAS threads {args.threads}")
    print(f"{'n':>5} {'AREs':>5} {'search_s':>8} {'cert_s':>7} {'total_s':>8} {'status':>9} {'rate':>9} "
          f"{'bound':>9} {'linear':>9} {'peak_MB':>8} {'schur_s':>8} {'ratio':>6}")
    for n in args.sizes:
        p = chain_plant(N=n // 2)
        ch = p.channels
        t0 = time.perf_counter()
        res = structured_riccati(p.A, p.B, p.C, ch.G, ch.H, ch.lo, ch.hi, lam=args.lam, max_gain=20.0,
                                 method=args.method)
        total = time.perf_counter() - t0
        lin = linearised_rate(p, res.K, res.F) if res.K is not None else float("nan")
        ref = float("nan")
        if not args.no_reference:
            M = np.random.default_rng(0).standard_normal((2 * n, 2 * n))
            t1 = time.perf_counter()
            sla.schur(M, output="real", overwrite_a=True, check_finite=False)
            ref = time.perf_counter() - t1
        tm = res.timings
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        print(f"{p.n:>5} {len(res.tries):>5} {tm.get('search', 0):>8.2f} {tm.get('certificate', 0):>7.2f} "
              f"{total:>8.2f} {res.status:>9} {res.rate:>9.4g} {res.rate_bound:>9.4g} {lin:>9.4g} {peak:>8.0f} "
              f"{ref:>8.2f} {total / ref:>6.2f}", flush=True)
        if not res.ok:
            print(f"      reason: {res.reason}")


if __name__ == "__main__":
    main()
