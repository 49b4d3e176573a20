"""Print per-design compile and solve times on a plant (a benchmark that prints figures).

Usage: ``python benchmarks/design_times.py [plant_id] [repeats]`` (defaults: flexible_link, 5).
Each design is run ``repeats`` times in a warm process (imports excluded), twice over: *cold*
(the compiled-program cache cleared before every call, so each call builds and compiles its
cvxpy problem) and *cached* (the program compiled by the first call is re-used, as in a sweep
or a bisection). The median wall, compile and solve seconds of each are printed.
"""

from __future__ import annotations

import statistics
import sys
import time

from bench.constants import compute_constants
from bench.registry import DESIGNS, PLANTS
from bench.lmi import clear_program_cache


def main() -> None:
    pid = sys.argv[1] if len(sys.argv) > 1 else "flexible_link"
    reps = int(sys.argv[2]) if len(sys.argv) > 2 else 5
    plant = PLANTS.create(pid)
    consts = compute_constants(plant).used
    import cvxpy  # noqa: F401  (warm imports)

    print(f"{'design':<16} {'status':<12} {'solves':>6} | cold: {'wall_s':>8} {'compile_s':>10} {'solve_s':>8} "
          f"| cached: {'wall_s':>8} {'compile_s':>10} {'solve_s':>8}")
    med = statistics.median
    for did in DESIGNS.ids():
        d = DESIGNS.create(did)
        if d.applicable(plant, consts) is not None:
            continue
        cells = []
        for cold in (True, False):
            clear_program_cache()
            walls, comps, sols = [], [], []
            for _ in range(reps):
                if cold:
                    clear_program_cache()
                t0 = time.perf_counter()
                r = d.design(plant, consts)
                walls.append(time.perf_counter() - t0)
                comps.append(r.compile_s)
                sols.append(r.solve_s)
            cells.append(f"{med(walls):>8.4f} {med(comps):>10.4f} {med(sols):>8.4f}")
        print(f"{did:<16} {r.status:<12} {r.n_solves:>6} |       {cells[0]} |         {cells[1]}")

if __name__ == "__main__":
    main()
