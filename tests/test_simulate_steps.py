"""The simulator's integration, checked against closed forms and against itself built the plain way.

Linear plants with the input held over each sample interval have the exact step (Van Loan's augmented
exponential, computed here with scipy's ``expm``): ``x(t_k + dt) = e^{A dt} x_k + int_0^dt e^{A s} ds B u_k``.
The sampled loop restarts scipy's Runge-Kutta solver in place at each interval; built anew at every interval
(``_SampledLoop.reuse_solver = False``, the way scipy documents it) it must take the same steps, bit for bit.
A non-finite state or right-hand side, and the budget of right-hand sides, stop a run with their messages.
"""

import math
import re
import warnings

import numpy as np
import pytest
import scipy.integrate
from scipy.linalg import expm

import bench.simulate as sim
from bench.registry import PLANTS
from bench.simulate import SimOptions, simulate, simulate_controller
from designs.ekf import EKFSpec
from plants import Plant
from plants._core import sine_terms

# a lightly damped oscillator, driven through its second state, measured on its first
A2 = np.array([[0.0, 1.0], [-2.0, -0.5]])
B2 = np.array([[0.0], [1.0]])
C2 = np.array([[1.0, 0.0]])
F2 = np.array([[-0.3, -0.4]])


def _zero(x):
    return np.zeros_like(np.asarray(x, dtype=float))


def _oscillator(**kw) -> Plant:
    return Plant(id="oscillator_test", A=A2, B=B2, C=C2, f=_zero, x0=np.array([1.0, -0.5]),
                 x_hat0=np.array([0.2, 0.3]), t_final=2.0, **kw)


def _held_step(A, B, dt):
    """``(e^{A dt}, int_0^dt e^{A s} ds B)`` from the exponential of ``[[A, B], [0, 0]] dt`` (Van Loan 1978)."""
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A, B
    E = expm(M * dt)
    return E[:n, :n], E[:n, n:]


class _Predictor:
    """A run-time estimator that follows the model's prediction (``predicts_with_model``): ``x_hat <- x_next``;
    it records what it was given."""

    predicts_with_model = True

    def __init__(self, x_hat0, dt):
        self.x, self.dt, self.log, self.updates = np.array(x_hat0, dtype=float), dt, [], 0

    def update(self, y):
        self.updates += 1

    def predict(self, u, x_next):
        self.log.append((self.x.copy(), np.array(u, dtype=float), np.array(x_next, dtype=float)))
        self.x = np.array(x_next, dtype=float)


class _Blind(_Predictor):
    """An estimator that predicts with its own (wrong: none) model: ``x_hat`` stays; the plant alone is integrated."""

    predicts_with_model = False

    def predict(self, u):
        self.log.append((self.x.copy(), np.array(u, dtype=float), None))


@pytest.mark.parametrize("method", ["RK45", "DOP853", "RK23", "Radau"])
def test_a_held_input_moves_a_linear_plant_and_its_model_by_the_exact_step(method):
    """Plant and model prediction, integrated as one ODE over each interval, both follow the exact step."""
    plant, dt = _oscillator(), 0.05
    Phi, Gam = _held_step(A2, B2, dt)
    est = _Predictor(plant.x_hat0, dt)
    tr = simulate_controller(plant, F2, estimator=est, t_final=1.0, options=SimOptions(method=method))
    assert tr.status == "ok" and tr.t.size == 21 and len(est.log) == 20
    for k, (xh, u, x_next) in enumerate(est.log):
        np.testing.assert_allclose(u, F2 @ xh, rtol=1e-15)
        np.testing.assert_allclose(tr.u[:, k], u, rtol=1e-15)
        np.testing.assert_allclose(x_next, Phi @ xh + Gam @ u, rtol=1e-7, atol=1e-10)
        np.testing.assert_allclose(tr.x[:, k + 1], Phi @ tr.x[:, k] + Gam @ u, rtol=1e-7, atol=1e-10)
        np.testing.assert_allclose(tr.x_hat[:, k + 1], x_next, rtol=0, atol=0)


