"""Corollary 1 of the paper (Lipschitz f): as printed (Remarks 2-3) and corrected.

References
----------
Observer-based stabilization of one-sided Lipschitz systems with application to flexible link
manipulator, Corollary 1, eqs. (27)-(32), Remarks 2-3. Errata and corrected forms: ``docs/paper.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.registry import register_design
from designs import _discrete
from designs._core import Design, DesignResult, check_positive, check_values_in
from designs._separated import YoungForm, concluded, joint_program, scalar, state_feedback_block, young_layout
from designs._young import YoungDesign
from plants import Constants, Plant

__all__ = ["Cor1", "Cor1Printed"]


def lipschitz_w22(d: dict, I: np.ndarray):
    """``W22 = A'R + RA - C'Kh - Kh'C + mu2 alpha^2 I`` (values dict; ``a2`` = alpha^2)."""
    A, C, R, Kh = d["A"], d["C"], d["R"], d["Kh"]
    return A.T @ R + R @ A - C.T @ Kh - Kh.T @ C + d["mu2"] * d["a2"] * I


@register_design("cor1_sep", "Corollary 1, corrected, separated: x-side and e-side 2n LMIs solved apart, joint "
                 "certificate rebuilt and verified.", order=16, method="separated")
@register_design("cor1", order=12)
@dataclass(frozen=True, kw_only=True)
class Cor1(YoungDesign):
    """Corollary 1, corrected (kappa = 1/mu1 exact, docs/paper.md): the joint 6n LMI, Young weight phi2 searched.

    For fixed phi2, the LMI in Q, R, Fh, Kh, kappa, mu2 is the Young layout
    (:func:`designs._separated.young_layout`) with the e-side ``[[W22, R], [R, -mu2 I]]`` (W22:
    :func:`lipschitz_w22`) and the Schur weight ``kappa / alpha^2`` (no Schur column for alpha = 0);
    ``K = R^{-1} Kh'``, ``F = Fh' Q^{-1}``.

    On a discrete plant: the discrete Lipschitz x-side (``mu1 = 1/kappa``) and e-side of
    :mod:`designs._discrete`, solved apart, the joint discrete certificate rebuilt and verified.

    Parameters
    ----------
    phi2 : float, optional
        Fixed Young weight; None (default) searches ``phi2_range``.
    phi2_range : tuple of float
    n_grid, n_refine, cap, method, solver
        :class:`designs._young.YoungDesign`.
    """

    phi2: float | None = None
    phi2_range: tuple[float, float] = (1e-4, 10.0)

    needs = ("alpha",)
    phi_name = "phi2"
    scaled_variant = "cor1_scaled"
    cert_level = "full"
    cert_uses = ("alpha",)

    def discrete_forms(self, plant: Plant, constants: Constants) -> list:
        """The discrete form ``(YoungForm, multipliers, params)`` (:mod:`designs._discrete`): 3n x 3n sides."""
        n = plant.n
        I = np.eye(n)
        a2 = float(constants.alpha) ** 2
        schur = a2 > 0

        def eside(d):
            return _discrete.lipschitz_eside(d, I)

        form = YoungForm(what="discrete corrected Corollary 1", key=("cor1.discrete", schur),
                         blocks=(None, _discrete.xside(n, schur=schur, f_row=False), eside), e_scalars=("mu2",),
                         constants={"a2": a2, "sw": float(np.sqrt(a2))})

        def multipliers(xv, ev):
            if not schur:  # alpha = 0: the class is f = 0
                return np.zeros((n, 0)), np.zeros((n, n)), np.zeros((n, 0)), np.zeros((n, n))
            mu1, mu2 = 1 / max(float(xv["kappa"]), 1e-300), float(ev["mu2"])
            return (I, np.block([[mu1 * a2 * I, 0 * I], [0 * I, -mu1 * I]]), I,
                    np.block([[mu2 * a2 * I, 0 * I], [0 * I, -mu2 * I]]))

        return [(form, multipliers, {"form_size": 3 * n})]

    def form(self, plant: Plant, constants: Constants) -> YoungForm:
        """6n x 6n (5n when alpha = 0), constants ``a2`` = alpha^2 and ``ia2`` = 1/alpha^2."""
        n = plant.n
        I = np.eye(n)
        a2 = float(constants.alpha) ** 2
        schur = a2 > 0

        def eside(d):
            return [[lipschitz_w22(d, I), d["R"]], [d["R"], -d["mu2"] * I]]

        return YoungForm(what="corrected Corollary 1", key=("cor1", schur),
                         blocks=young_layout(n, eside, (lambda d: d["kappa"] * d["ia2"]) if schur else None),
                         e_scalars=("mu2",), constants={"a2": a2, "ia2": 1 / a2 if schur else 0.0})

    def solved_params(self, vals: dict, constants: Constants, phi: float | None = None) -> dict:
        kappa = scalar(vals, "kappa")
        mult = {"kappa": kappa, "mu1": 1 / kappa if kappa > 0 else float("nan"), "mu2": scalar(vals, "mu2"),
                "alpha": constants.alpha}
        return mult if phi is None else {"phi2": phi, **mult, "cap": self.cap}


