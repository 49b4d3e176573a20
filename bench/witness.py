"""What a class of nonlinearities allows, shown by its members: witnesses against a certificate, and
the ceiling on a certified rate.

A certificate of the ladder (:mod:`bench.certify`) proves ``V' <= -2 lam V`` for *every* f in a
class (the trusted constants, or the channels ``f = G phi(H x)`` with slopes in a box). Two kinds
of member bound what it can prove, with fixed gains K, F:

- **linear members** ``f = L x``, with ``L = G diag(c) H`` for slopes ``c`` in the box (or ``L``
  meeting every scalar constant of the class). With f linear the loop (9) is block triangular,
  ``z' = [[A + L + B F, -B F], [0, A + L - K C]] z``: its eigenvalues are those of
  ``A + L + B F`` and ``A + L - K C``. A certificate over the class makes every member decay at
  ``lam`` at least, so an unstable member is a *witness* that no certificate over the class
  exists (global or local: the LMI does not depend on the region), and the smallest decay rate
  over the members is a *ceiling* on any certified rate (:func:`rate_ceiling`);
- **equilibria** of the true closed loop other than the origin (:func:`equilibrium_witness`): the
  loop is then not globally asymptotically stable, so no certificate of any form proves global
  convergence.

Members are the box's vertices and a grid for few channels, seeded samples beyond (the text of
each result says which); a ceiling is then an upper bound found by search, not the exact minimum.

Discrete time (a plant with ``dt > 0``, ``z_{k+1} = Acl z_k + Gb w_k``): a linear member's loop decays at
``-ln(rho) / dt`` per second, rho its spectral radius, and is a witness when ``rho >= 1``; an equilibrium is a
fixed point ``z = Phi(z)`` of the closed-loop map besides the origin.
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass

import numpy as np

from bench.checks import vector

__all__ = ["Witness", "rate_ceiling"]

#: Grid points per channel for few channels (q channels: ``GRID[q] ** q`` members, vertices included).
GRID = {1: 41, 2: 9, 3: 5}

#: Seeded members for more channels (half at random vertices, half inside the box).
SAMPLES = 128

#: Seeded random directions of the low-rank members of a scalar class (:func:`_subspaces`).
DIRECTIONS = 16

#: Low-rank members of a scalar class are searched up to this many states (``s I`` beyond).
SUBSPACE_MAX_N = 16

#: A member is unstable when its loop has an eigenvalue of real part above this, relative to the size of A, B F, K C.
UNSTABLE_TOL = 1e-9


@dataclass
class Witness:
    """A member of the class that rules a certificate out.

    Attributes
    ----------
    kind : str
        ``"linear member"`` or ``"equilibrium"``.
    text : str
        The witness in words (slopes and eigenvalue, or the equilibrium and its residual).
    slopes : ndarray or None
        Channel slopes of a linear member (None for a scalar-class member or an equilibrium).
    L : ndarray or None
        The linear member ``f = L x``.
    eig : complex
        Its loop's eigenvalue of largest real part.
    z : ndarray or None
        The equilibrium ``(x, e)``.
    residual : float
        ``||z'||`` of the true closed loop at ``z``.
    """

    kind: str
    text: str
    slopes: np.ndarray | None = None
    L: np.ndarray | None = None
    eig: complex = complex("nan")
    z: np.ndarray | None = None
    residual: float = float("nan")


def admits(L: np.ndarray, scalars: tuple[str, ...], constants) -> bool:
    """True when ``f(x) = L x`` meets the scalar constants ``scalars`` (of ``"osl"``, ``"qib"``, ``"lip"``).

    OSL: ``sym(L) <= rho I``; QIB: ``L' L <= beta I + gamma sym(L)``; Lipschitz: ``||L||_2 <= alpha``; each
    within ``tol = 1e-12 max(1, max |L_ij|)``, checked in the order of ``scalars`` up to the first one unmet. A
    largest eigenvalue is taken as :func:`bench.lmi.max_eig` takes it (NaN, so unmet, for a non-finite matrix);
    ``||L||_2`` is the largest singular value. :func:`admitted` applies the same rule to a stack of matrices.

    Parameters
    ----------
    L : ndarray
        The linear member, shape (n, n).
    scalars : tuple of str
        Constants to meet, of ``"osl"``, ``"qib"``, ``"lip"``.
    constants : Constants
        Their values (``rho``, ``beta``, ``gamma``, ``alpha``; None reads as 0).

    Returns
    -------
    bool
        Whether ``f(x) = L x`` meets every constant of ``scalars``.
    """
    c, S = constants, (L + L.T) / 2
    tol = 1e-12 * max(1.0, float(np.abs(L).max(initial=0.0)))
    for k in scalars:
        if k == "lip":
            if not float(np.linalg.svd(L, compute_uv=False).max()) <= (c.alpha or 0.0) + tol:
                return False
            continue
        if k == "osl":
            M = S - (c.rho or 0.0) * _eye(len(L))
        elif k == "qib":
            M = L.T @ L - (c.beta or 0.0) * _eye(len(L)) - (c.gamma or 0.0) * S
        else:
            raise KeyError(k)
        if not (np.isfinite(M).all() and float(np.linalg.eigvalsh((M + M.T) / 2)[-1]) <= tol):
            return False
    return True


@functools.lru_cache(maxsize=32)
def _eye(n: int) -> np.ndarray:
    """``np.eye(n)``, made once (read-only)."""
    eye = np.eye(n)
    eye.flags.writeable = False
    return eye


def _max_eigs(M: np.ndarray) -> np.ndarray:
    """:func:`bench.lmi.max_eig` of each matrix of the stack ``M`` (N, n, n): one batched ``eigvalsh``."""
    out = np.full(len(M), np.nan)
    fin = np.isfinite(M).all(axis=(1, 2))
    if fin.any():
        Mf = M[fin]
        out[fin] = np.linalg.eigvalsh((Mf + Mf.transpose(0, 2, 1)) / 2)[:, -1]
    return out


def admitted(Ls: np.ndarray, scalars: tuple[str, ...], constants) -> np.ndarray:
    """:func:`admits` for each matrix of the stack ``Ls`` (N, n, n), as a boolean array (N,).

    The same rule with the same tolerance ``1e-12 max(1, max |L_ij|)`` per matrix, by batched LAPACK calls
    (``eigvalsh``, ``svd``: the same routine on each matrix, the same numbers as one call per matrix); a constant
    is checked only on the matrices that met the ones before it, in the order of ``scalars``. A stack with a
    non-finite entry takes :func:`admits` matrix by matrix.

    Parameters
    ----------
    Ls : ndarray
        The linear members, shape (N, n, n).
    scalars : tuple of str
        Constants to meet, of ``"osl"``, ``"qib"``, ``"lip"``.
    constants : Constants
        Their values (``rho``, ``beta``, ``gamma``, ``alpha``; None reads as 0).

    Returns
    -------
    ndarray of bool
        Whether each ``f(x) = L x`` meets every constant of ``scalars``.
    """
    Ls = np.asarray(Ls, dtype=float)
    ok = np.ones(len(Ls), dtype=bool)
    if not scalars or not len(Ls):
        return ok
    if not np.all(np.isfinite(Ls)):
        return np.array([admits(L, scalars, constants) for L in Ls], dtype=bool)
    c, eye = constants, _eye(Ls.shape[1])
    S = (Ls + Ls.transpose(0, 2, 1)) / 2
    tol = 1e-12 * np.maximum(1.0, np.abs(Ls).max(axis=(1, 2), initial=0.0))
    for k in scalars:
        i = np.flatnonzero(ok)
        if not i.size:
            break
        if k not in ("osl", "qib", "lip"):
            raise KeyError(k)
        if k == "osl":
            ok[i] = _max_eigs(S[i] - (c.rho or 0.0) * eye) <= tol[i]
        elif k == "qib":
            L = Ls[i]
            ok[i] = _max_eigs(L.transpose(0, 2, 1) @ L - (c.beta or 0.0) * eye - (c.gamma or 0.0) * S[i]) <= tol[i]
        else:
            ok[i] = np.linalg.svd(Ls[i], compute_uv=False).max(axis=1) <= (c.alpha or 0.0) + tol[i]
    return ok


def _slope_points(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, str]:
    """Slope vectors in the box ``[lo, hi]``, shape (N, q), and how they were chosen."""
    q = lo.size
    if q in GRID:
        axes = [np.unique(np.linspace(a, b, GRID[q])) for a, b in zip(lo, hi)]
        pts = np.array(list(itertools.product(*axes)), dtype=float)
        return pts, f"the box's vertices and a grid of {GRID[q]} slopes per channel ({len(pts)} members)"
    rng = np.random.default_rng([0, 24])
    corners = np.where(rng.random((SAMPLES // 2, q)) < 0.5, lo, hi)
    inside = lo + (hi - lo) * rng.random((SAMPLES - SAMPLES // 2, q))
    pts = np.vstack([(lo + hi)[None] / 2, corners, inside])
    return pts, f"{len(pts)} seeded members (random vertices and interior points of the box, q = {q})"


def eigen_interval(constants, scalars: tuple[str, ...]) -> tuple[float, float] | None:
    """The eigenvalues ``s`` a symmetric member ``L`` of a scalar class may have (None: no member).

    For a symmetric L every constant reads eigenvalue by eigenvalue: OSL ``s <= rho``, QIB
    ``s^2 - gamma s - beta <= 0``, Lipschitz ``|s| <= alpha``; so ``L`` is a member exactly when its
    eigenvalues lie in the interval returned. An end the constants leave open is put at ``-span`` or
    ``span`` (alpha, else the size of the constants and of A).
    """
    c = constants
    span = c.alpha if c.alpha is not None else max(abs(c.rho or 0.0), math.sqrt(abs(c.beta or 0.0)),
                                                   abs(c.gamma or 0.0), 1.0)
    lo, hi = -span, span
    if "osl" in scalars:
        hi = min(hi, c.rho)
    if "qib" in scalars:
        disc = c.gamma**2 + 4.0 * c.beta
        if disc < 0:
            return None
        lo, hi = max(lo, (c.gamma - math.sqrt(disc)) / 2), min(hi, (c.gamma + math.sqrt(disc)) / 2)
    return (lo, hi) if lo <= hi else None


def _subspaces(plant, K: np.ndarray, F: np.ndarray) -> list[np.ndarray]:
    """Orthonormal bases (n, 1) or (n, 2) of the directions a low-rank member acts on: the right and left
    eigenvectors of ``A + B F`` and ``A - K C`` (the plane of a complex pair, and each of its real and imaginary
    parts), the eigenvectors of their symmetric parts, and :data:`DIRECTIONS` seeded random directions."""
    n, out = plant.n, []
    for M in (plant.A + plant.B @ F, plant.A - K @ plant.C):
        for X in (M, M.T):
            for v in np.linalg.eig(X)[1].T:
                out += [v.real[:, None], v.imag[:, None], np.column_stack([v.real, v.imag])]
        out += [v[:, None] for v in np.linalg.eigh((M + M.T) / 2)[1].T]
    out += [v[:, None] for v in np.random.default_rng([0, 31]).standard_normal((DIRECTIONS, n))]
    # each V's orthonormal basis Q (the columns of V's QR kept where R's diagonal is not negligible) and projector
    # Q Q', by batched calls over the V of each width (the same numbers as one call per V); kept in their order
    # unless their projector (to 9 decimals) came before
    Qs, keys = [None] * len(out), [None] * len(out)
    for w in (1, 2):
        i = [k for k, V in enumerate(out) if V.shape[1] == w]
        if not i:
            continue
        V = np.stack([out[k] for k in i])
        Q, R = np.linalg.qr(V)
        Q = np.ascontiguousarray(Q)
        keep = np.abs(np.diagonal(R, axis1=1, axis2=2)) > 1e-9 * np.fmax(1.0, np.abs(V).max(axis=(1, 2)))[:, None]
        P = np.round(Q @ Q.transpose(0, 2, 1), 9)
        for j, k in enumerate(i):
            Qs[k] = Q[j][:, keep[j]]
            keys[k] = P[j].tobytes() if keep[j].all() else np.round(Qs[k] @ Qs[k].T, 9).tobytes()
    bases, seen = [], set()
    for Q, key in zip(Qs, keys):
        if Q.shape[1] and key not in seen:
            seen.add(key)
            bases.append(Q)
    return bases


def _symmetric_members(plant, K, F, interval: tuple[float, float]) -> tuple[list[np.ndarray], str]:
    """Symmetric members with eigenvalues in ``interval``: ``s I`` on a grid, and (with gains K, F, up to
    :data:`SUBSPACE_MAX_N` states) ``s I + (u - s) Q Q'`` for ``s, u`` among the interval's ends and middle
    and the subspaces Q of :func:`_subspaces`."""
    lo, hi = interval
    Ls = [s * np.eye(plant.n) for s in np.unique(np.linspace(lo, hi, GRID[1]))]
    how = f"L = s I for s in [{lo:.4g}, {hi:.4g}]"
    if K is None or plant.n > SUBSPACE_MAX_N or plant.n == 1:
        return Ls, how
    ends = np.unique([lo, (lo + hi) / 2, hi])
    bases = _subspaces(plant, K, F)
    if bases:  # every (Q, s, u) at once, in the order Q, then s, then u != s
        i, j = np.nonzero(ends[:, None] != ends[None, :])
        n, P = plant.n, np.stack([Q @ Q.T for Q in bases])[:, None]
        Ls += list((ends[i, None, None] * np.eye(n) + (ends[j] - ends[i])[:, None, None] * P).reshape(-1, n, n))
    return Ls, how + f", and s I + (u - s) Q Q' on {len(bases)} rank-one and rank-two subspaces Q"


def members(plant, know, *, channels: bool, scalars: tuple[str, ...], box: tuple | None = None,
            K: np.ndarray | None = None,
            F: np.ndarray | None = None) -> tuple[list[tuple[np.ndarray | None, np.ndarray]], str]:
    """The linear members ``(slopes, L)`` of a class (slopes None outside the channel class) and how they
    were chosen.

    With ``channels``: the slope box of ``know``'s channels (``box`` instead when given). Otherwise the
    class is every f meeting the scalar constants ``scalars``: its symmetric members
    (:func:`eigen_interval`; ``s I``, and with the gains K, F the low-rank members of
    :func:`_symmetric_members`), and the channel members, if any. Every member kept meets ``scalars``
    (:func:`admits`).
    """
    ch = know.channels
    out, how = [], []
    if ch is not None and (channels or scalars):
        lo, hi = box if box is not None else (ch.lo, ch.hi)
        pts, what = _slope_points(np.asarray(lo, float), np.asarray(hi, float))
        out = list(zip(pts, ch.G @ (pts[:, :, None] * ch.H)))  # L = G diag(c) H for every c at once
        how.append(what if channels else f"channel members meeting the scalar constants, among {what}")
    if not channels:
        interval = eigen_interval(know.constants, scalars)
        if interval is not None:
            Ls, what = _symmetric_members(plant, K, F, interval)
            out += [(None, L) for L in Ls]
            how.append(f"{what} meeting the constants")
    if scalars and out:
        keep = admitted(np.stack([L for _, L in out]), scalars, know.constants)
        out = [m for m, k in zip(out, keep) if k]
    return out, "; ".join(how)


def _dt(plant) -> float:
    return float(getattr(plant, "dt", 0.0) or 0.0)


def slowest_loop(plant, K: np.ndarray, F: np.ndarray, Ls: list[np.ndarray]) -> tuple[int, float, complex] | None:
    """The slowest of the linear loops with ``f = L x``: its index in ``Ls``, its decay rate ``-max Re eig``
    (discrete time: ``-ln(max |eig|) / dt`` per second) and that eigenvalue (None without any L)."""
    if not len(Ls):
        return None
    return _slowest(_loop_parts(plant, K, F), np.stack(Ls))


def _loop_parts(plant, K: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """``(A, B F, K C, dt)``: what :func:`_slowest` needs of a loop, computed once for many members."""
    return plant.A, plant.B @ F, K @ plant.C, _dt(plant)


def _slowest(parts: tuple, Ls: np.ndarray) -> tuple[int, float, complex]:
    """:func:`slowest_loop` of the stack ``Ls`` (N, n, n), N >= 1, with the loop's ``parts`` (:func:`_loop_parts`):
    the eigenvalues of every ``A + L + B F`` and ``A + L - K C`` in one batched call."""
    A, BF, KC, dt = parts
    AL, N = A[None] + Ls, len(Ls)
    w = np.linalg.eigvals(np.concatenate([AL + BF, AL - KC]))
    eig = np.concatenate([w[:N], w[N:]], axis=1)
    key = np.abs(eig) if dt > 0 else eig.real
    worst = eig[np.arange(N), np.argmax(key, axis=1)]
    wkey = np.abs(worst) if dt > 0 else worst.real
    i = int(np.argmax(wkey))
    if dt > 0:
        with np.errstate(divide="ignore"):
            return i, float(-np.log(abs(worst[i])) / dt), complex(worst[i])
    return i, float(-worst[i].real), complex(worst[i])


def _rate1(parts: tuple, L: np.ndarray) -> float:
    """The decay rate of :func:`_slowest` for the one member ``L`` (n, n): the same eigenvalues (one batched call
    on ``A + L + B F`` and ``A + L - K C``), the same one of them picked."""
    A, BF, KC, dt = parts
    AL = A + L
    eig = np.linalg.eigvals(np.stack((AL + BF, AL - KC))).reshape(-1)
    if dt > 0:
        worst = eig[np.argmax(np.abs(eig))]
        with np.errstate(divide="ignore"):
            return float(-np.log(abs(worst)) / dt)
    return float(-eig.real.max())


def unstable(plant, K: np.ndarray, F: np.ndarray, eig: complex) -> bool:
    """Whether a loop's eigenvalue ``eig`` is unstable beyond the rounding: real part above
    :data:`UNSTABLE_TOL` times the size of A, B F, K C (continuous), modulus above ``1 + UNSTABLE_TOL`` times it
    (discrete: spectral radius >= 1)."""
    if _dt(plant) > 0:
        return abs(eig) - 1.0 > UNSTABLE_TOL * _scale(plant, K, F)
    return eig.real > UNSTABLE_TOL * _scale(plant, K, F)


def _scale(plant, K, F) -> float:
    return max(1.0, *(float(np.abs(M).max(initial=0.0)) for M in (plant.A, plant.B @ F, K @ plant.C)))


def linear_witness(plant, K: np.ndarray, F: np.ndarray, know, *, channels: bool,
                   scalars: tuple[str, ...]) -> Witness | None:
    """The least stable linear member of the class (:func:`members`) when its loop is unstable, else None."""
    cands, how = members(plant, know, channels=channels, scalars=scalars, K=K, F=F)
    slowest = slowest_loop(plant, K, F, [L for _, L in cands])
    if slowest is None or not unstable(plant, K, F, slowest[2]):
        return None
    i, _, eig = slowest
    c, L = cands[i]
    imag = "" if abs(eig.imag) < 1e-12 else f" {'+' if eig.imag >= 0 else '-'} {abs(eig.imag):.4g}j"
    text = (f"the linear member {_describe(c, L)} (in the class; searched: {how}) leaves the loop with the "
            f"eigenvalue {eig.real:+.4g}{imag}")
    if _dt(plant) > 0:
        text += f" (modulus {abs(eig):.6g} >= 1: spectral radius of the discrete loop)"
    return Witness("linear member", text, slopes=c, L=L, eig=eig)


def _describe(c: np.ndarray | None, L: np.ndarray) -> str:
    """A linear member in words: f = 0, its channel slopes, s x, or the eigenvalues of a symmetric L."""
    if not np.any(L):
        return "f = 0"
    if c is not None:
        return f"phi(s) = c s with slopes c = {vector(c, '.5g')}"
    if np.array_equal(L, L[0, 0] * np.eye(len(L))):
        return f"f = {L[0, 0]:.4g} x"
    return f"f = L x with L symmetric, eigenvalues {vector(np.linalg.eigvalsh(L), '.4g')}"


#: The last ceilings computed (:func:`rate_ceiling` is asked for the same class by the ladder's search and by
#: the pipeline's report of it): key -> (plant, know, result), the objects held so that their ids stay theirs.
_CEILINGS: dict = {}


def _memo_ceiling(fn):
    """:func:`rate_ceiling` remembered for the same plant and knowledge objects, gains, class and box."""

    @functools.wraps(fn)
    def memo(plant, K, F, know, *, channels, scalars, box=None):
        key = (id(plant), id(know), np.asarray(K, float).tobytes(), np.asarray(F, float).tobytes(), bool(channels),
               tuple(scalars), None if box is None else tuple(np.asarray(b, float).tobytes() for b in box))
        hit = _CEILINGS.get(key)
        if hit is not None and hit[0] is plant and hit[1] is know:
            return hit[2]
        out = fn(plant, K, F, know, channels=channels, scalars=scalars, box=box)
        if len(_CEILINGS) >= 16:
            _CEILINGS.pop(next(iter(_CEILINGS)))
        _CEILINGS[key] = (plant, know, out)
        return out

    return memo


@_memo_ceiling
def rate_ceiling(plant, K: np.ndarray, F: np.ndarray, know, *, channels: bool, scalars: tuple[str, ...],
                 box: tuple | None = None) -> tuple[float, str]:
    """The smallest decay rate over the class's linear members: no certificate over the class proves more.

    The members of :func:`members`; the best is refined by a bounded local search (Powell): over the
    slopes for a channel member, over ``s I + (u - s) v v'`` (eigenvalues ``s, u`` in
    :func:`eigen_interval`, any direction v) for a symmetric one. Any member's rate is a valid ceiling,
    found minimum or not.

    Returns
    -------
    float, str
        The ceiling (NaN when the class has no linear member here) and how it was found.
    """
    cands, how = members(plant, know, channels=channels, scalars=scalars, box=box, K=K, F=F)
    slowest = slowest_loop(plant, K, F, [L for _, L in cands])
    if slowest is None:
        return float("nan"), "no linear member found in the class"
    best, (c0, L0) = slowest[1], cands[slowest[0]]
    if c0 is not None:
        refined = _refine_slopes(plant, K, F, know, scalars, c0, box, best)
    else:
        refined = _refine_symmetric(plant, K, F, know, scalars, L0, best)
    if refined < best:
        best, how = refined, how + ", refined by a bounded local search"
    return best, how


def _refine_slopes(plant, K, F, know, scalars, c0: np.ndarray, box, best: float) -> float:
    """The smallest rate a bounded local search over the channel slopes finds from ``c0`` (``best`` if none lower)."""
    from scipy.optimize import minimize

    ch = know.channels
    lo, hi = (np.asarray(b, float) for b in (box if box is not None else (ch.lo, ch.hi)))
    free = hi > lo
    if not np.any(free):
        return best

    parts, lo_free, hi_free = _loop_parts(plant, K, F), lo[free], hi[free]

    def rate(v):
        c = c0.copy()
        c[free] = np.clip(v, lo_free, hi_free)
        L = ch.G @ (c[:, None] * ch.H)
        if scalars and not admits(L, scalars, know.constants):
            return best
        return _rate1(parts, L)

    res = minimize(rate, c0[free], method="Powell", bounds=list(zip(lo_free, hi_free)),
                   options={"maxfev": 60 * int(free.sum()), "xtol": 1e-6, "ftol": 1e-9})
    return float(res.fun) if np.isfinite(res.fun) else best


def _refine_symmetric(plant, K, F, know, scalars, L0: np.ndarray, best: float) -> float:
    """The smallest rate a bounded local search over ``s I + (u - s) v v'`` finds from the symmetric ``L0``
    (``best`` if none lower; only up to :data:`SUBSPACE_MAX_N` states)."""
    from scipy.optimize import minimize

    interval = eigen_interval(know.constants, scalars)
    n = plant.n
    if interval is None or n > SUBSPACE_MAX_N or n == 1:
        return best
    w, V = np.linalg.eigh(L0)
    odd = 0 if w[-1] - w[1] <= 1e-12 * max(1.0, abs(w[-1])) else n - 1  # the eigenvalue of L0's rank-one part
    x0 = np.concatenate([np.clip([w[n - 1 - odd], w[odd]], *interval), V[:, odd]])

    parts, eye = _loop_parts(plant, K, F), np.eye(n)

    def rate(p):
        s, u, v = np.clip(p[0], *interval), np.clip(p[1], *interval), p[2:]
        if not np.linalg.norm(v) > 1e-9:
            return best
        L = s * eye + (u - s) * (v[:, None] * v) / (v @ v)
        if not admits(L, scalars, know.constants):
            return best
        return _rate1(parts, L)

    res = minimize(rate, x0, method="Powell", bounds=[interval, interval] + [(-1.0, 1.0)] * n,
                   options={"maxfev": 60 * (n + 2), "xtol": 1e-6, "ftol": 1e-9})
    return min(float(res.fun), best) if np.isfinite(res.fun) else best


def _loop_fns(plant, K: np.ndarray, F: np.ndarray):
    """``(rhs, jac)`` of the true closed loop (9) in ``z = (x, e)``, with ``B F``, ``A + B F`` and ``A - K C``
    computed once for the whole root search (``jac`` None when the plant has no Jacobian).

    ``rhs``: ``x' = (A + B F) x - B F e + f(x)``, ``e' = (A - K C) e + f(x) - f(x - e)``; in discrete time the
    map's ``z_{k+1} - z_k`` (zero at a fixed point). ``jac``: its Jacobian from the plant's.
    """
    n, f, jacobian, disc = plant.n, plant.f, plant.jacobian, _dt(plant) > 0
    BF = plant.B @ F
    ABF, AK, mBF = plant.A + BF, plant.A - K @ plant.C, -BF

    def rhs(z: np.ndarray) -> np.ndarray:
        x, e = z[:n], z[n:]
        fx = np.asarray(f(x), float)
        out = np.concatenate([ABF @ x - BF @ e + fx, AK @ e + fx - np.asarray(f(x - e), float)])
        return out - z if disc else out

    def jac(z: np.ndarray) -> np.ndarray:
        x, e = z[:n], z[n:]
        Jx, Jh = np.asarray(jacobian(x), float), np.asarray(jacobian(x - e), float)
        J = np.empty((2 * n, 2 * n))
        J[:n, :n], J[:n, n:], J[n:, :n], J[n:, n:] = ABF + Jx, mBF, Jx - Jh, AK + Jh
        return J - np.eye(2 * n) if disc else J

    return rhs, (jac if jacobian is not None else None)


def _starts(plant, K, F, know) -> list[np.ndarray]:
    """Starts of the root search: null directions of near-singular linear members' loops, then random points."""
    n, out = plant.n, []
    ch = know.channels
    sizes = np.geomspace(0.3, 30.0, 7)
    if ch is not None:
        cands, _ = members(plant, know, channels=True, scalars=())
        for blk, M0 in (("x", plant.A + plant.B @ F), ("e", plant.A - K @ plant.C)):
            mats = M0 + np.stack([L for _, L in cands])  # an equilibrium makes one of them singular
            if _dt(plant) > 0:  # a fixed point: M - I singular
                mats = mats - np.eye(n)
            for j in np.argsort(np.abs(np.linalg.eigvals(mats)).min(axis=1))[:2]:
                w, V = np.linalg.eig(mats[j])
                v = np.real(V[:, int(np.argmin(np.abs(w)))])
                hv = float(np.abs(ch.H @ v).max()) or 1.0
                for s in sizes:
                    for sign in (1.0, -1.0):
                        d = sign * s * v / hv
                        out.append(np.concatenate([d, np.zeros(n)]) if blk == "x" else np.concatenate([d, d]))
    rng = np.random.default_rng([0, 7])
    for s in np.geomspace(0.3, 30.0, 16):
        d = rng.standard_normal(2 * n)
        out.append(s * d / np.linalg.norm(d))
    return out


