"""bench.interop: python-control systems agree with hand-built expectations and with bench.simulate."""

from __future__ import annotations

import control
import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from bench.interop import closed_loop_nlsys, controller_ss, observer_nlsys, plant_nlsys
from bench.registry import PLANTS
from bench.simulate import simulate
from plants import Plant, PlantError
from plants.flexible_link import PAPER_F, PAPER_K


@pytest.fixture(scope="module")
def link() -> Plant:
    return PLANTS.create("flexible_link")


def assert_same_multiset(got, want, tol):
    """Complex multisets equal up to tol (optimal one-to-one matching, so multiplicities count)."""
    got, want = np.asarray(got, complex), np.asarray(want, complex)
    assert got.shape == want.shape, (got, want)
    dist = np.abs(got[:, None] - want[None, :])
    rows, cols = linear_sum_assignment(dist)
    assert dist[rows, cols].max() <= tol * max(1.0, np.abs(want).max()), (np.sort_complex(got), np.sort_complex(want))


def test_controller_ss_signals_and_matrices(link):
    ctrl = controller_ss(link, PAPER_K, PAPER_F)
    assert isinstance(ctrl, control.StateSpace)
    assert (ctrl.ninputs, ctrl.noutputs, ctrl.nstates) == (link.p, link.m, link.n)
    assert ctrl.input_labels == ["y[0]", "y[1]"]
    assert ctrl.output_labels == ["u[0]"]
    assert ctrl.state_labels == [f"xhat[{i}]" for i in range(4)]
    assert ctrl.isctime()
    np.testing.assert_array_equal(ctrl.D, 0.0)


def test_controller_transfer_function_by_hand(link):
    """G(s) = F (sI - (A + BF - KC))^{-1} K at a few points, computed with numpy alone."""
    A, B, C = link.A, link.B, link.C
    M = A + B @ PAPER_F - PAPER_K @ C
    ctrl = controller_ss(link, PAPER_K, PAPER_F)
    for s in (0.3j, 1.0 + 2.0j, 10j, -0.5 + 0.1j):
        want = PAPER_F @ np.linalg.solve(s * np.eye(4) - M, PAPER_K)
        got = np.asarray(ctrl(s)).reshape(want.shape)
        np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12)


def test_separation_principle_with_control_feedback(link):
    """Plant's linear part in positive feedback with controller_ss: eig = eig(A+BF) U eig(A-KC)."""
    A, B, C = link.A, link.B, link.C
    P = control.ss(A, B, C, 0)
    loop = control.feedback(P, controller_ss(link, PAPER_K, PAPER_F), sign=+1)
    want = np.concatenate([np.linalg.eigvals(A + B @ PAPER_F), np.linalg.eigvals(A - PAPER_K @ C)])
    assert_same_multiset(loop.poles(), want, 1e-8)


def test_observer_linearises_to_controller_plus_jacobian(link):
    """observer_nlsys at 0 is controller_ss plus the Jacobian of f at 0 (f(x_hat) is in the observer)."""
    obs = observer_nlsys(link, PAPER_K, PAPER_F)
    assert isinstance(obs, control.NonlinearIOSystem)
    assert obs.input_labels == ["y[0]", "y[1]"] and obs.output_labels == ["u[0]"]
    lin = control.linearize(obs, np.zeros(4), np.zeros(2))
    ctrl = controller_ss(link, PAPER_K, PAPER_F)
    np.testing.assert_allclose(lin.A, ctrl.A + link.jacobian(np.zeros(4)), atol=1e-6)
    np.testing.assert_allclose(lin.B, ctrl.B, atol=1e-8)
    np.testing.assert_allclose(lin.C, ctrl.C, atol=1e-8)


def test_plant_nlsys_signals_and_rhs(link):
    sys = plant_nlsys(link)
    assert sys.input_labels == ["u[0]"]
    assert sys.output_labels == ["y[0]", "y[1]"]
    assert sys.state_labels == [f"x[{i}]" for i in range(4)]
    x = np.array([0.3, -0.2, 0.7, 0.1])
    u = np.array([1.5])
    np.testing.assert_allclose(sys.dynamics(0.0, x, u), link.A @ x + link.B @ u + link.f(x), rtol=1e-14)
    np.testing.assert_allclose(sys.output(0.0, x, u), link.C @ x, rtol=1e-14)


