"""Discrete-time forms of the corrected Theorem 1 and Corollary 1: the two sides and the joint certificate.

Plant ``x_{k+1} = A x_k + B u_k + f(x_k)``, ``y_k = C x_k``; observer (one-step predictor)
``x_hat_{k+1} = A x_hat_k + B u_k + f(x_hat_k) + K (y_k - C x_hat_k)``; ``u_k = F x_hat_k``. With
``e = x - x_hat``, ``Ac = A + B F``, ``Ae = A - K C``, ``df = f(x) - f(x_hat)``::

    x_{k+1} = Ac x_k - B F e_k + f(x_k)
    e_{k+1} = Ae e_k + df_k

and ``V = x' P x + s e' R e``. The class enters as in continuous time, by the S-procedure on the pairs
``(x, f(x))`` (``f(0) = 0``) and ``(e, df)``: the OSL term ``2 eps (rho |v|^2 - <g, v>) >= 0`` and the QIB term
``2 eps' (beta |v|^2 + gamma <g, v> - |g|^2) >= 0`` (Theorem 1), or ``mu (alpha^2 |v|^2 - |g|^2) >= 0``
(Corollary 1), for ``(v, g) = (x, f(x))`` and ``(e, df)``.

**e-side** (``R > 0``, ``Kh = K' R``, i.e. ``K = R^-1 Kh'``). ``V_e(e_{k+1}) - V_e(e_k)`` plus the multiplier
terms is the quadratic form of ``[Ae, I]' R [Ae, I] - diag(R, 0) + Pi_e`` in ``(e, df)``; a Schur complement
on ``R`` (``R [Ae, I] = [R A - Kh' C, R]``) gives the LMI (3n x 3n) ::

    [ -R + 2(eps3 rho + eps4 beta) I   (eps4 gamma - eps3) I   A'R - C'Kh ]
    [ *                                -2 eps4 I               R          ]  < 0      (Theorem 1)
    [ *                                *                       -R         ]

    [ -R + mu2 alpha^2 I   0          A'R - C'Kh ]
    [ *                    -mu2 I     R          ]  < 0                                (Corollary 1)
    [ *                    *          -R         ]

This is the discrete OSL / QIB observer LMI of Benallouch, Boutayeb & Zasadzinski (2012) and of Nguyen,
Pathirana & Trinh (2018), LMI (20) without its disturbance terms; for Corollary 1 the discrete Lipschitz
observer LMI of the same form (e.g. Abbaszadeh & Marquez 2009, without the H-infinity terms).

**x-side** (``Q = P^-1``, ``Fh = Q F'``, i.e. ``F = Fh' Q^-1``). ``[Ac, I]' P [Ac, I] - diag(P, 0) + Pi_x`` in
``(x, f)`` with ``Pi_x = [[eta1 I, eta2 I], [eta2 I, -2 eps2 I]]``, ``eta1 = 2(eps1 rho + eps2 beta)``,
``eta2 = eps2 gamma - eps1``. Fix the ratio ``c = eps1 / eps2 >= 0`` and write ``kappa = 1 / (2 eps2)``; the
congruence ``diag(Q, I / eps2)`` and a Schur complement on ``P = Q^-1`` give, exactly, ::

    [ -Q      (gamma - c) Q   Q A' + Fh B'   Q                       ]
    [ *       -4 kappa I      2 kappa I      0                       ]
    [ *       *               -Q             0                       ]  < 0
    [ Q       0               0              -(kappa / (c rho + beta)) I ]

(the last row a Schur column for ``eta1 Q Q``, dropped when ``c rho + beta <= 0``). Every block is affine in
``(Q, Fh, kappa)``. With ``c = gamma`` (the corrected Theorem 1's choice ``eps1 = gamma eps2``, possible when
``gamma >= 0``) the second row couples only to the third and a Schur complement removes it, adding
``kappa I`` there: the 3n x 3n LMI ::

    [ -Q             Q A' + Fh B'    Q                  ]
    [ A Q + B Fh'    -Q + kappa I    0                  ]  < 0,    w = beta + gamma rho  (Theorem 1)
    [ Q              0               -(kappa / w) I     ]                 w = alpha^2    (Corollary 1, mu1 = 1/kappa)

For ``gamma < 0`` the ratio ``c`` is searched on a grid (the role of the a-priori scalar ``eps0`` of Nguyen et
al. 2018, Theorem 1 and Remark 2) with the 4n form.

**Separation.** Both sides are homogeneous in their variables, and the joint condition (the S-procedure
on ``V(z_{k+1}) - V(z_k)`` in ``(x, e, f, df)`` with the multipliers of both sides) holds iff both sides hold:
*only if*: the sides are the joint form at ``e = 0, df = 0`` and at ``x = 0, f = 0`` (with ``s = 1``); *if*: with
``v = Ac x + f`` and ``d = -B F e``, ``(v + d)' P (v + d) <= (1 + phi) v'Pv + (1 + 1/phi) d'Pd`` for every
``phi > 0``; the x-side's margin ``a_x`` absorbs ``phi [Ac, I]'P[Ac, I]`` for
``phi = a_x / (2 lmax([Ac, I]'P[Ac, I]))`` and the scaled e-side ``s`` (margin ``a_e``) absorbs
``(1 + 1/phi) F'B'PBF`` for ``s = 2 (1 + 1/phi) lmax(F'B'PBF) / a_e``. :func:`joint_certificate` builds the
joint 4n matrix at these ``phi`` and ``s`` (and at nearby ``s``, keeping the best contraction), verifies it by
its eigenvalues after Jacobi equilibration (Sylvester's law of inertia), and finds the contraction factor
``r`` it proves, ``V(z_{k+1}) <= r^2 V(z_k)``, by bisection on ``r^2``: the rate per second is
``-ln(r) / dt``.

What follows the literature and what is ours: the e-side LMIs are the published discrete OSL / QIB and
Lipschitz observer conditions; the x-side is the discrete counterpart of the corrected Theorem 1's x-side,
derived here (the x-side of Nguyen et al.'s LMI (19) without the disturbance and with ``eps0 = gamma``);
the separation with the rebuilt, verified joint certificate and its contraction factor are ours, as in
continuous time (``docs/paper.md``).

References
----------
M. Benallouch, M. Boutayeb and M. Zasadzinski, "Observer design for one-sided Lipschitz discrete-time
systems", Systems & Control Letters 61(9), 879-886, 2012.
C. M. Nguyen, P. N. Pathirana and H. Trinh, "Robust observer-based control designs for discrete nonlinear
systems with disturbances", European Journal of Control, 2018 (doi 10.1016/j.ejcon.2018.09.002), Theorem 1,
LMIs (19)-(20).
M. Abbaszadeh and H. J. Marquez, "LMI optimization approach to robust H-infinity observer design and static
output feedback stabilization for discrete-time nonlinear uncertain systems", Int. J. Robust Nonlinear
Control 19(3), 313-340, 2009.
"""

