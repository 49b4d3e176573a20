"""The comparison designs of issue 3: LQR/LQE (python-control), RH Riccati, LMI observers, EKF."""

from dataclasses import replace

import control
import numpy as np
import pytest
from scipy.linalg import solve_continuous_are

from bench.estimators import ContinuousDiscreteEKF
from bench.harness import RunOptions, run
from bench.registry import DESIGNS
from bench.simulate import simulate_sampled
from designs import DesignError
from designs._parts import ESTIMATORS, FEEDBACKS
from designs.ekf import EKFSpec
from designs.riccati import rh_solve
from plants import Constants
from plants.flexible_link import PAPER_F
from tests.conftest import hurwitz


def test_lqr_gain_is_python_controls_and_solves_its_riccati_equation(flex, flex_constants):
    Q, R = np.diag([1.0, 2.0, 3.0, 4.0]), np.array([[0.5]])
    part = FEEDBACKS.create("lqr", Q=Q, R=R).compute(flex, flex_constants.valid)
    K_lqr, _, _ = control.lqr(flex.A, flex.B, Q, R, method="scipy")
    np.testing.assert_allclose(part.gain, -np.asarray(K_lqr), rtol=1e-10)  # u = F x = -K_lqr x
    # independently: scipy's CARE and K = R^-1 B'S
    S = solve_continuous_are(flex.A, flex.B, Q, R)
    np.testing.assert_allclose(part.gain, -np.linalg.solve(R, flex.B.T @ S), rtol=1e-8)
    assert hurwitz(flex.A + flex.B @ part.gain)


def test_lqe_gain_is_python_controls(flex, flex_constants):
    part = ESTIMATORS.create("lqe").compute(flex, flex_constants.valid)
    L, _, _ = control.lqe(flex.A, np.eye(4), flex.C, np.eye(4), np.eye(2), method="scipy")
    np.testing.assert_allclose(part.gain, L, rtol=1e-10)


def test_rh_riccati_residual_and_hurwitz(flex, flex_constants):
    part = ESTIMATORS.create("rh_riccati").compute(flex, flex_constants.valid)
    assert part.status == "feasible"
    eps, alpha = part.params["eps"], 0.333
    P, _ = rh_solve(flex.A, flex.C, alpha, eps)
    n = 4
    res = flex.A @ P + P @ flex.A.T + P @ (alpha**2 * np.eye(n) - flex.C.T @ flex.C / eps) @ P + (1 + eps) * np.eye(n)
    assert np.abs(res).max() < 1e-8 * max(1.0, np.abs(P).max() ** 2)
    assert np.linalg.eigvalsh(P).min() > 0
    np.testing.assert_allclose(part.gain, P @ flex.C.T / (2 * eps))
    assert hurwitz(flex.A - part.gain @ flex.C)


def test_rh_riccati_reports_no_solution_for_large_alpha(flex):
    part = ESTIMATORS.create("rh_riccati").compute(flex, Constants(alpha=100.0))
    assert part.status == "infeasible" and "no stabilizing solution" in part.reason and part.gain is None


@pytest.mark.parametrize("est", ["rajamani", "zhang_osl"])
def test_lmi_observers_verified(flex, flex_constants, est):
    part = ESTIMATORS.create(est).compute(flex, flex_constants.valid)
    assert part.status == "feasible", part.reason
    assert part.margin < 0 and part.min_eig["P"] > 0
    # the LMI implies (A-KC)'P + P(A-KC) < 0, hence A - KC Hurwitz
    assert hurwitz(flex.A - part.gain @ flex.C)


def test_lmi_observer_decay_is_honoured(flex, flex_constants):
    part = ESTIMATORS.create("rajamani", decay=0.5).compute(flex, flex_constants.valid)
    assert part.status == "feasible"
    # V' <= -2 lam V for the linear part gives every eigenvalue of A - KC real part <= -lam
    assert np.linalg.eigvals(flex.A - part.gain @ flex.C).real.max() <= -0.5 + 1e-9


def _ekf_run(flex, noise):
    ekf = ContinuousDiscreteEKF(flex, EKFSpec(dt=0.01), flex.x_hat0)
    return simulate_sampled(flex, PAPER_F, ekf=ekf, dt=0.01, noise=noise, seed=1)


