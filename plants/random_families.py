"""Random plant families for sweeps: seeded n-state plants with constants known in closed form.

The linear part is stabilizable and detectable by construction, then checked by the PBH test:
``A = T blockdiag(A_u, A_s) T'``, ``B = T [B_u; B_s]``, ``C = [C_u, C_s] T'`` with T random orthogonal.
``A_u`` is unreduced upper Hessenberg shifted to the largest real part ``max_re``; with
``B_u[:, 0] = e_1`` and ``C_u[0, :] = e_{n_u}'`` its Krylov and observability matrices are
triangular with nonzero diagonals, so (A_u, B_u) is controllable and (A_u, C_u) observable.
``A_s = -(G G' / n_s + delta I) + (S - S') / 2`` has ``A_s + A_s' <= -2 delta I``, so it is Hurwitz.

Nonlinearities, each scaled by ``c`` (A, B, C and f's directions come from separate seeded streams):

- Lipschitz (global): ``f(x) = c G sin(H x)``, G, H orthogonal. ``df = c G D H dx`` with D
  diagonal, ``|D_ii| <= 1``: alpha = c (tight at x = 0), rho = c (Cauchy-Schwarz),
  (beta, gamma) = (c^2, 0). Channels ``c G``, ``H``, ``phi = sin``, slopes in [-1, 1].
- OSL (on ``||x|| <= r``): ``f(x) = -c W (W' x)^3``, W orthogonal, ``f = -grad (c/4) sum (w_i' x)^4``
  (convex). Along a segment in the ball ``df = -M dx``, M symmetric, ``0 <= M <= 3 c r^2 I``:
  rho = 0, alpha = 3 c r^2, and ``M^2 <= 3 c r^2 M`` gives (beta, gamma) = (0, -3 c r^2); alpha
  and gamma tight at ``x = r w_i``. Channels ``z = W' x``, ``phi(z) = -c z^3``, slopes in
  ``[-3 c r^2, 0]``.
"""

from __future__ import annotations

import math

import numpy as np

from bench.registry import register_plant
from plants._core import Channels, Constants, Plant, PlantError, check_int, check_real, cubic_slopes, sine_slopes

__all__ = ["random_lipschitz_plant", "random_lti", "random_osl_plant"]

#: Relative PBH margin below which a pair is declared not stabilizable / not detectable.
PBH_TOL = 1e-8

_SOURCE = "oslbench random family (plants/random_families.py), constants in closed form"


#: Largest state dimension the generators accept.
MAX_N = 4096


def pbh_margin(A, B) -> float:
    """PBH margin of stabilizability of ``(A, B)``: ``min sigma_min([lambda I - A, B]) / max(1, ||[A, B]||_2)``
    over the eigenvalues of A with ``Re lambda >= 0`` (``inf`` when A is Hurwitz); (A, B) is stabilizable iff it
    is positive (numerically, above :data:`PBH_TOL`)."""
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    n = A.shape[0]
    scale = max(1.0, float(np.linalg.norm(np.hstack([A, B]), 2)))
    worst = math.inf
    for lam in np.linalg.eigvals(A):
        if lam.real >= -1e-12 * scale:
            M = np.hstack([lam * np.eye(n) - A, B.astype(complex)])
            worst = min(worst, float(np.linalg.svd(M, compute_uv=False)[-1]) / scale)
    return worst


def is_stabilizable(A, B, tol: float = PBH_TOL) -> bool:
    """True when ``(A, B)`` passes the PBH test on the closed right half-plane (see :func:`pbh_margin`)."""
    return pbh_margin(A, B) > tol


def is_detectable(A, C, tol: float = PBH_TOL) -> bool:
    """True when ``(A, C)`` is detectable, i.e. ``(A', C')`` is stabilizable (PBH)."""
    return pbh_margin(np.asarray(A).T, np.asarray(C).T) > tol


def _orthogonal(rng: np.random.Generator, n: int) -> np.ndarray:
    Q, R = np.linalg.qr(rng.standard_normal((n, n)))
    return Q * np.where(np.diag(R) < 0, -1.0, 1.0)  # Haar distributed