def test_a_held_input_moves_a_linear_plant_alone_by_the_exact_step():
    """An estimator with its own model: the simulator integrates the plant alone (``x_hat`` stays put here)."""
    plant, dt = _oscillator(), 0.1
    Phi, Gam = _held_step(A2, B2, dt)
    est = _Blind(plant.x_hat0, dt)
    tr = simulate_controller(plant, F2, estimator=est, t_final=2.0)
    assert tr.status == "ok" and len(est.log) == 20
    u = F2 @ plant.x_hat0
    np.testing.assert_allclose(tr.u, np.repeat(u[:, None], 21, axis=1), rtol=0, atol=0)
    for k in range(20):
        np.testing.assert_allclose(tr.x[:, k + 1], Phi @ tr.x[:, k] + Gam @ u, rtol=1e-7, atol=1e-10)


def test_a_noisy_gain_observer_moves_by_the_exact_step_of_the_loop():
    """A gain K with noise v_k held over each interval: ``z' = L z + (0, K v_k)``, L the loop matrix
    ``[[A, BF], [KC, A + BF - KC]]`` written here; v_k the seeded N(0, noise^2) samples, one per interval."""
    plant, dt, noise = _oscillator(), 0.05, 0.01
    K = np.array([[1.5], [0.8]])
    L = np.block([[A2, B2 @ F2], [K @ C2, A2 + B2 @ F2 - K @ C2]])
    inject = np.vstack([np.zeros((2, 1)), K])
    Phi, Gam = _held_step(L, inject, dt)
    tr = simulate_controller(plant, F2, K=K, t_final=1.0, noise=noise, noise_dt=dt, seed=3)
    V = noise * np.random.default_rng(3).standard_normal((21, 1))
    assert tr.status == "ok" and tr.t.size == 21
    Z = np.vstack([tr.x, tr.x_hat])
    for k in range(20):
        np.testing.assert_allclose(Z[:, k + 1], Phi @ Z[:, k] + Gam @ V[k], rtol=1e-7, atol=1e-10)


