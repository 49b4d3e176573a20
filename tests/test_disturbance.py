"""Disturbances: the seeded signal, the L2 norms on a grid, the measured attenuation of a linear loop against
python-control's H-infinity norm (below it for any w, at it for a sinusoid at the peak frequency), the
disturbance paths of every simulator, the pipeline's columns and the verdict on a certified gain."""

import dataclasses
import math

import control
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import minimize_scalar

from bench.cli import _build_parser
from bench.constants import compute_constants
from bench.disturbance import SeededDisturbance, l2_norm, measured_attenuation, window
from bench.pipeline import COLUMNS, RunOptions, evaluate_pair
from bench.registry import PLANTS
from bench.simulate import SimOptions, simulate, simulate_controller
from bench.verdicts import attenuation_note
from designs import Design, DesignResult
from plants import Constants, Plant


def oscillator(dt=0.0):
    """x'' = -4 x - 0.4 x' + u + w, y = x + 0.1 w (f = 0), or its zoh discretisation."""
    A = np.array([[0.0, 1.0], [-4.0, -0.4]])
    B = np.array([[0.0], [1.0]])
    p = Plant(id="osc", A=A, B=B, C=np.array([[1.0, 0.0]]), f=lambda x: np.zeros_like(np.asarray(x, dtype=float)),
              x0=np.array([1.0, 0.0]), x_hat0=np.zeros(2), Bw=B, Dw=np.array([[0.1]]), t_final=20.0,
              bounds=Constants(alpha=0.0, rho=0.0, beta=0.0, gamma=0.0))
    return p if dt == 0 else p.discretise(dt, "zoh")


def gains(p):
    """A mildly damped loop: python-control's (d)lqr with a small state weight, (d)lqe (u = F x_hat)."""
    if p.discrete:
        G, _, _ = control.dlqr(p.A, p.B, 0.1 * np.eye(2), np.eye(1))
        L, _, _ = control.dlqe(p.A, np.eye(2), p.C, 1e-3 * np.eye(2), np.eye(1))  # both loops peak near 2 rad/s
        return p.A @ L, -G
    G, _, _ = control.lqr(p.A, p.B, 0.1 * np.eye(2), np.eye(1))
    L, _, _ = control.lqe(p.A, np.eye(2), p.C, np.eye(2), np.eye(1))
    return L, -G


def loop_from_w(p, K, F, which):
    """(Acl, Bd, Cz) of the linear loop in (x, e) from w to zeta = e or x (docs: z' = Acl z + Bd w)."""
    A, B, C = p.A, p.B, p.C
    Acl = np.block([[A + B @ F, -B @ F], [np.zeros((2, 2)), A - K @ C]])
    Bd = np.vstack([p.Bw, p.Bw - K @ p.Dw])
    Cz = np.hstack([np.zeros((2, 2)), np.eye(2)]) if which == "e" else np.hstack([np.eye(2), np.zeros((2, 2))])
    return Acl, Bd, Cz


def hinf(p, K, F, which):
    """python-control's H-infinity norm, B padded with zero columns to a square system (0.10.2 needs it)."""
    Acl, Bd, Cz = loop_from_w(p, K, F, which)
    Bsq = np.hstack([Bd, np.zeros((4, Cz.shape[0] - Bd.shape[1]))])
    return float(control.norm(control.ss(Acl, Bsq, Cz, 0, p.dt), "inf"))


def peak_frequency(p, K, F, which):
    """The frequency (rad/s) where |G(j w)| (or |G(e^{j w dt})|) peaks, by a grid and a bounded refinement."""
    Acl, Bd, Cz = loop_from_w(p, K, F, which)

    def gain(w):
        s = np.exp(1j * w * p.dt) if p.discrete else 1j * w
        return float(np.linalg.norm(Cz @ np.linalg.solve(s * np.eye(4) - Acl, Bd)))

    top = math.pi / p.dt if p.discrete else 100.0
    grid = np.geomspace(1e-3, top * 0.999, 4000)
    k = int(np.argmax([gain(w) for w in grid]))
    res = minimize_scalar(lambda w: -gain(w), bounds=(grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]),
                          method="bounded", options={"xatol": 1e-10})
    return res.x, -res.fun


