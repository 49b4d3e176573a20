"""LMI observers for Lipschitz (Rajamani-style) and OSL/QIB (Zhang et al. 2012) systems.

Both solve a 2n x 2n LMI maximising a margin ``slack`` under ``P << cap I``, verified with numpy
(:func:`bench.lmi.solve_side`).

References
----------
R. Rajamani, "Observers for Lipschitz nonlinear systems", IEEE TAC 43(3), 1998 (LMI form as in
Rajamani & Cho 1998). W. Zhang, H. Su, H. Wang and Z. Han, "Full-order and reduced-order
observers for one-sided Lipschitz nonlinear systems using Riccati equations", Commun. Nonlinear
Sci. Numer. Simul. 17(12), 2012, and the LMI form of Abbaszadeh & Marquez (ACC 2010).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from bench import lmi
from designs._core import DesignResult, check_choice, check_positive
from designs._parts import Part, register_estimator
from designs._separated import joint_result, scalar, side_program, synthesis_variables
from plants import Constants, Plant

__all__ = ["RajamaniLMI", "ZhangOSL"]


@dataclass(frozen=True, kw_only=True)
class _ObserverLMI(Part):
    """The hyperparameters of an observer LMI: ``decay`` (lam >= 0) asks for ``V' <= -2 lam V``; cap, solver."""

    decay: float = 0.0
    cap: float = 1e3
    solver: str = "auto"

    def __post_init__(self) -> None:
        check_positive("decay", self.decay, allow_zero=True)
        check_positive("cap", self.cap)
        check_choice("solver", self.solver, ("auto", "CLARABEL", "SCS"))


def _solve_observer(part: "Part", plant: Plant, key: tuple, blocks, matrices: tuple[str, ...], mats: lmi.Matrices,
                    constants: dict, nonneg: tuple[str, ...], *, what: str, searched: str,
                    gain: Callable[[dict], np.ndarray], params: Callable[[dict], dict]) -> DesignResult:
    """Solve the LMI ``blocks`` in ``matrices`` and the scalars ``nonneg`` under ``P << cap I``, a marginal verdict
    again under ``I << P << cap I``; K is ``gain(values)`` when feasible, the scalars ``params(values)``."""
    def variables():
        return synthesis_variables(plant.n, plant.m, plant.p, nonneg, matrices)

    prog = side_program(key, blocks, variables, mats, constants, nonneg, "P", cap=part.cap, scale_free=False)
    log = lmi.solve_side(prog, part.solver, plant.n)
    concl = lmi.conclude(prog, what=what, normalisation=f"P << {part.cap:g} I, slack <= 1", searched=searched)
    if concl["status"] == "marginal":
        sf = side_program(key, blocks, variables, mats, constants, nonneg, "P", cap=part.cap, scale_free=True)
        lmi.solve_side(sf, "CLARABEL" if part.solver == "auto" else part.solver)
        norm = f"I << P << {part.cap:g} I"
        dec = lmi.conclude(sf, what=what, normalisation=norm, searched=f"{searched} (scale-free)")
        if dec["status"] == "infeasible":
            concl = {**concl, "status": "infeasible", "reason": (
                f"{dec['reason']}; the LMI is homogeneous in its variables, so this loses only points with "
                f"cond(P) > {part.cap:g} (under P << {part.cap:g} I alone the best margin shrinks to 0 with the "
                f"variables: max eig {concl['margin']:.3g})")}
    vals = prog.values()
    K = gain(vals) if concl["status"] == "feasible" else None
    return joint_result(prog, concl, params(vals), gains=(K, None), log=log)


@register_estimator("rajamani")
@dataclass(frozen=True, kw_only=True)
class RajamaniLMI(_ObserverLMI):
    """Lipschitz LMI observer: [(A-KC)'P + P(A-KC) + eps alpha^2 I + 2 lam P, P; P, -eps I] < 0.

    With ``W = P K`` this is an LMI in (P, W, eps) (V = e'Pe, Young's inequality on
    2 e'P (f - f_hat)); ``K = P^{-1} W``.
    """

    needs = ("alpha",)

    def compute(self, plant: Plant, constants: Constants) -> DesignResult:
        """Solve the LMI and return K."""
        n, p = plant.n, plant.p
        a2, lam = float(constants.alpha) ** 2, float(self.decay)
        I = np.eye(n)

        def blocks(d):
            A, C, P, W = d["A"], d["C"], d["P"], d["W"]
            S = A.T @ P + P @ A - C.T @ W.T - W @ C + d["eps"] * d["a2"] * I + 2 * lam * P
            return [[S, P], [P, -d["eps"] * I]]

        mats = lmi.matrices(A=plant.A, C=plant.C)
        return _solve_observer(self, plant, ("rajamani", n, p, lam), blocks, ("P", "W"), mats, {"a2": a2}, ("eps",),
                               what="Rajamani LMI observer", searched=f"with decay {lam:g}",
                               gain=lambda vals: np.linalg.solve(vals["P"], vals["W"]),
                               params=lambda vals: {"alpha": constants.alpha, "decay": lam, "eps": scalar(vals, "eps")})


@register_estimator("zhang_osl")
@dataclass(frozen=True, kw_only=True)
class ZhangOSL(_ObserverLMI):
    """OSL/QIB LMI observer (Zhang et al. 2012): K = (sigma/2) P^{-1} C'.

    The LMI, in (P, sigma, eps1, eps2) ::

        [ A'P + PA + (eps1 rho + eps2 beta) I - sigma C'C + 2 lam P   P + ((gamma eps2 - eps1)/2) I ]
        [ *                                                           -eps2 I                       ]  < 0

    is the S-procedure on V = e'Pe with the OSL and QIB inequalities for ``f - f_hat``.
    """

    needs = ("rho", "beta", "gamma")

    def compute(self, plant: Plant, constants: Constants) -> DesignResult:
        """Solve the LMI and return K."""
        C = plant.C
        n = plant.n
        rho, beta, gamma = constants.rho, constants.beta, constants.gamma
        lam = float(self.decay)
        I = np.eye(n)

        def blocks(d):
            A, P = d["A"], d["P"]
            S = (A.T @ P + P @ A + (d["eps1"] * d["rho"] + d["eps2"] * d["beta"]) * I - d["sigma"] * d["CtC"]
                 + 2 * lam * P)
            X = P + ((d["gamma"] * d["eps2"] - d["eps1"]) / 2) * I
            return [[S, X], [X.T, -d["eps2"] * I]]

        # C'C is one parameter: sigma * (C' C) with C a parameter would not be DPP
        mats = lmi.matrices(A=plant.A, CtC=C.T @ C)
        return _solve_observer(self, plant, ("zhang_osl", n, lam), blocks, ("P",), mats,
                               {"rho": rho, "beta": beta, "gamma": gamma}, ("sigma", "eps1", "eps2"),
                               what="Zhang OSL LMI observer", searched=f"with decay {lam:g}",
                               gain=lambda vals: (float(vals["sigma"]) / 2) * np.linalg.solve(vals["P"], C.T),
                               params=lambda vals: {"rho": rho, "beta": beta, "gamma": gamma, "decay": lam,
                                                    **{k: scalar(vals, k) for k in ("sigma", "eps1", "eps2")}})
