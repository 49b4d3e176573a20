"""The Riccati route of the structured design: each side by an algebraic Riccati equation, searched.

The loop and the joint certificate are :mod:`bench.joint`'s. With one multiplier per side
(``S = s I``, ``T = t I``) and ``Y = -tau B'`` (``F = -tau B' P``), the Schur complement of the x-side
LMI of :mod:`designs.structured`, multiplied by ``P = Q^-1`` on both sides, is the Riccati inequality ::

    (A0 + lam I)' P + P (A0 + lam I) - P (2 tau B B' - s G G') P + H' Dr^2 H / s < 0,

the ARE ``a' P + P a - P M P + q = 0`` with ``a = A0 + lam I``, ``M = b diag(rr)^-1 b'``,
``b = [B, G]``, ``rr = (1/(2 tau), -1/s)``, ``q = H' Dr^2 H / s + eps I``: at a solution the side
matrix is ``-eps I``. The e-side is the dual: ``a = (A0 + lam I)'``, ``b = [C', H' Dr]``,
``rr = (1/(2 tau'), -1/t)``, ``q = G G' / t + eps I``, ``R = X^-1``, ``K = tau' X C'``. The
multipliers s, t are redundant (the x-side is invariant under ``(tau, s, eps, P) -> (a tau, a s, eps / a, P / a)``),
so they are fixed at ``s = ||Dr H|| / ||G||``, ``t = 1 / s``; tau and eps are taken from grids
relative to the natural scales ``tau0 = sigma / ||B||^2``, ``eps0 = sigma``, ``sigma = ||Dr H|| ||G||``.

The design searches, side by side, the largest decay target lam at which the side's ARE has a
solution that verifies (P > 0, side matrix negative definite one rate-grid step below lam,
recomputed from the gain) with ``||gain|| <= max_gain`` (:func:`_search`: the gain interpolated
in lam); the x-side at the e-side's target first. The pair is certified by
:func:`bench.joint.certify`, which measures the rate the certificate proves.

AREs (:func:`solve_are`, indefinite ``M``, the stabilizing solution): ``"sign"`` (default) is the
matrix sign function of the Hamiltonian ``[[a, -M], [-q, -a']]`` (Newton iteration with
determinant scaling), ``X`` from ``[W12; W22 + I] X = -[W11 + I; W21]``; ``"scipy"``
``scipy.linalg.solve_continuous_are`` (the ordered Schur form of the extended pencil), the
fallback when a solution fails its accuracy checks (residual, symmetry). A solution is used only
through the side's own Lyapunov test, which also proves the closed loop Hurwitz.

References
----------
J. D. Roberts, "Linear model reduction and solution of the algebraic Riccati equation by use of
the sign function", Int. J. Control 32(4), 1980. R. Byers, "Solving the algebraic Riccati equation
with the matrix sign function", Linear Algebra Appl. 85, 1987.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import scipy.linalg as sla

from bench import joint, lmi
from bench.search import RATE_RTOL

__all__ = ["structured_riccati"]

#: Largest relative ARE residual accepted.
RESIDUAL_TOL = 1e-8
#: Default tau grid, relative to the natural scale (smallest gain first).
TAU_GRID = (1.0, 10.0, 1e2, 1e3, 1e4, 1e5)
#: Default eps grid, relative to the natural scale.
EPS_GRID = (1e-2, 1e-4)


def _eig_at(M: np.ndarray, index: int) -> float:
    """The ``index``-th smallest eigenvalue of a symmetric M (``-1``: the largest)."""
    k = M.shape[0]
    i = index % k
    try:
        return float(sla.eigvalsh(M, subset_by_index=[i, i], check_finite=False)[0])
    except (np.linalg.LinAlgError, ValueError):  # LAPACK's subset driver can fail on clustered spectra
        return float(np.linalg.eigvalsh(M)[i])


def _norm2(X: np.ndarray) -> float:
    """Spectral norm via the smaller Gram matrix."""
    X = np.asarray(X, dtype=float)
    if X.size == 0:
        return 0.0
    Gm = X.T @ X if X.shape[0] >= X.shape[1] else X @ X.T
    return float(math.sqrt(max(_eig_at(Gm, -1), 0.0)))


@dataclass(frozen=True)
class AREInfo:
    """Diagnostics of one ARE solve (:func:`solve_are`): method, relative residual
    ``||a'X + Xa - XMX + q||_1 / (2 ||a||_1 ||X||_1 + ||M||_1 ||X||_1^2 + ||q||_1)``, largest real part
    of ``a - M X`` (-inf when not computed), and the reason of a failure (empty on success)."""

    method: str
    residual: float = math.inf
    closed_loop_max_re: float = math.inf
    reason: str = ""


def _are_residual(a, M, q, X) -> float:
    res = a.T @ X
    res = res + res.T - X @ M @ X + q
    nX = np.abs(X).sum(axis=0).max()
    den = 2 * np.abs(a).sum(axis=0).max() * nX + np.abs(M).sum(axis=0).max() * nX**2 + np.abs(q).sum(axis=0).max()
    return float(np.abs(res).sum(axis=0).max() / max(den, 1e-300))


def _sign_are(a, M, q, *, tol=1e-6, maxit=60):
    """The Newton iteration ``Z <- (c Z + Z^-1 / c) / 2`` for the sign of the Hamiltonian, determinant
    scaling ``c = |det Z|^(-1/2n)`` in the first 8 steps. It stops when the relative step is below
    ``tol`` (the convergence is quadratic: the iterate's error is then of the order of its square) and
    fails when, after 12 steps, a step no longer halves."""
    n = a.shape[0]
    Z = np.block([[a, -M], [-q, -a.T]])
    I2 = np.eye(2 * n)
    err = math.inf
    for it in range(maxit):
        try:
            with warnings.catch_warnings():  # an exactly singular iterate is reported below, not warned about
                warnings.simplefilter("ignore", sla.LinAlgWarning)
                lu, piv = sla.lu_factor(Z, check_finite=False)
        except (np.linalg.LinAlgError, ValueError) as exc:
            return None, True, f"sign iteration: singular iterate ({exc}): eigenvalues on the imaginary axis"
        with np.errstate(divide="ignore"):
            logdet = float(np.sum(np.log(np.abs(np.diag(lu)))))
        if not math.isfinite(logdet):
            return None, True, "sign iteration: singular iterate: eigenvalues on the imaginary axis"
        Zn = sla.lu_solve((lu, piv), I2, check_finite=False)
        c = math.exp(-logdet / (2 * n)) if it < 8 else 1.0  # determinant scaling while far off
        Zn *= 0.5 / c
        Zn += (0.5 * c) * Z  # in place: the next iterate, and Z - Zn its step (Frobenius norms)
        Z -= Zn
        err, prev = float(np.linalg.norm(Z) / max(np.linalg.norm(Zn), 1e-300)), err
        Z = Zn
        if not math.isfinite(err):
            return None, True, "sign iteration: singular iterate: eigenvalues on the imaginary axis"
        if err < tol:
            break
        if it >= 12 and err > 0.5 * prev:  # no quadratic convergence: eigenvalues on or near the axis
            return None, True, f"sign iteration stalled at relative step {err:.2g} (eigenvalues near the imaginary axis)"
    else:
        return None, True, f"sign iteration did not converge in {maxit} steps (eigenvalues near the imaginary axis)"
    I = np.eye(n)
    lhs = np.vstack([Z[:n, n:], Z[n:, n:] + I])
    rhs = -np.vstack([Z[:n, :n] + I, Z[n:, :n]])
    X = sla.lstsq(lhs, rhs, check_finite=False, lapack_driver="gelsy")[0]
    return X, False, ""


def solve_are(a, b, rr, q, *, method: str = "sign", fallback: bool = True, fallback_max_n: int = 512,
              residual_tol: float = RESIDUAL_TOL) -> tuple[np.ndarray | None, AREInfo]:
    """Stabilizing solution of ``a' X + X a - X b diag(rr)^{-1} b' X + q = 0`` (rr may be indefinite).

    Parameters
    ----------
    a : ndarray, shape (n, n)
    b : ndarray, shape (n, k)
    rr : ndarray, shape (k,)
        Nonzero diagonal weights of any sign (``R = diag(rr)`` in scipy's notation).
    q : ndarray, shape (n, n)
        Symmetric.
    method : {"sign", "scipy"}
        See the module docstring.
    fallback : bool
        If the chosen method fails an accuracy check (residual, symmetry), try
        ``"scipy"`` (balanced QZ on the extended pencil). Not when the Hamiltonian has eigenvalues
        on (or within rounding of) the imaginary axis: no method has a stabilizing solution then.
    fallback_max_n : int
        No fallback above this n.
    residual_tol : float
        Largest relative residual accepted.

    Returns
    -------
    X : ndarray or None
        Symmetric solution, or None when none passed the checks.
    info : AREInfo
        Method, residual, closed-loop largest real part, and the reason of a failure.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    rr = np.asarray(rr, dtype=float).reshape(-1)
    q = lmi.sym(np.asarray(q, dtype=float))
    if method not in ("sign", "scipy"):
        raise ValueError(f"method: expected 'sign' or 'scipy', got {method!r}")
    if np.any(rr == 0) or not np.all(np.isfinite(rr)):
        raise ValueError(f"rr: weights must be finite and nonzero, got {rr.tolist()}")
    M = lmi.sym((b / rr) @ b.T)
    n = a.shape[0]
    X, max_re, definite, reason = _solve_by(method, a, b, rr, M, q)
    res = math.inf
    if X is not None:
        X, res, reason = _accurate(X, a, M, q, max_re, residual_tol)
    info = AREInfo(method=method, residual=res, closed_loop_max_re=max_re, reason=reason)
    if X is None and fallback and method != "scipy" and not definite and n <= fallback_max_n:
        X2, info2 = solve_are(a, b, rr, q, method="scipy", fallback=False, residual_tol=residual_tol)
        if X2 is not None:
            return X2, info2
        info = AREInfo(method=method, residual=res, closed_loop_max_re=max_re,
                       reason=f"{reason}; scipy fallback: {info2.reason}")
    return X, info


def _solve_by(method: str, a, b, rr, M, q) -> tuple[np.ndarray | None, float, bool, str]:
    """One ARE solve by ``method``: ``X`` (None on failure), the largest real part of ``a - M X``, whether
    the failure is definite (Hamiltonian eigenvalues on, or within rounding of, the imaginary axis: no
    method has a stabilizing solution), and the reason of a failure."""
    X, max_re, reason, definite = None, math.inf, "", False
    try:
        if method == "sign":
            X, definite, reason = _sign_are(a, M, q)
            # the side's Lyapunov test (P > 0, side matrix < 0) proves the closed loop Hurwitz; the spectrum
            # is computed only where it is cheap
            if X is not None and a.shape[0] <= 128:
                max_re = float(np.linalg.eigvals(a - M @ X).real.max())
            else:
                max_re = -math.inf
        else:
            X = sla.solve_continuous_are(a, b, q, np.diag(rr))
            max_re = float(np.linalg.eigvals(a - M @ X).real.max())
    except (np.linalg.LinAlgError, ValueError) as exc:
        X, reason = None, f"{method}: {str(exc).splitlines()[0]}"
    return X, max_re, definite, reason


def _accurate(X: np.ndarray, a, M, q, max_re: float, residual_tol: float) -> tuple[np.ndarray | None, float, str]:
    """The accuracy checks of a solution: finite, symmetric (relative asymmetry <= 1e-6), relative residual
    within ``residual_tol``, ``a - M X`` Hurwitz. Returns the symmetrised X (None when a check fails), the
    residual and the reason of a failure."""
    if not np.all(np.isfinite(X)):
        return None, math.inf, "non-finite solution"
    asym = float(np.abs(X - X.T).max() / max(np.abs(X).max(), 1e-300))
    X = lmi.sym(X)
    res = _are_residual(a, M, q, X)
    reason = ""
    if asym > 1e-6:
        reason = f"solution not symmetric (relative asymmetry {asym:.2g})"
    elif not res <= residual_tol:
        reason = f"ARE residual {res:.2g} above {residual_tol:g}"
    elif not max_re < 0:
        reason = f"a - M X is not Hurwitz (largest real part {max_re:.3g}): not the stabilizing solution"
    return (None if reason else X), res, reason


# -- the two sides ------------------------------------------------------------
@dataclass(frozen=True)
class SideSolution:
    """A verified solution of one side (:func:`solve_x_side` or :func:`solve_e_side`).

    Attributes
    ----------
    P : ndarray (n, n)
        The side's Lyapunov matrix: P (x-side) or R = X^-1 (e-side), positive definite.
    gain : ndarray
        F (m x n, x-side) or K (n x p, e-side).
    side_matrix : ndarray (n, n)
        ``Mx`` or ``Me`` of :mod:`bench.joint` at ``lam``, recomputed from the gain.
    min_eig : float
        Smallest eigenvalue of P (or R) over its largest.
    multiplier, tau, eps, lam : float
        s (or t), tau (or tau'), eps, and the rate at which the side matrix is verified (the ARE's
        decay target over ``1 + RATE_RTOL``).
    are : AREInfo
    """

    P: np.ndarray
    gain: np.ndarray
    side_matrix: np.ndarray
    min_eig: float
    multiplier: float
    tau: float
    eps: float
    are: AREInfo
    lam: float = 0.0

    @property
    def gain_norm(self) -> float:
        """``||gain||_2``."""
        return _norm2(self.gain)


def _pos_def(P: np.ndarray) -> float:
    """Smallest over largest eigenvalue of a symmetric P (negative or 0: not positive definite)."""
    lo, hi = _eig_at(P, 0), _eig_at(P, -1)
    return lo / hi if hi > 0 else -math.inf


def _loop(A0, B, C, G, H, r) -> joint.Loop:
    n = A0.shape[0]
    C = np.zeros((0, n)) if C is None else C
    B = np.zeros((n, 0)) if B is None else B
    r = np.asarray(r, dtype=float).reshape(-1)
    return joint.loop(A0, B, C, G, H, -r, r)


def _side_are(a, inputs, acts, reads, mult, tau, eps, method):
    """One side's ARE: ``b = [inputs, acts]``, ``rr = (1/(2 tau), -1/mult)``, ``q = reads' reads / mult + eps I``."""
    n = a.shape[0]
    bb = np.hstack([inputs, acts])
    rr = np.concatenate([np.full(inputs.shape[1], 1.0 / (2 * tau)), np.full(acts.shape[1], -1.0 / mult)])
    qq = reads.T @ reads / mult + eps * np.eye(n)
    return solve_are(a, bb, rr, qq, method=method, fallback=False)  # a failing probe is a failed probe


def solve_x_side(A0, B, G, H, r, lam, s, tau, eps, *, method: str = "sign") -> tuple[SideSolution | None, str]:
    """x-side: ``F = -tau B' P`` from the ARE with ``a = A0 + lam I``, ``b = [B, G]``, ``rr = (1/(2 tau), -1/s)``.

    Parameters
    ----------
    A0 : ndarray (n, n)
        ``A + G diag(c0) H``.
    B : ndarray (n, m)
    G, H : ndarray (n, q), (q, n)
        Channels.
    r : ndarray (q,)
        Half widths of the slope intervals (channels with ``r_i = 0`` are dropped).
    lam : float
        Decay target.
    s, tau, eps : float
        Channel multiplier, gain scale, strictness (all > 0).
    method : str
        ARE method (:func:`solve_are`).

    Returns
    -------
    (SideSolution or None, str)
        The verified solution (P > 0, ``Mx(lam / (1 + RATE_RTOL)) < 0``, its ``lam`` that rate) and
        ``""``, or None and the reason in words. At the ARE's solution ``Mx(lam) = -eps I`` on this side
        but ``-eps R^2`` on the e-side, which rounding can make marginal when R is ill-conditioned;
        at the lower rate the side matrix has ``-2 lam RATE_RTOL / (1 + RATE_RTOL) R`` more.
    """
    A0, B = np.asarray(A0, dtype=float), np.asarray(B, dtype=float)
    lp = _loop(A0, B, None, G, H, r)
    n = A0.shape[0]
    P, info = _side_are(A0 + lam * np.eye(n), B, lp.G, lp.DH, s, tau, eps, method)
    if P is None:
        return None, f"x-side ARE: {info.reason}"
    pmin = _pos_def(P)
    if not pmin > 0:
        return None, f"x-side: P is not positive definite (min/max eigenvalue {pmin:.3g})"
    F = -tau * (B.T @ P)
    lam = lam / (1 + RATE_RTOL)
    Mx = joint.side_matrices(lp, F, np.zeros((n, 0)), P, np.eye(n), s, 1.0, lam)[0]
    return _verified_side("x-side", Mx, P, F, pmin, s, tau, eps, lam, info)


def solve_e_side(A0, C, G, H, r, lam, t, tau, eps, *, method: str = "sign") -> tuple[SideSolution | None, str]:
    """e-side: ``K = tau' X C'``, ``R = X^-1``, X from the ARE with ``a = (A0 + lam I)'``, ``b = [C', H' Dr]``.

    Parameters and returns as :func:`solve_x_side` (``t`` the e-side multiplier; ``SideSolution.P``
    is R and ``.gain`` is K).
    """
    A0, C = np.asarray(A0, dtype=float), np.asarray(C, dtype=float)
    lp = _loop(A0, None, C, G, H, r)
    n = A0.shape[0]
    X, info = _side_are((A0 + lam * np.eye(n)).T, C.T, lp.DH.T, lp.G.T, t, tau, eps, method)
    if X is None:
        return None, f"e-side ARE: {info.reason}"
    try:
        cf = sla.cho_factor(X, lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        return None, f"e-side: X is not positive definite (min/max eigenvalue {_pos_def(X):.3g})"
    R = lmi.sym(sla.cho_solve(cf, np.eye(n), check_finite=False))
    rmin = _pos_def(R)
    if not rmin > 0:
        return None, f"e-side: R = X^-1 is not positive definite (min/max eigenvalue {rmin:.3g})"
    K = tau * (X @ C.T)
    lam = lam / (1 + RATE_RTOL)
    Me = joint.side_matrices(lp, np.zeros((0, n)), K, np.eye(n), R, 1.0, t, lam)[1]
    return _verified_side("e-side", Me, R, K, rmin, t, tau, eps, lam, info)


def _verified_side(side, M, P, gain, pmin, mult, tau, eps, lam, info) -> tuple[SideSolution | None, str]:
    """The side's solution when its matrix is verified negative definite (:func:`bench.joint.verdict`)."""
    v = joint.verdict(M)
    if v != "verified":
        return None, f"{side} matrix not verified negative definite ({v})"
    return SideSolution(P=P, gain=gain, side_matrix=M, min_eig=pmin, multiplier=mult, tau=tau,
                        eps=eps, are=info, lam=lam), ""


@dataclass
class RiccatiRouteResult:
    """Outcome of :func:`structured_riccati`.

    Attributes
    ----------
    status : str
        ``"feasible"`` (joint certificate verified), ``"marginal"`` or ``"infeasible"``.
    reason : str
    K, F : ndarray or None
        Observer gain (n x p) and feedback (m x n), ``u = F x_hat``.
    P, R : ndarray or None
        Side Lyapunov matrices (largest eigenvalue 1); ``V = x'Px + mu e'Re``.
    s, t, mu : float
        Multipliers (``1/s`` x channels, ``mu t`` e channels) and the e-side weight.
    tau, tau_e, eps_x, eps_e : float
        The grid point used on each side.
    lam : float
        The decay target the sides were designed for.
    rate : float
        The rate the joint certificate proves (:func:`bench.joint.certify`; NaN unless feasible).
    rate_bound : float
        Its exact generalised eigenvalue (``rate`` is the grid point below).
    margin : float
        Equilibrated max eigenvalue of the reduced joint matrix at rate 0.
    residual_x, residual_e : float
    methods : tuple of str
    timings : dict
        Seconds: ``search``, ``certificate``, ``total``.
    tries : list of tuple
        ``(side, lam, tau, eps, reason or "ok")`` of every ARE solved.
    """

    status: str
    reason: str
    K: np.ndarray | None = None
    F: np.ndarray | None = None
    P: np.ndarray | None = None
    R: np.ndarray | None = None
    s: float = math.nan
    t: float = math.nan
    mu: float = math.nan
    tau: float = math.nan
    tau_e: float = math.nan
    eps_x: float = math.nan
    eps_e: float = math.nan
    lam: float = 0.0
    rate: float = math.nan
    rate_bound: float = math.nan
    margin: float = math.nan
    residual_x: float = math.nan
    residual_e: float = math.nan
    methods: tuple = ()
    timings: dict = field(default_factory=dict)
    tries: list = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True when the joint certificate is verified (``status == "feasible"``)."""
        return self.status == "feasible"


class _Side:
    """One side's verified solutions by decay target: the (tau, eps) grid in full at the first target
    that is solved, then the grid point that verified there."""

    def __init__(self, label, solve, taus, epss, max_gain, tries):
        self.label, self.solve, self.taus, self.epss = label, solve, list(taus), list(epss)
        self.max_gain, self.tries, self.found, self.why = max_gain, tries, {}, "empty grid"
        self.tau_from = self.eps_from = None

    def at(self, lam: float, quick: bool = False) -> SideSolution | None:
        """The verified solution with the smallest grid tau at ``lam`` (None: none; gains not checked);
        ``quick``: the first grid point only."""
        if lam in self.found:
            return self.found[lam]
        sol = None
        if quick or self.tau_from is None:
            grid = [(0, self.epss[0])] if quick else [(i, e) for e in self.epss for i in range(len(self.taus))]
        else:
            grid = [(self.tau_from, self.eps_from)]
        for i, eps in grid:
            sol, why = self.solve(lam, self.taus[i], eps)
            self.tries.append((self.label, lam, self.taus[i], eps, why or "ok"))
            if sol is not None:
                if self.tau_from is None:
                    self.tau_from, self.eps_from = i, eps
                break
            self.why = why
        self.found[lam] = sol
        return sol

    def gain(self, lam: float, quick: bool = False) -> float:
        """``||gain||`` of the solution at ``lam`` (inf: none)."""
        sol = self.at(lam, quick)
        return sol.gain_norm if sol is not None else math.inf


def _search(side: _Side, lam: float | None, top: float, rtol: float, other: bool = False) -> float | None:
    """The side's largest decay target in ``[0, top]`` with ``||gain|| <= side.max_gain`` (``lam`` given:
    that one; ``other``: ``top`` is the other side's target, tried first at the first grid point).

    ``g(l) = ||gain(l)||`` grows with l. After 0 the target ``min(1/8, top/2)`` is tried; then, between
    a passing and a failing target, the mean of the linear interpolations of ``g`` and of ``log g``
    to the bound (g is convex and log g concave in l on the families seen, so the two straddle the
    root); above the passing targets a log-linear extrapolation (at most 4 times up); below a target
    without a solution a quarter (or half) of the way. It stops when the targets, the passing gain
    and the bound, or the next target and the passing one are within ``1 + rtol`` (``1 + rtol / 2``).
    Returns the target (0 when the bound fails at 0), or None when there is no solution at 0.
    """
    if lam is not None:
        return lam if side.at(lam) is not None else None
    if other and side.gain(top, quick=True) <= side.max_gain:
        return top
    g_lo = side.gain(0.0)
    if not math.isfinite(g_lo):
        return None
    lo, up, g_up, prev, x = 0.0, top, math.nan, None, min(0.125, top / 2)
    target = side.max_gain / math.sqrt(1 + rtol)  # aim inside the accepted band
    for _ in range(12):
        if g_lo * (1 + rtol) >= side.max_gain or up <= lo * (1 + rtol) or x in side.found:
            break
        g = side.gain(x)
        if g <= side.max_gain:
            prev, lo, g_lo = (lo, g_lo), x, g
        else:
            up, g_up = x, g
        if math.isfinite(g_up):  # bracketed by gains
            lin = (target - g_lo) / (g_up - g_lo)
            log = math.log(target / g_lo) / math.log(g_up / g_lo)
            x = lo + (up - lo) * min(max((lin + log) / 2, 0.01), 0.99)
            if x <= lo * (1 + rtol / 2):  # the predicted gain is below the tolerance
                break
        elif math.isnan(g_up):  # nothing failed yet: extrapolate log g from the last two passing targets
            slope = math.log(g_lo / prev[1]) / (lo - prev[0])
            x = min(top, 4 * lo, lo + math.log(target / g_lo) / slope if slope > 0 else 4 * lo)
        else:  # no solution at up
            x = lo + (up - lo) * (0.25 if lo == 0 else 0.5)
    return lo


def structured_riccati(A, B, C, G, H, lo, hi, *, lam: float | None = 0.0, max_gain: float = math.inf,
                       max_decay: float = 10.0, rtol: float = 0.05, taus: Sequence[float] = TAU_GRID,
                       eps: Sequence[float] = EPS_GRID, s: float | None = None, t: float | None = None,
                       method: str = "sign") -> RiccatiRouteResult:
    """Structured observer-based design by AREs, certified by :func:`bench.joint.certify`.

    Parameters
    ----------
    A, B, C : array_like
        Shapes (n, n), (n, m), (p, n).
    G, H : array_like
        Channels ``f(x) = G phi(H x)``, shapes (n, q), (q, n).
    lo, hi : float or array_like (q,)
        Slope bounds of each channel.
    lam : float or None
        A fixed decay target, or None to search the largest one (see the module docstring).
    max_gain : float
        Bound on ``||F||`` and ``||K||`` in the search.
    max_decay : float
        Upper end of the search.
    rtol : float
        Relative tolerance of the search (:func:`_search`).
    taus, eps : sequence of float
        Grids of the gain scale and the strictness relative to their natural scales (module docstring).
    s, t : float, optional
        Channel multipliers (default ``s = ||Dr H|| / ||G||``, ``t = 1 / s``).
    method : str
        ARE method (:func:`solve_are`).

    Returns
    -------
    RiccatiRouteResult
        ``"feasible"`` only when the joint certificate is verified; ``rate`` is the rate it proves.
    """
    t_start = time.perf_counter()
    A, B, C, G, H = (np.asarray(v, dtype=float) for v in (A, B, C, G, H))
    q = _check_shapes(A, B, C, G, H, lo, hi)
    lp = joint.loop(A, B, C, G, H, lo, hi)
    r = np.broadcast_to(np.asarray((np.asarray(hi, float) - np.asarray(lo, float)) / 2), (q,))
    A0 = lp.A0
    sigma, s, t, tau0_x, tau0_e = _scales(lp, B, C, s, t)
    tries: list = []
    res = RiccatiRouteResult(status="infeasible", reason="", s=s, t=t, tries=tries)
    xs = _Side("x", lambda la, tau, e: solve_x_side(A0, B, G, H, r, la, s, tau * tau0_x, e * sigma, method=method),
               taus, eps, max_gain, tries)
    es = _Side("e", lambda la, tau, e: solve_e_side(A0, C, G, H, r, la, t, tau * tau0_e, e * sigma, method=method),
               taus, eps, max_gain, tries)
    # the e-side first, then the x-side up to its target (the joint rate is the slower side's)
    lam_e = _search(es, lam, max_decay, rtol)
    lam_x = _search(xs, lam, lam_e if lam is None and lam_e else max_decay, rtol, other=bool(lam is None and lam_e))
    if lam_x is None or lam_e is None:
        res.reason = "; ".join(f"{side.label}-side infeasible on the grid (last: {side.why})"
                               for side, found in ((xs, lam_x), (es, lam_e)) if found is None)
        res.timings = {"search": time.perf_counter() - t_start, "total": time.perf_counter() - t_start}
        return res
    t1 = time.perf_counter()
    _certify_pair(res, lp, xs, es, lam_x, lam_e, s, t)
    res.timings = {"search": t1 - t_start, "certificate": time.perf_counter() - t1,
                   "total": time.perf_counter() - t_start}
    return res


def _scales(lp: joint.Loop, B: np.ndarray, C: np.ndarray, s: float | None,
            t: float | None) -> tuple[float, float, float, float, float]:
    """The natural scales (module docstring): ``sigma = ||Dr H|| ||G||`` (``||A0||`` without channels), the
    multipliers ``s`` (default ``||Dr H|| / ||G||``) and ``t`` (default its inverse), and the gain scales
    ``tau0 = sigma / ||B||^2`` (x-side) and ``sigma / ||C||^2`` (e-side)."""
    nG, nDH = _norm2(lp.G), _norm2(lp.DH)
    sigma, s0 = (nG * nDH, nDH / nG) if nG > 0 and nDH > 0 else (max(_norm2(lp.A0), 1e-12), 1.0)
    s = s0 if s is None else float(s)
    t = 1 / s0 if t is None else float(t)
    return sigma, s, t, sigma / max(_norm2(B) ** 2, 1e-300), sigma / max(_norm2(C) ** 2, 1e-300)


def _check_shapes(A, B, C, G, H, lo, hi) -> int:
    """The number of channels q, or ValueError naming a matrix of the wrong shape or a channel with lo > hi."""
    n = A.shape[0]
    q = G.shape[1] if G.ndim == 2 else -1
    for name, X, shape in (("A", A, (n, n)), ("B", B, (n, B.shape[-1])), ("C", C, (C.shape[0], n)),
                           ("G", G, (n, q)), ("H", H, (q, n))):
        if X.ndim != 2 or X.shape != shape:
            raise ValueError(f"{name}: expected shape {shape} (A is {A.shape}, G is {G.shape}), got {X.shape}")
    if np.any(np.broadcast_to(lo, (q,)) > np.broadcast_to(hi, (q,))):
        raise ValueError("lo/hi: every channel needs lo <= hi")
    return q


def _certify_pair(res: RiccatiRouteResult, lp: joint.Loop, xs: _Side, es: _Side, lam_x: float, lam_e: float,
                  s: float, t: float) -> None:
    """Fill ``res`` (in place) with the sides' solutions at the slower side's target ``min(lam_x, lam_e)``
    (a side without one there keeps its own) and the joint certificate of the pair."""
    res.lam = min(lam_x, lam_e)
    x, e = xs.at(res.lam) or xs.at(lam_x), es.at(res.lam) or es.at(lam_e)
    # normalise P and R to a unit largest eigenvalue: (P, s) -> (P/a, s a), (R, t) -> (R/b, t/b) keep both sides
    a_x, a_e = _eig_at(x.P, -1), _eig_at(e.P, -1)
    res.P, res.R, res.s, res.t = x.P / a_x, e.P / a_e, s * a_x, t / a_e
    res.F, res.K = x.gain, e.gain
    res.tau, res.eps_x, res.tau_e, res.eps_e = x.tau, x.eps, e.tau, e.eps
    res.residual_x, res.residual_e = x.are.residual, e.are.residual
    res.methods = (x.are.method, e.are.method)
    cert = joint.certify(lp, res.F, res.K, res.P, res.R, res.s, res.t)
    res.mu, res.margin, res.rate, res.rate_bound = cert.mu, cert.margin, cert.rate, cert.bound
    res.status = {"verified": "feasible", "marginal": "marginal"}.get(cert.status, "infeasible")
    res.reason = (f"joint certificate verified (equilibrated max eigenvalue {cert.margin:.3g}), rate {cert.rate:.4g}"
                  if cert.verified else f"joint certificate {cert.status} (equilibrated max eigenvalue {cert.margin:.3g})")


def constants_riccati(A, B, C, *, alpha: float | None = None, rho: float | None = None,
                      beta: float | None = None, gamma: float | None = None, lam: float = 0.0,
                      thetas: Sequence[float] = (0.0, 0.1, 0.3, 1.0, 3.0, 10.0), **kwargs) -> tuple[RiccatiRouteResult, dict]:
    """The Riccati route with the scalar constants of f instead of channels (G = H = I).

    With one multiplier per side only the sum over channels of the S-procedure terms is used, so
    ``G = H = I`` with ``|dpsi| <= r |dz|`` covers any f with an incremental bound
    ``|f(a) - f(b) - c0 (a - b)| <= r |a - b|``:

    - Lipschitz alpha: ``c0 = 0``, ``r = alpha`` (Corollary 1's constraint).
    - OSL rho plus QIB (beta, gamma): ``theta (rho |dx|^2 - <dx, df>) + (beta |dx|^2 + gamma <dx, df>
      - |df|^2) >= 0`` for a fixed ``theta >= 0`` is ``|df - c0 dx|^2 <= r^2 |dx|^2`` with
      ``c0 = (gamma - theta) / 2``, ``r^2 = c0^2 + theta rho + beta`` (complete the square); theta is
      searched on ``thetas`` (Theorem 1's constraints with ``eps3 / eps4 = theta``).

    Parameters
    ----------
    A, B, C : array_like
    alpha, rho, beta, gamma : float, optional
        Constants; the OSL/QIB form needs beta and gamma (rho optional, thetas > 0 need it), the
        Lipschitz form alpha. Both are tried when both are given.
    lam : float
        Decay target.
    thetas : sequence of float
        Ratios eps3/eps4 tried for the OSL/QIB form.
    **kwargs
        Passed to :func:`structured_riccati`.

    This is a Riccati analogue of the corrected Theorem 1 / Corollary 1 (``docs/paper.md``), not the
    same condition: one ball ``(c0, r)`` serves both sides and the joint certificate has the cross
    term handled by mu, while those LMIs use the QIB pair (``beta_eff = beta + gamma rho``) on
    the x-side and OSL + QIB with separate multipliers on the e-side. Both are only sufficient.

    Returns
    -------
    (RiccatiRouteResult, dict)
        The best result (feasible first, then the most negative margin) and the constraint used
        (``{"form": "lipschitz" | "osl_qib", "c0": ..., "r": ..., "theta": ...}``).
    """
    A = np.asarray(A, dtype=float)
    I = np.eye(A.shape[0])
    best, best_c = None, None
    for cand in _balls(alpha, rho, beta, gamma, thetas):
        res = structured_riccati(A, B, C, I, I, cand["c0"] - cand["r"], cand["c0"] + cand["r"], lam=lam, **kwargs)
        key = (res.ok, -res.margin if np.isfinite(res.margin) else -math.inf)
        if best is None or key > (best.ok, -best.margin if np.isfinite(best.margin) else -math.inf):
            best, best_c = res, cand
    return best, best_c


def _balls(alpha, rho, beta, gamma, thetas) -> list[dict]:
    """The incremental balls ``|df - c0 dx| <= r |dx|`` the constants give (:func:`constants_riccati`), or
    ValueError when they give none."""
    cands = []
    if alpha is not None:
        cands.append({"form": "lipschitz", "c0": 0.0, "r": float(alpha), "theta": math.nan})
    if beta is not None and gamma is not None:
        for th in thetas:
            if th > 0 and rho is None:
                continue
            c0 = (gamma - th) / 2
            r2 = c0 * c0 + th * (rho or 0.0) + beta
            if r2 >= 0:
                cands.append({"form": "osl_qib", "c0": c0, "r": math.sqrt(r2), "theta": float(th)})
    if not cands:
        raise ValueError("constants: give alpha, or beta and gamma (and rho for theta > 0)")
    return cands
