"""Ceilings are taken over the members the certified level's class contains: for scalar constants the
symmetric members L that meet every constant, not only L = s I. moving_object_v1's class (alpha = 300,
rho = 0, QIB (0, -300)) holds every -M with 0 <= M <= 300 I, rank-one M included; the test builds such
members itself, checks the constants by hand and computes their loops' rates by eigenvalues."""

from __future__ import annotations

import numpy as np
import pytest

from bench.certify import certify
from bench.constants import Knowledge
from bench.registry import DESIGNS, PLANTS
from bench.witness import admits, rate_ceiling


def _rate(plant, K, F, L) -> float:
    eig = np.concatenate([np.linalg.eigvals(plant.A + L + plant.B @ F), np.linalg.eigvals(plant.A + L - K @ plant.C)])
    return float(-eig.real.max())


@pytest.mark.parametrize("design", ["thm1", "lqr+lqe"])
def test_the_ceiling_is_at_most_the_slowest_rank_one_member_built_here(design):
    plant = PLANTS.create("moving_object_v1")
    c = plant.bounds
    res = DESIGNS.create(design).design(plant, c)
    K, F = np.asarray(res.K), np.asarray(res.F)
    know = Knowledge.trusting(plant)
    # L = -300 v v' (eigenvalues 0 and -300): sym L = L <= 0 = rho I; L'L = 300^2 v v' = -300 L, so
    # L'L <= beta I + gamma sym L with beta = 0, gamma = -300 (with equality); ||L|| = 300 = alpha
    members = []
    for th in np.linspace(0.0, np.pi, 181):
        v = np.array([np.cos(th), np.sin(th)])
        members.append(-300.0 * np.outer(v, v))
    rates = [_rate(plant, K, F, L) for L in members]
    L = members[int(np.argmin(rates))]
    assert np.linalg.eigvalsh(L).max() <= 1e-9 and np.linalg.norm(L, 2) <= 300 + 1e-9
    assert np.linalg.eigvalsh(L.T @ L + 300 * L).max() <= 1e-6
    assert admits(L, ("osl", "qib", "lip"), c)
    s_only = min(_rate(plant, K, F, s * np.eye(2)) for s in np.linspace(-300, 0, 3001))
    assert min(rates) < 0.9 * s_only  # the multiples of I alone would overstate the ceiling
    for scalars in (("osl", "qib"), ("osl", "qib", "lip")):
        ceil, how = rate_ceiling(plant, K, F, know, channels=False, scalars=scalars)
        assert ceil <= min(rates) * (1 + 1e-6), (scalars, ceil, min(rates), how)
    cert = certify(plant, K, F, know)
    assert cert.certified and cert.decay_rate <= min(rates)
