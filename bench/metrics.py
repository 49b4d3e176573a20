"""Metrics of a closed-loop trajectory: pure functions of (t, x, x_hat, u).

- ``settling_time(t, s)``: 2 % settling time of a norm signal s, the first time after which
  ``s`` stays at or below 2 % of its peak over the run (NaN if it never does by the end);
- ``converged``: the run finished and both ``||x||`` and ``||e||`` at the end are at most
  ``CONVERGED_RATIO`` (1e-3) times their peaks;
- with measurement noise (``noisy=True``) the norms cannot shrink by 1e-3, so ``converged``
  means the run finished and both norms settled (finite 2 % settling times);
- IAE of ``||e||`` by the trapezoid rule; ``rms_e``, the RMS of ``||e||`` over the second half of
  the horizon (the steady state, where noise dominates); peak ``|u|`` over all inputs and times.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["CONVERGED_RATIO", "SETTLING_FRACTION", "trajectory_metrics", "settling_time"]

SETTLING_FRACTION = 0.02
CONVERGED_RATIO = 1e-3


def settling_time(t: np.ndarray, s: np.ndarray, fraction: float = SETTLING_FRACTION) -> float:
    """First time after which ``s`` stays within ``fraction`` of its peak (NaN if never)."""
    t = np.asarray(t, dtype=float)
    s = np.asarray(s, dtype=float)
    if s.size == 0 or not np.all(np.isfinite(s)):
        return math.nan
    peak = float(np.max(s))
    if peak == 0:
        return 0.0
    outside = np.nonzero(s > fraction * peak)[0]
    if outside.size == 0:
        return float(t[0])
    last = outside[-1]
    if last == s.size - 1:
        return math.nan
    return float(t[last + 1])


def trajectory_metrics(t, x, x_hat, u, *, finished: bool = True, noisy: bool = False) -> dict[str, float | bool]:
    """Metrics of one trajectory.

    Parameters
    ----------
    t : ndarray (N,)
    x, x_hat : ndarray (n, N)
    u : ndarray (m, N)
    finished : bool
        False when the simulation stopped early (diverged): then ``converged`` is False.
    noisy : bool
        The run had measurement noise (changes the meaning of ``converged``, see above).

    Returns
    -------
    dict
        ``converged``, ``settling_x_s``, ``settling_e_s``, ``final_x``, ``final_e``,
        ``iae_e``, ``rms_e``, ``peak_u``.
    """
    t = np.asarray(t, dtype=float)
    nx = np.linalg.norm(np.asarray(x, dtype=float), axis=0)
    ne = np.linalg.norm(np.asarray(x, dtype=float) - np.asarray(x_hat, dtype=float), axis=0)
    final_x, final_e = float(nx[-1]), float(ne[-1])
    ok = finished and np.all(np.isfinite(nx)) and np.all(np.isfinite(ne))
    conv = bool(
        ok
        and final_x <= CONVERGED_RATIO * max(float(nx.max()), 1e-300)
        and final_e <= CONVERGED_RATIO * max(float(ne.max()), 1e-300)
    )
    iae = float(np.sum((ne[1:] + ne[:-1]) * np.diff(t)) / 2) if t.size > 1 else 0.0
    sx = settling_time(t, nx) if ok else math.nan
    se = settling_time(t, ne) if ok else math.nan
    if noisy:
        conv = bool(ok and math.isfinite(sx) and math.isfinite(se))
    tail = t >= t[0] + (t[-1] - t[0]) / 2
    rms = float(np.sqrt(np.mean(ne[tail] ** 2))) if ok else math.nan
    return {
        "converged": conv,
        "settling_x_s": sx,
        "settling_e_s": se,
        "final_x": final_x,
        "final_e": final_e,
        "iae_e": iae,
        "rms_e": rms,
        "peak_u": float(np.max(np.abs(u))) if np.size(u) else math.nan,
    }
