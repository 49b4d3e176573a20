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