from __future__ import annotations

import math

import numpy as np

from bench import lmi

__all__ = ["joint_certificate", "lipschitz_eside", "osl_qib_eside", "xside"]


def osl_qib_eside(d: dict, I: np.ndarray) -> list:
    """The discrete Theorem 1 e-side blocks (module docstring), values dict with A, C, R, Kh, eps3, eps4, rho,
    beta, gamma."""
    A, C, R, Kh = d["A"], d["C"], d["R"], d["Kh"]
    W = A.T @ R - C.T @ Kh
    S = -R + 2 * (d["eps3"] * d["rho"] + d["eps4"] * d["beta"]) * I
    Y = (d["eps4"] * d["gamma"] - d["eps3"]) * I
    return [[S, Y, W], [Y, -2 * d["eps4"] * I, R], [W.T, R, -R]]


def lipschitz_eside(d: dict, I: np.ndarray) -> list:
    """The discrete Corollary 1 e-side blocks (module docstring), values dict with A, C, R, Kh, mu2, a2."""
    A, C, R, Kh = d["A"], d["C"], d["R"], d["Kh"]
    W = A.T @ R - C.T @ Kh
    Z = np.zeros(I.shape)
    return [[-R + d["mu2"] * d["a2"] * I, Z, W], [Z, -d["mu2"] * I, R], [W.T, R, -R]]


