"""Raghavan-Hedrick Riccati observer for Lipschitz systems.

If, for some eps > 0, the Riccati equation ::

    A P + P A' + P (alpha^2 I - C'C / eps) P + (1 + eps) I = 0

has a solution P > 0, then ``K = P C' / (2 eps)`` makes the estimation error of
``x_hat' = A x_hat + B u + f(x_hat) + K (y - C x_hat)`` converge for every f with Lipschitz
constant alpha (V = e' P^{-1} e). The equation is solved with scipy's
``solve_continuous_are(A', [C', I], (1 + eps) I, diag(eps I_p, -I_n / alpha^2))``: the
indefinite weight makes ``B R^{-1} B' = C'C/eps - alpha^2 I`` (eps searched: :class:`RHRiccati`).

References
----------
S. Raghavan and J. K. Hedrick, "Observer design for a class of nonlinear systems",
Int. J. Control 59(2), 1994. R. Rajamani, "Observers for Lipschitz nonlinear systems",
IEEE TAC 43(3), 1998.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from designs._core import DesignResult, check_int, check_positive, check_range
from designs._parts import Part, register_estimator
from plants import Constants, Plant

__all__ = ["RHRiccati"]


def rh_solve(A: np.ndarray, C: np.ndarray, alpha: float, eps: float,
             residual_tol: float) -> tuple[tuple | None, str]:
    """Solve the Raghavan-Hedrick ARE for one eps and check the solution (P > 0, the relative residual, A - KC
    Hurwitz); returns ``((K, residual, lmin(P)), "")`` or ``(None, why)``."""
    from scipy.linalg import block_diag, solve_continuous_are

    n, p = A.shape[0], C.shape[0]
    Bb = np.hstack([C.T, np.eye(n)]) if alpha > 0 else C.T
    R = block_diag(eps * np.eye(p), -np.eye(n) / alpha**2) if alpha > 0 else eps * np.eye(p)
    try:
        P = solve_continuous_are(A.T, Bb, (1 + eps) * np.eye(n), R)
    except (np.linalg.LinAlgError, ValueError) as exc:
        return None, str(exc).splitlines()[0]
    if not np.all(np.isfinite(P)):
        return None, "non-finite solution"
    P = (P + P.T) / 2
    res = A @ P + P @ A.T + P @ (alpha**2 * np.eye(n) - C.T @ C / eps) @ P + (1 + eps) * np.eye(n)
    res = float(np.abs(res).max() / max(1.0, float(np.abs(P).max()) ** 2, 1 + eps))
    lo = float(np.linalg.eigvalsh(P)[0])
    K = P @ C.T / (2 * eps)
    if lo <= 0:
        return None, "P not positive definite"
    if res > residual_tol:
        return None, f"residual above {residual_tol:g}"
    if np.linalg.eigvals(A - K @ C).real.max() >= 0:
        return None, "A - KC not Hurwitz"
    return (K, res, lo), ""


@register_estimator("rh_riccati")
@dataclass(frozen=True, kw_only=True)
class RHRiccati(Part):
    """Raghavan-Hedrick Riccati observer, K = P C' / (2 eps); eps searched (scipy ARE).

    Parameters
    ----------
    eps : float, optional
        Fixed eps; None (default) tries ``n_grid`` log-spaced values in ``eps_range`` and keeps
        the largest eps with a valid solution.
    eps_range : tuple of float
    n_grid : int
    residual_tol : float
        Maximum relative ARE residual.
    """

    eps: float | None = None
    eps_range: tuple[float, float] = (1e-4, 1e2)
    n_grid: int = 25
    residual_tol: float = 1e-8

    needs = ("alpha",)

    def __post_init__(self) -> None:
        if self.eps is not None:
            check_positive("eps", self.eps)
        check_range("eps_range", self.eps_range, strict=False)
        check_positive("residual_tol", self.residual_tol)
        check_int("n_grid", self.n_grid, minimum=1)

    def compute(self, plant: Plant, constants: Constants) -> DesignResult:
        """Search eps and return K, or 'no stabilizing solution' with the failures seen."""
        import time

        A, C, alpha = plant.A, plant.C, float(constants.alpha)
        grid = [float(self.eps)] if self.eps is not None else list(
            np.logspace(math.log10(self.eps_range[0]), math.log10(self.eps_range[1]), int(self.n_grid)))
        t0 = time.perf_counter()
        valid, failures = [], {}
        for eps in grid:
            sol, why = rh_solve(A, C, alpha, eps, self.residual_tol)
            if sol is None:
                failures.setdefault(why, []).append(eps)
            else:
                valid.append((eps, *sol))
        base = dict(route="riccati", solver="scipy.solve_continuous_are", solve_s=time.perf_counter() - t0,
                    n_solves=len(grid))
        if not valid:
            summary = "; ".join(f"{why} (eps = {', '.join(f'{e:.2g}' for e in es[:3])}{', ...' if len(es) > 3 else ''})"
                                for why, es in failures.items())
            return DesignResult(status="infeasible", solver_status="no solution", params={"alpha": alpha}, **base,
                                reason=f"no stabilizing solution P > 0 of the RH Riccati equation for alpha = {alpha:.4g} "
                                       f"on {len(grid)} eps values in [{grid[0]:.2g}, {grid[-1]:.2g}]: {summary}")
        eps, K, res, lo = max(valid, key=lambda v: v[0])
        return DesignResult(status="feasible", K=K, solver_status="solved", min_eig={"P": lo}, **base,
                            params={"eps": eps, "alpha": alpha, "riccati_residual": res,
                                    "eps_valid_min": min(v[0] for v in valid), "eps_valid_max": eps})
