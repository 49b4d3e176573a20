"""Discrete-time plants: discretisation (linear part against python-control's c2d, the transported constants
on independent samples), the stepped simulation (against python-control's own discrete simulation, the
statuses, noise against the discrete Lyapunov equation, run-time estimators), the closed loop's spectra and
the pipeline's rows of a discrete plant."""

import dataclasses
import math

import control
import numpy as np
import pytest
from scipy.linalg import expm, solve_discrete_lyapunov

from bench import checks
from bench.constants import compute_constants, linear_prechecks
from bench.pipeline import RunOptions, evaluate_pair
from bench.registry import PLANTS
from bench.simulate import SimOptions, simulate, simulate_controller
from designs import Design, DesignResult
from plants import Constants, Plant, PlantError

H = 0.01


def dlqg(plant):
    """Discrete LQR feedback and a predictor-form Kalman observer gain, from python-control (u = F x_hat)."""
    G, _, _ = control.dlqr(plant.A, plant.B, np.eye(plant.n), np.eye(plant.m))
    L, _, _ = control.dlqe(plant.A, np.eye(plant.n), plant.C, np.eye(plant.n), np.eye(plant.p))
    return plant.A @ L, -G


def linear_plant(dt=0.0, **kw):
    """A lightly damped oscillator with a disturbance input (f = 0): x'' = -4 x - 0.4 x' + u + w."""
    A = np.array([[0.0, 1.0], [-4.0, -0.4]])
    B = np.array([[0.0], [1.0]])
    C = np.array([[1.0, 0.0]])
    plant = Plant.from_statespace(control.ss(A, np.hstack([B, B]), C, 0), disturbances=1, id="osc",
                                  x0=np.array([1.0, 0.0]), bounds=Constants(alpha=0.0, rho=0.0, beta=0.0, gamma=0.0),
                                  Dw=np.array([[0.1]]), t_final=20.0)
    return plant if dt == 0 else plant.discretise(dt, "zoh", **kw)


