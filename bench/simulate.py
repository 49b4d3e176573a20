"""Closed-loop simulation of plant (1) with the observer-based controller (6).

States ``z = (x, x_hat)`` (2n), ``u = F x_hat``::

    x'     = A x + B F x_hat + f(x)
    x_hat' = A x_hat + B F x_hat + f(x_hat) + K C (x - x_hat)

integrated with scipy's ``solve_ivp``. A discrete-time plant (``plant.dt > 0``) is stepped instead, no ODE
solver (:func:`simulate_controller` dispatches on ``plant.dt``)::

    x_{k+1}     = A x_k + B u_k + f(x_k) (+ Bw w_k),    y_k = C x_k (+ Dw w_k) (+ v_k),    u_k = F x_hat_k
    x_hat_{k+1} = A x_hat_k + B u_k + f(x_hat_k) + K (y_k - C x_hat_k)

A run stops with status ``"diverged"`` (non-finite, or ``||z||`` above ``blowup * max(1, ||z(0)||)``),
``"budget"`` (``max_nfev`` right-hand sides, or steps) or ``"timeout"`` (``max_wall_s`` seconds).

A disturbance ``w(t)`` (a callable returning shape (q,), :mod:`bench.disturbance`) enters as
``x' = ... + Bw w``, ``y = C x + Dw w``; a discrete plant takes ``w_k = w(k dt)``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from bench import checks
from bench.errors import SimulationStopped as _Stop
from plants import Plant

__all__ = ["SimOptions", "Trajectory", "discrete_steps", "disturbance_input", "simulate", "simulate_controller"]


@dataclass(frozen=True, kw_only=True)
class SimOptions:
    """Integration settings.

    Parameters
    ----------
    method : str
        ``solve_ivp`` method, or ``"auto"`` (:func:`choose_method`).
    rtol, atol : float
        Tolerances.
    n_points : int
        Output grid size (uniform on [0, t_final]).
    blowup : float
        Divergence threshold on ``||z|| / max(1, ||z(0)||)``.
    max_nfev : int
        Budget of right-hand-side evaluations.
    max_wall_s : float, optional
        Wall-clock budget in seconds (None: none).
    """

    method: str = "auto"
    rtol: float = 1e-8
    atol: float = 1e-12
    n_points: int = 2001
    blowup: float = 1e6
    max_nfev: int = 2_000_000
    max_wall_s: float | None = None

    def __post_init__(self) -> None:
        checks.horizon(self.max_wall_s, name="max_wall_s")
        for name in ("rtol", "atol", "blowup"):
            checks.real(name, getattr(self, name), lo=0.0, strict=True)
        checks.integer("n_points", self.n_points, lo=2)
        checks.integer("max_nfev", self.max_nfev, lo=1)


@dataclass
class Trajectory:
    """A simulated closed loop: ``t`` (N,), ``x``, ``x_hat`` (n, N), ``u`` (m, N), ``status`` (``"ok"``,
    ``"diverged"``, ``"budget"``, ``"timeout"`` or ``"failed"``), ``message``, ``wall_s``, ``nfev``, and the
    integrator's ``dense`` output ``z(t) = (x, x_hat)`` (a scipy ``OdeSolution``; continuous loops only)."""

    t: np.ndarray
    x: np.ndarray
    x_hat: np.ndarray
    u: np.ndarray
    status: str
    message: str
    wall_s: float
    nfev: int
    dense: object = None

    @property
    def e(self) -> np.ndarray:
        """Estimation error ``x - x_hat``."""
        return self.x - self.x_hat


#: ``method="auto"`` takes an implicit method when ``max(-Re lambda) * t_final`` of the linear loop exceeds this.
STIFF = 5000.0


def loop_matrix(plant, K: np.ndarray, F: np.ndarray) -> np.ndarray:
    """The linear part ``[[A, BF], [KC, A + BF - KC]]`` of the closed loop (6) in ``z = (x, x_hat)``."""
    A, B, C = plant.A, plant.B, plant.C
    BF, KC = B @ F, K @ C
    return np.block([[A, BF], [KC, A + BF - KC]])


