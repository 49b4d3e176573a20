"""The Riccati route: the structured (channel) design and its joint certificate without an SDP.

Setting (``../shared/design/STRUCTURE.md``): ``x' = A x + B u + G phi(H x)``, ``y = C x``,
``u = F x_hat``, observer ``x_hat' = A x_hat + B u + G phi(H x_hat) + K (y - C x_hat)``, each
channel slope-restricted, ``lo_i <= dphi_i / dz_i <= hi_i``. Loop transformation:
``c0 = (lo + hi) / 2``, ``r = (hi - lo) / 2``, ``A0 = A + G diag(c0) H``, ``psi(z) = phi(z) - c0 z``
so that ``|psi_i(a) - psi_i(b)| <= r_i |a - b|``; with ``e = x - x_hat``::

    x' = (A0 + B F) x - B F e + G psi(H x)
    e' = (A0 - K C) e + G (psi(H x) - psi(H x_hat))

Channels with ``r_i = 0`` are exactly linear (they are inside A0) and are dropped.

Side Riccati equations
----------------------
With one multiplier per side (``S = s I``, ``T = t I``) and ``Y = -tau B'`` (so ``F = Y Q^{-1} =
-tau B' P`` with ``P = Q^{-1}``), the Schur complement of the x-side LMI, multiplied by P on both
sides, is the Riccati inequality ::

    (A0 + lam I)' P + P (A0 + lam I) - P (2 tau B B' - s G G') P + H' Dr^2 H / s  < 0,

i.e. the ARE ``a' P + P a - P M P + q = 0`` with ``a = A0 + lam I``, ``M = b diag(rr)^{-1} b'``,
``b = [B, G]``, ``rr = (1/(2 tau), ..., -1/s, ...)``, ``q = H' Dr^2 H / s + eps I``: any solution has
the side matrix equal to ``-eps I`` (in P coordinates), so P > 0 makes the x-side LMI strictly
feasible (``Q = P^{-1}``, ``Y = -tau B'``, ``S = s I``). With ``Kh = tau' C'`` (K = R^{-1} Kh) the e-side's
Schur complement, multiplied by ``X = R^{-1}`` on both sides, is ::

    (A0 + lam I) X + X (A0 + lam I)' - X (2 tau' C' C - t H' Dr^2 H) X + G G' / t  < 0,

the ARE with ``a = (A0 + lam I)'``, ``b = [C', H' Dr]``, ``rr = (1/(2 tau'), ..., -1/t, ...)``,
``q = G G' / t + eps I``; then ``R = X^{-1}`` and ``K = R^{-1} Kh = tau' X C'``. These are the formulas
of STRUCTURE.md ("A Riccati route for large n"), re-derived here and found right; STRUCTURE.md
writes the choice as ``Kh = tau' C'`` and the gain as ``K = tau' X C'``, which agree since
``R^{-1} = X``. (Its "searched" multipliers s, t are redundant: the x-side is invariant under
``(tau, s, eps, P) -> (a tau, a s, eps / a, P / a)``, which leaves F unchanged, and likewise the
e-side, so s and t are fixed here at the balance ``s = ||Dr H|| / ||G||``, ``t = 1 / s`` and only
``tau`` and ``eps`` are searched.)

Joint certificate
-----------------
``V = x' P x + mu e' R e``, S-procedure multipliers ``1/s`` on ``r^2 (Hx)^2 - psi(Hx)^2 >= 0`` and
``mu t`` on ``r^2 (He)^2 - dpsi^2 >= 0``; with ``xi = (x, e, psi(Hx), dpsi)`` ::

    V' + 2 lam V <= xi' M xi,
    M = [[(A0+BF)'P + P(A0+BF) + 2 lam P + H'Dr^2 H / s,  -P B F,  P G,  0     ],
         [*,  mu ((A0-KC)'R + R(A0-KC) + 2 lam R + t H'Dr^2 H),     0,    mu R G],
         [*,  *,  -I / s,  0     ],
         [*,  *,  *,      -mu t I]]

(re-derived: ``x' = ... - B F e`` enters ``V'`` as ``2 x' P (-B F) e``, hence the (x, e) block
``-P B F``; ``e' = ... + G dpsi`` as ``2 mu e' R G dpsi``). ``M < 0`` certifies
``V(t) <= exp(-2 lam t) V(0)`` along every trajectory (for channels with a local slope bound, while
the trajectory stays in the region).

The last two block rows are diagonal (``-I/s`` and ``-mu t I``) and couple only to x (through
``P G``) and to e (through ``mu R G``). By the Schur complement lemma, ``M < 0`` iff those blocks
are negative definite (they are, s, t, mu > 0) and ::

    M_red = [[Mx, -P B F], [-(P B F)', mu Me]] < 0,     (2n x 2n)
    Mx = (A0+BF)'P + P(A0+BF) + 2 lam P + H'Dr^2 H / s + s P G G' P,
    Me = (A0-KC)'R + R(A0-KC) + 2 lam R + t H'Dr^2 H + R G G' R / t,

so the eigenvalue test runs on 2n x 2n, not 2n + 2q. (The eigenvalues of ``M_red`` are not those of
M; only the inertia test is equivalent. Mx and Me are the side matrices with the channel blocks
eliminated: ``Mx = -eps I`` and ``Me = -eps R^2`` at an exact ARE solution, but they are recomputed
here from K, F, P, R, never taken from the ARE.)

Choice of mu. The cross term has rank <= m: ``P B F = U F`` with ``U = P B``. Given ``Mx < 0`` and
``Me < 0``, the Schur complement ``mu Me + F' W F`` with ``W = U' (-Mx)^{-1} U`` (m x m) is
negative definite iff ``mu > mu_min = lambda_max(W^{1/2} F (-Me)^{-1} F' W^{1/2})``, an m x m
eigenvalue problem (closed form, no search). Any ``mu = kappa mu_min``, kappa > 1, certifies, and
``mu Me + F' W F <= (1 - 1/kappa) mu Me``: kappa = 10 keeps 90 % of the e-side's margin. (A search of
mu is pointless for the reported margin: with the Jacobi equilibration below, the margin is
``lambda_max`` of ``[[Mx~, N~ / sqrt(mu)], [N~' / sqrt(mu), Me~]]``, an even convex function of
``1 / sqrt(mu)``, so it only improves as mu grows.)

Margin. ``margin = lambda_max(D M_red D)``, ``D = diag(|M_red,ii|^{-1/2})`` (a Jacobi equilibration: a
congruence, so the inertia is kept; for a negative definite M_red the diagonal of ``D M_red D`` is
``-1`` and the margin lies in ``[-1, 0)``). Status: ``"feasible"`` when ``margin < -1e-7`` (and a
Cholesky factorisation of ``-D M_red D`` succeeds), ``"marginal"`` when ``|margin| <= 1e-7``,
``"infeasible"`` otherwise, each with a reason in words.

ARE solver
----------
``a' X + X a - X M X + q = 0`` with ``M`` indefinite, the stabilizing solution (``a - M X``
Hurwitz). Methods (:func:`solve_are`):

- ``"schur"`` (default): ordered real Schur form of the 2n x 2n Hamiltonian
  ``[[a, -M], [-q, -a']]`` (``scipy.linalg.schur(..., sort='lhp')``), ``X = U21 U11^{-1}``; the
  closed-loop spectrum of the ARE is that of ``T11``, whose real parts are the diagonal of T11 in
  LAPACK's standardised real Schur form, so the Hurwitz check costs nothing.
- ``"sign"``: the matrix sign function of the Hamiltonian (Newton iteration with determinant
  scaling; Roberts 1971, Byers 1987), X from ``[W12; W22 + I] X = -[W11 + I; W21]``; the Hurwitz
  check is an eigenvalue computation of ``a - M X``.
- ``"scipy"``: ``scipy.linalg.solve_continuous_are`` on the extended (2n + k) pencil, balanced.

Measured on this 2-core machine, shared with other jobs (one ARE of the chain plant, one BLAS
thread, ``python benchmarks/riccati_scaling.py --solvers --sizes 128 256 512 1024``), seconds at
n = 128 / 256 / 512 / 1024: schur 0.14 / 0.46 / 1.8 / 11 (the 2n x 2n Schur form takes 7.7 s and its
reordering 3.3 s at n = 1024; everything else < 0.5 s); sign (13 iterations, plus the eigenvalues
of a - M X for the Hurwitz check) 0.07 / 0.45 / 3.2 / 20; scipy 0.19 / 2.0 / 18 / -; Newton-Kleinman
from X0 = 0 (A is Hurwitz there) 0.40 / 2.8 / 34 / - with 30 / 34 / 38 Lyapunov solves. All residuals
<= 2e-15. On 400 random instances (n = 4 .. 32, random tau, s, eps, many without a solution) the
three direct methods accepted and rejected exactly the same ones. Schur is kept (backward stable,
the Hurwitz check is free, a clean failure when eigenvalues sit on the imaginary axis); scipy's
solver is the fallback when the Schur solution fails an accuracy check. Every solution is checked:
residual, symmetry, closed-loop Hurwitz.

References
----------
J. D. Roberts, "Linear model reduction and solution of the algebraic Riccati equation by use of
the sign function", Int. J. Control 32(4), 1980 (report 1971). R. Byers, "Solving the algebraic
Riccati equation with the matrix sign function", Linear Algebra Appl. 85, 1987. A. J. Laub,
"A Schur method for solving algebraic Riccati equations", IEEE TAC 24(6), 1979.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import scipy.linalg as sla

__all__ = [
    "AREInfo",
    "RiccatiRouteResult",
    "SideSolution",
    "constants_riccati",
    "equilibrated_max_eig",
    "joint_matrix",
    "joint_margin",
    "min_mu",
    "solve_are",
    "solve_e_side",
    "solve_x_side",
    "structured_riccati",
]

#: Relative margin (after Jacobi equilibration) below which a matrix counts as negative definite.
MARGIN_TOL = 1e-7
#: Largest relative ARE residual accepted.
RESIDUAL_TOL = 1e-8
#: Default tau grid, relative to the natural scale (see :func:`structured_riccati`).
TAU_GRID = (1.0, 10.0, 1e2, 1e3, 1e4, 1e5)
#: Default eps grid, relative to the natural scale.
EPS_GRID = (1e-2, 1e-4)


# -- small helpers ------------------------------------------------------------------------------
def _sym(X: np.ndarray) -> np.ndarray:
    return (X + X.T) / 2


def equilibrated_max_eig(M: np.ndarray) -> float:
    """Largest eigenvalue of ``D M D``, ``D = diag(|M_ii|^{-1/2})`` (Jacobi equilibration).

    Parameters
    ----------
    M : ndarray, shape (k, k)
        Symmetric (its symmetric part is used).

    Returns
    -------
    float
        ``lambda_max(D M D)``. The congruence keeps the inertia, so the sign says whether M is
        negative definite; for a negative definite M the value lies in ``[-1, 0)``. A zero
        diagonal entry is scaled as if it were ``1e-300`` relative to the largest.
    """
    M = _sym(np.asarray(M, dtype=float))
    d = np.abs(np.diag(M))
    d = np.maximum(d, 1e-300 * max(float(d.max(initial=0.0)), 1e-300))
    s = 1.0 / np.sqrt(d)
    E = M * s[:, None] * s[None, :]
    return _eig_at(E, -1)


def _eig_at(M: np.ndarray, index: int) -> float:
    """The ``index``-th smallest eigenvalue of a symmetric M (``-1``: the largest).

    LAPACK's subset driver (``evr``) is O(k^2) for one eigenvalue but can stop with "Internal
    Error" on tightly clustered spectra (seen on a near-identity Gram matrix at n = 16); the full
    divide-and-conquer driver is the fallback.
    """
    k = M.shape[0]
    i = index % k
    try:
        return float(sla.eigvalsh(M, subset_by_index=[i, i], check_finite=False)[0])
    except (np.linalg.LinAlgError, ValueError):
        return float(np.linalg.eigvalsh(M)[i])


def _norm2(X: np.ndarray) -> float:
    """Spectral norm via the smaller Gram matrix."""
    X = np.asarray(X, dtype=float)
    if X.size == 0:
        return 0.0
    Gm = X.T @ X if X.shape[0] >= X.shape[1] else X @ X.T
    return float(math.sqrt(max(_eig_at(Gm, -1), 0.0)))


# -- the ARE ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class AREInfo:
    """Diagnostics of one ARE solve (:func:`solve_are`).

    Attributes
    ----------
    method : str
        The method that produced the solution (``"schur"``, ``"sign"`` or ``"scipy"``).
    residual : float
        ``||a'X + Xa - XMX + q||_1 / (2 ||a||_1 ||X||_1 + ||M||_1 ||X||_1^2 + ||q||_1)``.
    closed_loop_max_re : float
        Largest real part of an eigenvalue of ``a - M X`` (negative: stabilizing).
    seconds : float
        Wall time of the solve and its checks.
    reason : str
        Empty on success, else why the solution was rejected (or not found).
    """

    method: str
    residual: float = math.inf
    closed_loop_max_re: float = math.inf
    seconds: float = 0.0
    reason: str = ""


def _are_residual(a, M, q, X) -> float:
    res = a.T @ X
    res = res + res.T - X @ M @ X + q
    nX = np.abs(X).sum(axis=0).max()
    den = 2 * np.abs(a).sum(axis=0).max() * nX + np.abs(M).sum(axis=0).max() * nX**2 + np.abs(q).sum(axis=0).max()
    return float(np.abs(res).sum(axis=0).max() / max(den, 1e-300))


def _schur_are(a, M, q):
    n = a.shape[0]
    Ham = np.block([[a, -M], [-q, -a.T]])
    scale = float(np.abs(Ham).sum(axis=0).max())
    T, U, sdim = sla.schur(Ham, output="real", sort="lhp", overwrite_a=True, check_finite=False)
    if sdim != n:
        return None, math.inf, True, (f"the Hamiltonian has {sdim} eigenvalues with negative real part, not n = {n} "
                                "(eigenvalues on or near the imaginary axis: no stabilizing solution)")
    # LAPACK's standardised real Schur form: a 2x2 block has equal diagonal entries (its real part)
    re = np.diag(T)
    max_re, min_re_unstable = float(re[:n].max()), float(re[n:].min())
    if max_re > -1e-10 * scale or min_re_unstable < 1e-10 * scale:
        return None, max_re, True, (f"Hamiltonian eigenvalues within {1e-10:g} (relative) of the imaginary axis "
                              f"(closest {min(-max_re, min_re_unstable):.3g}): no reliable stabilizing solution")
    U11, U21 = U[:n, :n], U[n:, :n]
    try:
        lu = sla.lu_factor(U11.T, check_finite=False)
    except (np.linalg.LinAlgError, ValueError) as exc:
        return None, max_re, False, f"U11 is singular ({exc})"
    rcond = sla.lapack.dgecon(lu[0], np.abs(U11).sum(axis=0).max())[0] if n else 1.0
    if rcond < 1e-14:
        return None, max_re, False, f"U11 is numerically singular (rcond {rcond:.2g}): the stabilizing solution is unbounded"
    X = sla.lu_solve(lu, U21.T, check_finite=False).T
    return X, max_re, False, ""


def _sign_are(a, M, q, *, tol=1e-13, maxit=60):
    n = a.shape[0]
    Z = np.block([[a, -M], [-q, -a.T]])
    for it in range(maxit):
        try:
            lu, piv = sla.lu_factor(Z, check_finite=False)
        except (np.linalg.LinAlgError, ValueError) as exc:
            return None, True, f"sign iteration: singular iterate ({exc}): eigenvalues on the imaginary axis"
        logdet = float(np.sum(np.log(np.abs(np.diag(lu)))))
        Zi, info = sla.lapack.dgetri(lu, piv)
        if info != 0:
            return None, True, "sign iteration: singular iterate: eigenvalues on the imaginary axis"
        c = math.exp(-logdet / (2 * n)) if it < 8 else 1.0  # determinant scaling while far off
        Zn = 0.5 * (c * Z + Zi / c)
        err = float(np.abs(Zn - Z).sum(axis=0).max() / max(np.abs(Zn).sum(axis=0).max(), 1e-300))
        Z = Zn
        if err < tol:
            break
    else:
        return None, True, f"sign iteration did not converge in {maxit} steps (eigenvalues near the imaginary axis)"
    I = np.eye(n)
    lhs = np.vstack([Z[:n, n:], Z[n:, n:] + I])
    rhs = -np.vstack([Z[:n, :n] + I, Z[n:, :n]])
    X = sla.lstsq(lhs, rhs, check_finite=False)[0]
    return X, False, ""


def solve_are(a, b, rr, q, *, method: str = "schur", fallback: bool = True, fallback_max_n: int = 512,
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
    method : {"schur", "sign", "scipy"}
        See the module docstring.
    fallback : bool
        If the chosen method fails an accuracy check (residual, symmetry, conditioning of U11), try
        ``"scipy"`` (balanced QZ on the extended pencil). Not when the Hamiltonian has eigenvalues
        on (or within rounding of) the imaginary axis: no method has a stabilizing solution then.
    fallback_max_n : int
        No fallback above this n (scipy's solver takes ~100 s at n = 1024).
    residual_tol : float
        Largest relative residual accepted.

    Returns
    -------
    X : ndarray or None
        Symmetric solution, or None when none passed the checks.
    info : AREInfo
        Method, residual, closed-loop largest real part, time, and the reason of a failure.
    """
    t0 = time.perf_counter()
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    rr = np.asarray(rr, dtype=float).reshape(-1)
    q = _sym(np.asarray(q, dtype=float))
    if method not in ("schur", "sign", "scipy"):
        raise ValueError(f"method: expected 'schur', 'sign' or 'scipy', got {method!r}")
    if np.any(rr == 0) or not np.all(np.isfinite(rr)):
        raise ValueError(f"rr: weights must be finite and nonzero, got {rr.tolist()}")
    M = _sym((b / rr) @ b.T)
    n = a.shape[0]
    # definite: the Hamiltonian has eigenvalues on (or within rounding of) the imaginary axis, so
    # no method has a stabilizing solution and a fallback would only waste time
    X, max_re, reason, definite = None, math.inf, "", False
    try:
        if method == "schur":
            X, max_re, definite, reason = _schur_are(a, M, q)
        elif method == "sign":
            X, definite, reason = _sign_are(a, M, q)
            if X is not None:
                max_re = float(np.linalg.eigvals(a - M @ X).real.max())
        else:
            X = sla.solve_continuous_are(a, b, q, np.diag(rr))
            max_re = float(np.linalg.eigvals(a - M @ X).real.max())
    except (np.linalg.LinAlgError, ValueError) as exc:
        X, reason = None, f"{method}: {str(exc).splitlines()[0]}"
    res = math.inf
    if X is not None:
        if not np.all(np.isfinite(X)):
            X, reason = None, "non-finite solution"
        else:
            asym = float(np.abs(X - X.T).max() / max(np.abs(X).max(), 1e-300))
            X = _sym(X)
            res = _are_residual(a, M, q, X)
            if asym > 1e-6:
                reason = f"solution not symmetric (relative asymmetry {asym:.2g})"
            elif not res <= residual_tol:
                reason = f"ARE residual {res:.2g} above {residual_tol:g}"
            elif not max_re < 0:
                reason = f"a - M X is not Hurwitz (largest real part {max_re:.3g}): not the stabilizing solution"
            if reason:
                X = None
    info = AREInfo(method=method, residual=res, closed_loop_max_re=max_re,
                   seconds=time.perf_counter() - t0, reason=reason)
    if X is None and fallback and method != "scipy" and not definite and n <= fallback_max_n:
        X2, info2 = solve_are(a, b, rr, q, method="scipy", fallback=False, residual_tol=residual_tol)
        if X2 is not None:
            return X2, AREInfo(method="scipy", residual=info2.residual, closed_loop_max_re=info2.closed_loop_max_re,
                               seconds=time.perf_counter() - t0, reason="")
        info = AREInfo(method=method, residual=res, closed_loop_max_re=max_re, seconds=time.perf_counter() - t0,
                       reason=f"{reason}; scipy fallback: {info2.reason}")
    return X, info


