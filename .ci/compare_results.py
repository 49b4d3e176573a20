"""Compare a freshly generated results.csv with the committed one: the committed report must be what the
code prints.

Usage: ``python .ci/compare_results.py COMMITTED.csv FRESH.csv`` (exit 1 and a list of differences when they
disagree). Rows are matched by (plant, design). Every verdict column (:data:`VERDICTS`) must be equal;
every rate and metric must agree within its tolerance (:data:`TOLERANCES`: ``|a - b| <= atol + rtol |a|``,
NaN only with NaN); timings and free text (reasons, parameters) are not compared.
"""

from __future__ import annotations

import math
import sys

#: Columns that must be equal (the verdicts a reader acts on).
VERDICTS = ("status", "feasible", "stabilizing", "certified", "cert_level", "cert_scope", "converged", "cert_paper",
            "cert_full", "cert_structured", "in_region", "sim_status", "route", "solver_status", "horizon_rule",
            "witness")

#: Column -> (rtol, atol). Rates: the rate search's 1 % grid (a probe that flips on the tolerance moves a
#: rate by one grid step; two steps allowed); the rate ceiling: a seeded search, refined; solver-made
#: numbers (gains, margins): the solvers' own tolerances; simulated metrics: the integrator's tolerance
#: (rtol 1e-8) after the gains' differences; final norms are round-off (about 1e-11): absolute. Numbers of
#: a certificate's P (the level sets, V at x0) move with the point the solver picks among the feasible
#: ones, which differs between CPUs (a CPU with AVX-512 gave V(x0) 1.9 % off for one certificate whose rate
#: moved 1 %): as the rates' two grid steps, 5 %.
TOLERANCES = {
    **{c: (0.021, 1e-9) for c in ("decay_rate", "decay_paper", "decay_full", "decay_structured", "rate_ratio")},
    "rate_ceiling": (1e-3, 1e-9),
    **{c: (1e-3, 1e-6) for c in ("norm_K", "norm_F", "peak_u", "iae_e", "max_norm")},
    **{c: (1e-3, 1e-6) for c in ("settling_x_s", "settling_e_s", "max_re_eig_x", "max_re_eig_e")},
    **{c: (0.05, 1e-6) for c in ("horizon_s", "cert_horizon_s", "level_set", "level_x0", "cert_radius")},
    **{c: (0.0, 1e-6) for c in ("final_x", "final_e", "rms_e")},
}


def _same(a, b, rtol: float, atol: float) -> bool:
    a, b = float(a), float(b)
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return abs(a - b) <= atol + rtol * abs(a)


def compare(committed, fresh) -> list[str]:
    """The differences between two results tables (pandas DataFrames), one line each (empty: they agree)."""
    key = ["plant", "design"]
    a, b = committed.set_index(key), fresh.set_index(key)
    out = [f"pair {p} x {d} only in the committed table" for p, d in a.index.difference(b.index)]
    out += [f"pair {p} x {d} only in the fresh table" for p, d in b.index.difference(a.index)]
    for idx in a.index.intersection(b.index, sort=False):
        ra, rb = a.loc[idx], b.loc[idx]
        for c in VERDICTS:
            if c in ra and c in rb and str(ra[c]) != str(rb[c]):
                out.append(f"{idx[0]} x {idx[1]}: {c} committed {ra[c]!r}, fresh {rb[c]!r}")
        for c, (rtol, atol) in TOLERANCES.items():
            if c in ra and c in rb and not _same(ra[c], rb[c], rtol, atol):
                out.append(f"{idx[0]} x {idx[1]}: {c} committed {ra[c]!r}, fresh {rb[c]!r} (rtol {rtol:g}, atol {atol:g})")
    return out


def main(argv: list[str]) -> int:
    import pandas as pd

    if len(argv) != 2:
        print(__doc__.strip().splitlines()[2], file=sys.stderr)
        return 2
    read = lambda p: pd.read_csv(p, keep_default_na=True, dtype={c: str for c in VERDICTS})  # noqa: E731
    diffs = compare(read(argv[0]), read(argv[1]))
    for line in diffs:
        print(line)
    print(f"results: {'the same within tolerance' if not diffs else f'{len(diffs)} differences'} "
          f"({argv[0]} vs {argv[1]})")
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