def choose_method(plant, K: np.ndarray, F: np.ndarray, t_final: float, stiff: str = "BDF",
                  loop: checks.ClosedLoop | None = None) -> str:
    """The ``solve_ivp`` method for the closed loop (6): ``stiff`` if its linear part is stiff, else DOP853.

    Stiff: ``max(-Re lambda) * t_final > STIFF`` over the eigenvalues of ``A + BF`` and ``A - KC``
    (those of the loop, block triangular in ``(x, e)``, or ``loop``'s spectra); an explicit method would
    need about ``STIFF / 3`` steps for stability alone (Hairer & Wanner, *Solving ODEs II*, IV.2).
    """
    A, BF, KC = plant.A, plant.B @ F, K @ plant.C
    # a norm bounds every |lambda|: no eigenvalue computed when it is small enough
    if max(np.linalg.norm(A + BF, 1), np.linalg.norm(A - KC, 1)) * t_final <= STIFF:
        return "DOP853"
    spectra = (loop.eig_x, loop.eig_e) if loop is not None else (np.linalg.eigvals(M) for M in (A + BF, A - KC))
    fast = max(float(np.max(-eig.real)) for eig in spectra)
    return stiff if fast * t_final > STIFF else "DOP853"


def _all_finite(v: np.ndarray) -> bool:
    """Whether every entry of ``v`` is finite (cheaper than ``np.all`` on small arrays)."""
    return np.count_nonzero(np.isfinite(v)) == v.size


def _finite(v: np.ndarray, t: float, what: str = "the right-hand side") -> np.ndarray:
    """``v``, or FloatingPointError when it is not finite (a NaN derivative would stall solve_ivp)."""
    if not _all_finite(v):
        raise FloatingPointError(f"{what} is not finite (t = {t:.4g} within the sample interval)")
    return v


#: From this many states on, an A at most this dense is simulated sparse (:class:`_FactoredLoop`).
SPARSE_FROM_N, SPARSE_DENSITY = 200, 0.05


class _FactoredLoop:
    """``z -> L z`` for the loop (6) with sparse A, B, C, without forming the 2n x 2n loop matrix."""

    def __init__(self, plant, K: np.ndarray, F: np.ndarray):
        import scipy.sparse as sp

        self.A, self.B, self.C = (sp.csr_matrix(M) for M in (plant.A, plant.B, plant.C))
        self.K, self.F, self.n = K, F, plant.n

    def dot(self, z: np.ndarray) -> np.ndarray:
        """``L z`` (as ``ndarray.dot``, which the right-hand sides call)."""
        return self @ z

    def __matmul__(self, z: np.ndarray) -> np.ndarray:
        n = self.n
        x, xh = z[:n], z[n:]
        Bu = self.B @ (self.F @ xh)
        return np.concatenate([self.A @ x + Bu, self.A @ xh + Bu + self.K @ (self.C @ (x - xh))])


def _loop_operator(plant, K: np.ndarray, F: np.ndarray):
    """The loop's linear part: the dense matrix, or :class:`_FactoredLoop` for a large sparse plant."""
    A = plant.A
    if plant.n >= SPARSE_FROM_N and np.count_nonzero(A) <= SPARSE_DENSITY * A.size:
        return _FactoredLoop(plant, K, F)
    return loop_matrix(plant, K, F)


class Budget:
    """Counts right-hand sides; :meth:`spend` stops the run past ``max_nfev`` or ``max_wall_s``."""

    def __init__(self, options: SimOptions):
        self.options, self.count = options, 0
        self.wall_end = None if options.max_wall_s is None else time.perf_counter() + options.max_wall_s

    def spend(self, t: float) -> None:
        self.count += 1
        options = self.options
        if self.count > options.max_nfev:
            raise _Stop("budget", f"more than {options.max_nfev} right-hand-side evaluations by t = {t:.4g}")
        if self.wall_end is not None and time.perf_counter() > self.wall_end:
            raise _Stop("timeout", f"more than {options.max_wall_s:.3g} s of wall time by t = {t:.4g}")


