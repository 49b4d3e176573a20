import math
from dataclasses import replace

import numpy as np
from scipy.linalg import expm

from bench.certify import certify
from bench.metrics import settling_time, trajectory_metrics
from bench.simulate import simulate
from plants.flexible_link import PAPER_F, PAPER_K


def test_paper_gains_certified_and_converge(flex, flex_constants):
    cert = certify(flex, PAPER_K, PAPER_F, flex_constants.valid)
    assert cert.certified
    # a certified decay rate of V can never beat the slowest closed-loop eigenvalue
    slowest = min(-np.linalg.eigvals(flex.A + flex.B @ PAPER_F).real.max(),
                  -np.linalg.eigvals(flex.A - PAPER_K @ flex.C).real.max())
    assert 0 < cert.decay_rate <= slowest
    tr = simulate(flex, PAPER_K, PAPER_F)
    assert tr.status == "ok" and tr.t[-1] == 20.0
    assert np.linalg.norm(tr.x[:, -1]) < 1e-6
    np.testing.assert_allclose(tr.x[:, 0], [-2, -2, -1.5, 2])
    np.testing.assert_allclose(tr.x_hat[:, 0], [0.5, 1, 1, -1])


def test_destabilizing_gain_not_certified(flex, flex_constants):
    F = -PAPER_F  # A + BF has an eigenvalue in the right half plane: no quadratic certificate exists
    assert np.linalg.eigvals(flex.A + flex.B @ F).real.max() > 0
    assert not certify(flex, PAPER_K, F, flex_constants.valid).certified


def test_linear_simulation_matches_matrix_exponential(flex):
    lin = replace(flex, id="linear", f=lambda x: np.zeros_like(np.asarray(x, dtype=float)), channels=None)
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
    # ||x(5)|| / peak = e^-5 = 6.7e-3 > 1e-3: not converged on [0, 5]; on [0, 8] e^-8 = 3.4e-4 is
    assert not m["converged"]
    t8 = np.linspace(0, 8, 8001)
    x8 = np.vstack([np.exp(-t8)])
    assert trajectory_metrics(t8, x8, x8 - np.exp(-2 * t8), x8)["converged"]
