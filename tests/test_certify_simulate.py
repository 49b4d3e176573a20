"""Certificates and simulation of the flexible link's closed loop.

The decay rate of the certificate ladder is checked from both sides with quantities computed
here: above by the linearisation's rate (a quadratic V with V' <= -2 lam V makes the loop
linearised at 0 decay at rate lam), below by re-solving the paper's (20), written here from the
paper, at 0.9 times the rate, and along trajectories integrated here with scipy: V(z(t)) must stay
under V(z(0)) e^{-2 lam t}.
"""

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from bench.certify import Knowledge, certify
from bench.metrics import settling_time, trajectory_metrics
from bench.simulate import simulate
from plants.flexible_link import PAPER_F, PAPER_K
from tests.conftest import closed_loop, jacobian_at_zero, linearised_rate, paper20_certificate


@pytest.fixture(scope="module")
def paper_cert(flex, flex_knowledge):
    return certify(flex, PAPER_K, PAPER_F, flex_knowledge)


def test_paper_gains_certified_and_converge(flex, paper_cert):
    assert paper_cert.certified and paper_cert.levels["paper"].certified
    tr = simulate(flex, PAPER_K, PAPER_F)
    assert tr.status == "ok" and tr.t[-1] == 20.0
    # docs/paper.md: ||x(20)|| ~ 1e-9 from the paper's initial conditions
    assert np.linalg.norm(tr.x[:, -1]) < 1e-6
    np.testing.assert_allclose(tr.x[:, 0], [-2, -2, -1.5, 2])
    np.testing.assert_allclose(tr.x_hat[:, 0], [0.5, 1, 1, -1])


def test_decay_rate_below_the_linearisation(flex, paper_cert):
    """Upper bound: V' <= -2 lam V near 0 forces every eigenvalue of the linearised loop to Re <= -lam."""
    lin = linearised_rate(flex, PAPER_K, PAPER_F)
    # the test's own Df(0): f4 = -c sin(x3) gives d f4 / d x3 = -c at 0
    J = jacobian_at_zero(flex.f, 4)
    assert J[3, 2] == pytest.approx(-flex.params["c"], rel=1e-8) and np.count_nonzero(np.abs(J) > 1e-12) == 1
    for lv in paper_cert.levels.values():
        if lv.certified:
            assert 0 < lv.decay_rate <= lin * (1 + 1e-9), lv


def test_decay_rate_reverified_by_the_papers_20(flex, flex_knowledge, paper_cert):
    """Lower bound: the paper's (20), rebuilt here, is negative definite at 0.9 x the paper level's rate."""
    lam = paper_cert.levels["paper"].decay_rate
    assert lam > 0
    margin, p_min, r_min = paper20_certificate(flex, PAPER_K, PAPER_F, flex_knowledge.constants, 0.9 * lam)
    assert margin < -1e-7 and p_min > 0 and r_min > 0
    # and the rate is not far from the best (20) gives: at twice the rate, no certificate
    margin2, _, _ = paper20_certificate(flex, PAPER_K, PAPER_F, flex_knowledge.constants, 2 * lam)
    assert margin2 > 0


def test_certified_rate_holds_along_trajectories(flex, paper_cert):
    """V(z(t)) <= V(z(0)) e^{-2 lam t} for the best level's P and rate, on trajectories integrated here."""
    best = paper_cert.best
    assert best.radius is None  # the flexible link's constants are global: any initial condition
    P, lam = best.P, best.decay_rate
    assert np.linalg.eigvalsh((P + P.T) / 2)[0] > 0
    rng = np.random.default_rng(0)
    starts = [np.concatenate([flex.x0, flex.x_hat0])] + [rng.normal(0, 3, 8) for _ in range(4)]
    t = np.linspace(0, 6, 601)
    for z0 in starts:
        sol = solve_ivp(closed_loop(flex, PAPER_K, PAPER_F), (0, t[-1]), z0, t_eval=t, method="DOP853",
                        rtol=1e-10, atol=1e-12)
        assert sol.success
        x, xh = sol.y[:4], sol.y[4:]
        z = np.vstack([x, x - xh])
        V = np.einsum("it,ij,jt->t", z, P, z)
        bound = V[0] * np.exp(-2 * lam * t)
        assert np.all(V <= bound * (1 + 1e-6) + 1e-12 * V[0])


def test_destabilizing_gain_not_certified(flex, flex_knowledge):
    F = -PAPER_F  # A + BF has an eigenvalue in the right half plane: no quadratic certificate exists
    assert np.linalg.eigvals(flex.A + flex.B @ F).real.max() > 0
    cert = certify(flex, PAPER_K, F, flex_knowledge)
    assert not cert.certified and math.isnan(cert.decay_rate)
    for lv in cert.levels.values():
        assert lv.status in ("not certified", "marginal") and lv.reason and math.isnan(lv.decay_rate)


