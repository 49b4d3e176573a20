"""Slopes are narrowed only where they are declared (plants.Channels.slopes_on): a channel's declared
slopes hold on |z_i| <= radius ||H_i||, beyond it only what narrow(r) says counts. The issue's plant:
slope 0.3 on |z| <= 1 and a steeper slope beyond, declared [0, 0.3] on ||x|| <= 1 with a truthful
narrow(r). Any certificate the suite reports is checked here by sampling V'/V with the true f inside
the level set it claims, written from (1) and (6) without the suite's code."""

from __future__ import annotations

import numpy as np
import pytest

from bench.certify import certify, explain
from bench.constants import Knowledge
from plants import Channels, Plant


def _kinked(steep: float):
    """phi(z) = 0.3 z on |z| <= 1, slope ``steep`` beyond; its truthful narrowing."""

    def phi(z):
        z = np.asarray(z, dtype=float)
        a = np.abs(z)
        return np.sign(z) * np.where(a <= 1, 0.3 * a, 0.3 + steep * (a - 1))

    return phi, (lambda r: (0.3, 0.3) if r <= 1 else (0.3, steep))


def _plant(steep: float) -> Plant:
    phi, narrow = _kinked(steep)
    ch = Channels(G=[[0.0], [-1.0]], H=[[1.0, 0.0]], phi=phi, lo=0.0, hi=0.3, radius=1.0, narrow=narrow)
    return Plant(id="kinked", A=[[0.0, 1.0], [0.0, 0.0]], B=[[0.0], [1.0]], C=[[1.0, 0.0]], f=ch.apply,
                 x0=[1.2, 0.0], x_hat0=[0.0, 0.0], channels=ch)


def test_declared_slopes_hold_up_to_the_radius_times_the_row_norm_and_narrow_alone_beyond():
    phi, narrow = _kinked(6.0)
    ch = Channels(G=[[1.0], [0.0]], H=[[2.0, 0.0]], phi=phi, lo=0.0, hi=0.3, radius=1.0, narrow=narrow)
    # ||x|| <= 1 gives |z| = |2 x_1| <= 2: the declared [0, 0.3] holds there and is intersected with narrow(r)
    assert [v.tolist() for v in ch.slopes_on(1.5)] == [[0.3], [0.3]]
    assert [v.tolist() for v in ch.slopes_on(2.0)] == [[0.3], [0.3]]
    assert [v.tolist() for v in ch.slopes_on(2.5)] == [[0.3], [6.0]]  # beyond: narrow(r) alone
    glob = Channels(G=[[1.0], [0.0]], H=[[2.0, 0.0]], phi=phi, lo=0.0, hi=0.3, narrow=narrow)
    assert [v.tolist() for v in glob.slopes_on(2.5)] == [[0.3], [0.3]]  # global slopes hold everywhere


def _max_decay_ratio(plant, K, F, P, v0, n_points=200_000, seed=0) -> float:
    """The largest sampled V'/V on {z' P z <= v0} with the plant's true f (z = (x, e))."""
    rng = np.random.default_rng(seed)
    d = 2 * plant.n
    u = rng.standard_normal((d, n_points))
    u *= rng.random(n_points) ** (1 / d) / np.linalg.norm(u, axis=0)
    Z = np.sqrt(v0) * np.linalg.solve(np.linalg.cholesky(P).T, u)  # uniform in the ellipsoid
    x, e = Z[:plant.n], Z[plant.n:]
    BF = plant.B @ F
    fx = plant.f(x)
    Zd = np.vstack([(plant.A + BF) @ x - BF @ e + fx, (plant.A - K @ plant.C) @ e + fx - plant.f(x - e)])
    return float((2 * np.einsum("in,ij,jn->n", Z, P, Zd) / np.einsum("in,ij,jn->n", Z, P, Z)).max())


@pytest.mark.parametrize("steep, expect_certificate", [(6.0, False), (1.0, True)])
def test_no_reported_certificate_from_x0_is_contradicted_by_sampling(steep, expect_certificate):
    plant = _plant(steep)
    K, F = np.array([[1.0], [-0.1]]), np.array([[0.1, -1.0]])  # slope 0 destabilises: no global certificate
    know = Knowledge.trusting(plant)
    cert = explain(certify(plant, K, F, know), plant, K, F, know)
    assert not any(r.certified for r in cert.levels.values())
    assert (cert.local is not None) == expect_certificate, cert.local_note
    if cert.local is not None:
        P, lam = cert.local.P, cert.local.decay_rate
        z0 = np.concatenate([plant.x0, plant.x0 - plant.x_hat0])
        assert _max_decay_ratio(plant, K, F, P, float(z0 @ P @ z0)) <= -2 * lam * (1 - 1e-9)
