"""An H-infinity observer-based controller for the OSL / QIB class: corrected Theorem 1's sides with bounded-real terms.

Plant ``x' = A x + B u + f(x) + Bw w``, ``y = C x + Dw w`` with ``f`` one-sided Lipschitz (``rho``) and
quadratically inner-bounded (``beta``, ``gamma >= 0``); observer ``x_hat' = A x_hat + B u + f(x_hat) +
K (y - C x_hat)``, ``u = F x_hat``. With ``e = x - x_hat`` and ``v = F e``::

    e' = (A - K C) e + df + (Bw - K Dw) w
    x' = (A + B F) x + f(x) + Bw w - B v

The design keeps the corrected Theorem 1's structure (``docs/paper.md``): an e-side and an x-side solved
apart, each the S-procedure of the class with the multipliers of Theorem 1 (``eps1 = gamma eps2`` on the
x-side, ``eps3``, ``eps4`` on the e-side), now with the bounded-real terms ``V' + |zeta|^2 - g |w|^2``:

**e-side** (zeta = e), :mod:`designs._hinf`: ``V_e' + |e|^2 - ge |w|^2 <= 0`` over the class, the LMI in
``(R, Kh, eps3, eps4, ge)``; ``K = R^-1 Kh'``; ``gamma_e = sqrt(ge)`` bounds the L2 gain from ``w`` to ``e``
for every f of the class, whatever F is.

**x-side** (zeta = x, inputs ``w`` and the observer's error action ``v = F e``):
``V_x' + |x|^2 - gw |w|^2 - gv |v|^2 <= 0`` over the class. With ``V_x = x' Q^-1 x``, ``Fh = Q F'`` and
``kappa = 1 / (2 eps2)`` it is, as in the corrected Theorem 1 (congruence by ``Q``, a Schur complement on the
f row, Schur columns for ``x'x`` and ``eta1 x'x``, ``eta1 = 2 eps2 beta_eff``, ``beta_eff = beta + gamma rho``)::

    [ AQ + QA' + BFh' + FhB' + kappa I   Bw     -B     Q     sqrt(beta_eff) Q ]
    [ *                                  -gw I  0      0     0                ]
    [ *                                  *      -gv I  0     0                ]  <= 0
    [ *                                  *      *      -I    0                ]
    [ *                                  *      *      *     -kappa I         ]

It is not homogeneous (the ``-I`` of the output), and the infimum of ``gw`` is approached with unbounded
gains (a singular problem: the level is set by the class, and a large F costs nothing on this side). The
design therefore bounds the gain: ``Q = sigma Qt`` with ``Qt >= I`` and ``[[max_gain^2 I, Fht'], [Fht, Qt]] >= 0``
(so ``F Qt F' <= max_gain^2 I`` and ``||F|| <= max_gain``), and the congruence ``diag(sigma^-1/2, sigma^1/2, sigma^1/2,
sigma^-1/2, sigma^-1/2)`` turns the LMI into the same blocks in ``(Qt, Fht, kappa_t)`` with ``-sigma gw I``,
``-sigma gv I`` and ``-I / sigma`` in place of ``-gw I``, ``-gv I``, ``-I``: for each ``sigma`` an SDP;
``sigma`` is searched on a log grid (golden refinement).

**The loop's level** (zeta = x). ``||v|| = ||F e|| <= ||F|| gamma_e ||w||``, so with
``V = V_x + c V_e``, ``c = gv ||F||^2``: ``V' + |x|^2 - (gw + c ge) |w|^2 <= -(c |e|^2 - gv |F e|^2) <= 0``: the
L2 gain from ``w`` to ``x`` of the closed loop, over the whole class, is at most
``gamma_x = sqrt(gw + gv ||F||^2 ge)``. The x-side minimises ``gw + theta gv`` with the a-priori weight
``theta = (max_gain gamma_e)^2``, the value of ``||F||^2 ge`` at the gain bound. The joint bounded-real matrix
(``V = z' blkdiag(Q^-1, c R) z``, the sides' multipliers, in ``(x, e, f, df, w)``) is rebuilt with numpy and
verified by its eigenvalues (``certificate``, level ``"l2"``). Each side's level is verified at
``(1 + backoff)`` times its optimum (:func:`designs._hinf.min_level`).

What it follows and what is ours: the separation of the loop's L2 gain into an observer level and a
state-feedback level with the observer error as an input of the x-side is Nguyen, Pathirana & Trinh's "new
approach" (EJC 2018, Theorem 1, objectives (9)-(12): ``||x|| <= mu_e ||e|| + mu_de ||w||``,
``||e|| <= mu_ds ||w||``), there in discrete time with the error weighted by ``P1^-1``. Here: continuous time,
corrected Theorem 1's multipliers and Schur columns, the error entering through ``v = F e`` with its own
level ``gv`` (so that the coupling stays linear in ``(Q, Fh)``), the squared composition
``gamma_x^2 = gw + gv ||F||^2 ge`` (tighter than their sum of levels), the gain bound with ``sigma``, and the
rebuilt joint certificate. For ``gamma < 0`` (the choice ``eps1 = gamma eps2`` is impossible) the design is
inapplicable with that reason. Continuous time only.

References
----------
C. M. Nguyen, P. N. Pathirana and H. Trinh, "Robust observer-based control designs for discrete nonlinear
systems with disturbances", European Journal of Control, 2018 (doi 10.1016/j.ejcon.2018.09.002).
S. Boyd et al., *Linear Matrix Inequalities in System and Control Theory*, SIAM 1994, sections 6.3.2, 7.5.1.
The seed paper's Theorem 1 (corrected: ``docs/paper.md``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bench import lmi
from bench.registry import register_design
from designs._core import Design, DesignResult, check_choice, check_int, check_positive, check_range
from designs._hinf import eside_blocks, min_level
from designs.hinf_lipschitz import disturbance_inputs, no_disturbance
from plants import Constants, Plant

__all__ = ["HinfOSL", "joint_l2_matrix"]


def _xside_blocks(n: int, m: int, q: int, schur: bool):
    """The normalised x-side blocks (module docstring); values dict with A, B, Bw, Q, Fh, kappa, gw, gv, isig, sb."""
    I = np.eye(n)

    def blocks(d):
        A, B, Bw, Q, Fh = d["A"], d["B"], d["Bw"], d["Q"], d["Fh"]
        S = A @ Q + Q @ A.T + B @ Fh.T + Fh @ B.T + d["kappa"] * I
        Zq, Zm, Zn = np.zeros((n, q)), np.zeros((n, m)), np.zeros((n, n))
        rows = [[S, Bw, -B, Q],
                [Bw.T, -d["gw"] * np.eye(q), np.zeros((q, m)), Zq.T],
                [-B.T, np.zeros((m, q)), -d["gv"] * np.eye(m), Zm.T],
                [Q, Zq, Zm, -d["isig"] * I]]
        if schur:
            for i, row in enumerate(rows):
                row.append(d["sb"] * Q if i == 0 else (Zn if i == 3 else (Zq.T if i == 1 else Zm.T)))
            rows.append([d["sb"] * Q, Zq, Zm, Zn, -d["kappa"] * I])
        return rows

    return blocks


def joint_l2_matrix(A, B, C, Bw, Dw, F, K, P, R, c, mult_x, mult_e, g2, consts: Constants) -> np.ndarray:
    """The joint bounded-real matrix of the loop for ``zeta = x`` (module docstring) in ``(x, e, f, df, w)``.

    ``V = x'Px + c e'Re``; ``mult_x = (eps1, eps2)`` and ``mult_e = (eps3, eps4)`` the OSL / QIB multipliers
    on ``(x, f(x))`` and ``(e, df)``; the matrix is ``<= 0`` iff ``V' + |x|^2 - g2 |w|^2 <= 0`` for every member of
    the class (by the S-procedure terms, a sufficient condition).
    """
    n, q = A.shape[0], Bw.shape[1]
    I, Z, Zq = np.eye(n), np.zeros((n, n)), np.zeros((n, q))
    Ac, Ae, Bde = A + B @ F, A - K @ C, Bw - K @ Dw
    (e1, e2), (e3, e4) = mult_x, mult_e
    rho, beta, gamma = consts.rho, consts.beta, consts.gamma
    X11 = Ac.T @ P + P @ Ac + I + 2 * (e1 * rho + e2 * beta) * I
    E11 = c * (Ae.T @ R + R @ Ae + 2 * (e3 * rho + e4 * beta) * I)
    Xf = P + (e2 * gamma - e1) * I
    Ef = c * (R + (e4 * gamma - e3) * I)
    M = np.block([[X11, -P @ B @ F, Xf, Z, P @ Bw],
                  [(-P @ B @ F).T, E11, Z, Ef, c * R @ Bde],
                  [Xf.T, Z, -2 * e2 * I, Z, Zq],
                  [Z, Ef.T, Z, -2 * c * e4 * I, Zq],
                  [(P @ Bw).T, (c * R @ Bde).T, Zq.T, Zq.T, -g2 * np.eye(q)]])
    return lmi.sym(M)


@register_design("hinf_osl", order=18)
@dataclass(frozen=True, kw_only=True)
class HinfOSL(Design):
    """H-infinity observer-based controller for the OSL / QIB class (module docstring): ``gamma_e``, ``gamma_x``.

    Parameters
    ----------
    max_gain : float
        Bound on ``||F||`` (2-norm), through ``Qt >= I``, ``Fht' Qt^-1 Fht <= max_gain^2 I``.
    backoff : float
        Each side's verified level is ``(1 + backoff)`` times its optimum.
    sigma_range : tuple of float
        The search range of the x-side's scale ``sigma`` (log grid of ``n_grid`` points, ``n_refine`` golden steps).
    n_grid, n_refine : int
    solver : {"CLARABEL", "SCS"}
    """

    max_gain: float = 20.0
    backoff: float = 0.02
    sigma_range: tuple[float, float] = (1e-4, 1e2)
    n_grid: int = 7
    n_refine: int = 4
    solver: str = "CLARABEL"

    needs = ("rho", "beta", "gamma")

    def __post_init__(self) -> None:
        check_positive("max_gain", self.max_gain)
        check_positive("backoff", self.backoff)
        check_range("sigma_range", self.sigma_range)
        check_int("n_grid", self.n_grid, minimum=2)
        check_int("n_refine", self.n_refine, minimum=0)
        check_choice("solver", self.solver, ("CLARABEL", "SCS"))

    def applicable(self, plant: Plant, constants: Constants) -> str | None:
        why = no_disturbance(plant) or super().applicable(plant, constants)
        if why is None and constants.gamma < 0:
            return (f"gamma = {constants.gamma:g} < 0: the x-side's multiplier choice eps1 = gamma eps2 (corrected "
                    "Theorem 1) needs gamma >= 0")
        return why

    def design(self, plant: Plant, constants: Constants) -> DesignResult:
        """Solve the e-side, search the x-side's scale, verify both and the joint bounded-real certificate."""
        import cvxpy as cp

        n, m, p = plant.n, plant.m, plant.p
        Bw, Dw = disturbance_inputs(plant)
        q = Bw.shape[1]
        c = constants
        cost = [0.0, 0.0, 0]

        def spent(out):
            for i, k in enumerate(("compile_s", "solve_s", "n_solves")):
                cost[i] += out[k]

        def e_vars():
            return {"R": cp.Variable((n, n), symmetric=True, name="R"), "Kh": cp.Variable((p, n), name="Kh"),
                    "eps3": cp.Variable(name="eps3"), "eps4": cp.Variable(name="eps4"), "g": cp.Variable(name="g")}

        eo = min_level(eside_blocks("osl_qib", n, q), e_vars,
                       {"A": plant.A, "C": plant.C, "Bw": Bw, "Dw": Dw, "rho": c.rho, "beta": c.beta,
                        "gamma": c.gamma}, ("R",), ("eps3", "eps4"), ("g",), backoff=self.backoff,
                       solver=self.solver, what="H-infinity OSL/QIB e-side")
        spent(eo)
        base = dict(route="sdp", solver=self.solver)
        if eo["status"] != "feasible":
            return self._result(eo["status"], f"e-side: {eo['reason']}", cost, base, {})
        ge = eo["levels"]["g"]
        ev = eo["values"]
        K = np.linalg.solve(ev["R"], ev["Kh"].T)

        beff = c.beta + c.gamma * c.rho
        schur = beff > 0
        theta = self.max_gain ** 2 * ge
        xconst = {"A": plant.A, "B": plant.B, "Bw": Bw, "sb": math.sqrt(beff) if schur else 0.0}
        blocks = _xside_blocks(n, m, q, schur)

        def x_vars():
            return {"Q": cp.Variable((n, n), symmetric=True, name="Q"), "Fh": cp.Variable((n, m), name="Fh"),
                    "kappa": cp.Variable(name="kappa"), "gw": cp.Variable(name="gw"), "gv": cp.Variable(name="gv")}

        def extra(d):  # Qt >= I and Fht' Qt^-1 Fht <= max_gain^2 I: ||F|| <= max_gain / sqrt(lmin(Qt)) <= max_gain
            return [d["Q"] >> np.eye(n),
                    cp.bmat([[self.max_gain ** 2 * np.eye(m), d["Fh"].T], [d["Fh"], d["Q"]]]) >> 0]

        xv = x_vars()
        sig = cp.Parameter(pos=True, name="isig")
        M = lmi.sym(lmi.assemble(blocks, {**xconst, **xv, "isig": sig}, numeric=False))
        prob = cp.Problem(cp.Minimize(xv["gw"] + theta * xv["gv"]),
                          [M << 0, xv["kappa"] >= 0, *extra(xv)])

        def value(s: float) -> float:  # -(gw + theta gv) in original units, at sigma = s
            sig.value = 1.0 / s
            o = lmi.solve_timed(prob, self.solver)
            cost[0] += o.compile_s
            cost[1] += o.solve_s
            cost[2] += 1
            return -o.value / s if o.solved else -math.inf

        sigma, best = lmi.log_search(value, *self.sigma_range, n_grid=self.n_grid, n_refine=self.n_refine)
        if not math.isfinite(best):
            return self._result("infeasible", (
                f"x-side: no sigma in [{self.sigma_range[0]:g}, {self.sigma_range[1]:g}] with a solution under "
                f"||F|| <= max_gain = {self.max_gain:g} (solver status of the last solve: {prob.status})"),
                cost, base, {"gamma_e": math.sqrt(ge)})
        xo = min_level(blocks, x_vars, {**xconst, "isig": 1.0 / sigma}, ("Q",), ("kappa",), ("gw", "gv"),
                       objective=lambda v: v["gw"] + theta * v["gv"], extra=extra, backoff=self.backoff,
                       solver=self.solver, what="H-infinity OSL/QIB x-side")
        spent(xo)
        params = {"gamma_e": math.sqrt(ge), "gamma_e_optimum": math.sqrt(eo["optimum"]["g"]), "sigma": sigma,
                  "theta": theta, "max_gain": self.max_gain, "backoff": self.backoff}
        if xo["status"] != "feasible":
            return self._result(xo["status"], f"x-side: {xo['reason']}", cost, base, params)
        xs = xo["values"]
        F = np.linalg.solve(xs["Q"], xs["Fh"]).T
        gw, gv = xo["levels"]["gw"] / sigma, xo["levels"]["gv"] / sigma
        nF = float(np.linalg.norm(F, 2))
        g2 = gw + gv * nF ** 2 * ge
        Q = sigma * xs["Q"]
        P = np.linalg.inv(Q)
        P = (P + P.T) / 2
        kappa = sigma * float(xs["kappa"])
        eps2 = 1 / (2 * kappa) if kappa > 0 else math.inf
        cj = gv * nF ** 2 or 1.0
        J = joint_l2_matrix(plant.A, plant.B, plant.C, Bw, Dw, F, K, P, ev["R"], cj, (c.gamma * eps2, eps2),
                            (float(ev["eps3"]), float(ev["eps4"])), g2, c)
        Cx = np.eye(J.shape[0])
        Cx[:n, :n] = Q  # the x-side's own coordinates (a congruence: same inertia)
        Jq = lmi.sym(Cx.T @ J @ Cx)
        dg = np.diag(Jq)
        margin = math.inf
        if np.all(dg < 0):
            D = 1 / np.sqrt(-dg)
            E = Jq * D[:, None] * D[None, :]
            margin = lmi.max_eig(E)
        params.update(gamma_x=math.sqrt(g2), gamma_x_state_feedback=math.sqrt(gw), gv=math.sqrt(gv), F_norm=nF,
                      kappa=kappa, eps3=float(ev["eps3"]), eps4=float(ev["eps4"]), joint_margin=margin,
                      e_margin=eo["margin"], x_margin=xo["margin"])
        if not (math.isfinite(margin) and lmi.classify(margin, E) == "verified"):
            return self._result("undecided", (
                f"both sides verified (levels gamma_e = {math.sqrt(ge):.4g}, gw = {math.sqrt(gw):.4g}, "
                f"gv = {math.sqrt(gv):.4g}) but the rebuilt joint bounded-real matrix has equilibrated max eig "
                f"{margin:.3g}"), cost, base, params)
        cert = {"level": "l2", "P": np.block([[P, np.zeros((n, n))], [np.zeros((n, n)), cj * ev["R"]]]),
                "gamma_x": math.sqrt(g2), "gamma_e": math.sqrt(ge), "margin": margin,
                "how": "the design's joint bounded-real certificate V = x'Q^-1 x + c e'Re (zeta = x), the sides' "
                       "multipliers; gamma_e by V_e = e'Re alone"}
        return DesignResult(status="feasible", K=K, F=F, margin=margin, lmi_size=int(J.shape[0]),
                            min_eig={"Q": lmi.min_eig(Q), "R": lmi.min_eig(ev["R"])}, params=params, certificate=cert,
                            compile_s=cost[0], solve_s=cost[1], n_solves=cost[2],
                            solver_status=f"e {eo['solver_status']}; x {xo['solver_status']}", **base)

    def _result(self, status: str, reason: str, cost: list, base: dict, params: dict) -> DesignResult:
        return DesignResult(status=status, reason=f"H-infinity OSL/QIB design: {reason}", params=params,
                            compile_s=cost[0], solve_s=cost[1], n_solves=cost[2], **base)