class _LoopRHS(Budget):
    """Right-hand side of the loop (6) in ``z = (x, x_hat)``, stopping at the budgets or a non-finite state."""

    def __init__(self, L, f, n: int, options: SimOptions):
        super().__init__(options)
        self.L, self.f, self.n = L, f, n
        # L.dot(z) is L @ z (the same BLAS call) without the dispatch of the matmul operator: the right-hand side
        # is called ~10^5 times a run, every microsecond of it counts
        self._Lz, self._pair = L.dot, (2, n)

    def __call__(self, t, z):
        self.spend(t)
        if not _all_finite(z):
            raise _Stop("diverged", f"non-finite state at t = {t:.4g}")
        nl = np.asarray(self.f(z.reshape(self._pair).T), dtype=float).T.ravel()
        return self._Lz(z) + nl


def disturbance_input(plant, K: np.ndarray | None) -> np.ndarray:
    """How a disturbance w enters the loop in ``z = (x, x_hat)``: ``[Bw; K Dw]`` (2n, q) (``y = C x + Dw w``
    reaches the observer through K); ``[Bw; 0]`` without K (a run-time estimator sees ``Dw w`` in ``y``)."""
    lower = np.zeros_like(plant.Bw) if K is None else K @ plant.Dw
    return np.vstack([plant.Bw, lower])


def _check_disturbance(plant, disturbance):
    """``disturbance`` (None or a callable ``w(t) -> (q,)``) for ``plant``; ValueError when it cannot enter."""
    if disturbance is None:
        return None
    if not callable(disturbance):
        raise ValueError(f"disturbance: expected a callable w(t) -> (q,), got {checks.brief(disturbance)}")
    if plant.q == 0:
        raise ValueError(f"disturbance: plant {plant.id!r} has no disturbance input (Bw, Dw are None)")
    w0 = np.asarray(disturbance(0.0), dtype=float)
    if w0.shape != (plant.q,):
        raise ValueError(f"disturbance: w(0) must have shape ({plant.q},) (the plant's q), got {w0.shape}")
    return disturbance


class _DisturbedRHS(_LoopRHS):
    """:class:`_LoopRHS` plus ``Bd w(t)``, ``Bd`` from :func:`disturbance_input`."""

    def __init__(self, L, f, n: int, options: SimOptions, Bd: np.ndarray, w):
        super().__init__(L, f, n, options)
        self.Bd, self.w = Bd, w

    def __call__(self, t, z):
        return super().__call__(t, z) + self.Bd.dot(np.asarray(self.w(t), dtype=float))


def simulate(
    plant: Plant,
    K: np.ndarray,
    F: np.ndarray,
    *,
    t_final: float | None = None,
    x0: np.ndarray | None = None,
    x_hat0: np.ndarray | None = None,
    options: SimOptions = SimOptions(),
    loop: checks.ClosedLoop | None = None,
    disturbance=None,
) -> Trajectory:
    """Simulate the nonlinear closed loop plant + observer (6) from the plant's initial conditions.

    Parameters
    ----------
    plant : Plant
    K, F : ndarray
        Observer gain (n x p) and feedback (m x n), ``u = F x_hat``.
    t_final : float, optional
        Horizon (default ``plant.t_final``).
    x0, x_hat0 : ndarray, optional
        Initial conditions (default the plant's).
    options : SimOptions
    loop : ClosedLoop, optional
        The checked gains and their spectra (:func:`bench.checks.closed_loop`).
    disturbance : callable, optional
        ``w(t) -> (q,)``: ``x' = ... + Bw w``, ``y = C x + Dw w`` (the plant needs ``Bw``, ``Dw``).

    Returns
    -------
    Trajectory
        Truncated where the run stopped.

    Raises
    ------
    ValueError
        For a discrete-time plant (:func:`simulate_controller` steps those), bad gains or disturbance.
    """
    if plant.discrete:
        raise ValueError(f"plant {plant.id!r} is discrete-time (dt = {plant.dt:g} s): simulate it with "
                         "simulate_controller, which steps it")
    n = plant.n
    K, F = (loop.K, loop.F) if loop is not None else checks.gains(plant, K, F)
    T = checks.horizon(t_final, default=plant.t_final)
    x0 = np.asarray(plant.x0 if x0 is None else x0, dtype=float)
    xh0 = np.asarray(plant.x_hat0 if x_hat0 is None else x_hat0, dtype=float)
    z0 = np.concatenate([x0, xh0])
    w = _check_disturbance(plant, disturbance)
    if w is None:
        rhs = _LoopRHS(_loop_operator(plant, K, F), plant.f, n, options)
    else:
        rhs = _DisturbedRHS(_loop_operator(plant, K, F), plant.f, n, options, disturbance_input(plant, K), w)
    limit = options.blowup * max(1.0, float(np.linalg.norm(z0)))

    def blowup(t, z):  # a terminal event
        return np.linalg.norm(z) - limit

    blowup.terminal = True
    t0 = time.perf_counter()
    method = choose_method(plant, K, F, T, stiff="Radau", loop=loop) if options.method == "auto" else options.method
    sol, t_out, z, status, message = integrate(rhs, z0, T, method, options, events=blowup, dense_output=True)
    if sol is not None and sol.status == 1:
        status, message = "diverged", f"||z|| exceeded {limit:.3g} at t = {sol.t_events[0][0]:.4g}"
    elif status == "ok" and not np.all(np.isfinite(z)):
        status, message = "diverged", "non-finite state"
    wall = time.perf_counter() - t0
    x, xh = z[:n], z[n:]
    return Trajectory(t_out, x, xh, F @ xh, status, message, wall, rhs.count, None if sol is None else sol.sol)