# -- the two sides ------------------------------------------------------------------------------
@dataclass(frozen=True)
class SideSolution:
    """A verified solution of one side (:func:`solve_x_side` or :func:`solve_e_side`).

    Attributes
    ----------
    P : ndarray, shape (n, n)
        The side's Lyapunov matrix: P (x-side) or R = X^{-1} (e-side), positive definite.
    gain : ndarray
        F (m x n, x-side) or K (n x p, e-side).
    side_matrix : ndarray, shape (n, n)
        The side's matrix with the channel block eliminated (Mx or Me of the module docstring),
        recomputed from the gain, not taken from the ARE.
    margin : float
        Jacobi-equilibrated largest eigenvalue of ``side_matrix`` (< 0).
    min_eig : float
        Smallest eigenvalue of P (or R) over its largest.
    multiplier, tau, eps : float
        s (or t), tau (or tau'), eps.
    are : AREInfo
    """

    P: np.ndarray
    gain: np.ndarray
    side_matrix: np.ndarray
    margin: float
    min_eig: float
    multiplier: float
    tau: float
    eps: float
    are: AREInfo


def _reduce_channels(G, H, r):
    G = np.asarray(G, dtype=float)
    H = np.asarray(H, dtype=float)
    r = np.asarray(r, dtype=float).reshape(-1)
    keep = r > 0
    return G[:, keep], r[keep, None] * H[keep, :]  # G, Dr H