def test_destabilizing_gain_is_provably_not_certified(flex, flex_knowledge):
    # v* (Acl' P + P Acl) v = 2 Re(lam) v* P v > 0 at an unstable eigenvector v of A + BF (z = (v, 0), w = 0):
    # no P > 0 makes the certificate's matrix negative definite, so the level is decided, not marginal
    cert = certify(flex, PAPER_K, -PAPER_F, flex_knowledge, rates=False)
    assert {lv.status for lv in cert.levels.values()} == {"not certified"}


def test_linear_simulation_matches_matrix_exponential(flex):
    lin = replace(flex, id="linear", f=lambda x: np.zeros_like(np.asarray(x, dtype=float)), channels=None,
                  jacobian=None)
    tr = simulate(lin, PAPER_K, PAPER_F, t_final=2.0)
    BF = lin.B @ PAPER_F
    L = np.block([[lin.A, BF], [PAPER_K @ lin.C, lin.A + BF - PAPER_K @ lin.C]])
    z_end = expm(L * 2.0) @ np.concatenate([lin.x0, lin.x_hat0])
    np.testing.assert_allclose(np.concatenate([tr.x[:, -1], tr.x_hat[:, -1]]), z_end, rtol=1e-6, atol=1e-8)


def test_blowup_reported_as_diverged_quickly(flex):
    tr = simulate(flex, PAPER_K, -3 * PAPER_F)
    assert tr.status == "diverged" and tr.t[-1] < 20
    m = trajectory_metrics(tr.t, tr.x, tr.x_hat, tr.u, finished=False)
    assert not m["converged"]


def test_settling_time_of_exponential():
    t = np.linspace(0, 10, 100001)
    # e^{-t} stays below 2 % of its peak (1) from t = ln 50 on
    assert abs(settling_time(t, np.exp(-t)) - math.log(50)) < 1e-3
    assert math.isnan(settling_time(t, np.ones_like(t)))


def test_metrics_closed_forms():
    t = np.linspace(0, 5, 50001)
    x = np.vstack([np.exp(-t), np.zeros_like(t)])
    xh = np.vstack([np.exp(-t) - np.exp(-2 * t), np.zeros_like(t)])  # e = e^{-2t}
    u = np.vstack([3 * np.sin(t)])
    m = trajectory_metrics(t, x, xh, u)
    assert abs(m["iae_e"] - (1 - math.exp(-10)) / 2) < 1e-6
    assert abs(m["peak_u"] - 3.0) < 1e-6
    # peak of ||z|| = ||(x, e)|| is sqrt(2) at t = 0; ||x(5)|| = e^-5 = 6.7e-3 > 1e-3 sqrt(2): not converged
    assert not m["converged"]
    # on [0, 8]: e^-8 = 3.4e-4 < 1.4e-3 and ||e(8)|| = e^-16: converged
    t8 = np.linspace(0, 8, 8001)
    x8 = np.vstack([np.exp(-t8)])
    assert trajectory_metrics(t8, x8, x8 - np.exp(-2 * t8), x8)["converged"]


def test_trusting_knowledge_is_the_plants_declaration(flex):
    k = Knowledge.trusting(flex)
    assert k.constants == flex.bounds and k.channels is flex.channels


def test_large_sparse_plant_simulates_with_the_factored_loop_as_with_the_dense_matrix():
    # the chain at n = 240 takes the factored path (sparse A, B, C; gains as factors); the same
    # trajectory as the dense loop matrix [[A, BF], [KC, A + BF - KC]] applied by numpy, to tolerance
    from bench import simulate as sim
    from designs.structured import Structured
    from plants.chain import chain_plant

    plant = chain_plant(N=120)
    res = Structured(route="riccati").design(plant, plant.bounds)
    assert isinstance(sim._loop_operator(plant, res.K, res.F), sim._FactoredLoop)
    opts = sim.SimOptions(n_points=51, rtol=1e-9, atol=1e-12)
    fast = sim.simulate(plant, res.K, res.F, t_final=2.0, options=opts)
    L = np.block([[plant.A, plant.B @ res.F], [res.K @ plant.C, plant.A + plant.B @ res.F - res.K @ plant.C]])

    def rhs(_, z):
        return L @ z + np.asarray(plant.f(z.reshape(2, plant.n).T)).T.ravel()

    from scipy.integrate import solve_ivp
    ref = solve_ivp(rhs, (0, 2.0), np.concatenate([plant.x0, plant.x_hat0]), method="DOP853", rtol=1e-9, atol=1e-12,
                    t_eval=fast.t)
    np.testing.assert_allclose(np.vstack([fast.x, fast.x_hat]), ref.y, rtol=1e-6, atol=1e-8)
