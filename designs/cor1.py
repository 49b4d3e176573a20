"""Corollary 1 of the paper (Lipschitz f): as printed (Remarks 2-3) and corrected.

References
----------
Observer-based stabilization of one-sided Lipschitz systems with application to flexible link
manipulator, Corollary 1, eqs. (27)-(32), Remarks 2-3. Corrections: ``../shared/design/MATH.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench import lmi
from bench.registry import register_design
from designs._core import (Design, DesignResult, check_choice, check_int, check_positive, check_range,
                           check_values_in)
from designs._separated import coordinate_hint, joint_result, scalar, separated_design, synthesis_variables, young_layout
from plants import Constants, Plant

__all__ = ["Cor1", "Cor1Printed"]


@register_design("cor1_sep", order=16, method="separated")
@register_design("cor1", order=12)
@dataclass(frozen=True, kw_only=True)
class Cor1(Design):
    """Corollary 1, corrected (kappa = 1/mu1 exact, MATH.md); Young weight phi2 searched.

    The 6n x 6n LMI, for fixed phi2, in Q, R, Fh, Kh, kappa, mu2 ::

        [ S11+kappa I  0     0      Q                  B Fh'    0        ]
        [ 0            W22   R      0                  0        I        ]
        [ 0            R     -mu2 I 0                  0        0        ]
        [ Q            0     0      -(kappa/alpha^2) I 0        0        ]
        [ Fh B'        0     0      0                  -Q/phi2  0        ]
        [ 0            I     0      0                  0        -phi2 Q  ]

    with ``S11 = AQ + QA' + B Fh' + Fh B'`` and
    ``W22 = A'R + RA - C'Kh - Kh'C + mu2 alpha^2 I``; ``K = R^{-1} Kh'``, ``F = Fh' Q^{-1}``.
    For alpha = 0 (linear plant) the Schur column is dropped. phi2 is searched as Theorem 1's
    phi1 (log grid, then golden refinement, maximising the normalised margin).

    Parameters
    ----------
    phi2 : float, optional
        Fixed Young weight; None (default) searches ``phi2_range``.
    phi2_range : tuple of float
        Search interval.
    n_grid, n_refine : int
        Search effort.
    cap : float
        Normalisation ``Q, R << cap I``, margin ``t <= 1``.
    method : {"joint", "separated"}
        ``"separated"`` (registered as ``cor1_sep``) solves the x-side and e-side 2n x 2n LMIs apart
        and rebuilds a verified joint certificate (:mod:`designs._separated`).
    solver : {"auto", "CLARABEL", "SCS"}
        As for :class:`designs.thm1.Thm1`.
    """

    phi2: float | None = None
    phi2_range: tuple[float, float] = (1e-4, 10.0)
    n_grid: int = 7
    n_refine: int = 5
    cap: float = 1e3
    method: str = "joint"
    solver: str = "auto"

    needs = ("alpha",)

    @property
    def _joint_solver(self) -> str:
        return "CLARABEL" if self.solver == "auto" else self.solver

    def __post_init__(self) -> None:
        check_choice("solver", self.solver, ("auto", "CLARABEL", "SCS"))
        check_choice("method", self.method, ("joint", "separated"))
        if self.phi2 is not None:
            check_positive("phi2", self.phi2)
        check_range("phi2_range", self.phi2_range)
        check_positive("cap", self.cap)
        check_int("n_grid", self.n_grid, minimum=2)
        check_int("n_refine", self.n_refine, minimum=0)

    @staticmethod
    def _blocks(n: int, schur: bool):
        """Blocks ``(joint, xside, eside)`` of the joint 6n LMI (5n when alpha = 0).

        ``A``, ``B``, ``C``, ``a2`` (alpha^2) and ``ia2`` (1/alpha^2) are read from the values
        dict (:func:`designs._separated.young_layout`).
        """
        I = np.eye(n)

        def s11(d):
            A, B, Q, Fh = d["A"], d["B"], d["Q"], d["Fh"]
            return A @ Q + Q @ A.T + B @ Fh.T + Fh @ B.T + d["kappa"] * I

        def eside(d):
            A, C, R, Kh = d["A"], d["C"], d["R"], d["Kh"]
            W22 = A.T @ R + R @ A - C.T @ Kh - Kh.T @ C + d["mu2"] * d["a2"] * I
            return [[W22, R], [R, -d["mu2"] * I]]

        return young_layout(n, s11, eside, (lambda d: d["kappa"] * d["ia2"]) if schur else None)

    @staticmethod
    def _constants(alpha: float) -> tuple[dict, bool]:
        """Scalar parameter values (alpha^2, 1/alpha^2) and whether the Schur column is present."""
        a2 = float(alpha) ** 2
        schur = a2 > 0
        return {"a2": a2, "ia2": 1 / a2 if schur else 0.0}, schur

    def _program(self, plant: Plant, alpha: float) -> lmi.Program:
        """The joint program (compiled once per shape), plant and alpha set; phi2 left to the caller."""
        import cvxpy as cp

        n, m, p = plant.n, plant.m, plant.p
        vals, schur = self._constants(alpha)
        mats = lmi.plant_matrices(plant)

        def build():
            v = synthesis_variables(n, m, p, ("kappa", "mu2"))
            prm = {"phi": cp.Parameter(nonneg=True, name="phi2"), "iphi": cp.Parameter(nonneg=True, name="inv_phi2"),
                   **mats.parameters(), **lmi.scalar_parameters("a2", "ia2")}
            joint, _, _ = self._blocks(n, schur)

            def extra(d):
                return [d["kappa"] >= 0, d["mu2"] >= 0]

            return lmi.margin_program(joint, v, prm, ("Q", "R"), extra, cap=self.cap)

        prog = lmi.cached_program(("cor1.joint", n, m, p, schur, float(self.cap), mats.key), build)
        prog.set(**mats.settable(), **vals)
        return prog

    def _design_separated(self, plant: Plant, alpha: float) -> DesignResult:
        """x-side and e-side solved apart (two 2n LMIs), joint certificate rebuilt and verified."""
        vals, schur = self._constants(alpha)
        return separated_design(plant, self._blocks(plant.n, schur), ("mu2",), solver=self.solver, cap=self.cap,
                                what="corrected Corollary 1", phi_name="phi2", key=("cor1.sep", schur),
                                constants=vals,
                                extra_params=lambda v: {"kappa": scalar(v, "kappa"), "mu2": scalar(v, "mu2"),
                                                        "alpha": alpha,
                                                        "mu1": 1 / scalar(v, "kappa") if scalar(v, "kappa") > 0
                                                        else float("nan")})

    def design(self, plant: Plant, constants: Constants) -> DesignResult:
        """Solve the corrected Corollary 1 for ``plant`` with Lipschitz constant ``constants.alpha``."""
        alpha = constants.alpha
        if self.method == "separated":
            return coordinate_hint(plant, self._design_separated(plant, alpha), "cor1_scaled")
        prog = self._program(plant, alpha)

        def obj(phi):
            return prog.solve(solver=self._joint_solver, phi=phi, iphi=1 / phi)

        lo, hi = self.phi2_range
        if self.phi2 is None:
            phi, _ = lmi.log_search(obj, lo, hi, n_grid=self.n_grid, n_refine=self.n_refine)
            searched = f"over phi2 in [{lo:g}, {hi:g}] ({prog.n_solves} solves)"
            prog.restore_best()
        else:
            phi, searched = self.phi2, f"at phi2 = {self.phi2:g}"
            obj(phi)
        concl = lmi.conclude(prog, what="corrected Corollary 1",
                              normalisation=f"the normalisation Q, R << {self.cap:g} I, t <= 1", searched=searched)
        vals = prog.values()
        kappa = scalar(vals, "kappa")
        params = {"phi2": phi, "kappa": kappa, "mu1": 1 / kappa if kappa > 0 else float("nan"),
                  "mu2": scalar(vals, "mu2"), "alpha": alpha, "cap": self.cap}
        return coordinate_hint(plant, joint_result(prog, concl, params), "cor1_scaled")


@register_design("cor1_printed", order=13)
@dataclass(frozen=True, kw_only=True)
class Cor1Printed(Design):
    """Corollary 1 as printed, (27)-(32), with Remarks 2-3; xi searched on a grid in (0, 1).

    Remark 2 replaces ``-Q/phi2`` and ``-phi2 Q`` by ``-(2 alpha2 - beta2) I`` and ``-beta2 I``
    with ``Q > alpha2 I`` (alpha2, beta2 decision scalars, ``2 alpha2 - beta2 > 0``,
    ``beta2 > 0``); Remark 3 replaces ``-I/(mu1 alpha^2)`` by ``-xi I / alpha^2`` with a fixed
    ``0 < xi < 1`` and ``0 < mu1 < min(1, 1/xi)``. The 7n x 7n matrix W of (27)-(30) is then an
    LMI in Q, R, Fh, Kh, mu1, mu2, alpha2, beta2 for each xi in ``xis``.
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
        import cvxpy as cp

        n, m, p = plant.n, plant.m, plant.p
        I, Z = np.eye(n), np.zeros((n, n))
        a2 = constants.alpha**2
        mats = lmi.plant_matrices(plant)

        def blocks(d):
            A, B, C = d["A"], d["B"], d["C"]
            Q, R, Fh, Kh = d["Q"], d["R"], d["Fh"], d["Kh"]
            W11 = Q @ A.T + A @ Q + Fh @ B.T + B @ Fh.T
            W22 = A.T @ R + R @ A - C.T @ Kh - Kh.T @ C + d["mu2"] * d["a2"] * I
            BF = -B @ Fh.T
            return [
                # W1                                          | W2
                [W11, Z, I, Z, Q, BF, Z],
                [Z, W22, Z, R, Z, Z, I],
                [I, Z, -d["mu1"] * I, Z, Z, Z, Z],
                [Z, R, Z, -d["mu2"] * I, Z, Z, Z],
                # W2'                                         | W3 (Remarks 2-3)
                [Q, Z, Z, Z, -d["xi_a2"] * I, Z, Z],
                [BF.T, Z, Z, Z, Z, -(2 * d["alpha2"] - d["beta2"]) * I, Z],
                [Z, I, Z, Z, Z, Z, -d["beta2"] * I],
            ]

        def build():
            v = synthesis_variables(n, m, p, ("mu1", "mu2", "alpha2", "beta2"))
            prm = {"xi_a2": cp.Parameter(nonneg=True, name="xi_over_alpha2"),
                   "mu1_max": cp.Parameter(nonneg=True, name="mu1_max"),
                   **mats.parameters(), **lmi.scalar_parameters("a2")}

            def extra(d):
                t = d["t"]
                return [d["Q"] >> d["alpha2"] * I, d["alpha2"] >= t, d["beta2"] >= t,
                        2 * d["alpha2"] - d["beta2"] >= t, d["mu1"] >= t, d["mu1"] <= d["mu1_max"] - t,
                        d["mu2"] >= t]

            return lmi.margin_program(blocks, v, prm, ("Q", "R"), extra, cap=self.cap)

        prog = lmi.cached_program(("cor1.printed", n, m, p, float(self.cap), mats.key), build)
        prog.set(**mats.settable(), a2=a2)

        def obj(xi):
            return prog.solve(xi_a2=xi / a2, mu1_max=min(1.0, 1.0 / xi))

        vals = [(obj(float(x)), float(x)) for x in self.xis]
        best_xi = max(vals, key=lambda vx: np.nan_to_num(vx[0], nan=-np.inf))[1]
        prog.restore_best()
        concl = lmi.conclude(prog, what="Corollary 1 as printed (Remarks 2-3)",
                              normalisation=f"the normalisation Q, R << {self.cap:g} I, t <= 1",
                              searched=f"over xi in {tuple(self.xis)}")
        sv = prog.values()
        params = {"xi": best_xi, "alpha": constants.alpha, "cap": self.cap,
                  **{k: scalar(sv, k) for k in ("mu1", "mu2", "alpha2", "beta2")}}
        return joint_result(prog, concl, params)
