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

The design searches the e-side's largest decay target whose gain stays within ``max_gain``
(:func:`_search`), solves and verifies both sides there (:func:`_targets`) and certifies the pair
by :func:`bench.joint.certify`. The AREs (indefinite ``M``, the stabilizing solution) are solved by the
matrix sign function of the Hamiltonian (:func:`_sign_are`, :func:`_newton`) or scipy's ordered Schur
method (:func:`solve_are`). A solution is used only through its side's Lyapunov test, which also proves
the closed loop Hurwitz.

References
----------
J. D. Roberts, "Linear model reduction and solution of the algebraic Riccati equation by use of
the sign function", Int. J. Control 32(4), 1980. R. Byers, "Solving the algebraic Riccati equation
with the matrix sign function", Linear Algebra Appl. 85, 1987. D. Kleinman, "On an iterative
technique for Riccati equation computations", IEEE Trans. Automat. Control 13(1), 1968.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import scipy.linalg as sla
from scipy.linalg import lapack

from bench import joint, lmi
from bench.threads import parallel
from bench.search import RATE_RTOL

__all__ = ["structured_riccati"]

#: Largest relative ARE residual accepted.
RESIDUAL_TOL = 1e-8
#: From this n on, the sign iteration starts in single precision and Newton steps
#: refine its solution; the search's gain estimates stay in single precision.
SINGLE_FROM_N = 256
#: Default tau grid, relative to the natural scale (smallest gain first).
TAU_GRID = (1.0, 10.0, 1e2, 1e3, 1e4, 1e5)
#: Default eps grid, relative to the natural scale.
EPS_GRID = (1e-2, 1e-4)


def _norm2(X: np.ndarray) -> float:
    """Spectral norm via the largest eigenvalue of the smaller Gram matrix."""
    X = np.asarray(X, dtype=float)
    if X.size == 0:
        return 0.0
    Gm = X.T @ X if X.shape[0] >= X.shape[1] else X @ X.T
    i = Gm.shape[0] - 1
    try:
        top = float(sla.eigvalsh(Gm, subset_by_index=[i, i], check_finite=False)[0])
    except (np.linalg.LinAlgError, ValueError):  # LAPACK's subset driver can fail on clustered spectra
        top = float(np.linalg.eigvalsh(Gm)[i])
    return float(math.sqrt(max(top, 0.0)))


@dataclass(frozen=True)
class AREInfo:
    """Diagnostics of one ARE solve (:func:`solve_are`): method, relative residual
    ``||a'X + Xa - XMX + q||_1 / (2 ||a||_1 ||X||_1 + ||M||_1 ||X||_1^2 + ||q||_1)``, largest real part
    of ``a - M X`` (-inf when not computed), and the reason of a failure (empty on success)."""

    method: str
    residual: float = math.inf
    closed_loop_max_re: float = math.inf
    reason: str = ""


def _are_residual(a, M, q, X) -> tuple[float, np.ndarray]:
    """X's relative residual (:class:`AREInfo`) and its residual matrix ``a'X + Xa - XMX + q``."""
    res = a.T @ X
    res = res + res.T - X @ M @ X + q
    nX = np.abs(X).sum(axis=0).max()
    den = 2 * np.abs(a).sum(axis=0).max() * nX + np.abs(M).sum(axis=0).max() * nX**2 + np.abs(q).sum(axis=0).max()
    return float(np.abs(res).sum(axis=0).max() / max(den, 1e-300)), res


