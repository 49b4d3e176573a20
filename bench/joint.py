"""The joint certificate of the channel-structured loop: its matrix, its verdict and the rate it proves.

Setting (``docs/structured.md``): ``x' = A x + B u + G phi(H x)``, ``y = C x``,
``u = F x_hat``, the observer copies f, each channel slope-restricted, ``lo_i <= phi_i' <= hi_i``.
The loop transformation ``c0 = (lo + hi) / 2``, ``r = (hi - lo) / 2``, ``A0 = A + G diag(c0) H``,
``psi(z) = phi(z) - c0 z`` gives ``|psi_i(a) - psi_i(b)| <= r_i |a - b|`` and, with ``e = x - x_hat``, ::

    x' = (A0 + B F) x - B F e + G psi(H x)
    e' = (A0 - K C) e + G (psi(H x) - psi(H x_hat))

Channels with ``r_i = 0`` are linear (inside A0) and are dropped; ``Dr = diag(r)``.

``V = x' P x + mu e' R e`` with S-procedure multipliers ``diag(1/s)`` on
``(Dr H x)^2 - psi^2 >= 0`` and ``mu diag(t)`` on ``(Dr H e)^2 - dpsi^2 >= 0`` gives, in
``xi = (x, e, psi(Hx), dpsi)``, ``V' + 2 lam V <= xi' M(lam) xi`` with ::

    M = [[Xb,  -P B F,  P G,        0        ],
         [*,   mu Eb,   0,          mu R G   ],
         [*,   *,       -diag(1/s), 0        ],
         [*,   *,       *,          -mu diag(t)]],
    Xb = (A0+BF)'P + P(A0+BF) + 2 lam P + H'Dr diag(1/s) Dr H,
    Eb = (A0-KC)'R + R(A0-KC) + 2 lam R + H'Dr diag(t) Dr H.

``M(lam) < 0`` proves ``V(t) <= exp(-2 lam t) V(0)``. The channel blocks are diagonal and
negative, so by the Schur complement ``M < 0`` iff the 2n x 2n reduced matrix
``[[Mx, -P B F], [-(P B F)', mu Me]] < 0`` with the *side matrices* ::

    Mx = Xb + P G diag(s) G' P,     Me = Eb + R G diag(1/t) G' R.

The rate a certificate proves. Only the ``2 lam`` terms depend on lam:
``M_red(lam) = M_red(0) + 2 lam W``, ``W = blkdiag(P, mu R) > 0``, so the largest lam with
``M_red(lam) <= 0`` is half the smallest generalised eigenvalue of ``(-M_red(0), W)``; the rate
reported is the largest point of the grid of :mod:`bench.search` below it at which the matrix
verifies clearly (:func:`verdict`).

The weight mu. With ``Mx(lam), Me(lam) < 0`` the reduced matrix is negative definite iff
``mu > mu_min(lam) = lambda_max(W^1/2 F (-Me)^-1 F' W^1/2)``, ``W = (P B)' (-Mx)^-1 (P B)`` (an
m x m problem). A larger mu only helps the rate (the cross term scales as ``1 / sqrt(mu)`` after a
congruence), towards the smaller of the two sides' own rates; :func:`certify` takes
``mu = 2 mu_min`` at nine tenths of that.

Verdicts use the suite's one tolerance :data:`bench.lmi.VERIFY_TOL` on the Jacobi-equilibrated
matrix ``D M D``, ``D = diag(|M_ii|^-1/2)`` (a congruence: same inertia, unit diagonal).

References
----------
B. Acikmese and M. Corless, "Observers for systems with nonlinearities satisfying incremental
quadratic constraints", Automatica 47(7), 2011. S. Boyd et al., Linear Matrix Inequalities in
System and Control Theory, SIAM 1994, section 5.1 (decay rate as a generalised eigenvalue problem).
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from bench import lmi
from bench.search import RATE_RTOL, grid_floor

__all__ = ["JointCertificate", "Loop", "certify", "loop"]

#: A rate probe passes when the equilibrated margin is below ``-CLEAR * VERIFY_TOL``: clearly
#: verified, not within the tolerance where machines may disagree.
CLEAR = 10.0
#: From this size of the joint matrix on, a verified certificate's margin and rate bound are found by
#: Lanczos iteration on the inverse (a Cholesky factor) instead of a dense tridiagonal reduction.
LANCZOS_FROM = 512


@dataclass(frozen=True)
class Loop:
    """Loop-transformed data: ``A0 = A + G diag(c0) H``; ``G`` and ``DH = Dr H`` of the channels with
    ``r_i > 0``; ``keep`` marks those channels among all q."""

    A0: np.ndarray
    B: np.ndarray
    C: np.ndarray
    G: np.ndarray
    DH: np.ndarray
    keep: np.ndarray


def loop(A, B, C, G, H, lo, hi) -> Loop:
    """The loop transformation of a plant with channels (see the module docstring).

    Parameters
    ----------
    A, B, C : array_like
        Shapes (n, n), (n, m), (p, n).
    G, H : array_like
        Shapes (n, q), (q, n).
    lo, hi : float or array_like (q,)
        Slope bounds of the channels.

    Returns
    -------
    Loop
    """
    A, B, C, G, H = (np.asarray(v, dtype=float) for v in (A, B, C, G, H))
    q = G.shape[1]
    lo, hi = (np.broadcast_to(np.asarray(b, dtype=float), (q,)) for b in (lo, hi))
    c0, r = (lo + hi) / 2, (hi - lo) / 2
    keep = r > 0
    return Loop(A + (G * c0) @ H, B, C, G[:, keep], r[keep, None] * H[keep, :], keep)


def side_matrices(lp: Loop, F, K, P, R, s, t, lam: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """``Mx`` and ``Me`` of the module docstring (channel blocks eliminated), symmetric.

    Parameters
    ----------
    lp : Loop
    F, K : ndarray
        Gains (m x n, n x p).
    P, R : ndarray (n, n)
        x-side and e-side Lyapunov matrices.
    s, t : float or ndarray (q,)
        Multipliers: ``1/s`` on the x channels, ``t`` on the e channels (one per channel or one for all).
    lam : float
        Decay rate tested.
    """
    s, t = (np.full(lp.G.shape[1], float(v)) if np.ndim(v) == 0 else np.asarray(v, dtype=float)[lp.keep]
            for v in (s, t))  # the kept channels' multipliers: a scalar broadcast, or a (q,) vector restricted
    Mx = (lp.A0 + lp.B @ F).T @ P
    Mx = Mx + Mx.T + 2 * lam * P + (lp.DH.T / s) @ lp.DH + (P @ lp.G * s) @ (lp.G.T @ P)
    Me = (lp.A0 - K @ lp.C).T @ R
    Me = Me + Me.T + 2 * lam * R + (lp.DH.T * t) @ lp.DH + (R @ lp.G / t) @ (lp.G.T @ R)
    return lmi.sym(Mx), lmi.sym(Me)


def min_mu(B, F, P, Mx, Me) -> float:
    """Smallest mu making ``[[Mx, -P B F], [-(P B F)', mu Me]]`` negative definite (Mx, Me < 0).

    Returns
    -------
    float
        ``lambda_max(W^1/2 F (-Me)^-1 F' W^1/2)``, ``W = (P B)' (-Mx)^-1 (P B)``.

    Raises
    ------
    numpy.linalg.LinAlgError
        If Mx or Me is not negative definite.
    """
    U = P @ B
    W = lmi.sym(U.T @ sla.cho_solve(sla.cho_factor(-Mx, lower=True), U))
    Z = lmi.sym(F @ sla.cho_solve(sla.cho_factor(-Me, lower=True), F.T))
    w, V = np.linalg.eigh(W)
    Wh = (V * np.sqrt(np.maximum(w, 0))) @ V.T
    return float(max(np.linalg.eigvalsh(lmi.sym(Wh @ Z @ Wh)).max(initial=0.0), 0.0))


def _equilibrate(M: np.ndarray, sign: float = 1.0) -> np.ndarray:
    """``sign * D M D``, ``D = diag(|M_ii|^-1/2)``, a new array (LAPACK reads its lower triangle only)."""
    d = np.abs(np.diag(M))
    d = np.maximum(d, 1e-300 * max(float(d.max(initial=0.0)), 1e-300))
    s = 1.0 / np.sqrt(d)
    E = M * (sign * s)[:, None]
    E *= s[None, :]
    return E


def equilibrated_max_eig(M: np.ndarray) -> float:
    """Largest eigenvalue of the equilibrated ``D M D`` (module docstring; in ``[-1, 0)`` for M < 0)."""
    E = _equilibrate(np.asarray(M, dtype=float))
    k = E.shape[0]
    try:
        return float(sla.eigh(E, eigvals_only=True, subset_by_index=[k - 1, k - 1])[0])
    except (np.linalg.LinAlgError, ValueError):  # LAPACK's subset driver can fail on clustered spectra
        return float(np.linalg.eigvalsh(E)[-1])


def verdict(M: np.ndarray, *, clear: float = 1.0) -> str:
    """``"verified"``, ``"marginal"`` or ``"violated"`` for a symmetric M, by Cholesky factorisations of
    the equilibrated matrix ``E = D M D``: verified when ``E + clear * VERIFY_TOL I < 0``, marginal when
    not but ``E - VERIFY_TOL I < 0`` (every eigenvalue within the tolerance of zero or below), violated
    otherwise."""
    N = _equilibrate(np.asarray(M, dtype=float), -1.0)  # -E
    if not np.all(np.isfinite(N)):
        return "violated"
    diag = np.diag(N).copy()
    for shift, found in ((-clear * lmi.VERIFY_TOL, "verified"), (lmi.VERIFY_TOL, "marginal")):
        A = N.copy()
        np.fill_diagonal(A, diag + shift)
        with contextlib.suppress(np.linalg.LinAlgError):
            sla.cholesky(A, lower=True, overwrite_a=True, check_finite=False)
            return found
    return "violated"


def _rate_bound(M0: np.ndarray, *blocks: np.ndarray, L: np.ndarray | None = None) -> float:
    """The rate bound of the module docstring for ``W = blkdiag(blocks) = L L'`` (block by block): half the smallest
    eigenvalue of ``L^-1 (-M0) L^-T``; by :func:`_lanczos_min` when ``L``, a Cholesky factor of ``-M0``, is given."""
    if not M0.shape[0]:
        return math.inf
    try:
        Ls = [sla.cholesky(B, lower=True, check_finite=False) for B in blocks]
        bound = _lanczos_min(L, *Ls) / 2 if L is not None else math.nan
        if math.isfinite(bound):
            return bound
        at = np.cumsum([0] + [B.shape[0] for B in blocks])
        S = np.empty_like(M0)
        for i, Li in enumerate(Ls):
            for j in range(i, len(Ls)):
                Y = sla.solve_triangular(Li, -M0[at[i]:at[i + 1], at[j]:at[j + 1]], lower=True, check_finite=False)
                S[at[i]:at[i + 1], at[j]:at[j + 1]] = sla.solve_triangular(Ls[j], Y.T, lower=True, check_finite=False).T
                S[at[j]:at[j + 1], at[i]:at[i + 1]] = S[at[i]:at[i + 1], at[j]:at[j + 1]].T
        return float(sla.eigh(S, eigvals_only=True, subset_by_index=[0, 0], check_finite=False)[0]) / 2
    except (np.linalg.LinAlgError, ValueError):  # LAPACK's subset driver can fail on clustered spectra
        W = sla.block_diag(*blocks)
        return float(sla.eigh(-M0, W, eigvals_only=True)[0]) / 2


def _lanczos_min(L: np.ndarray, *factors: np.ndarray) -> float:
    """Smallest generalised eigenvalue of ``(L L', W)``, ``W = blkdiag(B B' for B in factors)`` (the identity
    without factors), as ``1 / lambda_max(B' (L L')^-1 B)`` by Lanczos iteration (``eigsh``); NaN when it does
    not converge. ``L`` and the factors are lower triangular."""
    from scipy.sparse.linalg import ArpackError, LinearOperator, eigsh

    trmv = sla.get_blas_funcs("trmv", (L,))
    k = L.shape[0]
    at = np.cumsum([0] + [B.shape[0] for B in factors])
    parts = list(zip(factors, at[:-1], at[1:]))

    def apply(v):
        v = np.ravel(v)
        y = np.concatenate([trmv(B, v[a:b], lower=1) for B, a, b in parts]) if parts else v
        z = sla.cho_solve((L, True), y, check_finite=False)
        return np.concatenate([trmv(B, z[a:b], lower=1, trans=1) for B, a, b in parts]) if parts else z

    try:
        w = eigsh(LinearOperator((k, k), matvec=apply, dtype=float), k=1, which="LA", tol=1e-12, v0=np.ones(k),
                  return_eigenvectors=False)
    except (ArpackError, ValueError):  # ValueError: ARPACK needs a matrix larger than 2 x 2
        return math.nan
    return 1.0 / float(w[0]) if w[0] > 0 else math.nan


@dataclass
class JointCertificate:
    """A verified (or not) joint certificate of fixed gains.

    Attributes
    ----------
    status : str
        ``"verified"``, ``"marginal"`` or ``"violated"`` at rate 0.
    rate : float
        The largest grid rate at which the matrix verifies clearly (0 when only rate 0 does; NaN
        unless verified).
    bound : float
        The exact largest rate of this certificate (the generalised eigenvalue), for reference.
    mu : float
    margin : float
        Equilibrated max eigenvalue of the reduced matrix at rate 0.
    P : ndarray or None
        ``blkdiag(P, mu R)``: ``V = z' P z``, ``z = (x, e)``.
    side_rates : tuple of float
        Each side's own largest rate (``(-Mx(0), P)`` and ``(-Me(0), R)``).
    """

    status: str
    rate: float = math.nan
    bound: float = math.nan
    mu: float = math.nan
    margin: float = math.nan
    P: np.ndarray | None = None
    side_rates: tuple = (math.nan, math.nan)

    @property
    def verified(self) -> bool:
        """True when the certificate holds (at rate 0 at least)."""
        return self.status == "verified"


def certify(lp: Loop, F, K, P, R, s, t, *,
            sides: tuple | None = None) -> JointCertificate:
    """Choose mu, verify the joint matrix and measure the rate it proves (see the module docstring).

    Parameters
    ----------
    lp : Loop
    F, K, P, R, s, t
        Gains, side Lyapunov matrices and multipliers (:func:`side_matrices`).
    sides : (ndarray, ndarray), optional
        ``side_matrices(lp, F, K, P, R, s, t)`` when the caller has them.

    Returns
    -------
    JointCertificate
    """
    try:
        Mx, Me = side_matrices(lp, F, K, P, R, s, t) if sides is None else sides
        sx, se = _rate_bound(Mx, P), _rate_bound(Me, R)
        target = 0.9 * min(sx, se)
        if not target > 0:
            return JointCertificate("violated", side_rates=(sx, se))
        mu = 2 * min_mu(lp.B, F, P, Mx + 2 * target * P, Me + 2 * target * R)
        mu = mu if mu > 0 else 1.0
    except (np.linalg.LinAlgError, ValueError):
        return JointCertificate("violated")
    PBF = P @ lp.B @ F
    M0 = np.block([[Mx, -PBF], [-PBF.T, mu * Me]])
    W = sla.block_diag(P, mu * R)
    out = JointCertificate(verdict(M0), mu=mu, side_rates=(sx, se), P=W)
    L = None  # a Cholesky factor of -M0 for Lanczos
    if out.verified and M0.shape[0] >= LANCZOS_FROM:
        with contextlib.suppress(np.linalg.LinAlgError):
            L = sla.cholesky(-M0, lower=True, check_finite=False)
    # D L is a Cholesky factor of -D M0 D
    out.margin = -_lanczos_min(L / np.sqrt(np.abs(np.diag(M0)))[:, None]) if L is not None else math.nan
    out.margin = out.margin if math.isfinite(out.margin) else equilibrated_max_eig(M0)
    if not out.verified:
        return out
    out.bound = _rate_bound(M0, P, mu * R, L=L)
    out.rate = 0.0
    if out.bound > 0:
        lam = grid_floor(out.bound * (1 - 1e-9))
        for _ in range(3):  # a grid point that verifies clearly (the first one, but for rounding)
            if verdict(M0 + 2 * lam * W, clear=CLEAR) == "verified":
                out.rate = lam
                break
            lam = grid_floor(lam / (1 + RATE_RTOL) * (1 + 1e-12))
    return out
