"""The gains printed by Nguyen, Pathirana & Trinh (Eur. J. Control 2018) for their two discrete examples (no solve).

Example 1 (Theorem 3) and Example 2 (Theorem 1) print a controller gain ``K`` for ``u = -K x_hat`` and an
observer gain ``L``; in oslbench's notation ``F = -K`` and ``K = L`` (:mod:`plants.nguyen2018`, which also says
how Example 1's 4 x 2 L is read). The gains belong to the Euler-discretised plants at ts = 1 ms, so the design
applies to a discrete plant whose sample time and matrices A, B, C are the example's (checked to 1e-12), such
as ``nguyen2018_ex1_flexible_joint_v1``, ``nguyen2018_ex2_moving_object_v1`` and their scaled classes
(:meth:`plants.Plant.scaled`), and to no other plant.

References
----------
C. M. Nguyen, P. N. Pathirana and H. Trinh, "Robust observer-based control designs for discrete nonlinear
systems with disturbances", European Journal of Control, 2018, doi:10.1016/j.ejcon.2018.09.002, Examples 1-2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.registry import register_design
from designs._core import Design, DesignResult
from plants import Constants, Plant
from plants import flexible_joint, moving_object, nguyen2018

__all__ = ["Nguyen2018Gains"]

#: (name, Ac, Bc, C, K printed, L printed, where printed) of each example; A = I + ts Ac, B = ts Bc.
EXAMPLES = (
    ("Example 1 (Theorem 3)", flexible_joint.A, flexible_joint.B, flexible_joint.C, nguyen2018.EX1_K,
     nguyen2018.EX1_L, "Example 1, gains of Theorem 3 (mu = 1.0100)"),
    ("Example 2 (Theorem 1, eps0 = 0.0372)", moving_object.A, moving_object.B, moving_object.C, nguyen2018.EX2_K,
     nguyen2018.EX2_L, "Example 2, gains of Theorem 1 (mu = 1.9956)"),
)


def _example(plant: Plant):
    """The example whose Euler-discretised (A, B, C) at ts = 1 ms is ``plant``'s (None if none)."""
    if not plant.discrete or abs(plant.dt - nguyen2018.TS) > 1e-15:
        return None
    ts = nguyen2018.TS
    for ex in EXAMPLES:
        _, Ac, Bc, C, *_ = ex
        A, B = np.eye(Ac.shape[0]) + ts * Ac, ts * Bc
        if plant.A.shape == A.shape and plant.B.shape == B.shape and plant.C.shape == C.shape and \
                all(np.allclose(M, N, rtol=0, atol=1e-12) for M, N in ((plant.A, A), (plant.B, B), (plant.C, C))):
            return ex
    return None


@register_design("nguyen2018_gains", order=15)
@dataclass(frozen=True, kw_only=True)
class Nguyen2018Gains(Design):
    """Nguyen, Pathirana & Trinh (2018)'s printed K and L (F = -K, K = L); their two ts = 1 ms examples only."""

    time_domains = ("discrete",)

    def applicable(self, plant: Plant, constants: Constants) -> str | None:
        if _example(plant) is None:
            return ("the printed gains belong to the Euler-discretised (ts = 1 ms) plants of Nguyen et al. 2018, "
                    f"Examples 1-2; {plant.id!r} has another sample time or other A, B, C")
        return None

    def design(self, plant: Plant, constants: Constants) -> DesignResult:
        """Return the printed gains in oslbench's notation (no solve)."""
        name, _, _, _, K_paper, L_paper, where = _example(plant)
        return DesignResult(status="given", route="given",
                            reason=f"printed in Nguyen et al. 2018, {where}; no LMI solved here",
                            K=L_paper.copy(), F=-K_paper.copy(), solver=None,
                            params={"source": f"Nguyen, Pathirana & Trinh 2018, {where}"})