@register_design("cor1_printed", order=13)
@dataclass(frozen=True, kw_only=True)
class Cor1Printed(Design):
    """Corollary 1 as printed, (27)-(32), with Remarks 2-3; xi searched on a grid in (0, 1).

    Remark 2 replaces ``-Q/phi2`` and ``-phi2 Q`` by ``-(2 alpha2 - beta2) I`` and ``-beta2 I``
    with ``Q > alpha2 I`` (alpha2, beta2 decision scalars, ``2 alpha2 - beta2 > 0``,
    ``beta2 > 0``); Remark 3 replaces ``-I/(mu1 alpha^2)`` by ``-xi I / alpha^2`` with a fixed
    ``0 < xi < 1`` and ``0 < mu1 < min(1, 1/xi)``. The 7n x 7n matrix W of (27)-(30) is then an
    LMI in Q, R, Fh, Kh, mu1, mu2, alpha2, beta2 for each xi in ``xis``. The largest xi has the largest
    slack (W decreases as xi grows; mu1's bound is 1 for every xi): it is solved first, and when its slack proves
    the LMI infeasible no other xi is.
    """

    xis: tuple[float, ...] = (0.1, 0.3, 0.5, 0.7, 0.9)
    cap: float = 1e3

    needs = ("alpha",)

    def __post_init__(self) -> None:
        check_values_in("xis", self.xis, 0.0, 1.0)  # Remark 3: 0 < xi < 1
        check_positive("cap", self.cap)

    def applicable(self, plant: Plant, constants: Constants) -> str | None:
        why = super().applicable(plant, constants)
        if why is None and constants.alpha == 0:
            return "alpha = 0: the block -I/(mu1 alpha^2) of (30) is undefined"
        return why

    def design(self, plant: Plant, constants: Constants) -> DesignResult:
        """Solve Corollary 1 as printed for each xi; report the best margin."""
        I, Z = np.eye(plant.n), np.zeros((plant.n, plant.n))

        def blocks(d):
            Q, R = d["Q"], d["R"]
            BF = -d["B"] @ d["Fh"].T
            return [
                # W1                                          | W2
                [state_feedback_block(d), Z, I, Z, Q, BF, Z],
                [Z, lipschitz_w22(d, I), Z, R, Z, Z, I],
                [I, Z, -d["mu1"] * I, Z, Z, Z, Z],
                [Z, R, Z, -d["mu2"] * I, Z, Z, Z],
                # W2'                                         | W3 (Remarks 2-3)
                [Q, Z, Z, Z, -d["xi_a2"] * I, Z, Z],
                [BF.T, Z, Z, Z, Z, -(2 * d["alpha2"] - d["beta2"]) * I, Z],
                [Z, I, Z, Z, Z, Z, -d["beta2"] * I],
            ]

        def extra(d):
            slack = d["slack"]
            return [d["Q"] >> d["alpha2"] * I, d["alpha2"] >= slack, d["beta2"] >= slack,
                    2 * d["alpha2"] - d["beta2"] >= slack, d["mu1"] >= slack, d["mu1"] <= d["mu1_max"] - slack,
                    d["mu2"] >= slack]

        a2 = constants.alpha**2
        prog = joint_program(plant, ("cor1.printed",), blocks, ("mu1", "mu2", "alpha2", "beta2"),
                             {"xi_a2": "xi_over_alpha2", "mu1_max": "mu1_max"}, {"a2": a2}, extra, cap=self.cap)
        def params(xi: float):
            return lambda sv: {"xi": xi, "alpha": constants.alpha, "cap": self.cap,
                               **{k: scalar(sv, k) for k in ("mu1", "mu2", "alpha2", "beta2")}}

        what = "Corollary 1 as printed (Remarks 2-3)"
        # The largest xi of the grid has its largest slack: xi enters W only as -xi I / alpha^2 on the diagonal, so W
        # decreases as xi grows, and mu1's bound min(1, 1/xi) is 1 for every 0 < xi < 1: every point (and slack)
        # feasible at a smaller xi is feasible at the largest. When that slack proves the LMI infeasible, so it is
        # at every xi; otherwise the grid is searched (the gains come from its best point, as without this).
        top = max(map(float, self.xis))
        prog.solve(xi_a2=top / a2, mu1_max=min(1.0, 1.0 / top))
        res = concluded(prog, params(top), what=what, cap=self.cap,
                        searched=(f"at xi = {top:g}, the largest of {tuple(self.xis)} (W decreases as xi grows, "
                                  "mu1 < 1 throughout: no xi has a larger slack)"))
        if res.status == "infeasible":
            return res
        prog.best = None  # the grid in its order (the largest xi answered by the program's memo)
        best_xi = max(map(float, self.xis),
                      key=lambda xi: np.nan_to_num(prog.solve(xi_a2=xi / a2, mu1_max=min(1.0, 1.0 / xi)), nan=-np.inf))
        return concluded(prog, params(best_xi), what=what, cap=self.cap, searched=f"over xi in {tuple(self.xis)}")