def xside(n: int, *, schur: bool, f_row: bool):
    """The discrete x-side blocks (module docstring) as a function of a values dict with A, B, Q, Fh, kappa,
    ``sw`` (= sqrt(w)) and, with ``f_row``, ``etac`` (= gamma - c).

    ``f_row=False`` is the 3n form (``c = gamma``, or Corollary 1), ``True`` the 4n form with the f row kept.
    The Schur column is written ``[sqrt(w) Q; 0; ...]`` with the corner ``-kappa I`` (a congruence of the
    module docstring's ``[Q; 0; ...]``, ``-(kappa / w) I``): for a fine sample time ``w`` is tiny (``h^2 beta``)
    and ``kappa / w`` would dominate the matrix's scale, and so the verification tolerance.
    """
    I, Z = np.eye(n), np.zeros((n, n))

    def blocks(d):
        Q = d["Q"]
        X = d["A"] @ Q + d["B"] @ d["Fh"].T  # Ac Q
        k = d["kappa"]
        if f_row:
            rows = [[-Q, d["etac"] * Q, X.T], [d["etac"] * Q, -4 * k * I, 2 * k * I], [X, 2 * k * I, -Q]]
        else:
            rows = [[-Q, X.T], [X, -Q + k * I]]
        if schur:
            for i, row in enumerate(rows):
                row.append(d["sw"] * Q if i == 0 else Z)
            rows.append([d["sw"] * Q, *[Z] * (len(rows) - 1), -k * I])
        return rows

    return blocks


def _quadratic(T: np.ndarray, P: np.ndarray, Pi: np.ndarray, k: int) -> np.ndarray:
    """``T' P T - diag(P, 0) + Pi`` for ``T = [M, G]`` (the first ``k`` coordinates carry ``V``)."""
    M = T.T @ P @ T + Pi
    M[:k, :k] -= P
    return lmi.sym(M)


def _equilibrated(M: np.ndarray) -> tuple[np.ndarray, float]:
    """``D M D`` with ``D = diag(|M_ii|^-1/2)`` and its largest eigenvalue (``inf`` with a nonnegative diagonal)."""
    M = lmi.sym(M)
    dg = np.diag(M)
    if not np.all(dg < 0):
        return M, math.inf
    d = 1.0 / np.sqrt(-dg)
    E = M * d[:, None] * d[None, :]
    return E, lmi.max_eig(E)


def _verified(M: np.ndarray) -> bool:
    E, top = _equilibrated(M)
    return lmi.classify(top, E) == "verified"


