"""Nine properties of the core that a plausible one-line bug breaks without any other test noticing
(issue 31, "What was seen" item 9). Each test names, in its docstring, the change it catches; each
expectation is derived here (by hand, or from the definitions), not copied from the code's output."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.certify import certify
from bench.constants import Knowledge
from plants import Channels, Constants, Plant


def test_the_structured_design_meets_its_decay_target_on_both_sides():
    """Catches an x-side LMI written with ``lam Q`` instead of ``2 lam Q`` (it then proves half the target)."""
    from bench.registry import DESIGNS, PLANTS

    plant = PLANTS.create("chain_v1")  # n = 6: the SDP route
    res = DESIGNS.create("structured").design(plant, plant.bounds)
    p = res.params
    assert res.status == "feasible" and p["decay_target"] > 0.1
    # each side's own rate (the generalised eigenvalue of its verified side matrix) is at least the target
    assert p["x_rate"] >= p["decay_target"] * (1 - 1e-9), p
    assert p["e_rate"] >= p["decay_target"] * (1 - 1e-9), p


def _small_plant(const_radius: float, channel_radius: float) -> Plant:
    """x' = A x + B u + G 0.2 sin(x1), with constants and channels declared on different radii."""
    G, H = np.array([[0.0], [1.0]]), np.array([[1.0, 0.0]])
    ch = Channels(G=G, H=H, phi=lambda z: 0.2 * np.sin(z), lo=-0.2, hi=0.2, radius=channel_radius)
    return Plant(id="two_radii", A=[[0.0, 1.0], [-1.0, -1.0]], B=[[0.0], [1.0]], C=[[1.0, 0.0]], f=ch.apply,
                 x0=[0.5, 0.0], x_hat0=[0.0, 0.0], channels=ch,
                 bounds=Constants(alpha=0.2, rho=0.2, beta=0.04, gamma=0.0, radius=const_radius))


@pytest.mark.parametrize("const_radius, channel_radius", [(1.0, 2.0), (2.0, 1.0)])
def test_a_certificate_holds_on_the_smallest_radius_of_what_it_uses(const_radius, channel_radius):
    """Catches ``max`` for ``min`` in the radius of a level using both constants and channels."""
    plant = _small_plant(const_radius, channel_radius)
    K, F = np.array([[2.0], [1.0]]), np.array([[-1.0, -1.0]])
    cert = certify(plant, K, F, Knowledge.trusting(plant), levels=("full", "structured"), inherit=False)
    full, structured = cert.levels["full"], cert.levels["structured"]
    assert full.certified and structured.certified
    assert full.radius == const_radius  # the constants alone
    assert structured.radius == min(const_radius, channel_radius)  # the constants (in channel coordinates) too


def test_an_equilibrium_witness_needs_a_residual_at_the_solvers_accuracy():
    """Catches a root accepted at a residual of 1e-3: f(x) = -x (1e-4 + (x - 2)^2) comes within 2e-4 of zero
    at x = 2 but vanishes only at 0, so the origin is the loop's only equilibrium (worked out below)."""
    from bench.witness import equilibrium_witness

    def f(x):
        x = np.asarray(x, dtype=float)
        return -x * (1e-4 + (x - 2.0) ** 2)

    plant = Plant(id="near_root", A=[[0.0]], B=[[1.0]], C=[[1.0]], f=f, x0=[1.0], x_hat0=[0.0])
    K, F = np.array([[1.0]]), np.array([[0.0]])
    # with F = 0: x' = f(x), zero only at x = 0; there e' = -e - f(-e) = -e (1 + 1e-4 + (e + 2)^2), zero only at e = 0
    assert equilibrium_witness(plant, K, F, Knowledge()) is None
    # and the search does find a true equilibrium when there is one: f(x) = -x (x - 2)^2 vanishes at x = 2
    plant2 = Plant(id="true_root", A=[[0.0]], B=[[1.0]], C=[[1.0]], x0=[1.0], x_hat0=[0.0],
                   f=lambda x: -np.asarray(x) * (np.asarray(x) - 2.0) ** 2)
    w = equilibrium_witness(plant2, K, F, Knowledge())
    assert w is not None and np.allclose(w.z, [2.0, 0.0], atol=1e-4) and w.residual < 1e-9


def test_program_verdict_rejects_a_p_that_is_not_positive_definite_even_when_the_lmi_holds():
    """Catches a verdict that checks the LMI matrix only: M = [[P - 2]] < 0 at P = -1, but P must be > 0."""
    import cvxpy as cp

    from bench import lmi

    P = cp.Variable((1, 1), symmetric=True, name="P")
    slack = cp.Variable(name="slack")
    prog = lmi.Program(cp.Problem(cp.Maximize(slack), [slack <= 1]), {"P": P, "slack": slack}, {},
                       lambda d: [[d["P"] - 2.0]], ("P",))
    prog.last_status = "optimal"
    slack.value = 0.5
    P.value = np.array([[-1.0]])
    verdict, margin = prog.verdict()
    assert margin == -3.0 and verdict == "violated"
    P.value = np.array([[1.0]])  # P > 0 and M = [[-1]] < 0: verified
    assert prog.verdict() == ("verified", -1.0)