def test_ekf_converges_without_noise(flex):
    tr = _ekf_run(flex, 0.0)
    ne = np.linalg.norm(tr.e, axis=0)
    assert tr.status == "ok" and ne[0] > 1 and (ne < 1e-3).any()
    assert ne[-1] < 1e-3


def test_ekf_bounded_with_noise(flex):
    tr = _ekf_run(flex, 0.01)
    ne = np.linalg.norm(tr.e, axis=0)
    assert tr.status == "ok"
    # bounded, at the level of the noise (sigma = 0.01), far below the initial error (~3.9)
    assert ne[len(ne) // 2:].max() < 0.2 and np.linalg.norm(tr.x[:, -1]) < 0.2


def test_ekf_with_destabilizing_feedback_is_diverged(flex):
    ekf = ContinuousDiscreteEKF(flex, EKFSpec(dt=0.01), flex.x_hat0)
    tr = simulate_sampled(flex, -3 * PAPER_F, ekf=ekf, dt=0.01)
    assert tr.status == "diverged"


def test_pairings_are_registered_and_visible():
    ids = DESIGNS.ids()
    for did in ("lqr+rh_riccati", "lqr+rajamani", "lqr+zhang_osl", "lqr+lqe", "lqr+ekf"):
        assert did in ids


def test_inapplicable_design_is_skipped_with_reason(flex):
    d = DESIGNS.create("lqr+zhang_osl")
    why = d.applicable(flex, Constants(alpha=0.333))
    assert why is not None and "rho" in why


@pytest.mark.parametrize(
    "kind, pid, kw, name",
    [
        ("feedback", "lqr", dict(Q=[[1.0, 2.0], [0.0, 1.0]]), "Q"),
        ("feedback", "lqr", dict(R=[[-1.0]]), "R"),
        ("feedback", "lqr", dict(Q=[[np.nan]]), "Q"),
        ("estimator", "lqe", dict(RN=[[1.0, 0.0], [0.0, 0.0]]), "RN"),
        ("estimator", "rh_riccati", dict(eps=0.0), "eps"),
        ("estimator", "rh_riccati", dict(eps=-1.0), "eps"),
        ("estimator", "ekf", dict(dt=0.0), "dt"),
        ("estimator", "ekf", dict(r=-1.0), "r"),
        ("estimator", "rajamani", dict(decay=-1.0), "decay"),
    ],
)
def test_bad_parameters_named(kind, pid, kw, name):
    reg = FEEDBACKS if kind == "feedback" else ESTIMATORS
    with pytest.raises(DesignError, match=rf"^{name}:"):
        reg.create(pid, **kw)


def test_weight_of_wrong_size_named(flex, flex_constants):
    with pytest.raises(DesignError, match="^Q:"):
        FEEDBACKS.create("lqr", Q=np.eye(3)).compute(flex, flex_constants.valid)


def test_sample_time_not_dividing_horizon_is_an_error_row():
    res = run(["flexible_link"], ["lqr+ekf"], RunOptions(n_samples=500))
    assert res.frame()["status"].iloc[0] == "feasible"
    from bench.registry import DESIGNS as D

    D.register("_ekf_bad_dt", lambda: D.create("lqr+ekf", estimator_params={"dt": 0.3}))
    try:
        df = run(["flexible_link"], ["_ekf_bad_dt"], RunOptions(n_samples=500)).frame()
    finally:
        D.unregister("_ekf_bad_dt")
    assert df["status"].iloc[0] == "error" and "dt" in df["reason"].iloc[0]


def test_noise_scenario_is_seeded_and_comparable():
    opts = RunOptions(n_samples=500, noise=0.01, seed=4, t_final=10.0)
    a = run(["flexible_link"], ["lqr+ekf", "lqr+lqe"], opts).frame().set_index("design")
    b = run(["flexible_link"], ["lqr+ekf", "lqr+lqe"], opts).frame().set_index("design")
    for d in ("lqr+ekf", "lqr+lqe"):
        assert np.isfinite(a.loc[d, "rms_e"]) and a.loc[d, "rms_e"] > 0
        assert a.loc[d, "rms_e"] == b.loc[d, "rms_e"]  # same seed, same noise, same numbers
        assert a.loc[d, "noise"] == 0.01