def joint_certificate(Ac, BF, Ae, Gx, Ge, P, R, Pix, Pie, *, dt: float, Sx: np.ndarray | None = None) -> dict:
    """The joint discrete certificate of a separated design (module docstring).

    Parameters
    ----------
    Ac, BF, Ae : ndarray (n, n)
        ``A + B F`` (or its loop-transformed form), ``B F`` and ``A - K C``.
    Gx, Ge : ndarray (n, kx), (n, ke)
        Where the x-side and e-side nonlinearity inputs enter (``I`` for f and df; ``G`` for channels).
    P, R : ndarray (n, n)
        The sides' Lyapunov matrices.
    Pix, Pie : ndarray
        The S-procedure terms on ``(x, fx)`` and ``(e, fe)`` with the sides' multipliers.
    dt : float
        The sample time (for the rate per second).
    Sx : ndarray (n, n), optional
        A nonsingular congruence of the x coordinates used for every verification (``Q = P^-1``: the x-side's
        own coordinates). The inertia is unchanged (Sylvester), but ``P`` may be badly conditioned and a
        margin of the x-side in ``Q`` coordinates shrinks by ``lmin(P)^2`` in the original ones.

    Returns
    -------
    dict
        ``status`` (``"feasible"`` or ``"undecided"``), ``reason``, ``margin`` (equilibrated joint max eig at
        ``r = 1``), ``raw_margin``, ``phi``, ``scale`` (``s``), ``x_margin``, ``e_margin``, ``contraction``
        (``r``), ``decay_rate`` (``-ln(r) / dt``), ``P`` (``blkdiag(P, s R)``), ``M`` (the joint matrix at r = 1,
        in the coordinates of ``Sx``), ``lmi_size``.
    """
    n, kx, ke = P.shape[0], Gx.shape[1], Ge.shape[1]
    Sx = np.eye(n) if Sx is None else np.asarray(Sx, dtype=float)
    Cx = np.eye(n + kx)
    Cx[:n, :n] = Sx
    Nx = Cx.T @ _quadratic(np.hstack([Ac, Gx]), P, Pix, n) @ Cx
    Ne = _quadratic(np.hstack([Ae, Ge]), R, Pie, n)
    ax, ae = -lmi.max_eig(Nx), -lmi.max_eig(Ne)
    out = {"status": "undecided", "margin": math.nan, "raw_margin": math.nan, "phi": math.nan, "scale": math.nan,
           "x_margin": -ax, "e_margin": -ae, "contraction": math.nan, "decay_rate": math.nan, "P": None,
           "M": None, "lmi_size": 2 * n + kx + ke}
    if not (ax > 0 and ae > 0 and _verified(Nx) and _verified(Ne)):
        out["reason"] = (f"a side's matrix rebuilt in the original coordinates is not negative definite "
                         f"(max eig x-side {-ax:.3g}, e-side {-ae:.3g})")
        return out
    TxP = np.hstack([Ac, Gx]) @ Cx
    phi = 0.5 * ax / max(lmi.max_eig(TxP.T @ P @ TxP), 1e-300)
    cross = lmi.max_eig(BF.T @ P @ BF)
    s0 = 2 * (1 + 1 / phi) * cross / ae if cross > 0 else 1.0
    # the joint map z_{k+1} = T (x, e, fx, fe)
    T = np.zeros((2 * n, 2 * n + kx + ke))
    T[:n, :n], T[:n, n:2 * n], T[:n, 2 * n:2 * n + kx] = Ac, -BF, Gx
    T[n:, n:2 * n], T[n:, 2 * n + kx:] = Ae, Ge
    Cj = np.eye(2 * n + kx + ke)
    Cj[:n, :n] = Sx

    def matrix(s: float) -> tuple[np.ndarray, np.ndarray]:
        """The joint matrix at ``r = 1`` and the matrix multiplying ``1 - r^2``, in the coordinates of ``Sx``."""
        Pj = np.block([[P, np.zeros((n, n))], [np.zeros((n, n)), s * R]])
        Pi = np.zeros((2 * n + kx + ke,) * 2)
        ix = np.r_[0:n, 2 * n:2 * n + kx]
        ie = np.r_[n:2 * n, 2 * n + kx:2 * n + kx + ke]
        Pi[np.ix_(ix, ix)] = Pix
        Pi[np.ix_(ie, ie)] = s * Pie
        M = T.T @ Pj @ T + Pi
        M[:2 * n, :2 * n] -= Pj
        D = np.zeros_like(M)
        D[:2 * n, :2 * n] = Pj
        return lmi.sym(Cj.T @ M @ Cj), lmi.sym(Cj.T @ D @ Cj)

    best = None
    for s in s0 * np.logspace(-3, 3, 13):  # the Young choice and around it: keep the best contraction
        M, D = matrix(s)
        if not _verified(M):
            continue
        d = _largest_shift(M, D)
        if best is None or d > best[0]:
            best = (d, s, M)
    if best is None:
        M, _ = matrix(s0)
        E, top = _equilibrated(M)
        out.update(margin=top, raw_margin=lmi.max_eig(M), phi=phi, scale=s0, reason=(
            f"both sides are strictly feasible (max eig {-ax:.3g}, {-ae:.3g}) but the rebuilt joint matrix has "
            f"equilibrated max eig {top:.3g} at phi = {phi:.3g}, s = {s0:.3g}: numerical range exceeded"))
        return out
    d, s, M = best
    r = math.sqrt(max(1.0 - d, 0.0))
    _, top = _equilibrated(M)
    out.update(status="feasible", reason="", margin=top, raw_margin=lmi.max_eig(M), phi=phi, scale=s,
               contraction=r, decay_rate=(-math.log(r) / dt) if r > 0 else math.inf, M=M,
               P=np.block([[P, np.zeros((n, n))], [np.zeros((n, n)), s * R]]))
    return out


def _largest_shift(M: np.ndarray, D: np.ndarray, *, rtol: float = 1e-4) -> float:
    """The largest ``d`` in ``[0, 1]`` with ``M + d D`` verified (``M`` verified, ``D >= 0``): ``r^2 = 1 - d``.

    Bisection on ``log d`` from ``1e-14`` (then on ``d``), to a relative ``rtol``.
    """
    if _verified(M + D):
        return 1.0
    lo, hi = 0.0, 1.0
    probe = 1.0
    while probe > 1e-14:  # bracket on a log scale first: d is about 2 lam dt, tiny for a fine sample time
        probe /= 10
        if _verified(M + probe * D):
            lo, hi = probe, probe * 10
            break
    else:
        return 0.0
    while hi - lo > rtol * lo:
        mid = 0.5 * (lo + hi)
        if _verified(M + mid * D):
            lo = mid
        else:
            hi = mid
    return lo
