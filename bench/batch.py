"""Vectorised closed-loop simulation of a batch of initial conditions (continuous and digital).

Continuous (:func:`simulate_batch`): the loop (6) for N initial conditions is one ODE of size
``2 n N`` (layout ``(n, 2N) = [x_1 .. x_N, x_hat_1 .. x_hat_N]``, f evaluated once on the whole
batch) and one ``solve_ivp`` call; the step size is shared, chosen from the RMS of the scaled
errors of all members. A member that blows up (``||z_j||`` above ``blowup * max(1, ||z_j(0)||)``,
or non-finite) is frozen (derivative zero) and reported ``diverged``.

A discrete-time plant (``dt > 0``) is stepped by :func:`simulate_batch` (no ODE): ``z_{k+1} = L z_k + (f(x_k),
f(x_hat_k))`` for the whole batch, ``L`` the loop matrix.

Digital (:func:`simulate_digital_batch`, continuous plants only): controller and observer at the sample period h, the
plant continuous. At ``t_k = k h``, ``y_k = C x(t_k)`` is read, ``u_k = F x_hat_k`` held, and the
observer advances by

- ``"zoh"``: ``x_hat' = A x_hat + f(x_hat) + B u_k + K (y_k - C x_hat_k)`` integrated over the
  period (for a linear plant the exact discretisation ``x_hat_{k+1} = e^{Ah} x_hat_k + Gamma (B u_k
  + K (y_k - C x_hat_k))``, ``Gamma = int_0^h e^{As} ds``);
- ``"euler"``: ``x_hat_{k+1} = x_hat_k + h (A x_hat_k + B u_k + f(x_hat_k) + K (y_k - C x_hat_k))``.

Between samples the plant (and the ``"zoh"`` observer) is integrated by RK4 with ``ceil(h / dt_max)``
sub-steps, ``dt_max = min(5e-3, 0.1 / rho(A))`` by default.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from bench import checks
from bench.metrics import batch_metrics
from bench.simulate import Budget, SimOptions, choose_method, integrate, loop_matrix

__all__ = ["simulate_batch", "simulate_digital_batch"]


@dataclass
class BatchTrajectory:
    """A batch of closed-loop trajectories on a common time grid: ``t`` (T,), ``x``, ``x_hat`` (n, N, T)
    (column j from initial condition j), ``diverged`` (N,) (members frozen after blowing up), ``status``
    (``"ok"``, or why the integrator stopped, with ``message``), ``wall_s``, ``nfev`` (right-hand sides on
    the whole batch), ``method`` (continuous batches) and ``u = F x_hat`` (m, N, T)."""

    t: np.ndarray
    x: np.ndarray
    x_hat: np.ndarray
    diverged: np.ndarray
    status: str
    message: str
    wall_s: float
    nfev: int
    method: str = ""
    u: np.ndarray | None = None

    @property
    def e(self) -> np.ndarray:
        """Estimation errors ``x - x_hat``, (n, N, T)."""
        return self.x - self.x_hat

    def metrics(self, *, noisy: bool = False) -> dict[str, np.ndarray]:
        """Per-member metrics (:func:`bench.metrics.batch_metrics`)."""
        return batch_metrics(self.t, self.x, self.x_hat, self.u, finished=self.status == "ok",
                             diverged=self.diverged, noisy=noisy)


def _check_inputs(plant, K, F, x0, x_hat0, t_final):
    """``K, F, X, XH, T``: gains, initial conditions as (n, N) arrays and horizon, checked (ValueError)."""
    K, F = checks.gains(plant, K, F)
    n = plant.n
    X, XH = (np.asarray(v, dtype=float) for v in (x0, x_hat0))
    X, XH = (v[:, None] if v.ndim == 1 else v for v in (X, XH))
    if X.ndim != 2 or X.shape[0] != n or X.shape[1] < 1:
        raise ValueError(f"x0: expected shape ({n}, N) with N >= 1, got {np.shape(x0)}")
    if XH.shape != X.shape:
        raise ValueError(f"x_hat0: expected shape {X.shape} like x0, got {np.shape(x_hat0)}")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(XH))):
        raise ValueError("x0, x_hat0: initial conditions must be finite")
    return K, F, X, XH, checks.horizon(t_final, default=plant.t_final)


def _norms(x: np.ndarray, xh: np.ndarray) -> np.ndarray:
    """``||z_j|| = sqrt(||x_j||^2 + ||x_hat_j||^2)`` of every member (columns; further axes kept)."""
    return np.sqrt(np.sum(x * x, axis=0) + np.sum(xh * xh, axis=0))


def _batch_sparsity(n: int, N: int):
    """Sparsity of the batch Jacobian: member j couples ``x[:, j]`` and ``x_hat[:, j]`` only."""
    import scipy.sparse as sp

    j = np.arange(N)[:, None]
    i = np.arange(n)[None, :]
    idx = np.concatenate([i * 2 * N + j, i * 2 * N + N + j], axis=1)  # (N, 2n) flat indices of member j
    rows = np.repeat(idx, 2 * n, axis=1).ravel()
    cols = np.tile(idx, (1, 2 * n)).ravel()
    return sp.csc_matrix((np.ones(rows.size), (rows, cols)), shape=(2 * n * N, 2 * n * N))


#: The batch's default integration settings (looser than a single trajectory's).
BATCH_OPTIONS = SimOptions(rtol=1e-6, atol=1e-9, n_points=401)


def simulate_batch(
    plant,
    K: np.ndarray,
    F: np.ndarray,
    x0: np.ndarray,
    x_hat0: np.ndarray,
    *,
    t_final: float | None = None,
    options: SimOptions = BATCH_OPTIONS,
) -> BatchTrajectory:
    """Simulate the continuous closed loop (6) from N initial conditions with one ODE solve.

    Parameters
    ----------
    plant : Plant
        Its ``f`` must accept an ``(n, M)`` batch (every registered plant's does).
    K, F : ndarray
        Observer gain (n x p) and feedback (m x n), ``u = F x_hat``.
    x0, x_hat0 : ndarray (n, N)
        Initial states and estimates (a single ``(n,)`` vector is a batch of one).
    t_final : float, optional
        Horizon (default ``plant.t_final``).
    options : SimOptions
        As for :func:`bench.simulate.simulate`; ``method="auto"`` gives BDF for a stiff loop, and
        implicit methods get the batch's block-diagonal ``jac_sparsity``.

    Returns
    -------
    BatchTrajectory
        For a discrete-time plant (``dt > 0``) the loop is stepped instead (:func:`_stepped_batch`).
    """
    K, F, X, XH, T = _check_inputs(plant, K, F, x0, x_hat0, t_final)
    if plant.discrete:
        return _stepped_batch(plant, K, F, X, XH, T)
    n, N = X.shape
    limit = options.blowup * np.maximum(1.0, _norms(X, XH))
    rhs = _BatchRHS(plant, K, F, N, limit, options)
    method = choose_method(plant, K, F, T) if options.method == "auto" else options.method
    extra = {"jac_sparsity": _batch_sparsity(n, N)} if method in ("BDF", "Radau") else {}
    Y0 = np.concatenate([X, XH], axis=1)
    t0 = time.perf_counter()
    sol, t_out, y, status, message = integrate(rhs, Y0.ravel(), T, method, options, **extra)
    wall = time.perf_counter() - t0
    nfev = rhs.count if sol is None else int(sol.nfev)
    Yt = y.reshape(n, 2 * N, -1)
    xs, xhs = Yt[:, :N], Yt[:, N:]
    diverged = ~np.all(_norms(xs, xhs) <= limit[:, None], axis=1)
    return BatchTrajectory(t_out, xs, xhs, diverged, status, message, wall, nfev, method,
                           u=np.einsum("mi,ijk->mjk", F, xhs))


class _BatchRHS(Budget):
    """Right-hand side of the batch loop (6), freezing the members above their limit; stops at the budgets."""

    def __init__(self, plant, K: np.ndarray, F: np.ndarray, N: int, limit: np.ndarray, options: SimOptions):
        super().__init__(options)
        L = loop_matrix(plant, K, F)  # [x'; x_hat'] = Px x + Ph x_hat
        self.Px, self.Ph = np.ascontiguousarray(L[:, :plant.n]), np.ascontiguousarray(L[:, plant.n:])
        self.f, self.n, self.N, self.limit = plant.f, plant.n, N, limit
        self.fast2 = float(limit.min()) ** 2  # while ||y||^2 <= fast2, no member can exceed its limit

    def __call__(self, t, y):
        self.spend(t)
        n, N = self.n, self.N
        Y = y.reshape(n, 2 * N)
        x, xh = Y[:, :N], Y[:, N:]
        lin = self.Px @ x + self.Ph @ xh  # (2n, N)
        dY = np.asarray(self.f(Y), dtype=float) + np.hstack([lin[:n], lin[n:]])
        if not (y @ y) <= self.fast2:  # rare path (also taken on NaN): freeze the members that blew up
            frozen = ~(_norms(x, xh) <= self.limit)
            if frozen.any():
                dY[:, :N][:, frozen] = 0.0
                dY[:, N:][:, frozen] = 0.0
        return dY.ravel()


DISCRETISATIONS = ("zoh", "euler")

#: At most this many sample instants of a digital batch are recorded.
MAX_RECORDS = 4001


def simulate_digital_batch(
    plant,
    K: np.ndarray,
    F: np.ndarray,
    x0: np.ndarray,
    x_hat0: np.ndarray,
    *,
    h: float,
    t_final: float | None = None,
    discretisation: str = "zoh",
) -> BatchTrajectory:
    """Simulate the sampled-data loop (discrete observer and controller at period h, continuous plant).

    Parameters
    ----------
    plant : Plant
    K, F : ndarray
        Continuous-time gains (n x p, m x n).
    x0, x_hat0 : ndarray (n, N)
    h : float
        Sample period (> 0); the run covers ``ceil(t_final / h)`` periods.
    t_final : float, optional
        Horizon (default ``plant.t_final``).
    discretisation : {"zoh", "euler"}
        Observer discretisation.

    Returns
    -------
    BatchTrajectory
        At most :data:`MAX_RECORDS` sample instants (evenly strided, the last one always; ``x_hat`` the
        estimate used there); members above ``1e6 max(1, ||z_j(0)||)`` are frozen and reported diverged.
    """
    K, F, X, XH, T = _check_inputs(plant, K, F, x0, x_hat0, t_final)
    if plant.discrete:
        raise ValueError(f"plant {plant.id!r} is discrete-time (dt = {plant.dt:g} s): a digital controller samples a "
                         "continuous-time plant; simulate a discrete plant with simulate_batch (stepped)")
    checks.real("h", h, lo=0.0, strict=True)
    if discretisation not in DISCRETISATIONS:
        raise ValueError(f"discretisation: must be one of {DISCRETISATIONS}, got {discretisation!r}")
    rho = float(np.abs(np.linalg.eigvals(plant.A)).max())
    dt_max = min(5e-3, 0.1 / rho) if rho > 0 else 5e-3
    n_steps, n_sub = max(1, math.ceil(T / h - 1e-9)), max(1, math.ceil(h / dt_max - 1e-9))
    loop = _DigitalLoop(plant, K, F, h, n_sub, zoh=discretisation == "zoh")
    stride = math.ceil((n_steps + 1) / MAX_RECORDS)
    rec_idx = sorted({*range(0, n_steps + 1, stride), n_steps})
    limit = 1e6 * np.maximum(1.0, np.linalg.norm(np.vstack([X, XH]), axis=0))
    t0 = time.perf_counter()
    xs, xhs, diverged, nfev = _march(loop, X, XH, n_steps, rec_idx, limit)
    wall = time.perf_counter() - t0
    t = np.array([kk * h for kk in rec_idx])
    return BatchTrajectory(t, xs, xhs, diverged, "ok", "", wall, nfev, u=np.einsum("mi,ijk->mjk", F, xhs))


def _stepped_batch(plant, K: np.ndarray, F: np.ndarray, X: np.ndarray, XH: np.ndarray, T: float) -> BatchTrajectory:
    """The loop of a discrete-time plant stepped for a batch: ``ceil(T / dt)`` steps of
    ``x_{k+1} = A x_k + B F x_hat_k + f(x_k)``, ``x_hat_{k+1} = A x_hat_k + B F x_hat_k + f(x_hat_k) + K C (x_k -
    x_hat_k)``, at most :data:`MAX_RECORDS` instants recorded, members above ``1e6 max(1, ||z_j(0)||)`` frozen."""
    from bench.simulate import discrete_steps

    n_steps = discrete_steps(plant.dt, T)
    stride = math.ceil((n_steps + 1) / MAX_RECORDS)
    rec_idx = sorted({*range(0, n_steps + 1, stride), n_steps})
    limit = 1e6 * np.maximum(1.0, np.linalg.norm(np.vstack([X, XH]), axis=0))
    t0 = time.perf_counter()
    xs, xhs, diverged, nfev = _march(_SteppedLoop(plant, K, F), X, XH, n_steps, rec_idx, limit)
    wall = time.perf_counter() - t0
    t = np.array([kk * plant.dt for kk in rec_idx])
    return BatchTrajectory(t, xs, xhs, diverged, "ok", "", wall, nfev, method="stepped",
                           u=np.einsum("mi,ijk->mjk", F, xhs))


class _SteppedLoop:
    """One step of a discrete-time plant's loop for a batch (:func:`_stepped_batch`)."""

    def __init__(self, plant, K: np.ndarray, F: np.ndarray):
        L = loop_matrix(plant, K, F)  # z_{k+1} = L z_k + (f(x_k), f(x_hat_k))
        self.Px, self.Ph, self.f, self.n = L[:, :plant.n], L[:, plant.n:], plant.f, plant.n

    def advance(self, x: np.ndarray, xh: np.ndarray, a) -> int:
        """Step the members ``a`` of ``x`` and ``x_hat`` once, in place; one evaluation of f on the batch."""
        n, xa, xha = self.n, x[:, a], xh[:, a]
        M = xa.shape[1]
        nl = np.asarray(self.f(np.concatenate([xa, xha], axis=1)), dtype=float)
        lin = self.Px @ xa + self.Ph @ xha
        x[:, a], xh[:, a] = lin[:n] + nl[:, :M], lin[n:] + nl[:, M:]
        return 1


def _march(loop: "_DigitalLoop", X: np.ndarray, XH: np.ndarray, n_steps: int, rec_idx: list[int],
           limit: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Advance ``n_steps`` periods: recorded states and estimates, diverged members, right-hand sides spent."""
    rec_pos = {k: i for i, k in enumerate(rec_idx)}
    n, N = X.shape
    xs = np.empty((n, N, len(rec_idx)))
    xhs = np.empty((n, N, len(rec_idx)))
    active = np.ones(N, dtype=bool)
    x, xh = X.copy(), XH.copy()
    nfev = 0
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(n_steps + 1):
            if k in rec_pos:
                xs[:, :, rec_pos[k]] = x
                xhs[:, :, rec_pos[k]] = xh
            active &= _norms(x, xh) <= limit
            if k == n_steps or not active.any():
                later = [i for kk, i in rec_pos.items() if kk > k]  # everything diverged: the frozen state
                xs[:, :, later] = x[:, :, None]
                xhs[:, :, later] = xh[:, :, None]
                break
            nfev += loop.advance(x, xh, active if not active.all() else slice(None))
    return xs, xhs, ~active | ~(_norms(x, xh) <= limit), nfev


class _DigitalLoop:
    """One period of the sampled-data loop for a batch (module docstring)."""

    def __init__(self, plant, K: np.ndarray, F: np.ndarray, h: float, n_sub: int, *, zoh: bool):
        self.A, self.B, self.C, self.f = plant.A, plant.B, plant.C, plant.f
        self.K, self.F, self.h, self.n_sub, self.zoh = K, F, h, n_sub, zoh
        self.dt = h / n_sub

    def rk4(self, S: np.ndarray, W: np.ndarray) -> np.ndarray:
        """n_sub RK4 steps of S' = A S + f(S) + W on an (n, M) batch, W held."""
        A, f, dt = self.A, self.f, self.dt
        for _ in range(self.n_sub):
            k1 = A @ S + f(S) + W
            k2 = A @ (S2 := S + (0.5 * dt) * k1) + f(S2) + W
            k3 = A @ (S3 := S + (0.5 * dt) * k2) + f(S3) + W
            k4 = A @ (S4 := S + dt * k3) + f(S4) + W
            S = S + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        return S

    def advance(self, x: np.ndarray, xh: np.ndarray, a) -> int:
        """Advance the members ``a`` of ``x`` and ``x_hat`` by one period, in place; the right-hand sides spent."""
        xa, xha = x[:, a], xh[:, a]
        M = xa.shape[1]
        Bu = self.B @ (self.F @ xha)
        inj = self.K @ (self.C @ (xa - xha))
        if self.zoh:  # plant and observer model together, layout (n, 2M) = [x | x_hat]
            S = self.rk4(np.concatenate([xa, xha], axis=1), np.concatenate([Bu, Bu + inj], axis=1))
            x[:, a], xh[:, a] = S[:, :M], S[:, M:]
            return 4 * self.n_sub
        xh_next = xha + self.h * (self.A @ xha + Bu + np.asarray(self.f(xha), dtype=float) + inj)
        x[:, a] = self.rk4(xa, Bu)
        xh[:, a] = xh_next
        return 4 * self.n_sub + 1


def digital_matrix(A: np.ndarray, B: np.ndarray, C: np.ndarray, K: np.ndarray, F: np.ndarray, h: float,
                   discretisation: str = "zoh") -> np.ndarray:
    """The one-period matrix of the sampled loop for a linear plant, ``(x, x_hat)_{k+1} = Phi (x, x_hat)_k``.

    ``"zoh"``: ``Phi = [[Ad, G B F], [G K C, Ad + G B F - G K C]]``, ``Ad = e^{Ah}``,
    ``G = int_0^h e^{As} ds`` (from ``expm([[A, I], [0, 0]] h)``); ``"euler"``: the observer row is
    ``[h K C, I + h (A + B F - K C)]``. With ``A + df/dx(0)`` the spectral radius of Phi decides local
    exponential stability of the sampled loop's origin.
    """
    from scipy.linalg import expm

    n = A.shape[0]
    E = expm(np.block([[A, np.eye(n)], [np.zeros((n, 2 * n))]]) * h)
    Ad, G = E[:n, :n], E[:n, n:]
    BF, KC = B @ F, K @ C
    top = np.hstack([Ad, G @ BF])
    if discretisation == "zoh":
        bot = np.hstack([G @ KC, Ad + G @ BF - G @ KC])
    elif discretisation == "euler":
        bot = np.hstack([h * KC, np.eye(n) + h * (A + BF - KC)])
    else:
        raise ValueError(f"discretisation: must be one of {DISCRETISATIONS}, got {discretisation!r}")
    return np.vstack([top, bot])