def test_each_diverged_member_of_a_batch_stops_at_its_own_limit():
    """Catches one limit for the whole batch (the smallest member's): x' = x from z0 = (1, 1) and from 1000 (1, 1)."""
    from bench.batch import BATCH_OPTIONS, simulate_batch, simulate_digital_batch

    plant = Plant(id="unstable", A=[[1.0]], B=[[1.0]], C=[[1.0]], f=lambda x: 0 * np.asarray(x, dtype=float),
                  x0=[1.0], x_hat0=[1.0], t_final=30.0)
    X = np.array([[1.0, 1000.0]])
    K, F = np.zeros((1, 1)), np.zeros((1, 1))
    z0 = np.sqrt(2) * X[0]  # ||(x, x_hat)|| of each member
    for tr, limit in ((simulate_batch(plant, K, F, X, X.copy(), t_final=30.0), BATCH_OPTIONS.blowup * z0),
                      (simulate_digital_batch(plant, K, F, X, X.copy(), h=0.05, t_final=30.0), 1e6 * z0)):
        final = np.sqrt(tr.x[0, :, -1] ** 2 + tr.x_hat[0, :, -1] ** 2)
        assert tr.diverged.all()
        assert np.all(final >= limit) and np.all(final <= 1.2 * limit), (final, limit)


def test_the_corrected_theorem_1_uses_eta1_twice_the_weighted_constants_for_negative_gamma():
    """Catches eta1 = eps1 rho + eps2 beta (the factor 2 lost) in the fixed-eps form (gamma < 0)."""
    from designs.thm1 import Thm1

    # f = 0.2 sin(x) componentwise: slopes in [-0.2, 0.2], so rho = 0.2, alpha = 0.2, and with gamma = -0.1
    # beta = max over slopes c of c^2 - gamma c = 0.04 + 0.02 = 0.06
    c = Constants(alpha=0.2, rho=0.2, beta=0.06, gamma=-0.1)
    plant = Plant(id="sine2", A=[[0.0, 1.0], [-1.0, -1.0]], B=[[0.0], [1.0]], C=[[1.0, 0.0]],
                  f=lambda x: 0.2 * np.sin(np.asarray(x, dtype=float)), x0=[1.0, 0.0], x_hat0=[0.0, 0.0])
    p = Thm1().design(plant, c).params
    assert p["form"].startswith("fixed eps")
    assert math.isclose(p["eta1"], 2 * (p["eps1"] * c.rho + p["eps2"] * c.beta), rel_tol=1e-12)
    assert math.isclose(p["eta2"], p["eps2"] * c.gamma - p["eps1"], rel_tol=1e-12)


def test_a_riccati_route_side_that_is_only_marginal_is_not_verified():
    """Catches a side accepted unless "violated": M = [[-1, 1], [1, -1]] has eigenvalues 0 and -2 (marginal)."""
    from bench import joint
    from designs._riccati_route import _verified_side

    M = np.array([[-1.0, 1.0], [1.0, -1.0]])
    assert joint.verdict(M) == "marginal"
    sol, why = _verified_side("x-side", M, np.eye(2), np.zeros((1, 2)), (1.0, 1.0), 1.0, 0.1, None)
    assert sol is None and "marginal" in why
    ok, _ = _verified_side("x-side", -np.eye(2), np.eye(2), np.zeros((1, 2)), (1.0, 1.0), 1.0, 0.1, None)
    assert ok is not None


def test_the_euler_observer_step_uses_f_of_the_estimate():
    """Catches f(x) for f(x_hat) in the digital Euler observer: one period by hand."""
    from bench.batch import simulate_digital_batch

    def f(x):
        x = np.asarray(x, dtype=float)
        return np.stack([0 * x[0], -np.sin(x[0])])

    A, B, C = np.array([[0.0, 1.0], [-1.0, -1.0]]), np.array([[0.0], [1.0]]), np.array([[1.0, 0.0]])
    plant = Plant(id="euler", A=A, B=B, C=C, f=f, x0=[1.0, 0.0], x_hat0=[-0.5, 0.3])
    K, F, h = np.array([[0.7], [0.2]]), np.array([[-0.4, -0.9]]), 0.1
    x0, xh0 = np.array([1.0, 0.0]), np.array([-0.5, 0.3])
    tr = simulate_digital_batch(plant, K, F, x0[:, None], xh0[:, None], h=h, t_final=5 * h, discretisation="euler")
    k = int(np.flatnonzero(np.isclose(tr.t, h))[0])
    want = xh0 + h * (A @ xh0 + B @ (F @ xh0) + f(xh0) + K @ (C @ (x0 - xh0)))
    np.testing.assert_allclose(tr.x_hat[:, 0, k], want, rtol=1e-12, atol=1e-14)


def test_corollary_1_as_printed_keeps_remark_3s_bound_on_mu1():
    """Catches ``mu1 < 1 / xi`` alone (Remark 3 asks for ``0 < mu1 < min(1, 1 / xi)``): the margin grows with mu1,
    so the solver takes mu1 up to its bound (a damped oscillator with f = (0, -0.3 sin x1), where the printed
    Corollary 1 is feasible)."""
    from bench.registry import DESIGNS

    plant = Plant(id="osc", A=[[0.0, 1.0], [-1.0, -0.5]], B=[[0.0], [1.0]], C=[[1.0, 0.0]],
                  f=lambda x: np.stack([0.0 * x[0], -0.3 * np.sin(x[0])]), x0=[1.0, 0.0], x_hat0=[0.0, 0.0])
    res = DESIGNS.create("cor1_printed").design(plant, Constants(alpha=0.3, rho=0.15, beta=0.09, gamma=0.0))
    p = res.params
    assert res.status == "feasible", res.reason
    assert 0 < p["xi"] < 1 and 0 < p["mu1"] < min(1.0, 1.0 / p["xi"]), p