# -- the signal and the norms -------------------------------------------------------------------------------
def test_the_seeded_disturbance_has_its_documented_shape():
    w = SeededDisturbance(0.3, 2, 10.0, seed=4)
    t = np.linspace(0, 10, 10001)
    W = w(t)
    assert W.shape == (2, 10001) and w(2.5).shape == (2,)
    np.testing.assert_allclose(np.abs(W).max(axis=1), 0.3, rtol=1e-12)  # the peak on the normalising grid
    np.testing.assert_allclose(w(np.array([0.0, 10.0, 10.5, 100.0])), 0.0, atol=1e-15)  # windowed to zero
    np.testing.assert_array_equal(SeededDisturbance(0.3, 2, 10.0, seed=4)(t), W)  # same seed, same w
    assert not np.allclose(SeededDisturbance(0.3, 2, 10.0, seed=5)(t), W)
    assert np.all((w.omega >= 2 * np.pi / 10) & (w.omega <= 2 * np.pi * 30 / 10))
    d = SeededDisturbance(1.0, 1, 10.0, dt=0.1)
    assert d.omega.max() <= np.pi / (2 * 0.1)  # a quarter of the sampling frequency
    assert window(20.0) == 10.0 and window(20.0, 8.0) == 4.0


def test_a_scalar_time_gives_the_array_path_s_numbers_bit_for_bit():
    # the integrators call w(t) at one time; its fast path must agree exactly with w on the array [t], inside
    # the window (where a 0-d sine may differ from an array's in the last bit), at its ends and outside
    rng = np.random.default_rng(7)
    for q, seed, dt in ((1, 0, 0.0), (2, 3, 0.0), (3, 1, 0.05)):
        w = SeededDisturbance(0.4, q, 6.0, seed=seed, dt=dt)
        t = np.concatenate([rng.uniform(-2.0, 9.0, 3000), [0.0, 6.0, -1e-12, 6.0 + 1e-12]])
        one = np.stack([w(float(tk)) for tk in t], axis=1)
        np.testing.assert_array_equal(one, np.stack([w(np.array([tk]))[:, 0] for tk in t], axis=1))
        np.testing.assert_allclose(one, w(t), rtol=0, atol=1e-15)  # an array of times: the same w
        assert not np.any(one[:, (t < 0) | (t > 6.0)])  # zero outside [0, T_w]
        assert np.count_nonzero(one[:, (t > 0) & (t < 6.0)]) > 0


def test_l2_norms_on_a_grid():
    t = np.linspace(0, 2 * np.pi, 20001)
    assert l2_norm(t, np.sin(t)[None, :]) == pytest.approx(math.sqrt(math.pi), rel=1e-7)
    assert l2_norm(t, np.vstack([np.sin(t), np.cos(t)])) == pytest.approx(math.sqrt(2 * math.pi), rel=1e-7)
    v = np.array([[3.0, 4.0, 0.0]])
    assert l2_norm(np.arange(3) * 0.5, v, dt=0.5) == pytest.approx(math.sqrt(25 * 0.5))
    r = measured_attenuation(t, 2 * np.vstack([np.sin(t), 0 * t]), np.zeros((2, t.size)), np.sin(t)[None, :])
    assert r == pytest.approx((2.0, 2.0), rel=1e-9)
    assert all(math.isnan(v) for v in measured_attenuation(t, np.ones((1, t.size)), np.zeros((1, t.size)),
                                                            np.zeros((1, t.size))))


# -- measured attenuation of a linear loop against its H-infinity norm ----------------------------------------
@pytest.mark.parametrize("dt", [0.0, 0.05])
def test_the_measured_ratio_never_exceeds_the_hinf_norm(dt):
    p = oscillator(dt)
    K, F = gains(p)
    for seed in (0, 1, 2):
        w = SeededDisturbance(0.5, 1, 10.0, seed=seed, dt=dt)
        tr = simulate_controller(p, F, K=K, t_final=40.0, x0=np.zeros(2), x_hat0=np.zeros(2), disturbance=w,
                                 options=SimOptions(n_points=8001))
        re, rx = measured_attenuation(tr.t, tr.x, tr.x_hat, w(tr.t), dt)
        assert 0 < re <= hinf(p, K, F, "e") * (1 + 1e-3)
        assert 0 < rx <= hinf(p, K, F, "x") * (1 + 1e-3)


