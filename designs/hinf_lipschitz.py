"""An H-infinity observer for Lipschitz systems: the gain K minimising the L2 gain from w to e.

Plant ``x' = A x + B u + f(x) + Bw w``, ``y = C x + Dw w``, ``||f(x1) - f(x2)|| <= alpha ||x1 - x2||``; observer
``x_hat' = A x_hat + B u + f(x_hat) + K (y - C x_hat)``; error ``e' = (A - K C) e + df + (Bw - K Dw) w``.
With ``V = e' R e``, ``V' + |e|^2 - g |w|^2 + mu (alpha^2 |e|^2 - |df|^2) <= 0`` for all ``(e, df, w)`` gives
``||e||_L2 <= sqrt(g) ||w||_L2`` (zero initial error) for every f of the class, and with ``w = 0`` asymptotic
convergence. With ``Kh = K' R`` it is the LMI in ``(R, Kh, mu, g)`` ::

    [ A'R + RA - C'Kh - Kh'C + I + mu alpha^2 I    R         R Bw - Kh' Dw ]
    [ R                                            -mu I     0             ]  <= 0
    [ (R Bw - Kh' Dw)'                              0         -g I          ]

minimised in ``g``, then re-solved strictly at ``g = (1 + backoff)^2 g*`` and verified
(:func:`designs._hinf.min_level`); ``K = R^-1 Kh'``, ``gamma_e = sqrt(g)`` in ``params``.

What it follows: this is the Lipschitz observer condition of Rajamani (1998) (here the ``rajamani``
estimator, the first two rows with ``mu``) with the bounded-real terms of the H-infinity observers of Pertew,
Marquez & Zhao (2006) and Abbaszadeh & Marquez (2009-2010), in the form in which those papers pose the
problem: the S-procedure with a Lipschitz multiplier and the bounded real lemma, linear in the gain through
``Kh = K' R``. The printed LMIs of those papers could not be read here (only their openings: see the
project's literature notes), so this LMI is written and derived from the conditions they state, not copied;
with ``mu`` free it is at least as permissive as a fixed-multiplier form.

Inapplicable without disturbance inputs (``Bw``, ``Dw``: nothing to attenuate) or without a Lipschitz
constant the run trusts (``needs``). Continuous time only.

References
----------
A. M. Pertew, H. J. Marquez and Q. Zhao, "H-infinity observer design for Lipschitz nonlinear systems", IEEE
Trans. Automatic Control 51(7), 1211-1216, 2006.
M. Abbaszadeh and H. J. Marquez, "Robust H-infinity filtering for Lipschitz nonlinear systems via
multiobjective optimization", J. Signal and Information Processing 1, 24-34, 2010; and Int. J. Robust
Nonlinear Control 19(3), 313-340, 2009.
R. Rajamani, "Observers for Lipschitz nonlinear systems", IEEE TAC 43(3), 397-401, 1998.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from designs._core import DesignResult, check_choice, check_positive
from designs._hinf import eside_blocks, min_level
from designs._parts import Part, register_estimator
from plants import Constants, Plant

__all__ = ["HinfLipschitz", "disturbance_inputs"]


def disturbance_inputs(plant: Plant) -> tuple[np.ndarray, np.ndarray]:
    """``(Bw, Dw)`` of ``plant`` with a missing one as zeros (``q`` columns)."""
    q = plant.q or (plant.Dw.shape[1] if plant.Dw is not None else 0)
    Bw = plant.Bw if plant.Bw is not None else np.zeros((plant.n, q))
    Dw = plant.Dw if plant.Dw is not None else np.zeros((plant.p, q))
    return np.asarray(Bw, dtype=float), np.asarray(Dw, dtype=float)


def no_disturbance(plant: Plant) -> str | None:
    """The reason an H-infinity design does not apply to ``plant`` (no disturbance input), or None."""
    if plant.Bw is None and plant.Dw is None:
        return "the plant has no disturbance inputs (Bw, Dw): there is no L2 gain from w to attenuate"
    return None


@register_estimator("hinf_lipschitz")
@dataclass(frozen=True, kw_only=True)
class HinfLipschitz(Part):
    """H-infinity observer for Lipschitz systems (module docstring): K minimising the L2 gain w -> e.

    Parameters
    ----------
    backoff : float
        The verified level is ``(1 + backoff)`` times the optimum (a minimiser is never strictly feasible).
    solver : {"CLARABEL", "SCS"}
    """

    backoff: float = 0.02
    solver: str = "CLARABEL"

    needs = ("alpha",)

    def __post_init__(self) -> None:
        check_positive("backoff", self.backoff)
        check_choice("solver", self.solver, ("CLARABEL", "SCS"))

    def applicable(self, plant: Plant, constants: Constants) -> str | None:
        return no_disturbance(plant) or super().applicable(plant, constants)

    def compute(self, plant: Plant, constants: Constants) -> DesignResult:
        """Minimise the level, verify it, return K and ``gamma_e``."""
        import cvxpy as cp

        n, p = plant.n, plant.p
        Bw, Dw = disturbance_inputs(plant)
        q = Bw.shape[1]
        a2 = float(constants.alpha) ** 2

        def variables():
            return {"R": cp.Variable((n, n), symmetric=True, name="R"), "Kh": cp.Variable((p, n), name="Kh"),
                    "mu": cp.Variable(name="mu"), "g": cp.Variable(name="g")}

        out = min_level(eside_blocks("lipschitz", n, q), variables,
                        {"A": plant.A, "C": plant.C, "Bw": Bw, "Dw": Dw, "a2": a2}, ("R",), ("mu",), ("g",),
                        backoff=self.backoff, solver=self.solver, what="H-infinity Lipschitz observer LMI")
        K = None
        if out["status"] == "feasible":
            vals = out["values"]
            K = np.linalg.solve(vals["R"], vals["Kh"].T)
        g = out["levels"]["g"]
        return DesignResult(
            status=out["status"], reason=out.get("reason", ""), route="sdp", K=K, solver=self.solver,
            solver_status=out["solver_status"], compile_s=out["compile_s"], solve_s=out["solve_s"],
            n_solves=out["n_solves"], margin=out["margin"], lmi_size=out["lmi_size"], min_eig=out["min_eig"],
            params={"gamma_e": float(np.sqrt(g)) if out["status"] == "feasible" else float("nan"),
                    "gamma_e_optimum": float(np.sqrt(out["optimum"]["g"])), "backoff": self.backoff,
                    "alpha": constants.alpha,
                    "mu": float(out["values"]["mu"]) if out["values"] is not None else float("nan")})