def integrate(rhs: Budget, y0: np.ndarray, T: float, method: str, options: SimOptions, **kw):
    """``solve_ivp(rhs, (0, T), y0, **kw)`` on the output grid: ``sol, t, y, status, message`` (``"ok"`` or
    ``"failed"``; ``sol`` None and ``y0`` alone when ``rhs`` stopped the run)."""
    from scipy.integrate import solve_ivp

    t_eval = np.linspace(0.0, T, int(options.n_points))
    try:
        sol = solve_ivp(rhs, (0.0, T), y0, method=method, t_eval=t_eval, rtol=options.rtol, atol=options.atol,
                        **kw)
    except _Stop as stop:
        return None, np.array([0.0]), y0[:, None], stop.status, str(stop)
    status = "ok" if sol.status == 0 else "failed"
    return sol, sol.t, sol.y, status, "" if status == "ok" else sol.message


def simulate_controller(
    plant: Plant,
    F: np.ndarray,
    *,
    K: np.ndarray | None = None,
    estimator=None,
    t_final: float,
    noise: float = 0.0,
    noise_dt: float = 0.01,
    seed: int = 0,
    options: SimOptions = SimOptions(),
    loop: checks.ClosedLoop | None = None,
    x0: np.ndarray | None = None,
    x_hat0: np.ndarray | None = None,
    disturbance=None,
) -> Trajectory:
    """Simulate an observer-based controller, whatever its estimator and the plant's time domain.

    Continuous plant: a gain ``K`` without noise: :func:`simulate`; with noise ``v_k`` held over each
    ``noise_dt`` (``y = C x + v_k``) the loop (6) stays continuous. A run-time ``estimator`` (a
    specification, or a filter with ``dt``, ``x``, ``update(y)``, ``predict(u)``) runs at its own period,
    ``u_k`` held. Sampled paths return the samples (``x_hat`` the estimate used at ``t_k``).

    Discrete plant (``plant.dt > 0``): stepped, ``N = ceil(t_final / dt)`` steps (module docstring), one
    noise sample ``v_k`` per step (``noise_dt`` is not used). A run-time estimator must have ``dt ==
    plant.dt``; at each step ``update(y_k)``, ``x_hat_k = estimator.x``, ``u_k = F x_hat_k``, then
    ``predict(u_k)``, or ``predict(u_k, x_next=A x_hat_k + B u_k + f(x_hat_k))`` for an estimator whose
    ``predicts_with_model`` is True (the simulator supplies the model's step, as it supplies the
    model's flow in continuous time).

    Parameters
    ----------
    plant : Plant
    F : ndarray (m, n)
        The feedback, ``u = F x_hat``.
    K, estimator : ndarray (n, p), or specification or estimator, optional
        Exactly one: the observer gain, or the run-time estimator.
    t_final : float
        The horizon; a sample period must divide it.
    noise, noise_dt, seed
        Measurement noise (standard deviation, >= 0), its hold period for a gain, its seed.
    options : SimOptions
    loop : ClosedLoop, optional
        As for :func:`simulate`.
    x0, x_hat0 : ndarray (n,), optional
        Initial state and estimate (default the plant's).
    disturbance : callable, optional
        ``w(t) -> (q,)`` entering through the plant's ``Bw``, ``Dw`` (:mod:`bench.disturbance`).

    Returns
    -------
    Trajectory
    """
    if (K is None) == (estimator is None):
        raise ValueError("simulate_controller: give exactly one of K and estimator")
    checks.real("noise", noise, lo=0.0)
    x0 = np.asarray(plant.x0 if x0 is None else x0, dtype=float).copy()
    x_hat0 = np.asarray(plant.x_hat0 if x_hat0 is None else x_hat0, dtype=float).copy()
    w = _check_disturbance(plant, disturbance)
    if plant.discrete:
        t_final = discrete_steps(plant.dt, t_final) * plant.dt
    if estimator is not None:
        if not hasattr(estimator, "update"):  # a specification: build the filter
            from bench.estimators import runtime_estimator

            estimator = runtime_estimator(estimator, plant, x_hat0, t_final=t_final)
        if plant.discrete:
            return _DiscreteLoop(plant, F, None, estimator, t_final, noise, seed, options, x0, x_hat0, w).run()
        return _SampledLoop(plant, F, None, estimator, estimator.dt, t_final, noise, seed, options, x0, x_hat0,
                            w).run()
    if plant.discrete:
        K, F = (loop.K, loop.F) if loop is not None else checks.gains(plant, K, F)
        return _DiscreteLoop(plant, F, K, None, t_final, noise, seed, options, x0, x_hat0, w).run()
    if noise > 0:
        return _SampledLoop(plant, F, K, None, noise_dt, t_final, noise, seed, options, x0, x_hat0, w).run()
    return simulate(plant, K, F, t_final=t_final, options=options, loop=loop, x0=x0, x_hat0=x_hat0, disturbance=w)