@pytest.mark.parametrize("dt", [0.0, 0.05])
@pytest.mark.parametrize("which", ["e", "x"])
def test_a_sinusoid_at_the_peak_frequency_approaches_the_hinf_norm(dt, which):
    p = oscillator(dt)
    K, F = gains(p)
    omega, peak = peak_frequency(p, K, F, which)
    assert 1.0 < omega < 3.0  # a resonant peak, not at DC
    norm = hinf(p, K, F, which)
    assert peak == pytest.approx(norm, rel=1e-4)  # python-control and the sweep agree on the norm
    T = 200 * 2 * math.pi / omega
    tr = simulate_controller(p, F, K=K, t_final=T, x0=np.zeros(2), x_hat0=np.zeros(2),
                             disturbance=lambda t: np.atleast_1d(np.sin(omega * t)),
                             options=SimOptions(n_points=int(200 * 80) + 1))
    ratio = measured_attenuation(tr.t, tr.x, tr.x_hat, np.sin(omega * tr.t)[None, :], dt)[0 if which == "e" else 1]
    assert norm * 0.99 <= ratio <= norm * (1 + 1e-3)


# -- the disturbance paths of the simulators ----------------------------------------------------------------
def test_the_noise_held_path_carries_the_disturbance_like_the_ode_path():
    p = oscillator()
    K, F = gains(p)
    w = SeededDisturbance(0.5, 1, 10.0, seed=1)
    ode = simulate(p, K, F, t_final=20.0, x0=np.zeros(2), x_hat0=np.zeros(2), disturbance=w,
                   options=SimOptions(n_points=201))
    held = simulate_controller(p, F, K=K, t_final=20.0, noise=1e-14, noise_dt=0.1, x0=np.zeros(2),
                               x_hat0=np.zeros(2), disturbance=w)
    np.testing.assert_allclose(held.x, ode.x, atol=1e-6)
    np.testing.assert_allclose(held.x_hat, ode.x_hat, atol=1e-6)
    assert np.abs(ode.x).max() > 1e-2  # w moved the plant


class Recorder:
    """A run-time estimator that estimates nothing (x_hat = 0) and records what it is given."""

    dt = 0.1

    def __init__(self, with_model):
        self.predicts_with_model, self.ys, self.nexts = with_model, [], []

    @property
    def x(self):
        return np.zeros(2)

    def update(self, y):
        self.ys.append(np.array(y))

    def predict(self, u, x_next=None):
        self.nexts.append(x_next)