# -- discretisation ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("method", ["zoh", "euler"])
def test_linear_part_equals_python_control_c2d(method):
    plant = PLANTS.create("flexible_joint_v1")  # has a disturbance input: w rides along as an extra input
    sys = control.ss(plant.A, np.hstack([plant.B, plant.Bw]), plant.C, np.hstack([np.zeros((2, 1)), plant.Dw]))
    want = control.c2d(sys, 0.02, method=method)
    d = plant.discretise(0.02, method)
    np.testing.assert_allclose(d.A, want.A, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(d.B, want.B[:, :1], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(d.Bw, want.B[:, 1:], rtol=1e-10, atol=1e-12)
    np.testing.assert_array_equal(d.C, plant.C)
    np.testing.assert_array_equal(d.Dw, plant.Dw)
    assert d.dt == 0.02 and d.discrete and d.params["h"] == 0.02 and d.params["zoh"] == float(method == "zoh")
    assert d.id == "flexible_joint_v1_d20ms" and "0.02 s" in d.source


def test_f_is_held_over_the_step_like_u():
    """zoh: f_d = Gamma f with Gamma = int_0^h expm(As) ds, read off python-control's c2d of (A, I);
    Euler: f_d = h f; the Jacobians likewise; the channels' G likewise (the Plant checks them against f_d)."""
    plant = PLANTS.create("flexible_link")
    Gam = control.c2d(control.ss(plant.A, np.eye(4), np.eye(4), 0), H).B
    rng = np.random.default_rng(0)
    X = rng.standard_normal((4, 5))
    z, e = plant.discretise(H, "zoh"), plant.discretise(H, "euler")
    np.testing.assert_allclose(z.f(X), Gam @ plant.f(X), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(e.f(X), H * plant.f(X), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(z.jacobian(X[:, 0]), Gam @ plant.jacobian(X[:, 0]), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(z.channels.G, Gam @ plant.channels.G, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(e.channels.G, H * plant.channels.G, rtol=1e-12)
    np.testing.assert_array_equal(z.channels.H, plant.channels.H)
    assert (z.channels.lo, z.channels.hi) == (plant.channels.lo, plant.channels.hi)
    assert z.channels.slopes_on(0.5) == plant.channels.slopes_on(0.5)


def test_horizon_and_initial_conditions_are_kept():
    plant = PLANTS.create("flexible_link", t_final=1.0)
    d = plant.discretise(0.3, "euler")
    np.testing.assert_array_equal(d.x0, plant.x0)
    np.testing.assert_array_equal(d.x_hat0, plant.x_hat0)
    assert d.t_final == pytest.approx(1.2)  # rounded up to 4 steps
    mine = plant.discretise(0.25, "zoh", id="mine")
    assert mine.t_final == 1.0 and mine.id == "mine"


def test_bad_discretisations_are_refused():
    plant = PLANTS.create("flexible_link")
    with pytest.raises(PlantError, match="method"):
        plant.discretise(H, "tustin")
    with pytest.raises(PlantError, match="h"):
        plant.discretise(0.0)
    with pytest.raises(PlantError, match="already discrete"):
        plant.discretise(H).discretise(H)


def pair_ratios(f, x1, x2, gamma):
    dx, df = x1 - x2, f(x1) - f(x2)
    nx2 = np.sum(dx * dx, axis=0)
    inner = np.sum(dx * df, axis=0)
    nf2 = np.sum(df * df, axis=0)
    return np.sqrt(nf2 / nx2), inner / nx2, (nf2 - gamma * inner) / nx2


def pairs(rng, n, N, radius):
    x1 = rng.standard_normal((n, N)) * 10.0 ** rng.uniform(-2, 1, N)
    x2 = x1 + rng.standard_normal((n, N)) * 10.0 ** rng.uniform(-4, 0.5, N)
    if radius is not None:  # both inside the ball
        for X in (x1, x2):
            nrm = np.linalg.norm(X, axis=0)
            X *= np.where(nrm > radius, 0.999 * radius / nrm, 1.0)
    return x1, x2


@pytest.mark.parametrize("pid", ["flexible_link", "flexible_joint_v1", "pendulum_v1", "moving_object_v1"])
@pytest.mark.parametrize("method, h", [("zoh", 0.05), ("zoh", 0.002), ("euler", 0.05)])
def test_discretised_constants_hold_on_independent_samples(pid, method, h):
    """No sampled pair exceeds a transported constant (Lipschitz, OSL, QIB at its gamma)."""
    d = PLANTS.create(pid).discretise(h, method)
    b = d.bounds
    x1, x2 = pairs(np.random.default_rng(5), d.n, 20000, b.radius)
    a, rho, beta = pair_ratios(d.f, x1, x2, b.gamma if b.gamma is not None else 0.0)
    tol = 1e-9
    if b.alpha is not None:
        assert a.max() <= b.alpha * (1 + tol) + 1e-15
    if b.rho is not None:
        assert rho.max() <= b.rho + tol * max(abs(b.rho), b.alpha or 0.0) + 1e-15
    if b.beta is not None:
        assert beta.max() <= b.beta + tol * max(abs(b.beta), abs(b.gamma), 1e-12)


def test_transported_constants_follow_the_stated_rules():
    """Euler scales exactly (h alpha, h rho, (h^2 beta, h gamma)) and keeps claims; zoh: ||Gamma|| alpha, the OSL
    bound min(||Gamma|| alpha, h rho + ||Gamma - h I|| alpha) -> h rho as h -> 0, QIB (||Gamma||^2 alpha^2, 0)."""
    p = PLANTS.create("moving_object_v1")  # local constants with gamma < 0 and rho = 0
    b = p.bounds
    e = p.discretise(0.001, "euler")
    assert (e.bounds.alpha, e.bounds.rho, e.bounds.beta, e.bounds.gamma, e.bounds.radius) == pytest.approx(
        (0.001 * b.alpha, 0.0, 0.0, 0.001 * b.gamma, b.radius))
    assert e.claimed.gamma == pytest.approx(-4 * 10.0**2 * 0.001)  # Nguyen et al.'s gamma = -4 r^2 ts
    q = PLANTS.create("flexible_link")
    for h in (0.1, 0.01, 0.001):
        Gam = control.c2d(control.ss(q.A, np.eye(4), np.eye(4), 0), h).B
        g, dd = np.linalg.norm(Gam, 2), np.linalg.norm(Gam - h * np.eye(4), 2)
        z = q.discretise(h, "zoh").bounds
        a = q.bounds.alpha
        assert z.alpha == pytest.approx(g * a)
        assert z.rho == pytest.approx(min(g * a, h * q.bounds.rho + dd * a))
        assert (z.beta, z.gamma) == pytest.approx(((g * a) ** 2, 0.0))
    assert z.rho / 0.001 == pytest.approx(q.bounds.rho, rel=0.15)  # the OSL bound tends to h rho
    assert q.discretise(0.01, "zoh").claimed == Constants()  # zoh bounds are nobody's claim


def test_the_sampler_checks_a_discretised_plant_like_any_other():
    d = PLANTS.create("flexible_link_d10ms_v1")
    rep = compute_constants(d, seed=0, n_samples=3000, n_refine=2)
    assert not rep.disproved and not rep.channel_violations and not rep.prechecks
    for k in ("alpha", "rho", "beta"):
        assert getattr(rep.sampled, k) <= getattr(d.bounds, k) * (1 + 1e-9)
    assert rep.sampled.alpha >= 0.5 * d.bounds.alpha  # the bound is not vacuous


def test_nguyen_example_1_is_the_euler_discretisation_at_1_ms():
    """Nguyen, Pathirana & Trinh (Eur. J. Control 2018), Example 1, eq. (64) and the text below it: A = I + ts Ac,
    B = ts Bc, f = ts fc, W = ts Wc, C = Cc, D = Dc with ts = 1 ms (numbers typed from the paper here)."""
    ts = 0.001
    Ac = np.array([[0, 1, 0, 0], [-48.6, -1.25, 48.6, 0], [0, 0, 0, 1], [19.5, 0, -19.5, 0]])
    Bc, Wc, Dc = np.array([[0], [21.6], [0], [0]]), np.array([[1], [0], [0], [0]]), np.array([[1], [0]])
    d = PLANTS.create("flexible_joint_v1").discretise(ts, "euler")
    np.testing.assert_allclose(d.A, np.eye(4) + ts * Ac, rtol=1e-14)
    np.testing.assert_allclose(d.B, ts * Bc, rtol=1e-14)
    np.testing.assert_allclose(d.Bw, ts * Wc, rtol=1e-14)
    np.testing.assert_array_equal(d.Dw, Dc)
    x = np.array([0.3, -0.2, 1.1, 0.5])
    np.testing.assert_allclose(d.f(x), ts * np.array([0, 0, 0, -3.33 * math.sin(1.1)]), rtol=1e-14)


def test_discrete_prechecks_use_the_unit_circle():
    B, C = np.array([[1.0], [0.0]]), np.array([[1.0, 0.0]])
    zero = lambda x: np.zeros_like(np.asarray(x, dtype=float))  # noqa: E731
    for a22, bad in ((0.5, False), (-0.99, False), (1.2, True), (-1.0, True)):
        A = np.array([[0.3, 0.0], [0.0, a22]])  # x2 neither controllable nor observable
        p = Plant(id="d", A=A, B=B, C=C, f=zero, x0=np.ones(2), x_hat0=np.zeros(2), dt=0.1)
        assert bool(linear_prechecks(p)) is bad, a22
    # the same matrix read in continuous time: a22 = 0.5 is unstable there
    assert linear_prechecks(Plant(id="c", A=np.diag([0.3, 0.5]), B=B, C=C, f=zero, x0=np.ones(2),
                                  x_hat0=np.zeros(2)))


# -- the closed loop's spectra ------------------------------------------------------------------------------
def test_closed_loop_rates_are_per_second_in_discrete_time():
    p = linear_plant(0.05)
    K, F = dlqg(p)
    loop = checks.closed_loop(p, K, F)
    rx = np.abs(np.linalg.eigvals(p.A + p.B @ F)).max()
    re = np.abs(np.linalg.eigvals(p.A - K @ p.C)).max()
    assert loop.growth_x == pytest.approx(math.log(rx) / 0.05)
    assert loop.growth_e == pytest.approx(math.log(re) / 0.05)
    assert loop.linearised_rate == pytest.approx(-math.log(max(rx, re)) / 0.05)  # f = 0: no Jacobian term
    assert loop.stable is True
    bad = checks.closed_loop(p, K, np.zeros((1, 2)) + np.array([[0.0, 30.0]]))  # |eig(A + BF)| > 1
    assert bad.stable is False and bad.growth_x > 0


def test_the_linearised_rate_includes_the_jacobian_at_zero():
    d = PLANTS.create("flexible_link_d10ms_v1")
    K, F = dlqg(d)
    J = d.jacobian(np.zeros(4))
    want = max(np.abs(np.linalg.eigvals(d.A + J + d.B @ F)).max(), np.abs(np.linalg.eigvals(d.A + J - K @ d.C)).max())
    assert checks.closed_loop(d, K, F).linearised_rate == pytest.approx(-math.log(want) / d.dt)


def test_a_deadbeat_loop_grows_at_minus_infinity():
    A = np.array([[0.0, 1.0], [0.0, 0.0]])
    p = Plant(id="db", A=A, B=np.array([[0.0], [1.0]]), C=np.array([[1.0, 0.0]]),
              f=lambda x: np.zeros_like(np.asarray(x, dtype=float)), x0=np.ones(2), x_hat0=np.zeros(2), dt=1.0)
    loop = checks.closed_loop(p, np.array([[0.0], [0.0]]), np.zeros((1, 2)))  # A is nilpotent
    assert loop.growth_x == -math.inf and loop.stable and loop.linearised_rate == math.inf


# -- the stepped simulation ---------------------------------------------------------------------------------
def test_a_linear_loop_steps_like_python_controls_discrete_simulation():
    p = linear_plant(0.05)
    K, F = dlqg(p)
    A, B, C = p.A, p.B, p.C
    # (x, e) coordinates: x+ = (A + BF) x - BF e, e+ = (A - KC) e
    loop = control.ss(np.block([[A + B @ F, -B @ F], [np.zeros((2, 2)), A - K @ C]]), np.zeros((4, 1)), np.eye(4), 0,
                      0.05)
    tr = simulate_controller(p, F, K=K, t_final=3.0)
    ref = control.initial_response(loop, T=np.arange(61) * 0.05, X0=np.concatenate([p.x0, p.x0 - p.x_hat0]))
    np.testing.assert_allclose(tr.t, np.arange(61) * 0.05, rtol=1e-12)
    np.testing.assert_allclose(tr.x, ref.outputs[:2], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(tr.e, ref.outputs[2:], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(tr.u, F @ tr.x_hat, rtol=1e-12)
    assert tr.status == "ok" and tr.nfev == 60 and tr.dense is None


def test_a_nonlinear_loop_steps_like_python_controls_nonlinear_discrete_system():
    """The documented recurrence, written here as a python-control nlsys with the plant's dt."""
    p = PLANTS.create("flexible_link_d10ms_v1")
    K, F = dlqg(p)

    def update(t, z, u, params):
        x, xh = z[:4], z[4:]
        uk = F @ xh
        return np.concatenate([p.A @ x + p.B @ uk + p.f(x), p.A @ xh + p.B @ uk + p.f(xh) + K @ (p.C @ x - p.C @ xh)])

    sys = control.nlsys(update, lambda t, z, u, params: z, inputs=0, outputs=8, states=8, dt=p.dt)
    T = np.arange(201) * p.dt
    ref = control.input_output_response(sys, T, initial_state=np.concatenate([p.x0, p.x_hat0]))
    tr = simulate_controller(p, F, K=K, t_final=2.0)
    np.testing.assert_allclose(np.vstack([tr.x, tr.x_hat]), ref.outputs, rtol=1e-9, atol=1e-12)


def test_a_horizon_that_is_not_a_multiple_of_dt_is_rounded_up():
    p = linear_plant(0.3)
    K, F = dlqg(p)
    tr = simulate_controller(p, F, K=K, t_final=1.0)
    assert tr.t.size == 5 and tr.t[-1] == pytest.approx(1.2)


def test_statuses_of_a_stepped_run():
    p = linear_plant(0.05)
    K, F = dlqg(p)
    unstable = np.array([[-300.0, 0.0]])  # |eig(A + BF)| > 1
    tr = simulate_controller(p, unstable, K=K, t_final=20.0)
    assert tr.status == "diverged" and tr.t.size < 401 and "exceeded" in tr.message
    assert np.linalg.norm(np.concatenate([tr.x[:, -1], tr.x_hat[:, -1]])) > 1e6
    assert simulate_controller(p, F, K=K, t_final=20.0, options=SimOptions(max_nfev=10)).status == "budget"
    tr = simulate_controller(p, F, K=K, t_final=20.0, options=SimOptions(max_wall_s=1e-9))
    assert tr.status == "timeout" and tr.t.size < 401
    with pytest.raises(ValueError, match="discrete"):
        simulate(p, K, F)  # the ODE path refuses a discrete plant


def test_noise_spreads_the_error_as_the_discrete_lyapunov_equation_says():
    """e+ = (A - KC) e - K v with v ~ N(0, s^2): stationary covariance S = (A-KC) S (A-KC)' + s^2 K K'."""
    p = linear_plant(0.05)
    K, F = dlqg(p)
    s = 0.1
    tr = simulate_controller(p, F, K=K, t_final=3000.0, noise=s, seed=3)
    S = solve_discrete_lyapunov(p.A - K @ p.C, s**2 * K @ K.T)
    E = tr.e[:, 1000:]
    assert np.mean(np.sum(E * E, axis=0)) == pytest.approx(np.trace(S), rel=0.1)
    again = simulate_controller(p, F, K=K, t_final=3000.0, noise=s, seed=3)
    np.testing.assert_array_equal(again.x, tr.x)


class FilterForm:
    """A run-time estimator written here: update x_hat <- x_hat + M (y - C x_hat), predict by the model."""

    def __init__(self, plant, M, x0, with_model=False):
        self.p, self.M, self.xh, self.dt = plant, M, np.array(x0, dtype=float), plant.dt
        self.predicts_with_model = with_model
        self.seen = []

    @property
    def x(self):
        return self.xh.copy()

    def update(self, y):
        self.xh = self.xh + self.M @ (y - self.p.C @ self.xh)

    def predict(self, u, x_next=None):
        own = self.p.A @ self.xh + self.p.B @ u + self.p.f(self.xh)
        if self.predicts_with_model:
            self.seen.append((own, x_next))
            own = x_next
        self.xh = own


@pytest.mark.parametrize("with_model", [False, True])
def test_a_runtime_estimator_updates_then_predicts_at_every_step(with_model):
    p = PLANTS.create("flexible_link_d10ms_v1")
    K, F = dlqg(p)
    M = np.linalg.lstsq(p.A, K, rcond=None)[0]  # the filter gain of the predictor gain K
    est = FilterForm(p, M, p.x_hat0, with_model)
    tr = simulate_controller(p, F, estimator=est, t_final=1.0)
    x, xh = p.x0.copy(), p.x_hat0.copy()  # the recurrence, here: update at k, u_k, plant and model step
    for k in range(101):
        xh = xh + M @ (p.C @ x - p.C @ xh)
        np.testing.assert_allclose(tr.x_hat[:, k], xh, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(tr.x[:, k], x, rtol=1e-9, atol=1e-12)
        u = F @ xh
        x, xh = p.A @ x + p.B @ u + p.f(x), p.A @ xh + p.B @ u + p.f(xh)
    for own, given in est.seen:
        np.testing.assert_allclose(given, own, rtol=1e-12, atol=1e-15)
    assert len(est.seen) == (100 if with_model else 0)


def test_an_estimator_at_another_period_is_refused():
    p = PLANTS.create("flexible_link_d10ms_v1")
    K, F = dlqg(p)
    est = FilterForm(p, np.zeros((4, 2)), p.x_hat0)
    est.dt = 0.02
    with pytest.raises(ValueError, match="sample time"):
        simulate_controller(p, F, estimator=est, t_final=1.0)


def test_a_batch_of_a_discrete_plant_is_stepped_member_by_member():
    from bench.batch import simulate_batch, simulate_digital_batch

    p = PLANTS.create("flexible_link_d10ms_v1")
    K, F = dlqg(p)
    rng = np.random.default_rng(0)
    X, XH = rng.standard_normal((4, 3)), rng.standard_normal((4, 3))
    b = simulate_batch(p, K, F, X, XH, t_final=2.0)
    assert b.method == "stepped" and b.t.size == 201 and not b.diverged.any()
    for j in range(3):
        one = simulate_controller(p, F, K=K, t_final=2.0, x0=X[:, j], x_hat0=XH[:, j])
        np.testing.assert_allclose(b.x[:, j, :], one.x, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(b.x_hat[:, j, :], one.x_hat, rtol=1e-9, atol=1e-12)
    assert simulate_batch(p, K, np.array([[0.0, 300.0, 0.0, 0.0]]), X, XH, t_final=20.0).diverged.all()
    with pytest.raises(ValueError, match="discrete-time"):
        simulate_digital_batch(p, K, F, p.x0, p.x_hat0, h=0.01)


# -- the pipeline's rows ------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, kw_only=True)
class DiscreteLQG(Design):
    """dlqr + dlqe (python-control), written here; forms in both time domains for the tests."""

    time_domains = ("continuous", "discrete")

    def design(self, plant, constants):
        K, F = dlqg(plant)
        return DesignResult(status="computed", route="formula", K=K, F=F)


@dataclasses.dataclass(frozen=True, kw_only=True)
class OnlyDiscrete(DiscreteLQG):
    time_domains = ("discrete",)


@pytest.fixture(scope="module")
def d10():
    p = PLANTS.create("flexible_link_d10ms_v1")
    return p, compute_constants(p, seed=0, n_samples=2000, n_refine=1)


def test_a_discrete_pair_is_judged_in_discrete_time(d10):
    p, rep = d10
    p = PLANTS.create("flexible_link_d10ms_v1", t_final=5.0)  # short: the linearised rate sets the horizon
    rec = evaluate_pair(p, DiscreteLQG(), rep, RunOptions(n_samples=2000), design_id="dlqg").record
    K, F = dlqg(p)
    rx = np.abs(np.linalg.eigvals(p.A + p.B @ F)).max()
    assert rec["status"] == "computed" and rec["stabilizing"] is True
    assert rec["max_re_eig_x"] == pytest.approx(math.log(rx) / p.dt)
    assert rec["sim_status"] == "ok" and rec["converged"]
    # certified by the discrete-time ladder: its contraction factor per step is its rate per second's, and no
    # certificate beats the spectral radius of the loop (linearised at the origin: f'(0) enters)
    lam = checks.closed_loop(p, K, F).linearised_rate
    assert rec["certified"] and rec["cert_structured"] == "certified"
    assert rec["contraction"] == pytest.approx(math.exp(-rec["decay_rate"] * p.dt), rel=1e-12)
    assert 0 < rec["decay_rate"] <= lam and rec["contraction"] >= math.exp(-lam * p.dt)
    # the horizon rule reads the certified rate per second: (ln 1000 + ln(cond P) / 2) / lam seconds
    assert 5.0 < rec["cert_horizon_s"] < 50.0  # per step it would be 100 times longer
    assert rec["horizon_rule"] == "certified rate" and rec["horizon_s"] == math.ceil(rec["cert_horizon_s"])
    assert 0 < rec["settling_x_s"] <= rec["horizon_s"]
    assert rec["tail_rate"] > 0 and "INCONSISTENT" not in rec["reason"]


def test_a_design_without_the_plants_time_domain_is_inapplicable(d10):
    p, rep = d10
    rec = evaluate_pair(p, "lqr+rajamani", rep, RunOptions(n_samples=2000)).record  # continuous only
    assert rec["status"] == "inapplicable" and "lqr+rajamani has no discrete-time form" in rec["reason"]
    flex = PLANTS.create("flexible_link")
    rec = evaluate_pair(flex, OnlyDiscrete(), compute_constants(flex, n_samples=500, n_refine=0),
                        RunOptions(n_samples=500), design_id="only_d").record
    assert rec["status"] == "inapplicable" and "only_d has no continuous-time form" in rec["reason"]


def test_the_default_catalog_holds_a_discrete_flexible_link():
    p = PLANTS.create("flexible_link_d10ms_v1")
    c = PLANTS.create("flexible_link")
    assert p.dt == 0.01 and p.t_final == 20.0 and p.params["version"] == 1
    np.testing.assert_allclose(p.A, expm(0.01 * c.A), rtol=1e-12)
    assert "zero-order hold" in p.source and "h = 0.01 s" in p.source


def test_python_control_views_of_a_discrete_plant_keep_its_dt():
    from bench.interop import closed_loop_nlsys, controller_ss, plant_nlsys

    p = PLANTS.create("flexible_link_d10ms_v1")
    K, F = dlqg(p)
    assert plant_nlsys(p).dt == p.dt and controller_ss(p, K, F).dt == p.dt
    loop = closed_loop_nlsys(p, K, F)
    ref = control.input_output_response(loop, np.arange(101) * p.dt, initial_state=np.concatenate([p.x0, p.x_hat0]))
    tr = simulate_controller(p, F, K=K, t_final=1.0)
    np.testing.assert_allclose(ref.outputs[:4], tr.x, rtol=1e-9, atol=1e-12)
