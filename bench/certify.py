"""Certificates for any gain pair (K, F), however it was designed (analysis, not synthesis).

With K and F fixed, the closed loop (9) is certified if there are ``P > 0``, ``R > 0`` and
S-procedure multipliers ``eps1..eps4 >= 0`` such that the matrix of the paper's (20) (with the
coupling block ``-P B F``) is negative definite ::

    [ S11 + eta1 I   -P B F        P + eta2 I   0          ]
    [ *              S22 + eta1e I 0            R + eta3 I ]  <  0
    [ *              *             -2 eps2 I    0          ]
    [ *              *             *            -2 eps4 I  ]

with ``S11 = (A+BF)'P + P(A+BF) + 2 lam P``, ``S22 = (A-KC)'R + R(A-KC) + 2 lam R``,
``eta1 = 2(eps1 rho + eps2 beta)``, ``eta2 = eps2 gamma - eps1``,
``eta1e = 2(eps3 rho + eps4 beta)``, ``eta3 = eps4 gamma - eps3``. This is an LMI in
(P, R, eps). ``lam = 0`` certifies asymptotic stability (V = x'Px + e'Re decreasing); the
largest ``lam`` that stays feasible (bisection) is a certified exponential decay rate of V
(``V' <= -2 lam V``). The margin is maximised under ``trace(P) + trace(R) = 1`` (the analysis
LMI is homogeneous, so this normalisation loses nothing) and re-verified with numpy.

The constants must be *valid* ones (global, or on the region the trajectories stay in): a
certificate with wrong constants certifies nothing.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from designs import _lmi
from plants._core import Constants, Plant

__all__ = ["Certificate", "certify"]

#: A verified margin must be below this (relative to the matrix scale) to count as certified.
CERT_TOL = 1e-7


@dataclass
class Certificate:
    """Outcome of :func:`certify`.

    Attributes
    ----------
    certified : bool
        True when the analysis LMI at ``lam = 0`` has a verified negative margin.
    status : str
        ``"certified"``, ``"not_certified"``, ``"inapplicable"`` or the solver's status.
    margin : float
        Verified max eigenvalue of the analysis LMI at lam = 0 (negative = certified).
    decay_rate : float
        Largest certified lam (to ``rate_tol``), 0 if only lam = 0 certifies, NaN if not certified.
    reason : str
    solve_s : float
        Seconds spent in all solves.
    multipliers : dict
        eps1..eps4 at lam = 0.
    """

    certified: bool
    status: str
    margin: float = float("nan")
    decay_rate: float = float("nan")
    reason: str = ""
    solve_s: float = 0.0
    multipliers: dict = field(default_factory=dict)


def _program(plant: Plant, K: np.ndarray, F: np.ndarray, c: Constants) -> _lmi.Program:
    """The analysis program, compiled once per n and sparsity class (the constants and the dense
    ones of A+BF, A-KC, BF are cvxpy Parameters, :func:`designs._lmi.matrices`), so certifying
    another gain pair or plant of the same size re-uses it)."""
    n = plant.n

    def build():
        import cvxpy as cp

        I, Z = np.eye(n), np.zeros((n, n))
        v = {
            "P": cp.Variable((n, n), symmetric=True, name="P"),
            "R": cp.Variable((n, n), symmetric=True, name="R"),
            "e1": cp.Variable(name="eps1"),
            "e2": cp.Variable(name="eps2"),
            "e3": cp.Variable(name="eps3"),
            "e4": cp.Variable(name="eps4"),
            "t": cp.Variable(name="t"),
        }
        prm = {"lam": cp.Parameter(nonneg=True, name="lam"), **mats.parameters(),
               **_lmi.scalar_parameters("rho", "beta", "gamma")}

        def blocks(d):
            P, R, lam, Acl, Ae = d["P"], d["R"], d["lam"], d["Acl"], d["Ae"]
            rho, beta, gamma = d["rho"], d["beta"], d["gamma"]
            S11 = Acl.T @ P + P @ Acl + 2 * lam * P + 2 * (d["e1"] * rho + d["e2"] * beta) * I
            S22 = Ae.T @ R + R @ Ae + 2 * lam * R + 2 * (d["e3"] * rho + d["e4"] * beta) * I
            X13 = P + (d["e2"] * gamma - d["e1"]) * I
            X24 = R + (d["e4"] * gamma - d["e3"]) * I
            PBF = -P @ d["BF"]
            return [
                [S11, PBF, X13, Z],
                [PBF.T, S22, Z, X24],
                [X13.T, Z, -2 * d["e2"] * I, Z],
                [Z, X24.T, Z, -2 * d["e4"] * I],
            ]

        t_build = time.perf_counter()
        M = _lmi.sym(_lmi.assemble(blocks, {**v, **prm}, numeric=False))
        t = v["t"]
        cons = [
            M << -t * np.eye(4 * n),
            v["P"] >> t * I,
            v["R"] >> t * I,
            cp.trace(v["P"]) + cp.trace(v["R"]) == 1,
            v["e1"] >= 0, v["e2"] >= 0, v["e3"] >= 0, v["e4"] >= 0,
        ]
        prob = cp.Problem(cp.Maximize(t), cons)
        return _lmi.Program(prob, v, prm, blocks, ("P", "R"), build_s=time.perf_counter() - t_build)

    A, B, C = plant.A, plant.B, plant.C
    mats = _lmi.matrices(Acl=A + B @ F, Ae=A - K @ C, BF=B @ F)
    prog = _lmi.cached_program(("certify", n, mats.key), build)
    prog.set(**mats.settable(), rho=c.rho, beta=c.beta, gamma=c.gamma)
    return prog


def _verified(prog: _lmi.Program) -> tuple[bool, float]:
    if prog.last_status not in ("optimal", "optimal_inaccurate"):
        return False, float("nan")
    M = prog.numeric_matrix()
    vals = prog.values()
    margin = _lmi.max_eig(M)
    pos = min(_lmi.min_eig(vals["P"]), _lmi.min_eig(vals["R"]))
    ok = margin < -CERT_TOL * max(1.0, float(np.max(np.abs(M)))) and pos > 0
    return ok, margin


def certify(
    plant: Plant,
    K: np.ndarray,
    F: np.ndarray,
    constants: Constants,
    *,
    rate_tol: float = 1e-3,
    max_rate: float | None = None,
) -> Certificate:
    """Certify the observer-based closed loop with gains K, F and find a certified decay rate.

    Parameters
    ----------
    plant : Plant
    K, F : ndarray
        Observer gain (n x p) and feedback gain (m x n), ``u = F x_hat``.
    constants : Constants
        Valid OSL/QIB constants (rho, beta, gamma) of the plant.
    rate_tol : float
        Absolute tolerance of the decay-rate bisection.
    max_rate : float, optional
        Upper end of the bisection; default: the smallest ``-max Re eig`` of A+BF and A-KC
        (no quadratic certificate can certify a faster rate than the linear parts allow).

    Returns
    -------
    Certificate
    """
    if not constants.has_osl:
        return Certificate(False, "inapplicable", reason="no OSL/QIB constants (rho, beta, gamma) for the plant")
    K = np.asarray(K, dtype=float)
    F = np.asarray(F, dtype=float)
    prog = _program(plant, K, F, constants)
    prog.solve(lam=0.0)
    ok, margin = _verified(prog)
    vals = prog.values()
    mult = {k: float(vals[k]) for k in ("e1", "e2", "e3", "e4") if vals[k] is not None}
    if prog.last_status not in ("optimal", "optimal_inaccurate"):
        return Certificate(False, prog.last_status, margin, reason=f"solver status {prog.last_status!r} "
                           f"{prog.last_error}".strip(), solve_s=prog.compile_s + prog.solve_s)
    if not ok:
        return Certificate(False, "not_certified", margin, reason=(
            f"no P, R > 0 and multipliers make (20) negative definite: best max eig {margin:.3g} "
            f"(trace(P) + trace(R) = 1)"), solve_s=prog.compile_s + prog.solve_s, multipliers=mult)
    if max_rate is None:
        eig = np.concatenate([np.linalg.eigvals(plant.A + plant.B @ F), np.linalg.eigvals(plant.A - K @ plant.C)])
        max_rate = max(float(-eig.real.max()), rate_tol)
    lo, hi = 0.0, max_rate
    while hi - lo > rate_tol:
        mid = (lo + hi) / 2
        prog.solve(lam=mid)
        if _verified(prog)[0]:
            lo = mid
        else:
            hi = mid
    return Certificate(True, "certified", margin, decay_rate=lo, solve_s=prog.compile_s + prog.solve_s,
                       multipliers=mult)
