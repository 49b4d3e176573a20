# A design of your own (a plugin): both gains by pole placement with python-control.
from dataclasses import dataclass

import control
import numpy as np

from bench import Constants, Design, DesignResult, Plant, register_design


@register_design("my_poles")
@dataclass(frozen=True, kw_only=True)
class PolePlacement(Design):
    """Pole placement: eig(A + B F) = -rate (1, 1.5, 2, ...), eig(A - K C) speed times those."""

    rate: float = 2.0
    speed: float = 3.0

    needs = ()  # the constants of f the design uses, e.g. ("alpha",): none here

    def design(self, plant: Plant, constants: Constants) -> DesignResult:
        poles = -self.rate * (1.0 + 0.5 * np.arange(plant.n))
        try:
            # u = F x_hat: python-control's place gives G with eig(A - B G) = poles, so F = -G
            F = -control.place(plant.A, plant.B, poles)
            # the observer is the dual problem: eig(A' - C' L) = eig(A - L' C), so K = L'
            K = control.place(plant.A.T, plant.C.T, self.speed * poles).T
        except ValueError as exc:  # e.g. a pole repeated more often than rank(B)
            return DesignResult(status="inapplicable", reason=f"pole placement: {exc}")
        return DesignResult(status="computed", route="formula", K=K, F=F,
                            params={"rate": self.rate, "speed": self.speed})