def _pos_def(P: np.ndarray) -> float:
    """Smallest over largest eigenvalue of a symmetric P (negative or 0: not positive definite)."""
    lo, hi = _eig_at(P, 0), _eig_at(P, -1)
    return lo / hi if hi > 0 else -math.inf


def x_side_matrix(A0, B, F, P, G, DH, lam, s):
    """``Mx = (A0+BF)'P + P(A0+BF) + 2 lam P + H'Dr^2 H / s + s P G G' P`` (channels eliminated)."""
    Acl = A0 + B @ F
    M = Acl.T @ P
    M = M + M.T + 2 * lam * P
    if DH.shape[0]:
        PG = P @ G
        M = M + DH.T @ DH / s + s * PG @ PG.T
    return _sym(M)


def e_side_matrix(A0, C, K, R, G, DH, lam, t):
    """``Me = (A0-KC)'R + R(A0-KC) + 2 lam R + t H'Dr^2 H + R G G' R / t`` (channels eliminated)."""
    Acl = A0 - K @ C
    M = Acl.T @ R
    M = M + M.T + 2 * lam * R
    if DH.shape[0]:
        RG = R @ G
        M = M + t * DH.T @ DH + RG @ RG.T / t
    return _sym(M)


def _side_are(a, inputs, acts, reads, mult, tau, eps, method):
    """One side's ARE: ``b = [inputs, acts]``, ``rr = (1/(2 tau), -1/mult)``, ``q = reads' reads / mult + eps I``.

    The x-side is ``(A0 + lam I, B, G, Dr H)`` with multiplier s; the e-side is its dual,
    ``((A0 + lam I)', C', (Dr H)', G')`` with multiplier t.
    """
    n = a.shape[0]
    bb = np.hstack([inputs, acts])
    rr = np.concatenate([np.full(inputs.shape[1], 1.0 / (2 * tau)), np.full(acts.shape[1], -1.0 / mult)])
    qq = reads.T @ reads / mult + eps * np.eye(n)
    return solve_are(a, bb, rr, qq, method=method)


