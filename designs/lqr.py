"""LQR state feedback and the Kalman-gain (LQE) observer, both from python-control.

python-control's ``lqr`` returns K_lqr with ``u = -K_lqr x``; the paper's ``u = F x_hat`` has ``F = -K_lqr``.
``lqe`` returns the observer gain L of ``x_hat' = A x_hat + B u + L (y - C x_hat)``, the paper's K.

References
----------
B. D. O. Anderson and J. B. Moore, *Optimal Control: Linear Quadratic Methods*, 1990.
python-control, ``control.lqr`` and ``control.lqe``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from designs._core import DesignResult
from designs._parts import Part, check_weight, register_estimator, register_feedback
from plants import Constants, Plant

__all__ = ["LQEObserver", "LQRFeedback"]


@dataclass(frozen=True, kw_only=True)
class _Weighted(Part):
    """A part with weight matrices ``weights``: ``(field, definite, plant dimension)``, checked when built."""

    weights: ClassVar[tuple[tuple[str, bool, str], ...]] = ()

    def __post_init__(self) -> None:
        for name, definite, _ in self.weights:
            if getattr(self, name) is not None:
                check_weight(name, getattr(self, name), None, definite=definite)

    def _matrices(self, plant: Plant) -> list[np.ndarray]:
        """The weights for ``plant`` (None is the identity, a scalar s is s I)."""
        return [check_weight(name, getattr(self, name), getattr(plant, dim), definite=definite)
                for name, definite, dim in self.weights]


@register_feedback("lqr")
@dataclass(frozen=True, kw_only=True)
class LQRFeedback(_Weighted):
    """LQR state feedback F = -K_lqr from ``control.lqr(A, B, Q, R, method="scipy")``.

    Minimises the integral of ``x'Qx + u'Ru`` for the linear part. ``Q`` (n x n, symmetric
    PSD) defaults to I_n and ``R`` (m x m, symmetric PD) to I_m; a scalar means scalar * I.
    The Riccati residual ``A'S + SA - S B R^{-1} B' S + Q`` is recorded as evidence.
    """

    Q: Any = None
    R: Any = None

    weights = (("Q", False, "n"), ("R", True, "m"))

    def compute(self, plant: Plant, constants: Constants) -> DesignResult:
        """F = -K_lqr for ``plant``'s (A, B)."""
        import control

        A, B = plant.A, plant.B
        Q, R = self._matrices(plant)
        try:
            K_lqr, S, _ = control.lqr(A, B, Q, R, method="scipy")
        except Exception as exc:  # not stabilizable, Hamiltonian on the axis, ...
            return DesignResult(status="infeasible", reason=f"control.lqr failed: {exc}", route="formula",
                                solver="control.lqr", solver_status="failed")
        K_lqr = np.asarray(K_lqr, dtype=float)
        S = np.asarray(S, dtype=float)
        res = A.T @ S + S @ A - S @ B @ np.linalg.solve(R, B.T) @ S + Q
        return DesignResult(status="computed", route="formula", F=-K_lqr, solver="control.lqr", solver_status="solved",
                          params={"riccati_residual": float(np.abs(res).max()), "Q": "I" if self.Q is None else "set",
                                  "R": "I" if self.R is None else "set"})


@register_estimator("lqe")
@dataclass(frozen=True, kw_only=True)
class LQEObserver(_Weighted):
    """Kalman-gain observer K = L from ``control.lqe(A, I, C, QN, RN, method="scipy")``.

    ``QN`` (n x n, process noise, symmetric PSD) defaults to I_n and ``RN`` (p x p,
    measurement noise, symmetric PD) to I_p; a scalar means scalar * I. The design ignores the nonlinearity.
    """

    QN: Any = None
    RN: Any = None

    weights = (("QN", False, "n"), ("RN", True, "p"))

    def compute(self, plant: Plant, constants: Constants) -> DesignResult:
        """K = L for ``plant``'s (A, C)."""
        import control

        QN, RN = self._matrices(plant)
        try:
            L, _, _ = control.lqe(plant.A, np.eye(plant.n), plant.C, QN, RN, method="scipy")
        except Exception as exc:
            return DesignResult(status="infeasible", reason=f"control.lqe failed: {exc}", route="formula",
                                solver="control.lqe", solver_status="failed")
        return DesignResult(status="computed", route="formula", K=np.asarray(L, dtype=float), solver="control.lqe",
                            solver_status="solved")
