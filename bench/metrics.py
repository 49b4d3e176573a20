"""Metrics of closed-loop trajectories: pure functions of (t, x, x_hat, u), for one or a batch.

With ``z = (x, e)``, ``e = x - x_hat``: ``converged``: the run finished and at the end ``||x||`` and
``||e||`` are at most :data:`CONVERGED_RATIO` times the peak of ``||z||`` (what a certificate
``||z(t)|| <= sqrt(cond P) e^{-lam t} ||z(0)||`` guarantees by the horizon of
:func:`bench.verdicts.simulation_horizon`); with measurement noise, that both norms settled.
``settling_x_s``, ``settling_e_s``: the first time after which the norm stays within 2 % of its
peak (NaN if never); ``iae_e``: the integral of ``||e||``; ``rms_e``: the RMS of ``||e||`` over the
second half; ``peak_u``: the peak ``|u|``; ``tail_rate``: the decay rate of ``||z||`` fitted by least
squares on ``log ||z||`` over the last quarter; ``peak_x``, ``peak_e``; ``max_norm``: the largest
``max(||x||, ||x_hat||)``. With the integrator's dense output (:func:`dense_metrics`) the settling
times and the IAE do not depend on the output grid.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["settling_time", "trajectory_metrics"]

SETTLING_FRACTION = 0.02
CONVERGED_RATIO = 1e-3


def batch_settling_time(t: np.ndarray, s: np.ndarray, fraction: float = SETTLING_FRACTION) -> np.ndarray:
    """First time after which each row of ``s`` (N, T) stays within ``fraction`` of its peak (NaN if
    never or not finite, ``t[0]`` if it never leaves, 0 for an all-zero row)."""
    t = np.asarray(t, dtype=float)
    s = np.atleast_2d(np.asarray(s, dtype=float))
    N, Tn = s.shape
    out = np.full(N, np.nan)
    finite = np.all(np.isfinite(s), axis=1)
    peak = np.where(finite, np.max(np.where(np.isfinite(s), s, -np.inf), axis=1), np.nan)
    outside = s > fraction * peak[:, None]
    any_out = outside.any(axis=1)
    last = Tn - 1 - np.argmax(outside[:, ::-1], axis=1)
    ok = finite & any_out & (last < Tn - 1)
    out[ok] = t[np.minimum(last[ok] + 1, Tn - 1)]
    out[finite & ~any_out] = t[0]
    out[finite & (peak == 0)] = 0.0
    return out


def settling_time(t: np.ndarray, s: np.ndarray, fraction: float = SETTLING_FRACTION) -> float:
    """First time after which ``s`` stays within ``fraction`` of its peak (NaN if never)."""
    s = np.asarray(s, dtype=float)
    if s.size == 0:
        return math.nan
    return float(batch_settling_time(t, s[None, :], fraction)[0])


def _tail_rate(t: np.ndarray, nz: np.ndarray) -> np.ndarray:
    """Fitted decay rate of each row of ``nz`` (N, T) over the last quarter of ``t``."""
    k0 = int(0.75 * (t.size - 1))
    tt = t[k0:]
    with np.errstate(divide="ignore", invalid="ignore"):
        y = np.log(nz[:, k0:])
    out = np.full(nz.shape[0], np.nan)
    for j in range(nz.shape[0]):
        good = np.isfinite(y[j]) & (nz[j, k0:] > 1e-12 * max(float(np.max(nz[j])), 1e-300))
        if good.sum() >= 3 and np.ptp(tt[good]) > 0:
            out[j] = -float(np.polyfit(tt[good], y[j][good], 1)[0])
    return out


def batch_metrics(t, x, x_hat, u=None, *, finished=True, diverged=None, noisy: bool = False) -> dict[str, np.ndarray]:
    """Per-member metrics of a batch (module docstring): ``t`` (T,), ``x``, ``x_hat`` (n, N, T), ``u`` (m, N, T);
    not converged where not ``finished`` or ``diverged``; ``noisy``: converged means settled.

    Returns
    -------
    dict of ndarray (N,)
        ``converged``, ``settling_x_s``, ``settling_e_s``, ``final_x``, ``final_e``, ``iae_e``,
        ``rms_e``, ``peak_u``, ``peak_x``, ``peak_e``, ``max_norm``, ``tail_rate``.
    """
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    xh = np.asarray(x_hat, dtype=float)
    nx, ne, nh = (np.sqrt(np.einsum("ijk,ijk->jk", v, v)) for v in (x, x - xh, xh))
    nz = np.sqrt(nx**2 + ne**2)
    N = nx.shape[0]
    finite = np.all(np.isfinite(nz), axis=1)
    ok = finite & np.broadcast_to(np.asarray(finished, dtype=bool), (N,))
    if diverged is not None:
        ok &= ~np.asarray(diverged, dtype=bool)
    pz = np.where(finite, np.max(np.where(np.isfinite(nz), nz, 0.0), axis=1), np.nan)
    fx, fe = nx[:, -1], ne[:, -1]
    scale = CONVERGED_RATIO * np.maximum(pz, 1e-300)
    sx = np.where(ok, batch_settling_time(t, nx), np.nan)
    se = np.where(ok, batch_settling_time(t, ne), np.nan)
    if noisy:
        conv = ok & np.isfinite(sx) & np.isfinite(se)
    else:
        conv = ok & (fx <= scale) & (fe <= scale)
    iae = np.sum((ne[:, 1:] + ne[:, :-1]) * np.diff(t), axis=1) / 2 if t.size > 1 else np.zeros(N)
    tail = t >= t[0] + (t[-1] - t[0]) / 2
    rms = np.where(ok, np.sqrt(np.mean(ne[:, tail] ** 2, axis=1)), np.nan)
    no_u = u is None or np.size(u) == 0
    pu = np.full(N, np.nan) if no_u else np.max(np.abs(np.asarray(u, dtype=float)), axis=(0, 2))
    return {
        "converged": conv, "settling_x_s": sx, "settling_e_s": se, "final_x": fx, "final_e": fe, "iae_e": iae,
        "rms_e": rms, "peak_u": pu, "peak_x": np.max(nx, axis=1), "peak_e": np.max(ne, axis=1),
        "max_norm": np.max(np.maximum(nx, nh), axis=1), "tail_rate": _tail_rate(t, nz),
    }


def trajectory_metrics(t, x, x_hat, u, *, finished: bool = True, noisy: bool = False,
                       dense=None) -> dict[str, float | bool]:
    """:func:`batch_metrics` of one trajectory (``x``, ``x_hat`` (n, T), ``u`` (m, T)), as Python scalars;
    with the integrator's ``dense`` output the settling times and the IAE come from :func:`dense_metrics`."""
    x = np.asarray(x, dtype=float)[:, None, :]
    xh = np.asarray(x_hat, dtype=float)[:, None, :]
    uu = None if u is None or np.size(u) == 0 else np.asarray(u, dtype=float)[:, None, :]
    m = batch_metrics(t, x, xh, uu, finished=finished, noisy=noisy)
    out = {k: (bool(v[0]) if k == "converged" else float(v[0])) for k, v in m.items()}
    if dense is not None and np.size(t) > 1:
        fine = dense_metrics(dense, x.shape[0], float(t[0]), float(t[-1]))
        for k in ("settling_x_s", "settling_e_s"):
            if math.isfinite(out[k]):
                out[k] = fine[k]
        out["iae_e"] = fine["iae_e"]
    return out