def solve_x_side(A0, B, G, H, r, lam, s, tau, eps, *, method: str = "schur") -> tuple[SideSolution | None, str]:
    """x-side: ``F = -tau B' P`` from the ARE with ``a = A0 + lam I``, ``b = [B, G]``, ``rr = (1/(2 tau), -1/s)``.

    Parameters
    ----------
    A0 : ndarray, shape (n, n)
        ``A + G diag(c0) H``.
    B : ndarray, shape (n, m)
    G, H : ndarray, shapes (n, q), (q, n)
        Channels.
    r : ndarray, shape (q,)
        Half widths of the slope intervals (channels with ``r_i = 0`` are dropped).
    lam : float
        Decay target (>= 0 in use; any real accepted).
    s, tau, eps : float
        Channel multiplier (> 0), gain scale (> 0), strictness (> 0).
    method : str
        ARE method (:func:`solve_are`).

    Returns
    -------
    (SideSolution or None, str)
        The verified solution (P > 0, ``Mx < 0`` by an eigenvalue computation, small residual) and
        ``""``, or None and the reason in words.
    """
    A0 = np.asarray(A0, dtype=float)
    B = np.asarray(B, dtype=float)
    n = B.shape[0]
    Gk, DH = _reduce_channels(G, H, r)
    P, info = _side_are(A0 + lam * np.eye(n), B, Gk, DH, s, tau, eps, method)
    if P is None:
        return None, f"x-side ARE: {info.reason}"
    pmin = _pos_def(P)
    if not pmin > 0:
        return None, f"x-side: P is not positive definite (min/max eigenvalue {pmin:.3g})"
    F = -tau * (B.T @ P)
    return _verified_side("x-side", x_side_matrix(A0, B, F, P, Gk, DH, lam, s), P, F, pmin, s, tau, eps, info)