def _sign_are(a, M, q, *, tol=1e-6, maxit=60, single=False):
    """The Newton iteration ``Z <- (c Z + Z^-1 / c) / 2`` for the sign of the Hamiltonian, determinant
    scaling ``c = |det Z|^(-1/2n)`` in the first 8 steps, each inverse by LAPACK's getrf + getrs. It stops
    when the relative step is below ``tol`` and fails when, after 12 steps, a step no longer halves. X solves the
    stacked system ``[W12; W22 + I] X = -[W11 + I; W21]`` of ``W = sign(Z)`` by QR. ``single``: the
    iteration in single precision (X to about 1e-4, for the search's gain estimates). Returns X (or None) and
    the reason of a failure."""
    n = a.shape[0]
    dtype = np.float32 if single else np.float64
    getrf, getrs = (lapack.sgetrf, lapack.sgetrs) if single else (lapack.dgetrf, lapack.dgetrs)
    Z = np.asfortranarray(np.block([[a, -M], [-q, -a.T]]), dtype=dtype)
    I2 = np.asfortranarray(np.eye(2 * n, dtype=dtype))
    err = math.inf
    for it in range(maxit):
        lu, piv, info = getrf(Z)
        with np.errstate(divide="ignore"):
            logdet = float(np.sum(np.log(np.abs(np.diag(lu)), dtype=np.float64)))
        Zn, info2 = getrs(lu, piv, I2)
        if info != 0 or info2 != 0 or not math.isfinite(logdet):
            return None, "sign iteration: singular iterate: eigenvalues on the imaginary axis"
        c = math.exp(-logdet / (2 * n)) if it < 8 else 1.0  # determinant scaling while far off
        with np.errstate(over="ignore", invalid="ignore"):
            Zn *= Zn.dtype.type(0.5 / c)
            Zn += Zn.dtype.type(0.5 * c) * Z  # in place: the next iterate, and Z - Zn its step (Frobenius norms)
            Z -= Zn
            err, prev = float(np.linalg.norm(Z)) / max(float(np.linalg.norm(Zn)), 1e-300), err
        Z = Zn
        if not math.isfinite(err):
            return None, "sign iteration: singular iterate: eigenvalues on the imaginary axis"
        if err < tol:
            break
        if it >= 12 and err > 0.5 * prev:  # no quadratic convergence: eigenvalues on or near the axis
            return None, f"sign iteration stalled at relative step {err:.2g} (eigenvalues near the imaginary axis)"
    else:
        return None, f"sign iteration did not converge in {maxit} steps (eigenvalues near the imaginary axis)"
    Z = Z.astype(np.float64, copy=False)
    I = np.eye(n)
    lhs = np.vstack([Z[:n, n:], Z[n:, n:] + I])
    rhs = -np.vstack([Z[:n, :n] + I, Z[n:, :n]])
    Qf, Rf = sla.qr(lhs, mode="economic", overwrite_a=True, check_finite=False)
    try:
        X = sla.solve_triangular(Rf, Qf.T @ rhs, check_finite=False)
    except np.linalg.LinAlgError:
        return None, "sign iteration: the stacked system for X is singular"
    return X, ""


def _lyap_sign(A, Q, *, tol=1e-4, maxit=40):
    """X with ``A' X + X A + Q = 0`` for a Hurwitz A, by the sign iteration in single precision:
    ``A <- (c A + A^-1 / c) / 2``, ``Q <- (c Q + A^-T Q A^-1 / c) / 2`` (determinant scaling
    ``c = |det A|^(-1/n)`` in the first 8 steps), ``X = Q_inf / 2`` (Roberts 1980). None unless the
    iterates of A reach ``-I``."""
    n = A.shape[0]
    Ak = np.asfortranarray(A, dtype=np.float32)
    Qk = np.asarray(Q, dtype=np.float32)
    I = np.asfortranarray(np.eye(n, dtype=np.float32))
    for it in range(maxit):
        lu, piv, info = lapack.sgetrf(Ak)
        Ai, info2 = lapack.sgetrs(lu, piv, I)
        with np.errstate(divide="ignore"):
            logdet = float(np.sum(np.log(np.abs(np.diag(lu)), dtype=np.float64)))
        if info != 0 or info2 != 0 or not math.isfinite(logdet):
            return None
        c = np.float32(math.exp(-logdet / n) if it < 8 else 1.0)  # |det(c A)| = 1
        with np.errstate(over="ignore", invalid="ignore"):
            An = (c * Ak + Ai / c) / 2
            Qk = (c * Qk + (Ai.T @ Qk @ Ai) / c) / 2
            err = float(np.linalg.norm(An - Ak)) / max(float(np.linalg.norm(An)), 1e-30)
        Ak = np.asfortranarray(An)
        if not math.isfinite(err):
            return None
        if err < tol:
            break
    if not np.linalg.norm(Ak + I) <= 1e-2 * math.sqrt(n) or not np.all(np.isfinite(Qk)):  # the sign is not -I
        return None
    return Qk.astype(np.float64) / 2