def test_closed_loop_matches_bench_simulate(link):
    """input_output_response of closed_loop_nlsys agrees with bench.simulate on the same grid."""
    T = 10.0
    traj = simulate(link, PAPER_K, PAPER_F, t_final=T)
    assert traj.status == "ok"
    loop = closed_loop_nlsys(link, PAPER_K, PAPER_F)
    n = link.n
    assert loop.ninputs == 0 and loop.nstates == 2 * n and loop.noutputs == 2 * n + link.m
    assert loop.state_labels == [f"x[{i}]" for i in range(n)] + [f"xhat[{i}]" for i in range(n)]
    resp = control.input_output_response(
        loop, traj.t, initial_state=np.concatenate([link.x0, link.x_hat0]),
        solve_ivp_method="DOP853", solve_ivp_kwargs={"rtol": 1e-10, "atol": 1e-12})
    assert resp.success
    # both integrators resolve the loop to ~1e-8 relative; the states reach |x| ~ 30
    scale = max(1.0, np.abs(traj.x).max(), np.abs(traj.u).max())
    tol = dict(rtol=0.0, atol=1e-6 * scale)
    np.testing.assert_allclose(resp.outputs[:n], traj.x, **tol)
    np.testing.assert_allclose(resp.outputs[n:2 * n], traj.x_hat, **tol)
    np.testing.assert_allclose(resp.outputs[2 * n:], traj.u, **tol)
    np.testing.assert_allclose(resp.states, np.vstack([traj.x, traj.x_hat]), **tol)
    # the loop converges (not a comparison of two trivially zero signals)
    assert np.abs(traj.x[:, 0]).max() > 0.1 and np.abs(resp.outputs[:n, -1]).max() < 1e-2


@pytest.mark.parametrize("builder", [controller_ss, observer_nlsys, closed_loop_nlsys])
def test_gain_shapes_are_validated(link, builder):
    with pytest.raises(ValueError, match=r"K: expected shape \(4, 2\)"):
        builder(link, PAPER_K.T, PAPER_F)
    with pytest.raises(ValueError, match=r"F: expected shape \(1, 4\)"):
        builder(link, PAPER_K, PAPER_F.T)
    with pytest.raises(ValueError, match="K: entries must be finite"):
        builder(link, np.full((4, 2), np.nan), PAPER_F)
    # complex gains are refused by name, never truncated to their real part (also as Python complex numbers)
    with pytest.raises(ValueError, match=r"F: complex entries \(largest imaginary part 0.002.*the gains must be real"):
        builder(link, PAPER_K, PAPER_F + 2e-3j)
    with pytest.raises(ValueError, match="K: complex entries"):
        builder(link, [[complex(v, 1.0) for v in row] for row in PAPER_K], PAPER_F)
    builder(link, PAPER_K + 0j, PAPER_F)  # a complex type with zero imaginary parts is real
    with pytest.raises(TypeError, match="plant"):
        builder("flexible_link", PAPER_K, PAPER_F)


def _osc_f(x):
    return np.stack([0.0 * x[0], -0.5 * np.sin(x[0])])


def test_from_statespace_round_trip():
    A = np.array([[0.0, 1.0], [-1.0, -0.5]])
    B = np.array([[0.0], [1.0]])
    C = np.array([[1.0, 0.0]])
    sys = control.ss(A, B, C, 0, name="osc")
    plant = Plant.from_statespace(sys, f=_osc_f)
    np.testing.assert_array_equal(plant.A, A)
    np.testing.assert_array_equal(plant.B, B)
    np.testing.assert_array_equal(plant.C, C)
    assert plant.id == "osc"
    # and back: the linearisation of plant_nlsys at 0 is sys plus the Jacobian of f
    lin = control.linearize(plant_nlsys(plant), np.zeros(2), np.zeros(1))
    np.testing.assert_allclose(lin.A, A + np.array([[0.0, 0.0], [-0.5, 0.0]]), atol=1e-6)
    np.testing.assert_allclose(lin.B, B, atol=1e-12)
    np.testing.assert_allclose(lin.C, C, atol=1e-12)
    # a linear plant (f omitted) round-trips exactly
    lin0 = control.linearize(plant_nlsys(Plant.from_statespace(sys)), np.zeros(2), np.zeros(1))
    np.testing.assert_allclose(lin0.A, A, atol=1e-8)


def test_from_statespace_rejects_feedthrough_and_takes_dt_and_disturbances():
    A, B, C = [[0.0, 1.0], [-1.0, -0.5]], [[0.0], [1.0]], [[1.0, 0.0]]
    with pytest.raises(PlantError, match=r"\bD\b"):
        Plant.from_statespace(control.ss(A, B, C, [[0.2]]), f=_osc_f)
    # a discrete system keeps its sample time; an unspecified one (dt = True) is refused
    assert Plant.from_statespace(control.ss(A, B, C, 0, dt=0.1), f=_osc_f).dt == 0.1
    with pytest.raises(PlantError, match="sample time"):
        Plant.from_statespace(control.ss(A, B, C, 0, dt=True), f=_osc_f)
    # extra inputs named as disturbances become Bw and Dw; D may be nonzero there only
    sys = control.ss(A, [[0.0, 1.0], [1.0, 0.2]], C, [[0.0, 0.5]], inputs=["u", "w"])
    plant = Plant.from_statespace(sys, f=_osc_f, disturbances="w")
    np.testing.assert_array_equal(plant.B, [[0.0], [1.0]])
    np.testing.assert_array_equal(plant.Bw, [[1.0], [0.2]])
    np.testing.assert_array_equal(plant.Dw, [[0.5]])
    with pytest.raises(PlantError, match="no input named 'v'"):
        Plant.from_statespace(sys, f=_osc_f, disturbances="v")
    with pytest.raises(PlantError, match=r"\bD\b"):  # w not declared: its D column is a feedthrough from "u"
        Plant.from_statespace(sys, f=_osc_f)