@pytest.mark.parametrize("with_model", [False, True])
def test_a_runtime_estimator_sees_dw_w_and_its_model_never_sees_w(with_model):
    p = oscillator()
    w = SeededDisturbance(0.5, 1, 10.0, seed=2)
    est = Recorder(with_model)
    tr = simulate_controller(p, np.zeros((1, 2)), estimator=est, t_final=10.0, x0=np.zeros(2), disturbance=w,
                             options=SimOptions(rtol=1e-10, atol=1e-12))
    ref = solve_ivp(lambda t, x: p.A @ x + p.Bw @ w(t), (0, 10), np.zeros(2), t_eval=tr.t, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(tr.x, ref.y, atol=1e-7)  # u = 0: the plant driven by Bw w alone
    ys = np.array(est.ys)[:, 0]
    np.testing.assert_allclose(ys, (p.C @ tr.x)[0] + 0.1 * w(tr.t)[0], atol=1e-12)
    if with_model:
        np.testing.assert_allclose(np.array(est.nexts), 0.0, atol=1e-12)  # the model of x_hat = 0 stays at 0


def test_a_discrete_plant_takes_w_at_the_samples():
    p = oscillator(0.1)
    K, F = gains(p)
    w = SeededDisturbance(0.5, 1, 5.0, seed=3, dt=0.1)
    tr = simulate_controller(p, F, K=K, t_final=5.0, x0=np.zeros(2), x_hat0=np.zeros(2), disturbance=w)
    x, xh = np.zeros(2), np.zeros(2)
    for k in range(51):
        np.testing.assert_allclose(tr.x[:, k], x, atol=1e-13)
        wk = w(k * 0.1)
        u = F @ xh
        y = p.C @ x + p.Dw @ wk
        x, xh = p.A @ x + p.B @ u + p.Bw @ wk, p.A @ xh + p.B @ u + K @ (y - p.C @ xh)


def test_a_disturbance_needs_disturbance_inputs():
    p = PLANTS.create("flexible_link")
    with pytest.raises(ValueError, match="no disturbance input"):
        simulate_controller(p, np.zeros((1, 4)), K=np.zeros((4, 2)), t_final=1.0, disturbance=lambda t: np.zeros(1))
    q = oscillator()
    with pytest.raises(ValueError, match=r"shape \(1,\)"):
        simulate_controller(q, np.zeros((1, 2)), K=np.zeros((2, 1)), t_final=1.0, disturbance=lambda t: np.zeros(2))


# -- the pipeline, the CLI and the verdict --------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, kw_only=True)
class LQG(Design):
    time_domains = ("continuous", "discrete")

    def design(self, plant, constants):
        K, F = gains(plant)
        return DesignResult(status="computed", route="formula", K=K, F=F)


@pytest.mark.parametrize("dt", [0.0, 0.05])
def test_the_pipeline_measures_the_attenuation_from_zero(dt):
    p = oscillator(dt)
    rep = compute_constants(p, n_samples=200, n_refine=0)
    rec = evaluate_pair(p, LQG(), rep, RunOptions(n_samples=200, disturbance=0.2), design_id="lqg").record
    K, F = gains(p)
    assert rec["disturbance"] == 0.2
    assert 0 < rec["l2_measured_e"] <= hinf(p, K, F, "e") * (1 + 1e-3)
    assert 0 < rec["l2_measured_x"] <= hinf(p, K, F, "x") * (1 + 1e-3)
    assert rec["converged"]  # the main run (from x0, no w) is judged as before
    off = evaluate_pair(p, LQG(), rep, RunOptions(n_samples=200), design_id="lqg").record
    assert math.isnan(off["l2_measured_e"]) and off["disturbance"] == 0.0
    assert off["final_x"] == rec["final_x"]


def test_plants_without_disturbance_inputs_are_not_disturbed():
    """A plant without Bw, Dw: nothing measured, and its ``disturbance`` column says no amplitude was applied (the
    run's default disturbance applies to the plants with inputs only, without a note on every other row)."""
    p = PLANTS.create("flexible_link")
    rep = compute_constants(p, n_samples=500, n_refine=0)
    rec = evaluate_pair(p, "lqr+lqe", rep, RunOptions(n_samples=500, disturbance=0.2)).record
    assert math.isnan(rec["l2_measured_e"]) and math.isnan(rec["l2_measured_x"])
    assert rec["disturbance"] == 0.0 and "disturbance" not in rec["reason"]


def test_an_estimator_pair_is_measured_too():
    p = PLANTS.create("flexible_joint_v1")
    rep = compute_constants(p, n_samples=500, n_refine=0)
    rec = evaluate_pair(p, "lqr+ekf", rep, RunOptions(n_samples=500, disturbance=0.1)).record
    assert rec["status"] == "given" or rec["status"] == "computed"
    assert rec["l2_measured_e"] > 0 and rec["l2_measured_x"] > 0


def test_columns_and_options():
    i = COLUMNS.index
    assert i("l2_gain_e") + 1 == i("l2_gain_x") and i("l2_gain_x") + 1 == i("l2_measured_e") \
        and i("l2_measured_e") + 1 == i("l2_measured_x")
    args = _build_parser().parse_args(["run", "--disturbance", "0.5"])
    assert args.disturbance == 0.5
    # a run disturbs the plants with inputs by default (docs/results.md says why); the pipeline's options do not
    from bench.pipeline import RUN_DISTURBANCE
    assert _build_parser().parse_args(["run"]).disturbance == RUN_DISTURBANCE == 0.1
    import inspect

    import bench
    assert inspect.signature(bench.run).parameters["disturbance"].default == RUN_DISTURBANCE
    assert RunOptions().disturbance == 0.0
    with pytest.raises(SystemExit):
        _build_parser().parse_args(["run", "--disturbance", "-1"])
    with pytest.raises(ValueError, match="disturbance"):
        RunOptions(disturbance=-0.1)


def test_a_certified_gain_below_the_measured_ratio_is_inconsistent():
    base = {"l2_gain_e": 1.0, "l2_measured_e": 1.2, "l2_gain_x": 2.0, "l2_measured_x": 1.5}
    note = attenuation_note(base)
    assert "INCONSISTENT" in note and "error e" in note and "state x" not in note
    assert attenuation_note({**base, "l2_measured_e": 1.005}) == ""  # within the quadrature's tolerance
    assert attenuation_note({**base, "l2_gain_e": math.nan}) == ""  # nothing certified proves nothing
    assert attenuation_note({"l2_gain_x": 1.0, "l2_measured_x": 3.0}).count("INCONSISTENT") == 1
    assert attenuation_note({}) == ""