def _newton(a, M, q, X, residual_tol, steps=5):
    """Newton (Kleinman) steps ``X <- X + D``, ``(a - M X)' D + D (a - M X) = -(a' X + X a - X M X + q)``
    from an approximate solution: the residual in double precision, D by :func:`_lyap_sign`. The steps
    go on to ``residual_tol / 100`` while each cuts the relative residual tenfold. Returns X (None unless
    it is within ``residual_tol``) and its relative residual."""
    X = lmi.sym(np.asarray(X, dtype=np.float64))
    res_now, res = _are_residual(a, M, q, X)
    for _ in range(steps):
        if not res_now > 1e-2 * residual_tol:
            break
        D = _lyap_sign(a - M @ X, lmi.sym(res))
        if D is None:
            break
        X_new = X + lmi.sym(D)
        res_new, res_mat = _are_residual(a, M, q, X_new)
        if not res_new < res_now:
            break
        X, res_now, res, cut = X_new, res_new, res_mat, res_new < 0.1 * res_now
        if not cut:
            break
    return (X if res_now <= residual_tol else None), res_now


def solve_are(a, b, rr, q, *, method: str = "sign", X0=None) -> tuple[np.ndarray | None, AREInfo]:
    """Stabilizing solution of ``a' X + X a - X b diag(rr)^{-1} b' X + q = 0`` (rr may be indefinite), its relative
    residual within :data:`RESIDUAL_TOL`.

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
    X0 : ndarray, optional
        An approximate solution (``"sign"``: refined by Newton steps instead of the single-precision
        sign iteration).

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
    X, max_re, reason, res = _solve_by(method, a, b, rr, M, q, X0)
    if X is not None:
        X, res, reason = _accurate(X, a, M, q, max_re, res)
    return X, AREInfo(method=method, residual=res, closed_loop_max_re=max_re, reason=reason)


def _solve_by(method: str, a, b, rr, M, q, X0) -> tuple[np.ndarray | None, float, str, float | None]:
    """One ARE solve by ``method``: ``X`` (None on failure), the largest real part of ``a - M X``, the reason
    of a failure and X's relative residual when known. ``"sign"``: the sign iteration in single precision
    (or ``X0``) refined by Newton steps (:func:`_newton`), else in double precision."""
    X, max_re, reason, res = None, math.inf, "", None
    try:
        if method == "sign":
            if X0 is None and a.shape[0] >= SINGLE_FROM_N:
                X0 = _sign_are(a, M, q, tol=1e-2, single=True)[0]
            if X0 is not None:
                X, res = _newton(a, M, q, X0, RESIDUAL_TOL)
            if X is None:
                (X, reason), res = _sign_are(a, M, q), None
        else:
            X = sla.solve_continuous_are(a, b, q, np.diag(rr))
        if X is not None and (method == "scipy" or a.shape[0] <= 128):
            max_re = float(np.linalg.eigvals(a - M @ X).real.max())
        else:
            max_re = -math.inf
    except (np.linalg.LinAlgError, ValueError) as exc:
        X, reason = None, f"{method}: {str(exc).splitlines()[0]}"
    return X, max_re, reason, res


def _accurate(X: np.ndarray, a, M, q, max_re: float, res: float | None) -> tuple[np.ndarray | None, float, str]:
    """The accuracy checks of a solution: finite, symmetric (relative asymmetry <= 1e-6), relative residual
    (``res`` when the caller has it) within :data:`RESIDUAL_TOL`, ``a - M X`` Hurwitz. Returns the symmetrised X
    (None when a check fails), the residual and the reason of a failure."""
    if not np.all(np.isfinite(X)):
        return None, math.inf, "non-finite solution"
    asym = float(np.abs(X - X.T).max() / max(np.abs(X).max(), 1e-300))
    X = lmi.sym(X)
    res = _are_residual(a, M, q, X)[0] if res is None else res
    reason = ""
    if asym > 1e-6:
        reason = f"solution not symmetric (relative asymmetry {asym:.2g})"
    elif not res <= RESIDUAL_TOL:
        reason = f"ARE residual {res:.2g} above {RESIDUAL_TOL:g}"
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
    max_eig : float
        Largest eigenvalue of P (or R).
    tau, lam : float
        tau (or tau') and the rate at which the side matrix is verified (the ARE's decay target over
        ``1 + RATE_RTOL``).
    are : AREInfo
    """

    P: np.ndarray
    gain: np.ndarray
    side_matrix: np.ndarray
    min_eig: float
    tau: float
    are: AREInfo
    lam: float = 0.0
    max_eig: float = 1.0

    @property
    def gain_norm(self) -> float:
        """``||gain||_2``."""
        return _norm2(self.gain)