def discrete_steps(dt: float, t_final: float) -> int:
    """The number of steps ``N = ceil(t_final / dt)`` (at least 1) of a discrete-time run over ``t_final``."""
    checks.real("dt", dt, lo=0.0, strict=True)
    T = checks.horizon(t_final)
    return max(1, math.ceil(T / dt - 1e-9))


class _SampledLoop:
    """The sampled paths of :func:`simulate_controller`: ``N = t_final / dt`` intervals, noise drawn once."""

    #: Restart the previous interval's solver in place (:meth:`_start`) rather than build one per interval (False:
    #: the reference the tests compare with).
    reuse_solver = True

    def __init__(self, plant: Plant, F, K, estimator, dt: float, t_final: float, noise: float, seed: int,
                 options: SimOptions, x0=None, x_hat0=None, disturbance=None):
        import scipy.integrate

        checks.real("dt", dt, lo=0.0, strict=True)
        T = float(t_final)
        steps = T / dt
        if abs(steps - round(steps)) > 1e-9 * max(1.0, steps) or round(steps) < 1:
            raise ValueError(f"dt: the sample time {dt:g} must divide the horizon {T:g}")
        self.N = int(round(steps))
        self.V = noise * np.random.default_rng(seed).standard_normal((self.N + 1, plant.p))
        self.A, self.B, self.C, self.f, self.n = plant.A, plant.B, plant.C, plant.f, plant.n
        self.F = np.asarray(F, dtype=float)
        self.K = None if K is None else np.asarray(K, dtype=float)
        self.L = None if K is None else loop_matrix(plant, self.K, self.F)
        self.x0 = np.asarray(plant.x0 if x0 is None else x0, dtype=float).copy()
        self.xh0 = np.asarray(plant.x_hat0 if x_hat0 is None else x_hat0, dtype=float).copy()
        self.estimator, self.dt, self.options = estimator, dt, options
        # a disturbance w(t_k + s) over the interval starting at t_k: Bw w on the plant, K Dw w on the observer
        self.w, self.tk = disturbance, 0.0
        if disturbance is not None:
            self.Bw, self.Dw = plant.Bw, plant.Dw
            self.Bd = disturbance_input(plant, self.K)
        # "auto": RK45 for the smooth plant and model flow of an estimator, DOP853 with an observer gain
        method = options.method if options.method != "auto" else ("RK45" if estimator is not None else "DOP853")
        self.method = getattr(scipy.integrate, method) if isinstance(method, str) else method
        # scipy's explicit Runge-Kutta solvers are restarted in place at each interval (_start), others built anew
        self._restartable = self.method in (scipy.integrate.RK23, scipy.integrate.RK45, scipy.integrate.DOP853)
        self._solver = self._solver_fun = None
        self._nx2, self._pair = (self.n, 2), (2, self.n)
        self.held = None  # B u_k ((n, 1) beside the model, (n,) alone), or (0, K v_k) for the observer
        self.first = None  # the first step of the next interval (see _solve)
        self.nfev = 0

    def _w(self, t) -> np.ndarray:
        """The disturbance at ``t`` within the current interval."""
        return np.asarray(self.w(self.tk + t), dtype=float)

    # The right-hand sides: M.dot(v) is M @ v (the same BLAS call) without the matmul operator's dispatch.

    def _model_rhs(self, t, s):
        """Plant and the estimator's model flow, ``s`` the (n, 2) array ``[x, x_hat]`` raveled."""
        S = s.reshape(self._nx2)
        d = self.A.dot(S) + self.held + np.asarray(self.f(S), dtype=float)
        if self.w is not None:  # on the plant only: the model does not know w
            d[:, 0] += self.Bw.dot(self._w(t))
        return _finite(d, t).ravel()

    def _plant_rhs(self, t, s):
        """The plant alone, ``B u_k`` held."""
        d = self.A.dot(s) + self.held + self.f(s)
        return _finite(d if self.w is None else d + self.Bw.dot(self._w(t)), t)

    def _observer_rhs(self, t, s):
        """Plant and continuous observer (6) in ``z = (x, x_hat)``, the noise injection held."""
        d = self.L.dot(s) + self.held + np.asarray(self.f(s.reshape(self._pair).T), dtype=float).T.ravel()
        return _finite(d if self.w is None else d + self.Bd.dot(self._w(t)), t)

    def _start(self, fun, y0: np.ndarray):
        """The solver at the start of an interval: ``method(fun, 0, y0, dt, rtol=, atol=, first_step=first)``.

        scipy's Runge-Kutta solvers (RK23, RK45, DOP853) are built once per run (for the first interval, and
        whenever ``fun`` changes) and then put back in the state their constructor leaves with these arguments:
        building one per interval (checking the same arguments each time) took a fifth of an EKF run. The state
        the steps read is ``t``, ``y``, ``f = fun(t, y)``, ``h_abs`` (the first step) and ``status``, and the
        constants ``t_bound``, ``direction``, ``rtol``, ``atol``, ``max_step`` (the same every interval); ``K`` is
        scratch every stage writes before it is read; ``t_old``, ``y_old``, ``h_previous`` start None and
        ``nfev`` 0. ``y0`` is a finite float vector (:meth:`run` checks ``||z||`` before each interval), as the
        constructor requires. Other solvers are built per interval. The tests step both ways (``reuse_solver``)
        and compare bit for bit, so a scipy whose solvers keep other state fails them.
        """
        o, solver = self.options, self._solver
        if solver is None or self.first is None or fun != self._solver_fun or not self.reuse_solver:
            solver = self.method(fun, 0.0, y0, self.dt, rtol=o.rtol, atol=o.atol, first_step=self.first)
            if self._restartable and self.reuse_solver:
                self._solver, self._solver_fun = solver, fun
            return solver
        solver.t_old = solver.y_old = solver.h_previous = None
        solver.t, solver.y, solver.status, solver.nfev = 0.0, y0, "running", 0
        solver.f = solver.fun(0.0, y0)
        solver.h_abs = self.first  # in (0, dt]: validate_first_step's conditions
        return solver

    def _solve(self, fun, y0) -> tuple[np.ndarray, int]:
        """One interval with scipy's solver stepped directly: the end state and the right-hand sides used."""
        solver = self._start(fun, y0)
        largest = 0.0
        while solver.status == "running":
            t_prev = solver.t
            message = solver.step()
            if solver.status == "failed":
                raise FloatingPointError(f"the integrator failed within a sample interval ({message})")
            largest = max(largest, solver.t - t_prev)
        self.first = min(self.dt, 2.0 * largest) if largest > 0 else None
        return solver.y, solver.nfev

    def _step(self, x, xh, u, z, v):
        """Advance over one interval (measurement noise ``v``); count its right-hand sides."""
        est = self.estimator
        if est is None:
            self.held = np.concatenate([np.zeros(self.n), self.K.dot(v)])
            y, nfev = self._solve(self._observer_rhs, z)
            x, xh = y[:self.n], y[self.n:]
        else:
            _finite(np.asarray(self.f(xh), dtype=float), 0.0, "f at the estimate")
            bu = self.B.dot(u)
            if getattr(est, "predicts_with_model", False):  # plant and prediction: one ODE
                self.held = bu[:, None]
                s0 = np.empty(2 * self.n)  # [x, x_hat] (n, 2) raveled
                s0[0::2], s0[1::2] = x, xh
                y, nfev = self._solve(self._model_rhs, s0)
                S = y.reshape(self._nx2)
                est.predict(u, x_next=S[:, 1])  # the filter keeps a copy
                x = S[:, 0].copy()
            else:
                self.held = bu
                x, nfev = self._solve(self._plant_rhs, x)
                est.predict(u)
        self.nfev += nfev
        return x, xh

    def run(self) -> Trajectory:
        """Simulate the ``N`` intervals with the measurement noise ``V`` ((N + 1, p)); the trajectory at the samples."""
        est, C, F, dt, o, N, V = self.estimator, self.C, self.F, self.dt, self.options, self.N, self.V
        x, xh = self.x0, self.xh0
        limit = o.blowup * max(1.0, float(np.linalg.norm(np.concatenate([x, xh]))))
        ts, xs, xhs, us = [], [], [], []
        status, message = "ok", ""
        t0 = time.perf_counter()
        wall_end = None if o.max_wall_s is None else t0 + o.max_wall_s
        for k in range(N + 1):
            tk = self.tk = k * dt
            if est is not None:
                est.update(C.dot(x) + V[k] + (0.0 if self.w is None else self.Dw.dot(self._w(0.0))))
                xh = est.x
            u = F.dot(xh)
            ts.append(tk)
            xs.append(x.copy())
            xhs.append(xh.copy())
            us.append(u)
            z = np.concatenate([x, xh])
            # ||z|| as np.linalg.norm computes it (sqrt(z . z)), without its overhead
            if not math.sqrt(z.dot(z)) <= limit:  # above the limit, or not finite (a NaN norm)
                status, message = "diverged", f"||z|| exceeded {limit:.3g} (or became non-finite) at t = {tk:.4g}"
                break
            if k == N:
                break
            if wall_end is not None and time.perf_counter() > wall_end:
                status, message = "timeout", f"more than {o.max_wall_s:.3g} s of wall time by t = {tk:.4g}"
                break
            try:
                x, xh = self._step(x, xh, u, z, V[k])
            except (FloatingPointError, OverflowError, np.linalg.LinAlgError) as exc:
                status, message = "diverged", f"{type(exc).__name__} at t = {tk:.4g}: {exc}"
                break
            if self.nfev > o.max_nfev:
                status, message = "budget", f"more than {o.max_nfev} right-hand-side evaluations by t = {tk:.4g}"
                break
        wall = time.perf_counter() - t0
        return Trajectory(np.array(ts), np.array(xs).T, np.array(xhs).T, np.array(us).T, status, message, wall,
                          self.nfev)


