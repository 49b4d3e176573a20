"""LQR state feedback and the Kalman-gain (LQE) observer, both from python-control, in continuous and discrete time.

python-control's ``lqr`` returns K_lqr with ``u = -K_lqr x``; the paper's ``u = F x_hat`` has ``F = -K_lqr``.
``lqe`` returns the observer gain L of ``x_hat' = A x_hat + B u + L (y - C x_hat)``, the paper's K.

On a discrete plant (``plant.dt > 0``) the parts use ``dlqr`` (``u_k = -G x_k``, minimising the sum of
``x_k' Q x_k + u_k' R u_k``: ``F = -G``) and ``dlqe``. The suite's discrete observer is the one-step
*predictor* ``x_hat_{k+1} = A x_hat_k + B u_k + f(x_hat_k) + K (y_k - C x_hat_k)``. python-control's ``dlqe``
returns ``L = A P C' (C P C' + RN)^-1`` with ``P`` the stabilising solution of the filter DARE
``P = A P A' - A P C' (C P C' + RN)^-1 C P A' + QN`` (the a priori covariance), which is exactly the
predictor's gain (Anderson & Moore 1979, ch. 3, the one-step predictor ``x_hat_{k+1|k}``; the filter gain of
``x_hat_{k|k}`` is ``P C' (C P C' + RN)^-1`` and the predictor's is ``A`` times it): so ``K = L`` with no
conversion, and ``eig(A - K C)`` are the Kalman predictor's poles (``dlqe``'s third output).

References
----------
B. D. O. Anderson and J. B. Moore, *Optimal Control: Linear Quadratic Methods*, 1990.
B. D. O. Anderson and J. B. Moore, *Optimal Filtering*, Prentice-Hall 1979, ch. 3 (the one-step predictor).
python-control, ``control.lqr``, ``control.dlqr``, ``control.lqe`` and ``control.dlqe``.
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
    """LQR state feedback F = -K_lqr from ``control.lqr(A, B, Q, R, method="scipy")`` (``control.dlqr`` on a
    discrete plant).

    Minimises the integral (discrete: the sum) of ``x'Qx + u'Ru`` for the linear part. ``Q`` (n x n, symmetric
    PSD) defaults to I_n and ``R`` (m x m, symmetric PD) to I_m; a scalar means scalar * I.
    The Riccati residual (``A'S + SA - S B R^{-1} B' S + Q``, discrete:
    ``A'SA - S - A'SB (B'SB + R)^{-1} B'SA + Q``) is recorded as evidence.
    """

    Q: Any = None
    R: Any = None

    weights = (("Q", False, "n"), ("R", True, "m"))
    time_domains = ("continuous", "discrete")

    def compute(self, plant: Plant, constants: Constants) -> DesignResult:
        """F = -K_lqr for ``plant``'s (A, B)."""
        import control

        A, B = plant.A, plant.B
        Q, R = self._matrices(plant)
        name = "control.dlqr" if plant.discrete else "control.lqr"
        try:
            solve = control.dlqr if plant.discrete else control.lqr
            K_lqr, S, _ = solve(A, B, Q, R, method="scipy")
        except Exception as exc:  # not stabilizable, Hamiltonian on the axis, ...
            return DesignResult(status="infeasible", reason=f"{name} failed: {exc}", route="formula",
                                solver=name, solver_status="failed")
        K_lqr = np.asarray(K_lqr, dtype=float)
        S = np.asarray(S, dtype=float)
        if plant.discrete:
            res = A.T @ S @ A - S - A.T @ S @ B @ np.linalg.solve(B.T @ S @ B + R, B.T @ S @ A) + Q
        else:
            res = A.T @ S + S @ A - S @ B @ np.linalg.solve(R, B.T) @ S + Q
        return DesignResult(status="computed", route="formula", F=-K_lqr, solver=name, solver_status="solved",
                            params={"riccati_residual": float(np.abs(res).max()), "Q": "I" if self.Q is None else "set",
                                    "R": "I" if self.R is None else "set"})


@register_estimator("lqe")
@dataclass(frozen=True, kw_only=True)
class LQEObserver(_Weighted):
    """Kalman-gain observer K = L from ``control.lqe(A, I, C, QN, RN, method="scipy")`` (``control.dlqe`` on a
    discrete plant: the one-step predictor's gain, see the module docstring).

    ``QN`` (n x n, process noise, symmetric PSD) defaults to I_n and ``RN`` (p x p,
    measurement noise, symmetric PD) to I_p; a scalar means scalar * I. The design ignores the nonlinearity.
    """

    QN: Any = None
    RN: Any = None

    weights = (("QN", False, "n"), ("RN", True, "p"))
    time_domains = ("continuous", "discrete")

    def compute(self, plant: Plant, constants: Constants) -> DesignResult:
        """K = L for ``plant``'s (A, C)."""
        import control

        QN, RN = self._matrices(plant)
        name = "control.dlqe" if plant.discrete else "control.lqe"
        try:
            solve = control.dlqe if plant.discrete else control.lqe
            L, _, _ = solve(plant.A, np.eye(plant.n), plant.C, QN, RN, method="scipy")
        except Exception as exc:
            return DesignResult(status="infeasible", reason=f"{name} failed: {exc}", route="formula",
                                solver=name, solver_status="failed")
        params = {"form": "one-step predictor x_hat_{k+1|k} (K = A P C'(C P C' + RN)^-1)"} if plant.discrete else {}
        return DesignResult(status="computed", route="formula", K=np.asarray(L, dtype=float), solver=name,
                            solver_status="solved", params=params)