def solve_e_side(A0, C, G, H, r, lam, t, tau, eps, *, method: str = "schur") -> tuple[SideSolution | None, str]:
    """e-side: ``K = tau' X C'``, ``R = X^{-1}``, X from the ARE with ``a = (A0 + lam I)'``, ``b = [C', H' Dr]``.

    Parameters
    ----------
    A0 : ndarray, shape (n, n)
    C : ndarray, shape (p, n)
    G, H, r
        Channels, as in :func:`solve_x_side`.
    lam : float
        Decay target.
    t, tau, eps : float
        Channel multiplier (> 0), gain scale tau' (> 0), strictness (> 0);
        ``rr = (1/(2 tau'), -1/t)``, ``q = G G' / t + eps I``.
    method : str
        ARE method (:func:`solve_are`).

    Returns
    -------
    (SideSolution or None, str)
        ``SideSolution.P`` is R and ``.gain`` is K; or None and the reason.
    """
    A0 = np.asarray(A0, dtype=float)
    C = np.asarray(C, dtype=float)
    n = C.shape[1]
    Gk, DH = _reduce_channels(G, H, r)
    X, info = _side_are((A0 + lam * np.eye(n)).T, C.T, DH.T, Gk.T, t, tau, eps, method)
    if X is None:
        return None, f"e-side ARE: {info.reason}"
    try:
        cf = sla.cho_factor(X, lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        return None, f"e-side: X is not positive definite (min/max eigenvalue {_pos_def(X):.3g})"
    R = _sym(sla.cho_solve(cf, np.eye(n), check_finite=False))
    rmin = _pos_def(R)
    if not rmin > 0:
        return None, f"e-side: R = X^-1 is not positive definite (min/max eigenvalue {rmin:.3g})"
    K = tau * (X @ C.T)
    return _verified_side("e-side", e_side_matrix(A0, C, K, R, Gk, DH, lam, t), R, K, rmin, t, tau, eps, info)


def _verified_side(side: str, M, P, gain, pmin, mult, tau, eps, info) -> tuple[SideSolution | None, str]:
    """The side's solution when its matrix ``M`` is negative definite (equilibrated eigenvalues), else
    None and the reason."""
    margin = equilibrated_max_eig(M)
    if not margin < -MARGIN_TOL:
        return None, f"{side} matrix not negative definite (equilibrated max eigenvalue {margin:.3g})"
    return SideSolution(P=P, gain=gain, side_matrix=M, margin=margin, min_eig=pmin, multiplier=mult, tau=tau,
                        eps=eps, are=info), ""


# -- the joint certificate ----------------------------------------------------------------------
def min_mu(B, F, P, Mx, Me) -> float:
    """Smallest mu making ``[[Mx, -P B F], [-(P B F)', mu Me]]`` negative definite (Mx, Me < 0).

    Parameters
    ----------
    B, F, P : ndarray
        Shapes (n, m), (m, n), (n, n).
    Mx, Me : ndarray, shape (n, n)
        Negative definite side matrices (channels eliminated).

    Returns
    -------
    float
        ``lambda_max(W^{1/2} F (-Me)^{-1} F' W^{1/2})`` with ``W = (P B)' (-Mx)^{-1} (P B)``: the
        joint matrix is negative definite iff ``mu > min_mu``.

    Raises
    ------
    numpy.linalg.LinAlgError
        If Mx or Me is not negative definite (Cholesky fails).
    """
    U = P @ B
    cx = sla.cho_factor(-Mx, lower=True, check_finite=False)
    ce = sla.cho_factor(-Me, lower=True, check_finite=False)
    W = _sym(U.T @ sla.cho_solve(cx, U, check_finite=False))
    Z = _sym(F @ sla.cho_solve(ce, F.T, check_finite=False))
    w, V = np.linalg.eigh(W)
    Wh = (V * np.sqrt(np.maximum(w, 0))) @ V.T
    return float(max(np.linalg.eigvalsh(_sym(Wh @ Z @ Wh)).max(initial=0.0), 0.0))


def joint_matrix(A0, B, C, F, K, P, R, G, H, r, *, s, t, mu, lam=0.0, reduced: bool = True) -> np.ndarray:
    """The joint certificate matrix for fixed gains.

    Parameters
    ----------
    A0, B, C : ndarray
        ``A0 = A + G diag(c0) H``, B, C.
    F, K : ndarray
        Gains, shapes (m, n), (n, p).
    P, R : ndarray, shape (n, n)
        x-side and e-side Lyapunov matrices (``P_joint = diag(P, mu R)``).
    G, H, r
        Channels and the half widths of their slope intervals.
    s, t, mu, lam : float
        Multipliers ``1/s`` (x channels) and ``mu t`` (e channels), e-side weight, decay target.
    reduced : bool
        True: the 2n x 2n matrix with the (diagonal) channel blocks eliminated by the Schur
        complement (negative definite iff the full one is). False: the full
        ``(2n + 2q) x (2n + 2q)`` matrix in ``(x, e, psi(Hx), dpsi)`` (for tests at small n).

    Returns
    -------
    ndarray
    """
    A0, B, C, F, K, P, R = (np.asarray(v, dtype=float) for v in (A0, B, C, F, K, P, R))
    Gk, DH = _reduce_channels(G, H, r)
    Mx = x_side_matrix(A0, B, F, P, Gk, DH, lam, s) if reduced else None
    Me = e_side_matrix(A0, C, K, R, Gk, DH, lam, t) if reduced else None
    PBF = P @ B @ F
    if reduced:
        return np.block([[Mx, -PBF], [-PBF.T, mu * Me]])
    n, q = A0.shape[0], Gk.shape[1]
    Ax, Ae = A0 + B @ F, A0 - K @ C
    HH = DH.T @ DH
    M11 = _sym(Ax.T @ P + P @ Ax + 2 * lam * P + HH / s)
    M22 = mu * _sym(Ae.T @ R + R @ Ae + 2 * lam * R + t * HH)
    Z = np.zeros
    return np.block([
        [M11, -PBF, P @ Gk, Z((n, q))],
        [-PBF.T, M22, Z((n, q)), mu * R @ Gk],
        [Gk.T @ P, Z((q, n)), -np.eye(q) / s, Z((q, q))],
        [Z((q, n)), mu * Gk.T @ R, Z((q, q)), -mu * t * np.eye(q)],
    ])


def joint_margin(M: np.ndarray) -> tuple[float, str, str]:
    """Status of a joint matrix: ``(margin, status, reason)`` with the thresholds of the module docstring."""
    margin = equilibrated_max_eig(M)
    if margin < -MARGIN_TOL:
        s = 1.0 / np.sqrt(np.abs(np.diag(M)))
        try:
            sla.cholesky(-(M * s[:, None] * s[None, :]), lower=True, check_finite=False)
        except np.linalg.LinAlgError:
            return margin, "marginal", (f"equilibrated max eigenvalue {margin:.3g} but the Cholesky factorisation "
                                        "of its negative failed")
        return margin, "feasible", f"joint matrix negative definite (equilibrated max eigenvalue {margin:.3g})"
    if margin <= MARGIN_TOL:
        return margin, "marginal", f"equilibrated max eigenvalue {margin:.3g} within {MARGIN_TOL:g} of 0"
    return margin, "infeasible", f"joint matrix not negative definite (equilibrated max eigenvalue {margin:.3g})"


# -- the route ----------------------------------------------------------------------------------
@dataclass
class RiccatiRouteResult:
    """Outcome of :func:`structured_riccati`.

    Attributes
    ----------
    status : str
        ``"feasible"`` (joint matrix verified negative definite, margin < -1e-7), ``"marginal"``
        or ``"infeasible"``.
    reason : str
        In words.
    K, F : ndarray or None
        Observer gain (n x p) and feedback (m x n), ``u = F x_hat``.
    P, R : ndarray or None
        Side Lyapunov matrices, normalised to a largest eigenvalue of 1; the certificate is
        ``V = x'Px + mu e'Re``.
    s, t, mu, mu_min : float
        Multipliers (``1/s`` on the x channels, ``mu t`` on the e channels), the e-side weight and
        the smallest admissible one.
    tau, tau_e, eps_x, eps_e : float
        The grid point used on each side.
    lam : float
        Decay target built into the certificate (``V' <= -2 lam V``).
    margin : float
        Jacobi-equilibrated max eigenvalue of the reduced joint matrix (in [-1, 0) when feasible).
    margin_x, margin_e : float
        The same for each side matrix.
    residual_x, residual_e : float
        Relative ARE residuals.
    methods : tuple of str
        ARE method that produced each side.
    timings : dict
        Seconds per step (``x_side``, ``e_side``, ``mu``, ``joint_build``, ``joint_eig``, ``total``).
    tries : list of tuple
        Every grid point tried: ``(side, tau, eps, reason or "ok")``.
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
    mu_min: float = math.nan
    tau: float = math.nan
    tau_e: float = math.nan
    eps_x: float = math.nan
    eps_e: float = math.nan
    lam: float = 0.0
    margin: float = math.nan
    margin_x: float = math.nan
    margin_e: float = math.nan
    residual_x: float = math.nan
    residual_e: float = math.nan
    methods: tuple = ()
    timings: dict = field(default_factory=dict)
    tries: list = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True when the joint certificate is verified (``status == "feasible"``)."""
        return self.status == "feasible"


def _search_side(solve, taus, epss, tries, label):
    last = "empty grid"
    for eps in epss:  # the largest strictness first (a robust margin), then the smallest gain
        for tau in taus:
            sol, why = solve(tau, eps)
            tries.append((label, float(tau), float(eps), why or "ok"))
            if sol is not None:
                return sol, ""
            last = why
    return None, last


def structured_riccati(A, B, C, G, H, lo, hi, *, lam: float = 0.0, taus: Sequence[float] = TAU_GRID,
                       eps: Sequence[float] = EPS_GRID, taus_e: Sequence[float] | None = None,
                       eps_e: Sequence[float] | None = None, s: float | None = None, t: float | None = None,
                       mu_factor: float = 10.0, method: str = "schur") -> RiccatiRouteResult:
    """Structured observer-based design by two AREs, certified by one 2n x 2n eigenvalue test.

    Parameters
    ----------
    A, B, C : array_like
        Shapes (n, n), (n, m), (p, n).
    G, H : array_like
        Channels ``f(x) = G phi(H x)``, shapes (n, q), (q, n).
    lo, hi : float or array_like, shape (q,)
        Slope bounds of each channel.
    lam : float
        Decay target: the certificate proves ``V' <= -2 lam V`` (default 0).
    taus, eps : sequence of float
        Grids of the gain scale tau and the strictness eps, relative to the natural scales
        ``tau0 = sigma / ||B||^2`` and ``eps0 = sigma``, ``sigma = ||Dr H|| ||G||`` (or ``||A0||``
        without channels). Tried in order, eps outer (the largest strictness first: a robust
        margin), tau inner (the smallest gain first); the first point that passes every check is
        kept.
    taus_e, eps_e : sequence of float, optional
        The same for the e-side (``tau0' = sigma / ||C||^2``); default: the x-side grids.
    s, t : float, optional
        Channel multipliers; default ``s = ||Dr H|| / ||G||``, ``t = 1 / s`` (they need no search:
        see the module docstring).
    mu_factor : float
        ``mu = mu_factor * mu_min`` (> 1; see the module docstring).
    method : str
        ARE method (:func:`solve_are`).

    Returns
    -------
    RiccatiRouteResult
        Status ``"feasible"`` only when the joint matrix is verified negative definite.
    """
    t_start = time.perf_counter()
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    C = np.asarray(C, dtype=float)
    G = np.asarray(G, dtype=float)
    H = np.asarray(H, dtype=float)
    n = A.shape[0]
    q = G.shape[1] if G.ndim == 2 else -1
    for name, X, shape in (("A", A, (n, n)), ("B", B, (n, B.shape[-1])), ("C", C, (C.shape[0], n)),
                           ("G", G, (n, q)), ("H", H, (q, n))):
        if X.ndim != 2 or X.shape != shape:
            raise ValueError(f"{name}: expected shape {shape} (A is {A.shape}, G is {G.shape}), got {X.shape}")
    lo = np.broadcast_to(np.asarray(lo, dtype=float), (q,))
    hi = np.broadcast_to(np.asarray(hi, dtype=float), (q,))
    if np.any(lo > hi):
        raise ValueError("lo/hi: every channel needs lo <= hi")
    if not mu_factor > 1:
        raise ValueError(f"mu_factor: must be > 1, got {mu_factor!r}")
    c0, r = (lo + hi) / 2, (hi - lo) / 2
    A0 = A + (G * c0) @ H
    Gk, DH = _reduce_channels(G, H, r)
    nG, nDH = _norm2(Gk), _norm2(DH)
    if nG > 0 and nDH > 0:
        sigma = nG * nDH
        s0, t0 = nDH / nG, nG / nDH
    else:
        sigma = max(_norm2(A0), 1e-12)
        s0 = t0 = 1.0
    s = s0 if s is None else float(s)
    t = t0 if t is None else float(t)
    tau0_x = sigma / max(_norm2(B) ** 2, 1e-300)
    tau0_e = sigma / max(_norm2(C) ** 2, 1e-300)
    taus_e = taus if taus_e is None else taus_e
    eps_e = eps if eps_e is None else eps_e
    timings: dict[str, float] = {}
    tries: list = []
    res = RiccatiRouteResult(status="infeasible", reason="", s=s, t=t, lam=float(lam), timings=timings, tries=tries)

    t1 = time.perf_counter()
    xs, why_x = _search_side(
        lambda tau, e: solve_x_side(A0, B, G, H, r, lam, s, tau * tau0_x, e * sigma, method=method),
        taus, eps, tries, "x")
    timings["x_side"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    es, why_e = _search_side(
        lambda tau, e: solve_e_side(A0, C, G, H, r, lam, t, tau * tau0_e, e * sigma, method=method),
        taus_e, eps_e, tries, "e")
    timings["e_side"] = time.perf_counter() - t1
    if xs is None or es is None:
        res.reason = "; ".join(w for w in (
            f"x-side infeasible on the grid (last: {why_x})" if xs is None else "",
            f"e-side infeasible on the grid (last: {why_e})" if es is None else "") if w)
        timings["total"] = time.perf_counter() - t_start
        return res
    # Normalise P and R to unit largest eigenvalue: (P, s, Mx) -> (P/a, s a, Mx/a) and
    # (R, t, Me) -> (R/b, t/b, Me/b) leave both sides' matrices negative definite (scaled by 1/a, 1/b)
    # and make mu the relative weight of two unit-size quadratic forms.
    a_x, a_e = _eig_at(xs.P, -1), _eig_at(es.P, -1)
    P, R, Mx, Me = xs.P / a_x, es.P / a_e, xs.side_matrix / a_x, es.side_matrix / a_e
    res.s, res.t = s * a_x, t / a_e
    res.F, res.P, res.K, res.R = xs.gain, P, es.gain, R
    res.tau, res.eps_x, res.tau_e, res.eps_e = xs.tau, xs.eps, es.tau, es.eps
    res.margin_x, res.margin_e = xs.margin, es.margin
    res.residual_x, res.residual_e = xs.are.residual, es.are.residual
    res.methods = (xs.are.method, es.are.method)

    t1 = time.perf_counter()
    try:
        mu_min = min_mu(B, xs.gain, P, Mx, Me)
    except np.linalg.LinAlgError:
        res.reason = "a side matrix failed its Cholesky factorisation (not negative definite)"
        timings["total"] = time.perf_counter() - t_start
        return res
    mu = mu_factor * mu_min if mu_min > 0 else 1.0
    res.mu, res.mu_min = mu, mu_min
    timings["mu"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    PBF = P @ B @ xs.gain
    M = np.block([[Mx, -PBF], [-PBF.T, mu * Me]])
    timings["joint_build"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    res.margin, res.status, res.reason = joint_margin(M)
    timings["joint_eig"] = time.perf_counter() - t1
    timings["total"] = time.perf_counter() - t_start
    return res


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

    This is a Riccati analogue of the corrected Theorem 1 / Corollary 1 of MATH.md, not the same
    condition: one ball ``(c0, r)`` serves both sides and the joint certificate has the cross
    term handled by mu, while MATH.md's LMIs use the QIB pair (``beta_eff = beta + gamma rho``) on
    the x-side and OSL + QIB with separate multipliers on the e-side. Both are only sufficient.

    Returns
    -------
    (RiccatiRouteResult, dict)
        The best result (feasible first, then the most negative margin) and the constraint used
        (``{"form": "lipschitz" | "osl_qib", "c0": ..., "r": ..., "theta": ...}``).
    """
    A = np.asarray(A, dtype=float)
    n = A.shape[0]
    I = np.eye(n)
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
    best, best_c = None, None
    for cand in cands:
        res = structured_riccati(A, B, C, I, I, cand["c0"] - cand["r"], cand["c0"] + cand["r"], lam=lam, **kwargs)
        key = (res.ok, -res.margin if np.isfinite(res.margin) else -math.inf)
        if best is None or key > (best.ok, -best.margin if np.isfinite(best.margin) else -math.inf):
            best, best_c = res, cand
    return best, best_c
