"""A design of your own: both gains by pole placement (python-control), run like a built-in design.

    python -m bench list --plugin examples/my_design.py
    python -m bench run --plugin examples/my_design.py --plant flexible_link --design my_poles --out my_report

or, from Python: ``bench.run(plants=["flexible_link"], designs=[PolePlacement(rate=2.0)])``.
The suite then checks, certifies (the whole ladder), simulates and times it like any other design.
"""

from dataclasses import dataclass

import control
import numpy as np

from bench import Constants, Design, DesignResult, Plant, register_design


@register_design("my_poles")
@dataclass(frozen=True, kw_only=True)
class PolePlacement(Design):
    """Pole placement of both gains: A + B F and A - K C get real poles -rate (1 + k / 2), the observer `speed` times faster."""

    rate: float = 2.0
    speed: float = 3.0

    needs = ()  # no constant of f is used (they are named here when a design needs them: "alpha", "rho", ...)

    def design(self, plant: Plant, constants: Constants) -> DesignResult:
        poles = -self.rate * (1.0 + 0.5 * np.arange(plant.n))
        try:
            # u = F x_hat: python-control's place gives G with eig(A - B G) = poles, so F = -G
            F = -control.place(plant.A, plant.B, poles)
            # the observer is the dual problem: eig(A' - C' L) = eig(A - L' C), so K = L'
            K = control.place(plant.A.T, plant.C.T, self.speed * poles).T
        except ValueError as exc:  # e.g. (A, B) not controllable, or a pole of multiplicity > rank(B)
            return DesignResult(status="inapplicable", reason=f"pole placement: {exc}")
        return DesignResult(status="computed", route="formula", K=K, F=F,
                            params={"rate": self.rate, "speed": self.speed})
