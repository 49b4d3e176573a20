"""Theorem 1 of the paper: as printed (with Remark 1) and in the corrected convex form.

References
----------
Observer-based stabilization of one-sided Lipschitz systems with application to flexible link
manipulator, Theorem 1, eqs. (12)-(15), Remark 1. Errata and corrected forms: ``docs/paper.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench import lmi
from bench.registry import register_design
from designs import _discrete
from designs._core import Design, DesignError, DesignResult, check_int, check_positive, check_range, check_values_in
from designs._separated import (YoungForm, append_schur_column, concluded, joint_program, scalar,
                                state_feedback_block, young_layout)
from designs._young import YoungDesign
from plants import Constants, Plant

__all__ = ["Thm1", "Thm1Printed"]


def osl_qib_eside(d: dict, I: np.ndarray) -> tuple:
    """``(S22, X)`` of the e-side with the OSL and QIB multipliers eps3, eps4 (values dict).

    ``S22 = A'R + RA - C'Kh - Kh'C + 2(eps3 rho + eps4 beta) I`` and ``X = R + eta3 I`` with
    ``eta3 = eps4 gamma - eps3``; the e-side's third block is ``-2 eps4 I``.
    """
    A, C, R, Kh = d["A"], d["C"], d["R"], d["Kh"]
    S22 = A.T @ R + R @ A - C.T @ Kh - Kh.T @ C + 2 * (d["eps3"] * d["rho"] + d["eps4"] * d["beta"]) * I
    X = R + (d["eps4"] * d["gamma"] - d["eps3"]) * I
    return S22, X


@register_design("thm1_sep", "Theorem 1, corrected, separated: x-side and e-side 2n LMIs solved apart, joint certificate "
                 "rebuilt and verified.", order=15, method="separated")
@register_design("thm1", order=10)
@dataclass(frozen=True, kw_only=True)
class Thm1(YoungDesign):
    """Theorem 1, corrected convex form (docs/paper.md): the joint 6n LMI, Young weight phi1 searched.

    For ``gamma >= 0``: ``eps1 = gamma eps2`` (so ``eta2 = 0``), ``kappa = 1 / (2 eps2)``,
    ``beta_eff = beta + gamma rho``; for a fixed ``phi1`` the LMI in Q, R, Fh, Kh, kappa, eps3, eps4 is the
    Young layout (:func:`designs._separated.young_layout`) with the e-side of :func:`osl_qib_eside` and the
    Schur weight ``kappa / beta_eff`` (no Schur column when ``beta_eff <= 0``).

    For ``gamma < 0``: eps1 >= 0, eps2 > 0 fixed, the 7n x 7n form with the exact (1,3) block
    ``I + eta2 Q`` and the Schur column ``Q`` / ``-(1/eta1) I`` (``eta1 = 2(eps1 rho + eps2 beta)``,
    dropped when ``eta1 <= 0``); eps2 searched on a log grid jointly with phi1.
    Gains: ``K = R^{-1} Kh'``, ``F = Fh' Q^{-1}``.

    On a discrete plant: the discrete x-side and e-side of :mod:`designs._discrete` (OSL / QIB e-side of
    Benallouch et al. 2012 and Nguyen et al. 2018; x-side with ``eps1 = c eps2``, ``c = gamma`` for
    ``gamma >= 0``, ``c`` on the grid ``{0} U |gamma| logspace(-3, 3, 7)`` for ``gamma < 0``), solved apart, the
    joint discrete certificate rebuilt and verified, its contraction factor in ``certificate``.

    Parameters
    ----------
    phi1 : float, optional
        Fixed Young weight; None (default) searches ``phi1_range``.
    phi1_range : tuple of float
    eps1 : float
        OSL multiplier for the ``gamma < 0`` form.
    eps2_range : tuple of float
        Grid (5 log-spaced points) of the QIB multiplier for the ``gamma < 0`` form.
    n_grid, n_refine, cap, method, solver
        :class:`designs._young.YoungDesign`; for ``gamma < 0`` the separated method uses the joint form.
    """

    phi1: float | None = None
    phi1_range: tuple[float, float] = (1e-4, 10.0)
    eps1: float = 0.0
    eps2_range: tuple[float, float] = (1e-2, 1e2)

    needs = ("rho", "beta", "gamma")
    phi_name = "phi1"
    scaled_variant = "thm1_scaled"

    def __post_init__(self) -> None:
        super().__post_init__()
        check_positive("eps1", self.eps1, allow_zero=True)
        check_range("eps2_range", self.eps2_range, strict=False)

    def _design(self, plant: Plant, constants: Constants) -> DesignResult:
        """``gamma >= 0``: the convex form (joint or separated); ``gamma < 0``: the fixed-eps form."""
        if constants.gamma < 0:
            return self._design_fixed_eps(plant, constants)
        return super()._design(plant, constants)

    # -- gamma >= 0: convex form -------------------------------------------------------------
    def form(self, plant: Plant, c: Constants) -> YoungForm:
        """The convex form (``gamma >= 0``): 6n x 6n (5n when ``beta_eff <= 0``), constants ``rho``,
        ``beta``, ``gamma`` and ``ibeff`` = 1/beta_eff."""
        if c.gamma < 0:
            raise DesignError(f"gamma: the convex form needs gamma >= 0, got {c.gamma:g} (use the fixed-eps form)")
        n = plant.n
        I = np.eye(n)
        beff = c.beta + c.gamma * c.rho
        schur = beff > 0

        def eside(d):
            S22, X = osl_qib_eside(d, I)
            return [[S22, X], [X.T, -2 * d["eps4"] * I]]

        constants = {"rho": c.rho, "beta": c.beta, "gamma": c.gamma, "ibeff": 1 / beff if schur else 0.0}
        return YoungForm(what="corrected Theorem 1", key=("thm1", schur),
                         blocks=young_layout(n, eside, (lambda d: d["kappa"] * d["ibeff"]) if schur else None),
                         e_scalars=("eps3", "eps4"), constants=constants)

    def discrete_forms(self, plant: Plant, c: Constants) -> list:
        """The discrete candidate forms ``(YoungForm, multipliers, params)`` (:mod:`designs._discrete`): one with
        ``c = gamma`` for ``gamma >= 0``, the grid of ratios ``c = eps1 / eps2`` with the f row kept otherwise."""
        n = plant.n
        I = np.eye(n)
        f_row = c.gamma < 0
        ratios = [c.gamma] if not f_row else [0.0, *(abs(c.gamma) * np.logspace(-3, 3, 7))]
        linear = c.beta == 0 and c.gamma == 0  # QIB (0, 0): |df|^2 <= 0, the class is f = 0

        def eside(d):
            return _discrete.osl_qib_eside(d, I)

        out = []
        for cr in ratios:
            w = cr * c.rho + c.beta
            schur = w > 0
            consts = {"rho": c.rho, "beta": c.beta, "gamma": c.gamma, "sw": float(np.sqrt(w)) if schur else 0.0}
            if f_row:
                consts["etac"] = c.gamma - cr
            form = YoungForm(what="discrete corrected Theorem 1", key=("thm1.discrete", schur, f_row),
                             blocks=(None, _discrete.xside(n, schur=schur, f_row=f_row), eside),
                             e_scalars=("eps3", "eps4"), constants=consts)

            def multipliers(xv, ev, cr=cr):
                if linear:
                    return np.zeros((n, 0)), np.zeros((n, n)), np.zeros((n, 0)), np.zeros((n, n))
                eps2 = 1 / (2 * max(float(xv["kappa"]), 1e-300))
                return (I, _osl_qib_terms(I, cr * eps2, eps2, c), I,
                        _osl_qib_terms(I, float(ev["eps3"]), float(ev["eps4"]), c))

            out.append((form, multipliers, {"c": cr, "form_size": (4 if f_row else 3) * n}))
        return out

    def solved_params(self, vals: dict, c: Constants, phi: float | None = None) -> dict:
        kappa = scalar(vals, "kappa")
        if phi is None:
            return {"kappa": kappa, **self._multipliers(vals, c)}
        return {
            "form": "convex (eps1 = gamma eps2)",
            "phi1": phi,
            "kappa": kappa,
            "eps2": 1 / (2 * kappa) if kappa > 0 else float("nan"),
            "eps1": c.gamma / (2 * kappa) if kappa > 0 else float("nan"),
            **self._multipliers(vals, c),
        }

    def _multipliers(self, vals: dict, c: Constants) -> dict:
        """The e-side multipliers solved for, the constants and the cap."""
        return {"eps3": scalar(vals, "eps3"), "eps4": scalar(vals, "eps4"), "rho": c.rho, "beta": c.beta,
                "gamma": c.gamma, "cap": self.cap}

    # -- gamma < 0: fixed-eps form -----------------------------------------------------------
    def _program_fixed_eps(self, plant: Plant, c: Constants, schur: bool) -> lmi.Program:
        """The fixed-eps program for gamma < 0 (compiled once per shape and Schur flag), plant and
        constants set; phi1, eta2, two_eps2 (and inv_eta1) are left to the caller."""
        I, Z = np.eye(plant.n), np.zeros((plant.n, plant.n))

        def blocks(d):
            B, Q, Fh = d["B"], d["Q"], d["Fh"]
            S22, X = osl_qib_eside(d, I)
            Y = I + d["eta2"] * Q
            rows = [
                [state_feedback_block(d), Z, Y, Z, B @ Fh.T, Z],
                [Z, S22, Z, X, Z, I],
                [Y.T, Z, -d["two_eps2"] * I, Z, Z, Z],
                [Z, X.T, Z, -2 * d["eps4"] * I, Z, Z],
                [Fh @ B.T, Z, Z, Z, -d["iphi"] * Q, Z],
                [Z, I, Z, Z, Z, -d["phi"] * Q],
            ]
            return append_schur_column(rows, Q, -d["inv_eta1"] * I) if schur else rows

        nonneg = {"phi": "phi1", "iphi": "inv_phi1", "two_eps2": "two_eps2"}
        if schur:
            nonneg["inv_eta1"] = "inv_eta1"
        return joint_program(plant, ("thm1.fixed_eps", schur), blocks, ("eps3", "eps4"), nonneg,
                             {"rho": c.rho, "beta": c.beta, "gamma": c.gamma},
                             lambda d: [d["eps3"] >= 0, d["eps4"] >= 0], cap=self.cap, signed=("eta2",))

    def _design_fixed_eps(self, plant: Plant, c: Constants) -> DesignResult:
        """The fixed-eps form (gamma < 0): eps2 on a log grid, phi1 searched at each."""
        progs: dict[bool, lmi.Program] = {}
        eps1 = float(self.eps1)
        best = (-np.inf, None, None, None, None)
        for eps2 in np.logspace(np.log10(self.eps2_range[0]), np.log10(self.eps2_range[1]), 5):
            eta1 = 2 * (eps1 * c.rho + eps2 * c.beta)
            schur = eta1 > 0
            if schur not in progs:
                progs[schur] = self._program_fixed_eps(plant, c, schur)
            prog = progs[schur]
            fixed = dict(eta2=eps2 * c.gamma - eps1, two_eps2=2 * eps2)
            if schur:
                fixed["inv_eta1"] = 1 / eta1
            phi, val, _ = self._search_phi(lambda phi: prog.solve(solver=self._joint_solver, phi=phi, iphi=1 / phi,
                                                                  **fixed), n_grid=7, n_refine=3)
            if val > best[0] or best[4] is None:
                best = (val, eps2, eta1, phi, prog)
        _, eps2, eta1, phi, prog = best
        for k in ("compile_s", "solve_s", "n_solves"):
            setattr(prog, k, sum(getattr(p, k) for p in progs.values()))
        lo, hi = self.phi1_range
        searched = f"over eps2 in {self.eps2_range} x phi1 in [{lo:g}, {hi:g}] ({prog.n_solves} solves)"
        params = {
            "form": "fixed eps (gamma < 0)",
            "phi1": phi,
            "eps1": eps1,
            "eps2": eps2,
            "eta1": eta1,
            "eta2": eps2 * c.gamma - eps1,
        }
        return concluded(prog, lambda vals: {**params, **self._multipliers(vals, c)},
                         what="corrected Theorem 1 (fixed eps, gamma < 0)", cap=self.cap, searched=searched)


def _osl_qib_terms(I: np.ndarray, eps1: float, eps2: float, c: Constants) -> np.ndarray:
    """The S-procedure terms ``2 eps1 (rho |v|^2 - <g, v>) + 2 eps2 (beta |v|^2 + gamma <g, v> - |g|^2)`` as a
    matrix in ``(v, g)``."""
    eta = eps2 * c.gamma - eps1
    return np.block([[2 * (eps1 * c.rho + eps2 * c.beta) * I, eta * I], [eta * I, -2 * eps2 * I]])


@register_design("thm1_printed", order=11)
@dataclass(frozen=True, kw_only=True)
class Thm1Printed(Design):
    """Theorem 1 exactly as printed, (12)-(15), with Remark 1; eps1, eps2 fixed on a grid.

    psi = 1/((2 rho - 1) eps1 + (2 beta + gamma) eps2) and zeta = 1/(eps2 gamma - eps1) make (12) an LMI
    only for fixed eps1, eps2. Remark 1 replaces ``-Q/phi1`` and ``-phi1 Q`` in S3 by
    ``-(2 alpha1 - beta1) I`` and ``-beta1 I`` with ``Q > alpha1 I``, ``2 alpha1 - beta1 > 0``, ``beta1 > 0``.
    The statement needs ``psi > 0`` and ``zeta > 0`` (else a diagonal block of S3 is positive), and
    ``zeta > 0`` requires ``gamma > eps1 / eps2 > 0``: for ``gamma <= 0`` the design is infeasible without
    a solve; otherwise eps2 runs over ``n_eps2`` log-spaced points of ``eps2_range`` and eps1 = r gamma eps2
    for r in ``ratios``.
    """

    eps2_range: tuple[float, float] = (1e-2, 1e2)
    n_eps2: int = 5
    ratios: tuple[float, ...] = (0.25, 0.5, 0.75)
    cap: float = 1e3

    needs = ("rho", "beta", "gamma")

    def __post_init__(self) -> None:
        check_range("eps2_range", self.eps2_range, strict=False)
        check_int("n_eps2", self.n_eps2, minimum=1)
        check_values_in("ratios", self.ratios, 0.0, 1.0)
        check_positive("cap", self.cap)

    def _program(self, plant: Plant, c: Constants) -> lmi.Program:
        """The printed program (compiled once per shape), plant and constants set; psi, zeta and
        two_eps2 are left to the caller."""
        I, Z = np.eye(plant.n), np.zeros((plant.n, plant.n))

        def blocks(d):
            Q = d["Q"]
            S22, X = osl_qib_eside(d, I)
            BF = -d["B"] @ d["Fh"].T
            return [
                # S1                                                  | S2
                [state_feedback_block(d), Z, I, Z, BF, Z, Q, Z],
                [Z, S22, Z, X, Z, I, Z, Z],
                [I, Z, -d["two_eps2"] * I, Z, Z, Z, Z, I],
                [Z, X.T, Z, -2 * d["eps4"] * I, Z, Z, Z, Z],
                # S2'                                                 | S3 (Remark 1)
                [BF.T, Z, Z, Z, -(2 * d["alpha1"] - d["beta1"]) * I, Z, Z, Z],
                [Z, I, Z, Z, Z, -d["beta1"] * I, Z, Z],
                [Q, Z, Z, Z, Z, Z, -d["psi"] * I, Z],
                [Z, Z, I, Z, Z, Z, Z, -d["zeta"] * I],
            ]

        def extra(d):
            slack = d["slack"]
            return [d["Q"] >> d["alpha1"] * I, d["alpha1"] >= slack, d["beta1"] >= slack,
                    2 * d["alpha1"] - d["beta1"] >= slack, d["eps3"] >= 0, d["eps4"] >= 0]

        return joint_program(plant, ("thm1.printed",), blocks, ("eps3", "eps4", "alpha1", "beta1"),
                             {"psi": "psi", "zeta": "zeta", "two_eps2": "two_eps2"},
                             {"rho": c.rho, "beta": c.beta, "gamma": c.gamma}, extra, cap=self.cap)

    def design(self, plant: Plant, constants: Constants) -> DesignResult:
        """Solve Theorem 1 as printed, or explain why it cannot be satisfied."""
        c = constants
        params = {"rho": c.rho, "beta": c.beta, "gamma": c.gamma}
        combos = []
        for eps2 in np.logspace(np.log10(self.eps2_range[0]), np.log10(self.eps2_range[1]), int(self.n_eps2)):
            for r in self.ratios if c.gamma > 0 else ():
                eps1 = r * c.gamma * eps2
                den = (2 * c.rho - 1) * eps1 + (2 * c.beta + c.gamma) * eps2
                if den > 0:
                    combos.append((eps1, eps2, 1 / den, 1 / (eps2 * c.gamma - eps1)))
        if not combos:
            return DesignResult(status="infeasible", params=params, reason=(
                f"as printed, S3 holds -zeta I with zeta = 1/(eps2 gamma - eps1); with gamma = {c.gamma:g} <= 0, "
                "eps2 gamma - eps1 < 0 for every eps1, eps2 > 0, so -zeta I is positive definite and S < 0 "
                "is impossible (the proof needs eta2 = eps2 gamma - eps1 > 0, which the statement omits)"
                if c.gamma <= 0 else
                "as printed, psi = 1/((2 rho - 1) eps1 + (2 beta + gamma) eps2) <= 0 on the whole eps grid"))
        prog = self._program(plant, c)
        best = max(combos, key=lambda cb: np.nan_to_num(prog.solve(psi=cb[2], zeta=cb[3], two_eps2=2 * cb[1]), nan=-np.inf))
        eps1, eps2, psi, zeta = best
        params.update(eps1=eps1, eps2=eps2, psi=psi, zeta=zeta, cap=self.cap)
        return concluded(prog, lambda v: {**params, **{k: scalar(v, k) for k in ("alpha1", "beta1", "eps3", "eps4")}},
                         what="Theorem 1 as printed (Remark 1)", cap=self.cap,
                         searched=f"over {len(combos)} (eps1, eps2) pairs")