class _DiscreteLoop:
    """The stepped loop of a discrete-time plant (module docstring): ``N = t_final / dt`` steps, noise drawn once.

    With a gain K the step is ``z_{k+1} = L z_k + (f(x_k), f(x_hat_k)) + [Bw; K Dw] w_k + (0, K v_k)`` in
    ``z = (x, x_hat)``, ``L`` the matrix :func:`loop_matrix` (the same as in continuous time: the loop (6)
    with ``z'`` read as ``z_{k+1}``). With a run-time estimator, the plant steps and the estimator updates
    and predicts (:func:`simulate_controller`).
    """

    def __init__(self, plant: Plant, F, K, estimator, t_final: float, noise: float, seed: int,
                 options: SimOptions, x0: np.ndarray, x_hat0: np.ndarray, disturbance=None):
        dt = plant.dt
        if estimator is not None and abs(float(estimator.dt) - dt) > 1e-12 * dt:
            raise ValueError(f"estimator: its sample time {float(estimator.dt):g} s differs from the discrete "
                             f"plant's dt = {dt:g} s (a discrete plant's estimator runs at the plant's steps)")
        self.N = discrete_steps(dt, t_final)
        # the same stream as the continuous sampled paths: v_k ~ N(0, noise^2 I), one per sample
        self.V = noise * np.random.default_rng(seed).standard_normal((self.N + 1, plant.p))
        self.plant, self.dt, self.options, self.estimator = plant, dt, options, estimator
        self.F = np.asarray(F, dtype=float)
        self.K = None if K is None else np.asarray(K, dtype=float)
        self.x0, self.xh0 = x0, x_hat0
        self.W = None
        if disturbance is not None:
            self.W = np.array([np.asarray(disturbance(k * dt), dtype=float) for k in range(self.N + 1)])

    def run(self) -> Trajectory:
        """Step ``N`` times; the trajectory at every step ``t_k = k dt``."""
        p, o, N, dt = self.plant, self.options, self.N, self.dt
        n, A, B, C, f = p.n, p.A, p.B, p.C, p.f
        F, K, est, V, W = self.F, self.K, self.estimator, self.V, self.W
        X = np.full((n, N + 1), np.nan)
        XH = np.full((n, N + 1), np.nan)
        U = np.full((p.m, N + 1), np.nan)
        x, xh = self.x0.copy(), self.xh0.copy()
        limit = o.blowup * max(1.0, float(np.linalg.norm(np.concatenate([x, xh]))))
        if K is not None:
            L = loop_matrix(p, K, F)
            inject = np.vstack([np.zeros((n, p.p)), K])  # (0, K v_k)
            Bd = disturbance_input(p, K) if W is not None else None
        status, message, steps = "ok", "", 0
        t0 = time.perf_counter()
        wall_end = None if o.max_wall_s is None else t0 + o.max_wall_s
        z = np.concatenate([x, xh])
        k = 0
        for k in range(N + 1):
            if est is not None:
                y = C @ x + V[k] + (0.0 if W is None else p.Dw @ W[k])
                est.update(y)
                xh = est.x
                z = np.concatenate([x, xh])
            u = F @ xh
            X[:, k], XH[:, k], U[:, k] = x, xh, u
            if not np.linalg.norm(z) <= limit:  # above the limit, or not finite (a NaN norm)
                status, message = "diverged", f"||z|| exceeded {limit:.3g} (or became non-finite) at t = {k * dt:.4g}"
                break
            if k == N:
                break
            if wall_end is not None and time.perf_counter() > wall_end:
                status, message = "timeout", f"more than {o.max_wall_s:.3g} s of wall time by t = {k * dt:.4g}"
                break
            try:
                if K is not None:
                    nl = np.asarray(f(np.stack([x, xh], axis=1)), dtype=float)  # one batch call: f(x), f(x_hat)
                    z = L @ z + np.concatenate([nl[:, 0], nl[:, 1]]) + inject @ V[k]
                    if W is not None:
                        z = z + Bd @ W[k]
                    x, xh = z[:n], z[n:]
                else:
                    Bu = B @ u
                    nl = np.asarray(f(np.stack([x, xh], axis=1)), dtype=float)
                    x = A @ x + Bu + nl[:, 0] + (0.0 if W is None else p.Bw @ W[k])
                    if getattr(est, "predicts_with_model", False):
                        est.predict(u, x_next=A @ xh + Bu + nl[:, 1])
                    else:
                        est.predict(u)
            except (FloatingPointError, OverflowError, np.linalg.LinAlgError) as exc:
                status, message = "diverged", f"{type(exc).__name__} at t = {k * dt:.4g}: {exc}"
                break
            steps += 1
            if steps > o.max_nfev:
                status, message = "budget", f"more than {o.max_nfev} steps by t = {(k + 1) * dt:.4g}"
                break
        wall = time.perf_counter() - t0
        keep = k + 1
        return Trajectory(np.arange(keep) * dt, X[:, :keep], XH[:, :keep], U[:, :keep], status, message, wall, steps)