def random_lti(
    n: int, m: int = 1, p: int = 1, *, seed: int = 0, n_unstable: int | None = None, max_re: float = 0.5
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A seeded random ``(A, B, C)`` with (A, B) stabilizable and (A, C) detectable.

    Parameters
    ----------
    n, m, p : int
        States (>= 1), inputs and outputs (each between 1 and n).
    seed : int
        Seed (>= 0); the same seed gives the same matrices.
    n_unstable : int, optional
        Size of the block holding the eigenvalues with the largest real parts (default
        ``min(n, 2)``); 0 makes A Hurwitz.
    max_re : float
        Largest real part of an eigenvalue of that block (default 0.5: open-loop unstable).

    Returns
    -------
    A, B, C : ndarray
        Shapes (n, n), (n, m), (p, n); PlantError on a bad argument or a failed PBH check.
    """
    n = check_int("n", n, 1, MAX_N, what="the number of states ")
    m = check_int("m", m, 1, n, what=f"the number of inputs (B is n x m, n = {n}) ")
    p = check_int("p", p, 1, n, what=f"the number of outputs (C is p x n, n = {n}) ")
    nu = check_int("n_unstable", min(n, 2) if n_unstable is None else n_unstable, 0, n,
                   what=f"the size of the unstable block (n = {n}) ")
    seed = check_int("seed", seed, 0)
    max_re = check_real("max_re", max_re)
    rng = np.random.default_rng([seed, 0])
    ns = n - nu

    Ah = np.zeros((n, n))
    Bh = rng.standard_normal((n, m)) / math.sqrt(n)
    Ch = rng.standard_normal((p, n)) / math.sqrt(n)
    if nu:
        Hu = np.triu(rng.standard_normal((nu, nu))) * 0.5
        sub = rng.uniform(0.5, 1.5, size=nu - 1) * rng.choice([-1.0, 1.0], size=nu - 1)
        Hu += np.diag(sub, -1)
        Hu += (max_re - float(np.linalg.eigvals(Hu).real.max())) * np.eye(nu)
        Ah[:nu, :nu] = Hu
        Bh[:nu, 0] = 0.0
        Bh[0, 0] = 1.0  # B_u[:, 0] = e_1
        Ch[0, :nu] = 0.0
        Ch[0, nu - 1] = 1.0  # C_u[0, :] = e_{n_u}'
    if ns:
        delta = 0.2
        G = rng.standard_normal((ns, ns))
        S = rng.standard_normal((ns, ns))
        Ah[nu:, nu:] = -(G @ G.T / ns + delta * np.eye(ns)) + (S - S.T) / 2
    T = _orthogonal(rng, n)
    A, B, C = T @ Ah @ T.T, T @ Bh, Ch @ T.T
    if not is_stabilizable(A, B):
        raise PlantError(f"A, B: (A, B) failed the PBH stabilizability check (margin {pbh_margin(A, B):.3g})")
    if not is_detectable(A, C):
        raise PlantError(f"A, C: (A, C) failed the PBH detectability check (margin {pbh_margin(A.T, C.T):.3g})")
    return A, B, C


def _unit(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.standard_normal(n)
    return v / np.linalg.norm(v)


def random_lipschitz_plant(*, n: int = 4, m: int = 1, p: int = 1, c: float = 0.5, seed: int = 0,
                           n_unstable: int | None = None, max_re: float = 0.5, t_final: float = 20.0,
                           id: str | None = None) -> Plant:
    """A random plant with the globally Lipschitz nonlinearity ``f(x) = c G sin(H x)``, G, H orthogonal.

    Parameters
    ----------
    n, m, p : int
        States (>= 1), inputs and outputs (between 1 and n).
    c : float
        Scale of the nonlinearity, >= 0; it is the Lipschitz constant bound.
    seed : int
        Seed (>= 0) of A, B, C (stream 0) and of the nonlinearity's directions and x0 (stream 1).
    n_unstable, max_re
        Passed to :func:`random_lti`.
    t_final : float
        Simulation horizon in seconds.
    id : str, optional
        Plant id (default ``random_lipschitz_v1_n{n}_s{seed}``).

    Returns
    -------
    Plant
        Claimed = analytic (module docstring), global; ``x0`` a random unit vector, ``x_hat0 = 0``.
    """
    A, B, C, n, c, rng = _start(c, n=n, m=m, p=p, seed=seed, n_unstable=n_unstable, max_re=max_re)
    G = _orthogonal(rng, n)
    H = _orthogonal(rng, n).T

    def f(x: np.ndarray) -> np.ndarray:
        return c * (G @ np.sin(H @ np.asarray(x, dtype=float)))

    def jacobian(x: np.ndarray) -> np.ndarray:
        z = H @ np.asarray(x, dtype=float).reshape(-1)
        return c * (G * np.cos(z)) @ H

    return _member("random_lipschitz", A, B, C, f=f, jacobian=jacobian,
                   consts=Constants(alpha=c, rho=c, beta=c**2, gamma=0.0),
                   channels=Channels(G=c * G, H=H, phi=np.sin, lo=-1.0, hi=1.0, narrow=sine_slopes(1.0)),
                   x0=_unit(rng, n), t_final=t_final,
                   id=id, params={"c": c, "seed": int(seed), "max_re": float(max_re)},
                   notes="f = c G sin(H x), G and H orthogonal: alpha = rho = c, (beta, gamma) = (c^2, 0), global")


def random_osl_plant(*, n: int = 4, m: int = 1, p: int = 1, c: float = 1.0, r: float = 1.0, seed: int = 0,
                     n_unstable: int | None = None, max_re: float = 0.5, t_final: float = 20.0,
                     id: str | None = None) -> Plant:
    """A random plant with the one-sided Lipschitz nonlinearity ``f(x) = -c W (W' x)^3``.

    Parameters
    ----------
    n, m, p, seed, n_unstable, max_re, t_final
        As for :func:`random_lipschitz_plant`.
    c : float
        Scale of the nonlinearity, >= 0.
    r : float
        Radius (> 0) of the region ``||x|| <= r`` where the local constants hold.
    id : str, optional
        Plant id (default ``random_osl_v1_n{n}_s{seed}``).

    Returns
    -------
    Plant
        Claimed = analytic on ``||x|| <= r`` (module docstring); ``x0`` of norm r/2, ``x_hat0 = 0``.
    """
    A, B, C, n, c, rng = _start(c, n=n, m=m, p=p, seed=seed, n_unstable=n_unstable, max_re=max_re)
    r = check_real("r", r, lo=0.0, strict=True)
    W = _orthogonal(rng, n)

    def f(x: np.ndarray) -> np.ndarray:
        z = W.T @ np.asarray(x, dtype=float)
        return -c * (W @ (z * z * z))

    def jacobian(x: np.ndarray) -> np.ndarray:
        z = W.T @ np.asarray(x, dtype=float).reshape(-1)
        return -3.0 * c * (W * z**2) @ W.T

    k = 3.0 * c * r**2
    return _member("random_osl", A, B, C, f=f, jacobian=jacobian,
                   consts=Constants(alpha=k, rho=0.0, beta=0.0, gamma=-k, radius=r),
                   channels=Channels(G=W, H=W.T, phi=lambda z: -c * (z * z * z), lo=-k, hi=0.0, radius=r,
                                     narrow=cubic_slopes(c)),
                   x0=0.5 * r * _unit(rng, n), t_final=t_final, id=id,
                   params={"c": c, "r": r, "seed": int(seed), "max_re": float(max_re)},
                   notes="f = -c W (W'x)^3, W orthogonal: rho = 0, alpha = 3 c r^2, (beta, gamma) = (0, -3 c r^2) "
                         "on ||x|| <= r")


def _start(c, *, n, m, p, seed, n_unstable, max_re) -> tuple:
    """A member's A, B, C (seed stream 0), n, checked c (>= 0) and stream 1 (its nonlinearity and x0)."""
    A, B, C = random_lti(n, m, p, seed=seed, n_unstable=n_unstable, max_re=max_re)
    return A, B, C, A.shape[0], check_real("c", c, lo=0.0), np.random.default_rng([int(seed), 1])


def _member(family: str, A, B, C, *, consts: Constants, x0, t_final: float, id: str | None, params: dict,
            **fields) -> Plant:
    """A member of a family: constants claimed = analytic, ``x_hat0 = 0``, the common parameters recorded."""
    n = A.shape[0]
    return Plant(id=id or f"{family}_v1_n{n}_s{params['seed']}", A=A, B=B, C=C, x0=x0, x_hat0=np.zeros(n),
                 claimed=consts, bounds=consts, t_final=t_final, family=family, source=_SOURCE,
                 params={"n": n, "m": B.shape[1], "p": C.shape[0], **params, "version": 1}, **fields)


@register_plant("random_lipschitz_v1")
def random_lipschitz(*, n: int = 4, m: int = 1, p: int = 1, c: float = 0.2, seed: int = 0,
                     t_final: float = 20.0) -> Plant:
    """The registered member of :func:`random_lipschitz_plant` (n = 4, c = 0.2, seed 0)."""
    return random_lipschitz_plant(n=n, m=m, p=p, c=c, seed=seed, t_final=t_final, id="random_lipschitz_v1")


@register_plant("random_osl_v1")
def random_osl(*, n: int = 4, m: int = 1, p: int = 1, c: float = 0.3, r: float = 1.0, seed: int = 0,
               t_final: float = 20.0) -> Plant:
    """The registered member of :func:`random_osl_plant` (n = 4, c = 0.3, r = 1, seed 0)."""
    return random_osl_plant(n=n, m=m, p=p, c=c, r=r, seed=seed, t_final=t_final, id="random_osl_v1")