#: 5-point Gauss-Legendre nodes and weights on [0, 1].
_GL_NODES, _GL_WEIGHTS = (lambda p: ((p[0] + 1) / 2, p[1] / 2))(np.polynomial.legendre.leggauss(5))


def dense_metrics(dense, n: int, t0: float, t1: float, fraction: float = SETTLING_FRACTION) -> dict[str, float]:
    """Settling times and IAE (``settling_x_s``, ``settling_e_s``, ``iae_e``) over ``[t0, t1]`` from an
    integrator's dense output ``(x, x_hat)`` (2n,), independent of any output grid.

    The IAE is the 5-point Gauss-Legendre quadrature of ``||e||`` on each integrator step; a settling
    time is the root of ``||.|| - fraction * peak`` (Brent) in the last interval above the level.
    """
    from scipy.optimize import brentq

    ts = np.unique(np.clip(dense.ts, t0, t1))
    h = np.diff(ts)
    nodes = (ts[:-1, None] + h[:, None] * _GL_NODES[None, :]).ravel()
    both = np.concatenate([ts, nodes])
    order = np.argsort(both, kind="stable")
    grid = both[order]
    Z = np.asarray(dense(grid), dtype=float)

    def norms(Z):
        x, xh = Z[:n], Z[n:]
        return np.linalg.norm(x, axis=0), np.linalg.norm(x - xh, axis=0)

    nx, ne = norms(Z)
    # the nodes' columns of Z: a dense output evaluates each time on its own, so these are the values that
    # evaluating it at the nodes alone gives
    at = np.empty_like(order)
    at[order] = np.arange(order.size)
    _, ne_nodes = norms(np.asfortranarray(Z[:, at[ts.size:]]))  # laid out as dense() returns it
    iae = float(np.sum(h * (ne_nodes.reshape(-1, _GL_NODES.size) @ _GL_WEIGHTS)))
    out = {"iae_e": iae}
    for key, s, which in (("settling_x_s", nx, 0), ("settling_e_s", ne, 1)):
        b = out[key] = float(batch_settling_time(grid, s, fraction)[0])  # on the grid
        k = int(np.searchsorted(grid, b)) - 1  # the last grid point above the level, when b follows one
        if math.isfinite(b) and k >= 0:
            level = fraction * float(np.max(s))
            g = lambda tt: norms(np.asarray(dense(tt), dtype=float)[:, None])[which][0] - level  # noqa: E731
            a = float(grid[k])
            out[key] = brentq(g, a, b, xtol=1e-12 * max(1.0, abs(b)), rtol=1e-12) if g(b) <= 0 < g(a) else b
    return out