def test_a_nonlinear_interval_matches_solve_ivp_with_the_input_held():
    """The pendulum with its EKF: each interval of the plant agrees with scipy's solve_ivp run here at a tighter
    tolerance, ``x' = A x + B u_k + f(x)`` with the recorded ``u_k``."""
    plant = PLANTS.create("pendulum_v1")
    F = np.array([[-4.0, -2.0]])
    spec = EKFSpec(dt=0.02)
    tr = simulate_controller(plant, F, estimator=spec, t_final=2.0)
    assert tr.status == "ok" and tr.t.size == 101
    for k in range(0, 100, 7):
        u = tr.u[:, k]
        ref = scipy.integrate.solve_ivp(lambda t, x: plant.A @ x + plant.B @ u + plant.f(x), (0.0, spec.dt),
                                        tr.x[:, k], method="DOP853", rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(tr.x[:, k + 1], ref.y[:, -1], rtol=1e-7, atol=1e-10)


def _bitwise(a, b):
    assert (a.status, a.message, a.nfev) == (b.status, b.message, b.nfev)
    for name in ("t", "x", "x_hat", "u"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


def _both_ways(monkeypatch, run):
    monkeypatch.setattr(sim._SampledLoop, "reuse_solver", False)
    fresh = run()
    monkeypatch.setattr(sim._SampledLoop, "reuse_solver", True)
    return fresh, run()


@pytest.mark.parametrize("pid, disturbed", [("pendulum_v1", False), ("flexible_link_w_v1", True),
                                            ("chua_v1", False)])
def test_a_restarted_solver_steps_as_one_built_per_interval(monkeypatch, pid, disturbed):
    """The EKF path (RK45 on plant and model) bit for bit the same either way, with a disturbance too."""
    from bench.disturbance import SeededDisturbance

    plant = PLANTS.create(pid)
    F = -np.ones((plant.m, plant.n))
    w = SeededDisturbance(0.5, plant.q, 2.0, seed=1) if disturbed else None
    fresh, reused = _both_ways(monkeypatch, lambda: simulate_controller(
        plant, F * 0.5, estimator=EKFSpec(dt=0.01), t_final=2.0, noise=0.01, disturbance=w))
    assert fresh.status == "ok" and fresh.t.size == 201
    _bitwise(fresh, reused)


@pytest.mark.parametrize("method", ["DOP853", "RK23", "BDF"])
def test_a_restarted_solver_steps_as_one_built_per_interval_on_the_noisy_gain_path(monkeypatch, method):
    plant = PLANTS.create("flexible_link")
    from plants.flexible_link import PAPER_F, PAPER_K

    fresh, reused = _both_ways(monkeypatch, lambda: simulate_controller(
        plant, PAPER_F, K=PAPER_K, t_final=1.0, noise=0.01, noise_dt=0.02, options=SimOptions(method=method)))
    assert fresh.status == "ok" and fresh.t.size == 51
    _bitwise(fresh, reused)


def test_a_restarted_solver_steps_as_one_built_per_interval_on_the_plant_alone_path(monkeypatch):
    plant = _oscillator()
    fresh, reused = _both_ways(monkeypatch, lambda: simulate_controller(
        plant, F2, estimator=_Blind(plant.x_hat0, 0.1), t_final=2.0))
    _bitwise(fresh, reused)


def test_a_sampled_run_builds_its_runge_kutta_solver_once(monkeypatch):
    built = []

    class Counted(scipy.integrate.RK45):
        def __init__(self, *a, **kw):
            built.append(kw.get("first_step"))
            super().__init__(*a, **kw)

    monkeypatch.setattr(scipy.integrate, "RK45", Counted)
    plant = _oscillator()
    tr = simulate_controller(plant, F2, estimator=_Predictor(plant.x_hat0, 0.05), t_final=1.0)
    assert tr.status == "ok" and built == [None]  # the first interval's, which picks its own first step


def test_the_sampled_loop_counts_every_right_hand_side_and_stops_past_its_budget():
    """nfev: the calls of f less the one per interval at the estimate; the run stops after the interval
    that takes the count past max_nfev, at that interval's start."""
    calls = []

    def f(x):
        calls.append(1)
        return np.zeros_like(np.asarray(x, dtype=float))

    plant = Plant(id="counted_test", A=A2, B=B2, C=C2, f=f, x0=np.array([1.0, -0.5]), x_hat0=np.zeros(2),
                  t_final=2.0)

    class Logged(_Predictor):
        def update(self, y):
            self.log.append(len(calls))

        def predict(self, u, x_next):
            self.x = np.array(x_next, dtype=float)

    calls.clear()
    est = Logged(plant.x_hat0, 0.05)
    tr = simulate_controller(plant, F2, estimator=est, t_final=1.0)
    per_interval = np.diff(est.log) - 1  # f once at the estimate, then once per right-hand side
    assert tr.status == "ok" and tr.nfev == len(calls) - 20 == per_interval.sum() + (len(calls) - est.log[-1])
    assert (per_interval >= 7).all()  # the first stage plus at least one six-stage RK45 step

    budget = int(np.cumsum(per_interval)[4]) - 1  # the fifth interval takes the count past it
    calls.clear()
    est = Logged(plant.x_hat0, 0.05)
    tr = simulate_controller(plant, F2, estimator=est, t_final=1.0, options=SimOptions(max_nfev=budget))
    assert tr.status == "budget"
    assert tr.message == f"more than {budget} right-hand-side evaluations by t = {4 * 0.05:.4g}"
    assert tr.nfev == budget + 1 and tr.t.size == 5


def test_the_continuous_loop_stops_at_its_budget_of_right_hand_sides():
    calls = []

    def f(x):
        calls.append(1)
        return np.zeros_like(np.asarray(x, dtype=float))

    plant = Plant(id="counted_test", A=A2, B=B2, C=C2, f=f, x0=np.array([1.0, -0.5]), x_hat0=np.zeros(2))
    calls.clear()
    tr = simulate(plant, np.array([[1.0], [1.0]]), F2, options=SimOptions(max_nfev=30))
    assert tr.status == "budget" and tr.nfev == 31 and len(calls) == 30
    assert re.fullmatch(r"more than 30 right-hand-side evaluations by t = \S+", tr.message), tr.message


def _nan_beyond_5(x):
    """0 where ``x_1 <= 5``, NaN beyond (finite wherever the plant's checks probe it)."""
    x = np.asarray(x, dtype=float)
    return np.where(x[:1] > 5.0, np.nan, 0.0) * np.ones_like(x)


def _unstable_scalar():
    # x' = x from 1: x = e^t reaches 5 at t = ln 5 = 1.609
    return Plant(id="nan_beyond_test", A=np.array([[1.0]]), B=np.array([[1.0]]), C=np.array([[1.0]]),
                 f=_nan_beyond_5, x0=np.array([1.0]), x_hat0=np.array([0.0]), t_final=3.0)


def test_a_non_finite_right_hand_side_ends_a_sampled_run_as_diverged():
    """The estimate stays at 0 (u = 0), the plant x = e^t crosses 5 in the interval [1.6, 1.7] (dt = 0.1)."""
    plant = _unstable_scalar()

    class Still(_Predictor):
        def predict(self, u, x_next):
            pass

    tr = simulate_controller(plant, np.zeros((1, 1)), estimator=Still(plant.x_hat0, 0.1), t_final=3.0)
    assert tr.status == "diverged"
    assert re.fullmatch(r"FloatingPointError at t = 1\.6: the right-hand side is not finite "
                        r"\(t = \S+ within the sample interval\)", tr.message), tr.message
    assert tr.t[-1] == pytest.approx(1.6) and np.allclose(tr.x[0], np.exp(tr.t), rtol=1e-7)


def test_a_non_finite_state_ends_a_continuous_run_as_diverged():
    tr = simulate(_unstable_scalar(), np.zeros((1, 1)), np.zeros((1, 1)))
    assert tr.status == "diverged"
    match = re.fullmatch(r"non-finite state at t = (\S+)", tr.message)
    assert match and math.log(5.0) - 0.05 < float(match.group(1)) < 3.0, tr.message


def test_the_finiteness_checks_stop_on_every_non_finite_entry_and_only_on_those():
    """Huge entries are finite: no stop, and no warning either; any infinite or NaN entry stops."""
    rhs = sim._LoopRHS(np.eye(2), _zero, 1, SimOptions())
    big = np.array([1e200, -1e300])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(rhs(0.0, big), big)
        assert sim._finite(np.full((3, 2), 1e300), 0.5) is not None
    for bad in (np.array([np.nan, 0.0]), np.array([0.0, -np.inf]), np.array([np.inf, -np.inf]),
                np.array([np.inf, 1e300])):
        with pytest.raises(sim._Stop, match=r"^non-finite state at t = 0\.25$") as stop:
            rhs(0.25, bad)
        assert stop.value.status == "diverged"
    with pytest.raises(FloatingPointError, match=r"^the right-hand side is not finite \(t = 0\.5 within the "
                                                 r"sample interval\)$"):
        sim._finite(np.array([[1.0, 2.0], [np.nan, 1e300]]), 0.5)


def _sines_reference(x, n, acts, reads, gain):
    """``f_{acts[l]} = gain sin(x_{reads[l]})`` entry by entry."""
    x = np.asarray(x, dtype=float)
    out = np.zeros(x.shape)
    for a, r in zip(acts, reads):
        out[a] = gain * np.sin(x[r])
    return out


@pytest.mark.parametrize("n, acts, reads", [
    (4, [3], [2]), (2, [1], [0]), (6, [1, 3, 5], [0, 2, 4]), (6, [3, 4, 5], [0, 1, 2]),
    (6, [5, 1], [0, 3]), (5, [0, 4], [2, 1]), (3, [], []),
])
def test_sine_terms_f_is_its_formula_for_states_and_batches_of_any_layout(n, acts, reads):
    f = sine_terms(n, acts=acts, reads=reads, coef=-0.7, scale=2.0)["f"]
    rng = np.random.default_rng(n + len(acts))
    X = rng.standard_normal((n, 5)) * 3
    for x in (X[:, 0], X, np.asfortranarray(X), X[:, ::2], X.T.copy().T, X[:, :1]):
        out = f(x)
        assert np.array_equal(out, _sines_reference(x, n, acts, reads, -0.35))
        assert out.shape == x.shape and out.flags.c_contiguous == np.zeros_like(x).flags.c_contiguous
        assert np.array_equal(x, X[:, 0] if x.ndim == 1 else x)  # f does not write into its argument


def test_sine_terms_f_still_refuses_a_state_too_short_for_its_indices():
    f = sine_terms(4, acts=[3], reads=[2], coef=1.0)["f"]
    with pytest.raises(IndexError):
        f(np.zeros(3))
    np.testing.assert_array_equal(f(np.ones(5))[[3, 4]], [math.sin(1.0), 0.0])  # as before: the indices of n = 4