def _pos_def(P: np.ndarray) -> tuple[float, float]:
    """Smallest over largest eigenvalue of a symmetric P (negative or 0: not positive definite), and the largest."""
    try:
        w = sla.eigh(P, eigvals_only=True, check_finite=False)
    except (np.linalg.LinAlgError, ValueError):
        return -math.inf, math.nan
    return (w[0] / w[-1] if w[-1] > 0 else -math.inf), float(w[-1])


def _loop(A0, B, C, G, H, r) -> joint.Loop:
    r = np.asarray(r, dtype=float).reshape(-1)
    return joint.loop(A0, B, C, G, H, -r, r)


def _side_terms(inputs, acts, reads, mult, tau, eps) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One side's ARE terms: ``b = [inputs, acts]``, ``rr = (1/(2 tau), -1/mult)``, ``q = reads' reads / mult + eps I``."""
    b = np.hstack([inputs, acts])
    rr = np.concatenate([np.full(inputs.shape[1], 1.0 / (2 * tau)), np.full(acts.shape[1], -1.0 / mult)])
    return b, rr, reads.T @ reads / mult + eps * np.eye(inputs.shape[0])


def solve_x_side(A0, B, G, H, r, lam, s, tau, eps, *, method: str = "sign", X0=None) -> tuple[SideSolution | None, str]:
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
    X0 : ndarray, optional
        An approximate solution of the ARE (:func:`solve_are`).

    Returns
    -------
    (SideSolution or None, str)
        The verified solution (P > 0, ``Mx(lam / (1 + RATE_RTOL)) < 0``, its ``lam`` that rate) and
        ``""``, or None and the reason in words.
    """
    A0, B = np.asarray(A0, dtype=float), np.asarray(B, dtype=float)
    n = A0.shape[0]
    lp = _loop(A0, B, np.zeros((0, n)), G, H, r)
    P, info = solve_are(A0 + lam * np.eye(n), *_side_terms(B, lp.G, lp.DH, s, tau, eps), method=method, X0=X0)
    if P is None:
        return None, f"x-side ARE: {info.reason}"
    pmin, pmax = _pos_def(P)
    if not pmin > 0:
        return None, f"x-side: P is not positive definite (min/max eigenvalue {pmin:.3g})"
    F = -tau * (B.T @ P)
    lam = lam / (1 + RATE_RTOL)
    Mx = joint.side_matrices(lp, F, np.zeros((n, 0)), P, np.eye(n), s, 1.0, lam)[0]
    return _verified_side("x-side", Mx, P, F, (pmin, pmax), tau, lam, info)


