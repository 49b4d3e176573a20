"""Disturbances and measured attenuation: the seeded L2 disturbance of ``--disturbance`` and the ratios
``||e||_L2 / ||w||_L2``, ``||x||_L2 / ||w||_L2`` of a run.

The disturbance of a plant with ``q`` disturbance inputs (``Bw``, ``Dw``), amplitude ``a`` and window
``T_w``: each channel ``j`` is, for ``0 <= t <= T_w``,

    w_j(t) = a * s_j(t) / max |s_j|,    s_j(t) = sin(pi t / T_w)^2 * sum_{i=1}^{M} sin(omega_ij t + phi_ij),

and 0 after ``T_w`` (a Hann window: w and its derivative are continuous and vanish at both ends, so w is in
L2 and the integrator sees a smooth input). ``M = 8`` components; the frequencies ``omega_ij`` are drawn
log-uniformly from ``[2 pi / T_w, 60 pi / T_w]`` rad/s (1 to 30 cycles over the window; for a discrete plant
at most a quarter of the sampling frequency, ``pi / (2 dt)``), the phases uniformly from ``[0, 2 pi)``,
by ``numpy.random.default_rng([seed, 32])``; ``max |s_j|`` is taken on 10001 points of ``[0, T_w]``, so
the peak of each channel is ``a`` (to that grid). The same seed gives the same w for every design of a
plant. The pipeline uses ``T_w`` = half the plant's horizon (:func:`window`).

The measured attenuation (:func:`measured_attenuation`) comes from a run that starts at ``z(0) = 0``
(``x0 = x_hat0 = 0``): then every L2 gain ``g`` certified from w to ``zeta`` bounds the ratio,
``||zeta||_L2 <= g ||w||_L2``, so a larger measured ratio contradicts the certificate
(:func:`bench.verdicts.attenuation_note`). The norms are integrated on the trajectory's grid: the
trapezoidal rule in continuous time, ``sum_k |v_k|^2 dt`` in discrete time. Over a finite horizon the
ratio is a lower bound of the loop's L2 gain.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bench import checks

__all__ = ["SeededDisturbance", "l2_norm", "measured_attenuation", "window"]

#: Sinusoids per channel.
COMPONENTS = 8
#: Highest frequency, in cycles over the window.
MAX_CYCLES = 30.0
#: Points of [0, T_w] on which each channel is normalised to its amplitude.
NORM_POINTS = 10001


def window(t_plant: float, fixed: float | None = None) -> float:
    """The disturbance window ``T_w`` of a plant: half its horizon ``t_plant`` (or of a ``fixed`` horizon
    shorter than it), so the response has at least as long again to decay within every pair's horizon."""
    T = float(t_plant) if fixed is None else min(float(t_plant), float(fixed))
    return T / 2


@dataclass(frozen=True)
class SeededDisturbance:
    """The seeded disturbance ``w(t)`` of the module docstring; ``w(t)`` for a scalar t is shape (q,), for
    an array of times (N,) shape (q, N).

    Parameters
    ----------
    amplitude : float
        Peak of each channel (>= 0).
    q : int
        Number of channels (the plant's disturbance inputs).
    t_window : float
        ``T_w`` in seconds: w vanishes after it.
    seed : int
    dt : float
        The plant's sample time (0: continuous): caps the frequencies at ``pi / (2 dt)``.
    """

    amplitude: float
    q: int
    t_window: float
    seed: int = 0
    dt: float = 0.0

    def __post_init__(self) -> None:
        checks.real("amplitude", self.amplitude, lo=0.0)
        checks.integer("q", self.q, lo=1)
        checks.real("t_window", self.t_window, lo=0.0, strict=True)
        checks.real("dt", self.dt, lo=0.0)
        rng = np.random.default_rng([int(self.seed), 32])
        lo, hi = 2 * math.pi / self.t_window, 2 * math.pi * MAX_CYCLES / self.t_window
        if self.dt > 0:
            hi = min(hi, math.pi / (2 * self.dt))
            lo = min(lo, hi)
        omega = np.exp(rng.uniform(math.log(lo), math.log(hi), (self.q, COMPONENTS)))
        phase = rng.uniform(0.0, 2 * math.pi, (self.q, COMPONENTS))
        object.__setattr__(self, "omega", omega)
        object.__setattr__(self, "phase", phase)
        peak = np.abs(self._shape(np.linspace(0.0, self.t_window, NORM_POINTS))).max(axis=1)
        object.__setattr__(self, "scale", np.where(peak > 0, self.amplitude / np.maximum(peak, 1e-300), 0.0))

    def _shape(self, t: np.ndarray) -> np.ndarray:
        """``s_j(t)`` (q, N) on ``[0, T_w]``, 0 outside."""
        t = np.asarray(t, dtype=float)
        inside = (t >= 0) & (t <= self.t_window)
        hann = np.where(inside, np.sin(math.pi * t / self.t_window) ** 2, 0.0)
        waves = np.sin(self.omega[:, :, None] * t[None, None, :] + self.phase[:, :, None]).sum(axis=1)
        return hann[None, :] * waves

    def __call__(self, t):
        scalar = np.ndim(t) == 0
        if scalar:  # an integrator's call, ~10^5 a run: the numbers of the array path on [t], bit for bit
            t = float(t)
            if not 0.0 <= t <= self.t_window:
                return np.zeros(self.q)
            # a one-element array, not a scalar: numpy's sine of a 0-d value can differ in the last bit
            hann = np.sin(np.array([math.pi * t / self.t_window])) ** 2
            return self.scale * (hann * np.sin(self.omega * t + self.phase).sum(axis=1))
        T = np.atleast_1d(np.asarray(t, dtype=float))
        out = self.scale[:, None] * self._shape(T)
        return out[:, 0] if scalar else out


def l2_norm(t: np.ndarray, v: np.ndarray, dt: float = 0.0) -> float:
    """``||v||_L2`` of the samples ``v`` (k, N) at the times ``t`` (N,): the trapezoidal rule of ``|v|^2``
    (``dt = 0``) or ``sqrt(sum_k |v_k|^2 dt)`` (a discrete-time signal, ``dt > 0``)."""
    v = np.asarray(v, dtype=float)
    sq = np.sum(v * v, axis=0) if v.ndim == 2 else v * v
    if dt > 0:
        return float(math.sqrt(float(np.sum(sq)) * dt))
    t = np.asarray(t, dtype=float)
    if t.size < 2:
        return 0.0
    return float(math.sqrt(float(np.sum((sq[1:] + sq[:-1]) * np.diff(t)) / 2)))


def measured_attenuation(t: np.ndarray, x: np.ndarray, x_hat: np.ndarray, w: np.ndarray,
                         dt: float = 0.0) -> tuple[float, float]:
    """``(||e||_L2 / ||w||_L2, ||x||_L2 / ||w||_L2)`` of a run (from ``z(0) = 0`` to be compared with a
    certified gain), on its grid ``t`` (:func:`l2_norm`); NaN when ``||w||_L2 = 0``.

    Parameters
    ----------
    t : ndarray (N,)
    x, x_hat : ndarray (n, N)
    w : ndarray (q, N)
        The disturbance at the times ``t``.
    dt : float
        The plant's sample time (0: continuous).

    Returns
    -------
    ratio_e, ratio_x : float
    """
    x = np.asarray(x, dtype=float)
    nw = l2_norm(t, w, dt)
    if not nw > 0:
        return math.nan, math.nan
    return l2_norm(t, x - np.asarray(x_hat, dtype=float), dt) / nw, l2_norm(t, x, dt) / nw
