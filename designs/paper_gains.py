"""The gains printed in the paper, (37)-(38), as a reference row (no solve).

References
----------
Observer-based stabilization of one-sided Lipschitz systems with application to flexible link
manipulator, eqs. (37)-(38).
"""

from __future__ import annotations

from dataclasses import dataclass

from bench.registry import register_design
from designs._core import Design, DesignResult
from plants import Constants, Plant
from plants.flexible_link import PAPER_F, PAPER_K

__all__ = ["PaperGains"]


@register_design("paper_gains", order=14)
@dataclass(frozen=True, kw_only=True)
class PaperGains(Design):
    """The paper's printed gains K (37) and F (38); flexible link plants only."""

    def applicable(self, plant: Plant, constants: Constants) -> str | None:
        if plant.family != "flexible_link":
            return f"the printed gains belong to the flexible link manipulator, not to {plant.id!r}"
        if plant.A.shape != (4, 4) or plant.B.shape != (4, 1) or plant.C.shape != (2, 4):
            return "the printed gains need n = 4, m = 1, p = 2"
        return None

    def design(self, plant: Plant, constants: Constants) -> DesignResult:
        """Return the printed gains (no solve)."""
        return DesignResult(status="given", route="given", reason="printed in the paper (37)-(38); no LMI solved here",
                            K=PAPER_K.copy(), F=PAPER_F.copy(), solver=None,
                            params={"source": "eqs. (37)-(38)"})