def solve_e_side(A0, C, G, H, r, lam, t, tau, eps, *, method: str = "sign", X0=None) -> tuple[SideSolution | None, str]:
    """e-side: ``K = tau' X C'``, ``R = X^-1``, X from the ARE with ``a = (A0 + lam I)'``, ``b = [C', H' Dr]``.

    Parameters and returns as :func:`solve_x_side` (``t`` the e-side multiplier; ``SideSolution.P``
    is R and ``.gain`` is K).
    """
    A0, C = np.asarray(A0, dtype=float), np.asarray(C, dtype=float)
    n = A0.shape[0]
    lp = _loop(A0, np.zeros((n, 0)), C, G, H, r)
    X, info = solve_are((A0 + lam * np.eye(n)).T, *_side_terms(C.T, lp.DH.T, lp.G.T, t, tau, eps), method=method, X0=X0)
    if X is None:
        return None, f"e-side ARE: {info.reason}"
    try:
        cf = sla.cho_factor(X, lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        return None, f"e-side: X is not positive definite (min/max eigenvalue {_pos_def(X)[0]:.3g})"
    R = lmi.sym(sla.cho_solve(cf, np.eye(n), check_finite=False))
    rmin, rmax = _pos_def(R)
    if not rmin > 0:
        return None, f"e-side: R = X^-1 is not positive definite (min/max eigenvalue {rmin:.3g})"
    K = tau * (X @ C.T)
    lam = lam / (1 + RATE_RTOL)
    Me = joint.side_matrices(lp, np.zeros((0, n)), K, np.eye(n), R, 1.0, t, lam)[1]
    return _verified_side("e-side", Me, R, K, (rmin, rmax), tau, lam, info)


def _verified_side(side, M, P, gain, eigs, tau, lam, info) -> tuple[SideSolution | None, str]:
    """The side's solution when its matrix is verified negative definite (:func:`bench.joint.verdict`)."""
    v = joint.verdict(M)
    if v != "verified":
        return None, f"{side} matrix not verified negative definite ({v})"
    return SideSolution(P=P, gain=gain, side_matrix=M, min_eig=eigs[0], max_eig=eigs[1], tau=tau, are=info,
                        lam=lam), ""


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
    tau, tau_e : float
        The gain scales used on each side (:attr:`tries` has each side's grid point).
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
        ``(side, lam, tau, eps, reason or "ok")`` of every ARE solved, the e-side's first, each side's
        in the order of its targets; an estimate's reason starts with ``"estimate: "``.
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
    """One side of the route by decay target: gain estimates that steer the search (:meth:`estimate`;
    single precision from :data:`SINGLE_FROM_N` states) and verified solutions of the targets kept
    (:meth:`solve`), each recorded in :attr:`tries` in the order of its targets.

    While no (tau, eps) grid point is picked, each target estimated scans the grid until its ARE has a
    solution; the first point found in a stage (the smallest) is picked, and later estimates use it
    alone. The verified solves try it first, then the rest of the grid."""

    def __init__(self, label, n, are_data, gain_of, solve, grid, max_gain):
        self.label, self.n, self.are_data, self.gain_of, self.solve_at = label, n, are_data, gain_of, solve
        self.grid, self.max_gain = list(grid), max_gain
        self.pick: int | None = None
        self.est: dict[float, float] = {}
        self.start: dict[tuple, np.ndarray] = {}  # (lam, grid index) -> the estimate's solution
        self.found: dict[float, SideSolution | None] = {}
        self.tries: list = []
        self.why = "empty grid"

    def _scan(self, lam: float, first: int, last: int) -> list:
        """``(i, gain or inf, X, reason)`` along grid points ``first .. last - 1`` up to the first solution."""
        out = []
        for i in range(first, last):
            tau, eps = self.grid[i]
            a, M, q = self.are_data(lam, tau, eps)
            single = a.shape[0] >= SINGLE_FROM_N
            X, why = _sign_are(a, M, q, tol=1e-2 if single else 1e-6, single=single)
            g = self.gain_of(X, tau) if X is not None else math.inf
            out.append((i, g if math.isfinite(g) else math.inf, X, why))
            if math.isfinite(g):
                break
        return out

    def estimate(self, lams: Sequence[float], also: tuple | None = None) -> None:
        """Gain estimates ``||gain||`` at ``lams`` (inf: no stabilizing solution at the picked grid point)
        into :attr:`est`, computed concurrently (:func:`bench.threads.parallel`) with ``also``'s, a pair
        ``(other side, its targets)``."""
        plans = [(side, *side._plan(lams)) for side, lams in [(self, lams), *([also] if also else [])]]
        runs = iter(parallel([c for _, _, calls in plans for c in calls], self.n))
        for side, new, calls in plans:
            side._record(new, [next(runs) for _ in calls])

    def _plan(self, lams: Sequence[float]) -> tuple[list, list]:
        """The targets not estimated yet and a grid scan (:meth:`_scan`) for each."""
        new = [lam for lam in dict.fromkeys(lams) if lam not in self.est]
        first, last = (0, len(self.grid)) if self.pick is None else (self.pick, self.pick + 1)
        return new, [lambda la=la: self._scan(la, first, last) for la in new]

    def _record(self, new: list, runs: list) -> None:
        """Keep the scans' estimates (and pick the grid point if none is yet)."""
        if self.pick is None and runs:  # a scan that went past the smallest point found failed there
            self.pick = min((run[-1][0] for run in runs if math.isfinite(run[-1][1])), default=None)
        for lam, run in zip(new, runs):
            for i, g, X, why in run:
                tau, eps = self.grid[i]
                self.tries.append((self.label, lam, tau, eps, f"estimate: {why or 'ok'}"))
                if math.isfinite(g):
                    self.start[(lam, i)] = X
                else:
                    self.why = f"estimate at decay {lam:g}: {why or 'no finite gain'}"
            self.est[lam] = next((g for i, g, _, _ in run if i == self.pick), math.inf)

    def solve(self, lam: float) -> SideSolution | None:
        """The verified solution at ``lam`` (None: none on the grid; the gain bound is not checked)."""
        if lam in self.found:
            return self.found[lam]
        sol = None
        for i in sorted(range(len(self.grid)), key=lambda i: i != self.pick):  # the picked point first
            tau, eps = self.grid[i]
            sol, why = self.solve_at(lam, tau, eps, self.start.get((lam, i)))
            self.tries.append((self.label, lam, tau, eps, why or "ok"))
            if sol is not None:
                break
            self.why = why
        self.found[lam] = sol
        return sol


def _search(side: _Side, top: float, rtol: float, companion: _Side | None = None) -> float | None:
    """The side's largest decay target in ``[0, top]`` whose estimated gain is within ``side.max_gain``.

    First ``t1 = min(1/8, top/2)`` and ``t1/8`` are estimated (:meth:`_Side.estimate`, concurrently).
    With a passing target ``lo`` and a failing one ``up`` the next target is where the power law
    through them, ``g(l) = g(lo) (l / lo)^p``, meets ``max_gain / sqrt(1 + rtol)``; above the
    passing targets the power law of the two largest is extrapolated (at most 8 times up); without a
    solution at ``up``, the geometric mean; when every target fails, ``min / 8`` and 0. Beside each
    next target the ``companion`` side is estimated there (its solve at the final target then starts
    from it), or without a companion the target times ``1 + rtol``. It stops when the passing gain is
    within ``1 + rtol`` of the bound, a failing target within ``1 + rtol`` of the passing one, or the
    next target within ``1 + rtol / 2`` of it. Returns the target, 0 when the bound fails at 0, or None
    when there is no solution at 0.
    """
    G = side.max_gain
    aim = G / math.sqrt(1 + rtol)
    t1 = min(0.125, top / 2)
    lams, also = [t1, t1 / 8], None
    lo = None
    for _ in range(12):
        side.estimate(lams, also)
        est = side.est
        up = min((la for la, g in est.items() if not g <= G), default=None)
        lo = max((la for la, g in est.items() if g <= G and (up is None or la < up)), default=None)
        if lo is None:
            if 0.0 in est:
                return 0.0 if math.isfinite(est[0.0]) else None
            lams, also = [min(est) / 8, 0.0], None
            continue
        g_lo = est[lo]
        if g_lo * (1 + rtol) >= G or lo >= top or (up is not None and up <= lo * (1 + rtol)):
            return lo
        x = _next_target(est, lo, up, aim, top)
        if x <= lo * (1 + rtol / 2):
            return lo
        if companion is not None:
            lams, also = [x], (companion, [x])
        else:
            lams = [x, min(x * (1 + rtol), top) if up is None else min(x * (1 + rtol), math.sqrt(x * up))]
    return lo


def _next_target(est: dict, lo: float, up: float | None, aim: float, top: float) -> float:
    """The next target of :func:`_search` (its docstring), in ``(lo, up)``."""
    g_lo = est[lo]
    if up is None:
        below = [la for la in est if la < lo and 0 < est[la] <= g_lo]
        x = 8 * lo
        if below and lo > 0:
            l1 = max(below)
            p = math.log(g_lo / est[l1]) / math.log(lo / l1)
            if p > 0:
                x = min(x, lo * (aim / g_lo) ** (1 / p))
        return min(x, top)
    g_up = est[up]
    if lo == 0:
        return up / 4 if math.isfinite(g_up) else up / 8
    if not math.isfinite(g_up) or g_up <= g_lo:
        return math.sqrt(lo * up)
    p = math.log(g_up / g_lo) / math.log(up / lo)
    x = lo * (aim / g_lo) ** (1 / p)
    return min(max(x, lo), up / (1 + 1e-9))


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
        ARE method of the verified solves (:func:`solve_are`).

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
    scales = _scales(lp, B, C, s, t)
    res = RiccatiRouteResult(status="infeasible", reason="", s=scales[1], t=scales[2])
    xs, es = _sides(lp, G, H, r, scales, [(tau, e) for e in eps for tau in taus], max_gain, method)
    found = _targets(xs, es, lam, max_decay, rtol)
    res.tries, t1 = es.tries + xs.tries, time.perf_counter()
    res.timings = {"search": t1 - t_start}
    if isinstance(found, str):
        res.reason = found
    else:
        _certify_pair(res, lp, *found)
        res.timings["certificate"] = time.perf_counter() - t1
    res.timings["total"] = time.perf_counter() - t_start
    return res


def _sides(lp: joint.Loop, G, H, r, scales: tuple, grid: list, max_gain: float, method: str) -> tuple[_Side, _Side]:
    """The x-side and the e-side of the route (:class:`_Side`) on the (tau, eps) ``grid`` relative to ``scales``."""
    A0, B, C, n = lp.A0, lp.B, lp.C, lp.A0.shape[0]
    sigma, s, t, tau0_x, tau0_e = scales
    I = np.eye(n)
    xs = _Side("x", n, lambda la, tau, e: _are_data(A0 + la * I, B, lp.G, lp.DH, s, tau * tau0_x, e * sigma),
               lambda X, tau: _norm2(tau * tau0_x * (B.T @ X)),
               lambda la, tau, e, X0: solve_x_side(A0, B, G, H, r, la, s, tau * tau0_x, e * sigma, method=method, X0=X0),
               grid, max_gain)
    es = _Side("e", n, lambda la, tau, e: _are_data((A0 + la * I).T, C.T, lp.DH.T, lp.G.T, t, tau * tau0_e, e * sigma),
               lambda X, tau: _norm2(tau * tau0_e * (X @ C.T)),
               lambda la, tau, e, X0: solve_e_side(A0, C, G, H, r, la, t, tau * tau0_e, e * sigma, method=method, X0=X0),
               grid, max_gain)
    return xs, es


def _are_data(a, inputs, acts, reads, mult, tau, eps) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(a, M, q)`` of one side's ARE ``a' X + X a - X M X + q = 0``, ``M = b diag(rr)^-1 b'`` (:func:`_side_terms`)."""
    b, rr, q = _side_terms(inputs, acts, reads, mult, tau, eps)
    return a, lmi.sym((b / rr) @ b.T), lmi.sym(q)


def _targets(xs: _Side, es: _Side, lam: float | None, top: float, rtol: float) -> tuple | str:
    """The pair's target and the verified sides there, ``(target, x, e)``, or the reason there are none.

    A fixed ``lam``: both sides there. Searched: the e-side's target (:func:`_search`), both sides
    solved there concurrently; a side whose verified solution fails (or exceeds the gain bound) steps
    down to the next lower target estimated to pass (its own search for the x-side), and the other
    side is solved at the lower target too. At target 0 a solution is kept whatever its gain."""
    target = lam if lam is not None else _search(es, top, rtol, companion=xs)
    for _ in range(8):
        if target is None:
            return f"e-side: no stabilizing ARE solution at decay 0 on the grid (last: {es.why})"
        x, e = parallel([lambda: xs.solve(target), lambda: es.solve(target)], xs.n)
        keep = lam is not None or target == 0  # any verified solution: the smallest gains found

        def fits(side: _Side, sol: SideSolution | None) -> bool:
            return sol is not None and (keep or sol.gain_norm <= side.max_gain)

        if not fits(es, e):  # the estimate was optimistic: the next lower target estimated to pass
            if keep:
                return f"e-side: no verified solution at decay {target:g} on the grid (last: {es.why})"
            target = max((la for la, g in es.est.items() if la < target and g <= es.max_gain), default=0.0)
            continue
        if fits(xs, x):
            return target, x, e
        if keep:
            return f"x-side: no verified solution at decay {target:g} on the grid (last: {xs.why})"
        xs.est[target] = x.gain_norm if x is not None else math.inf  # its own search below the target
        target = _search(xs, target, rtol)
        if target is None:
            return f"x-side: no stabilizing ARE solution at decay 0 on the grid (last: {xs.why})"
    return "no target verified on both sides in 8 attempts"


def _scales(lp: joint.Loop, B: np.ndarray, C: np.ndarray, s: float | None,
            t: float | None) -> tuple[float, float, float, float, float]:
    """The module docstring's ``(sigma, s, t, tau0, tau0')``, ``tau0' = sigma / ||C||^2``, ``sigma = ||A0||`` without
    channels; ``s``, ``t`` when given."""
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


def _certify_pair(res: RiccatiRouteResult, lp: joint.Loop, lam: float, x: SideSolution, e: SideSolution) -> None:
    """Fill ``res`` (in place) with the sides' solutions at the target ``lam`` and the joint certificate."""
    res.lam = lam
    # normalise P and R to a unit largest eigenvalue: (P, s) -> (P/a, s a), (R, t) -> (R/b, t/b) keep both sides
    a_x, a_e = x.max_eig, e.max_eig
    res.P, res.R, res.s, res.t = x.P / a_x, e.P / a_e, res.s * a_x, res.t / a_e
    res.F, res.K = x.gain, e.gain
    res.tau, res.tau_e = x.tau, e.tau
    res.residual_x, res.residual_e = x.are.residual, e.are.residual
    res.methods = (x.are.method, e.are.method)
    # the sides' matrices at their verified rates, moved to rate 0 and normalised as P and R
    sides = ((x.side_matrix - 2 * x.lam * x.P) / a_x, (e.side_matrix - 2 * e.lam * e.P) / a_e)
    cert = joint.certify(lp, res.F, res.K, res.P, res.R, res.s, res.t, sides=sides)
    res.mu, res.margin, res.rate, res.rate_bound = cert.mu, cert.margin, cert.rate, cert.bound
    res.status = {"verified": "feasible", "marginal": "marginal"}.get(cert.status, "infeasible")
    res.reason = (f"joint certificate verified (equilibrated max eigenvalue {cert.margin:.3g}), rate {cert.rate:.4g}"
                  if cert.verified else f"joint certificate {cert.status} (equilibrated max eigenvalue {cert.margin:.3g})")