#: Most channels for which :func:`no_equilibrium` checks the ``4 ** q`` vertices.
VERTEX_MAX_Q = 6

#: Vertices :func:`no_equilibrium` takes per batched call.
VERTEX_BATCH = 256


def no_equilibrium(plant, K: np.ndarray, F: np.ndarray, know) -> bool:
    """True when the channel class proves the closed loop has no equilibrium besides the origin.

    At an equilibrium ``z = (x, e)`` of the loop with ``f = G phi(H x)``, each channel's secant
    ``phi_i(s) = d_i s`` has ``d_i`` in ``[lo_i, hi_i]`` (mean value theorem, ``phi(0) = 0``), at
    ``H x`` and at ``H x_hat`` separately (``D1``, ``D2``). So ``z`` is a null vector of

        M(D1, D2) = [[A + B F + G D1 H, -B F], [G (D1 - D2) H, A - K C + G D2 H]],

    whose determinant is affine in each of the ``2 q`` slopes (each enters a rank-one term), so it
    takes its extremes over the box at the vertices. If ``det M`` has one strict sign at every
    vertex (each vertex matrix well conditioned), no ``M`` in the box is singular and the origin is
    the only equilibrium. False means undecided (also for local channels, many channels, or a class
    without channels). In discrete time the fixed points: ``M(D1, D2) - I`` in place of ``M``.
    """
    ch = know.channels
    if ch is None or ch.radius is not None:
        return False
    lo, hi = (np.broadcast_to(np.asarray(b, float), (ch.H.shape[0],)) for b in (ch.lo, ch.hi))
    q, n = lo.size, plant.n
    if q > VERTEX_MAX_Q:
        return False
    BF, AK = plant.B @ F, plant.A - K @ plant.C
    scale = _scale(plant, K, F) + float(np.abs(ch.G).max() * np.abs(ch.H).max() * np.abs([lo, hi]).max())
    vertices, signs = np.array(list(itertools.product(*[(a, b) for a, b in zip(lo, hi)] * 2)), dtype=float), set()
    for d in np.array_split(vertices, -(-len(vertices) // VERTEX_BATCH)):  # batched, in order
        D1, D2, j = np.zeros((len(d), q, q)), np.zeros((len(d), q, q)), np.arange(q)
        D1[:, j, j], D2[:, j, j] = d[:, :q], d[:, q:]
        M = np.empty((len(d), 2 * n, 2 * n))  # each vertex's matrix, block by block
        M[:, :n, :n] = plant.A + BF + ch.G @ D1 @ ch.H
        M[:, :n, n:] = -BF
        M[:, n:, :n] = ch.G @ (D1 - D2) @ ch.H
        M[:, n:, n:] = AK + ch.G @ D2 @ ch.H
        if _dt(plant) > 0:
            M = M - np.eye(2 * n)
        finite = np.isfinite(M).all(axis=(1, 2))
        smin = np.full(len(M), np.nan)
        smin[finite] = np.linalg.svd(M[finite], compute_uv=False)[:, -1]  # the same numbers as one call per vertex
        low = smin <= 1e-8 * scale
        if not finite.all() and not low[:int(np.argmin(finite))].any():
            np.linalg.svd(M[int(np.argmin(finite))], compute_uv=False)  # raises LinAlgError, as vertex by vertex
        if low.any():
            return False
        signs.update(np.linalg.slogdet(M)[0].tolist())
    return len(signs) == 1


def equilibrium_witness(plant, K: np.ndarray, F: np.ndarray, know, *, tol: float = 1e-9) -> Witness | None:
    """An equilibrium of the true closed loop other than the origin (None if the search finds none); in discrete
    time a fixed point of the closed-loop map.

    A root search (scipy ``root``, hybrid Powell, with the plant's Jacobian when it has one) of the
    closed loop's right-hand side from the starts of :func:`_starts`; a root counts when
    ``||z'|| <= tol max(1, ||z||)`` recomputed with the plant's f and ``||z|| > 1e-6``.

    Returns
    -------
    Witness or None
        The equilibrium of smallest norm among those found.
    """
    from scipy.optimize import root

    scale = _scale(plant, K, F)
    rhs, jac = _loop_fns(plant, K, F)
    best = None
    with np.errstate(all="ignore"):
        for z0 in _starts(plant, K, F, know):
            try:
                sol = root(rhs, z0, jac=jac, method="hybr")
            except (ValueError, ArithmeticError, np.linalg.LinAlgError):
                continue
            z = sol.x
            if not np.all(np.isfinite(z)) or np.linalg.norm(z) <= 1e-6:
                continue
            res = float(np.linalg.norm(rhs(z)))
            if res <= tol * scale * max(1.0, float(np.linalg.norm(z))) and (
                    best is None or np.linalg.norm(z) < np.linalg.norm(best[0])):
                best = (z, res)
    if best is None:
        return None
    z, res = best
    what = "a fixed point of its map" if _dt(plant) > 0 else "an equilibrium"
    text = (f"the closed loop has {what} besides the origin at z = (x, e) = {vector(z, '.5g')} (residual "
            f"{res:.1e}): it is not globally asymptotically stable")
    return Witness("equilibrium", text, z=z, residual=res)
