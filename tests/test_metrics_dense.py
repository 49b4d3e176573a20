"""Settling times and IAE come from the integrator's dense output, not the output grid: closed forms
on a linear scalar loop for horizons from 1e-3 to 1e5 s."""

import math

import numpy as np
import pytest

from bench.metrics import trajectory_metrics
from bench.simulate import SimOptions, simulate
from plants import Plant


@pytest.mark.parametrize("T", [1e-3, 1.0, 1e3, 1e5])
def test_settling_and_iae_match_closed_forms_whatever_the_horizon(T):
    # x' = u, u = -k x_hat, y = x, x_hat' = u + l (x - x_hat): e' = -l e, e(t) = e0 e^{-l t};
    # x' = -k x + k e. Rates scaled so that everything settles within the horizon's first percent
    k, l = 2000.0 / T, 1000.0 / T
    plant = Plant(id="scalar", A=[[0.0]], B=[[1.0]], C=[[1.0]], f=lambda x: 0 * np.asarray(x, dtype=float),
                  x0=[1.0], x_hat0=[0.0], t_final=T)
    tr = simulate(plant, [[l]], [[-k]], options=SimOptions(n_points=201, rtol=1e-10, atol=1e-14))
    m = trajectory_metrics(tr.t, tr.x, tr.x_hat, tr.u, dense=tr.dense)
    e0 = 1.0
    # ||e|| = e0 e^{-l t} peaks at t = 0: 2 % of it at ln(50) / l
    assert m["settling_e_s"] == pytest.approx(math.log(50.0) / l, rel=1e-6)
    assert m["iae_e"] == pytest.approx(e0 * (1 - math.exp(-l * T)) / l, rel=1e-6)
    # x(t) = e^{-k t} + k (e^{-l t} - e^{-k t}) / (k - l) = 2 e^{-l t} - e^{-2 l t} (k = 2 l), decreasing
    # from its peak x(0) = 1: with y = e^{-l t}, 2 y - y^2 = 0.02 gives y = 1 - sqrt(0.98)
    y = 1 - math.sqrt(0.98)
    assert m["settling_x_s"] == pytest.approx(-math.log(y) / l, rel=1e-6)
    # the output grid alone would resolve only T / 200
    assert T / 200 > 1e-3 * m["settling_e_s"]


def test_the_iae_is_the_gauss_legendre_sum_of_the_dense_output_at_the_step_nodes():
    # the IAE reads ||e|| at each step's 5 Gauss-Legendre nodes from the values computed on the finer grid;
    # evaluated at the nodes alone, the dense output gives the same sum, to the last bit (9 states: a norm over
    # more than 8 entries is where a different memory layout would sum in another order)
    from scipy.integrate import solve_ivp

    from bench.metrics import dense_metrics

    n = 9
    rng = np.random.default_rng(3)
    M = rng.standard_normal((2 * n, 2 * n)) - 3 * np.eye(2 * n)
    sol = solve_ivp(lambda t, z: M @ z + 0.1 * np.sin(z), (0.0, 5.0), rng.standard_normal(2 * n),
                    method="DOP853", dense_output=True, rtol=1e-9).sol
    ts = np.unique(sol.ts)
    h = np.diff(ts)
    x, w = np.polynomial.legendre.leggauss(5)
    nodes = (ts[:-1, None] + h[:, None] * ((x + 1) / 2)[None, :]).ravel()
    Z = sol(nodes)
    ne = np.linalg.norm(Z[:n] - Z[n:], axis=0)
    expected = float(np.sum(h * (ne.reshape(-1, 5) @ (w / 2))))
    assert dense_metrics(sol, n, 0.0, 5.0)["iae_e"] == expected
