"""Witnesses against a global certificate, rate ceilings and certificates from x0 (bench.witness,
bench.certify.certify_from_x0), each checked by code that does not share the certificate's: the
closed loop is integrated here in (x, x_hat) coordinates, linear members by the matrix exponential,
level sets sampled with the plant's true f."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from bench.certify import certify, explain
from bench.constants import Knowledge
from bench.findings import findings
from bench.registry import DESIGNS, PLANTS
from bench.witness import rate_ceiling
from plants import Channels, PlantError
from plants._core import cubic_slopes, saturation_slopes, sine_slopes


def _pair(pid: str):
    plant = PLANTS.create(pid)
    res = DESIGNS.create("lqr+lqe").design(plant, plant.bounds)
    return plant, np.asarray(res.K), np.asarray(res.F)


@pytest.fixture(scope="module")
def pendulum():
    plant, K, F = _pair("pendulum_v1")
    know = Knowledge.trusting(plant)
    return plant, K, F, explain(certify(plant, K, F, know), plant, K, F, know)


@pytest.fixture(scope="module")
def joint():
    plant, K, F = _pair("flexible_joint_v1")
    know = Knowledge.trusting(plant)
    return plant, K, F, explain(certify(plant, K, F, know), plant, K, F, know)


def _loop(plant, K, F):
    """The observer-based loop in (x, x_hat), written out from (1) and the observer (independent of bench)."""
    n = plant.n

    def rhs(_t, s):
        x, xh = s[:n], s[n:]
        u = F @ xh
        return np.concatenate([plant.A @ x + plant.B @ u + plant.f(x),
                               plant.A @ xh + plant.B @ u + plant.f(xh) + K @ (plant.C @ x - plant.C @ xh)])
    return rhs


@pytest.mark.parametrize("fixture, expected", [
    ("pendulum", [3.5072, 0, 0, 0]),
    ("joint", [2.9156, 0, 2.8697, 0, 1.2841, 1.5979, 1.5572, 2.5097]),
])
def test_equilibrium_witness_is_an_equilibrium_of_the_true_loop(fixture, expected, request):
    plant, K, F, cert = request.getfixturevalue(fixture)
    eq = next(w for w in cert.witnesses if w.kind == "equilibrium")
    z = eq.z
    assert np.allclose(np.abs(z), np.abs(expected), atol=2e-3)  # the prototype (either sign: f is odd)
    n = plant.n
    s0 = np.concatenate([z[:n], z[:n] - z[n:]])  # (x, x_hat = x - e)
    sol = solve_ivp(_loop(plant, K, F), (0, 5.0), s0, rtol=1e-11, atol=1e-12)
    assert sol.success and np.abs(sol.y - s0[:, None]).max() < 1e-5 * max(1.0, np.abs(s0).max())


@pytest.mark.parametrize("fixture, lo, hi", [("pendulum", 1.0, 9.81), ("joint", 1.495, 3.33)])
def test_linear_witness_member_grows(fixture, lo, hi, request):
    plant, K, F, cert = request.getfixturevalue(fixture)
    w = next(w for w in cert.witnesses if w.kind == "linear member")
    c = float(w.slopes[0])
    assert lo - 1e-3 <= c <= hi + 1e-12  # the destabilising range, inside the declared box
    ch = plant.channels
    L = c * ch.G @ ch.H
    n = plant.n
    # the linear loop in (x, x_hat), by the matrix exponential
    M = np.block([[plant.A + L, plant.B @ F], [K @ plant.C, plant.A + L + plant.B @ F - K @ plant.C]])
    s0 = np.random.default_rng(1).standard_normal(2 * n)
    assert np.linalg.norm(expm(40.0 * M) @ s0) > 1e3 * np.linalg.norm(s0)
    # and every level is ruled out without a solve
    assert all(r.status == "not certified" and r.reason.startswith("no certificate over") for r in cert.levels.values())
    assert all(r.n_solves == 0 for r in cert.levels.values())


def test_flexible_joint_is_certified_from_x0_and_the_level_set_decays(joint):
    plant, K, F, cert = joint
    loc = cert.local
    assert loc is not None and cert.best is loc and loc.certified
    lam, P, r = loc.decay_rate, loc.P, loc.radius
    assert 0.2 <= r <= 2.0 and lam > 0.5  # the issue: r = 0.375 gives lam = 0.854
    n = plant.n
    z0 = np.concatenate([plant.x0, plant.x0 - plant.x_hat0])
    v0 = float(z0 @ P @ z0)
    # uniform samples inside the ellipsoid {z' P z <= v0}, and its boundary
    rng = np.random.default_rng(7)
    N = 20000
    U = rng.standard_normal((2 * n, N))
    U /= np.linalg.norm(U, axis=0)
    U *= rng.random(N) ** (1 / (2 * n))
    U[:, :2000] /= np.linalg.norm(U[:, :2000], axis=0)
    Lc = np.linalg.cholesky(P / v0)  # z' P z / v0 = |Lc' z|^2
    Z = np.linalg.solve(Lc.T, U)
    X, E = Z[:n], Z[n:]
    XH = X - E
    H = plant.channels.H
    assert np.abs(H @ X).max() <= r * (1 + 1e-9) and np.abs(H @ XH).max() <= r * (1 + 1e-9)
    BF = plant.B @ F
    dX = plant.A @ X + BF @ XH + plant.f(X)
    dXH = plant.A @ XH + BF @ XH + plant.f(XH) + K @ (plant.C @ (X - XH))
    dZ = np.vstack([dX, dX - dXH])
    V = np.einsum("ij,ij->j", Z, P @ Z)
    dV = 2 * np.einsum("ij,ij->j", Z, P @ dZ)
    assert np.all(dV + 2 * lam * V <= 1e-9 * np.abs(P).max())


def test_pendulum_has_no_certificate_from_x0_and_says_how_far_it_looked(pendulum):
    _, _, _, cert = pendulum
    assert cert.local is None and not cert.certified
    assert "no local quadratic certificate containing z0" in cert.local_note and "up to r = " in cert.local_note
    r_last = float(cert.local_note.split("up to r = ")[1].split()[0])
    assert 1.0 < r_last < 3.5072  # beyond |x0| = 1, short of the equilibrium


def test_flexible_link_ceiling_is_the_slowest_straight_line():
    plant, K, F = _pair("flexible_link")
    know = Knowledge.trusting(plant)
    ceil, how = rate_ceiling(plant, K, F, know, channels=True, scalars=())
    assert abs(ceil - 0.8367) <= 0.01 * 0.8367 and "grid" in how
    cert = certify(plant, K, F, know)
    assert cert.certified and cert.decay_rate <= ceil * (1 + 0.03)
    # a member's rate bounds the certificate: the linearisation at 0 (slope -c of -c sin) is one
    c = plant.channels.hi[0]
    for slope in (-c, c):
        L = slope * plant.channels.G @ plant.channels.H
        eig = np.concatenate([np.linalg.eigvals(plant.A + L + plant.B @ F), np.linalg.eigvals(plant.A + L - K @ plant.C)])
        assert ceil <= -eig.real.max() + 1e-12


@pytest.mark.parametrize("narrow, phi, lo, hi", [
    (sine_slopes(-2.0), lambda z: -2.0 * np.sin(z), -2.0, 2.0),
    (saturation_slopes(1.5), lambda z: 1.5 * np.clip(z, -1, 1), 0.0, 1.5),
    (cubic_slopes(0.7), lambda z: -0.7 * z**3, -100.0, 0.0),
])
@pytest.mark.parametrize("r", [0.3, 0.9, 1.7, 4.0])
def test_narrowed_slopes_hold_and_are_tight_on_samples(narrow, phi, lo, hi, r):
    ch = Channels(G=np.eye(1), H=np.eye(1), phi=phi, lo=lo, hi=hi, narrow=narrow)
    a_lo, a_hi = (float(v[0]) for v in ch.slopes_on(r))
    rng = np.random.default_rng(3)
    a, b = rng.uniform(-r, r, (2, 200000))
    a = np.concatenate([a, np.linspace(-r, r, 2001)[:-1], [r, r * 0.999, 0.0]])
    b = np.concatenate([b, np.linspace(-r, r, 2001)[1:], [-r, r, 1e-6]])
    keep = np.abs(a - b) > 1e-9
    s = (phi(a[keep]) - phi(b[keep])) / (a[keep] - b[keep])
    assert s.min() >= a_lo - 1e-9 and s.max() <= a_hi + 1e-9
    span = max(a_hi - a_lo, 1e-12)
    assert s.min() <= a_lo + 0.02 * span + 1e-6 and s.max() >= a_hi - 0.02 * span - 1e-6


def test_a_narrowing_that_leaves_no_slope_is_refused():
    ch = Channels(G=np.eye(1), H=np.eye(1), phi=np.sin, lo=-1.0, hi=1.0, narrow=lambda r: (2.0, 3.0))
    with pytest.raises(PlantError, match="channels.narrow"):
        ch.slopes_on(1.0)
    with pytest.raises(PlantError, match="channels.narrow"):
        Channels(G=np.eye(1), H=np.eye(1), phi=np.sin, lo=-1.0, hi=1.0, narrow=3.0)


def test_findings_split_uncertified_converging_pairs_by_witness():
    frame = pd.DataFrame({"plant": ["p"] * 3, "design": ["a", "b", "c"], "converged": [True, True, True],
                          "certified": [False, False, True], "witness": ["equilibrium", "", ""],
                          "decay_rate": [math.nan, math.nan, 1.0], "cert_level": ["", "", "structured"],
                          "cert_scope": ["", "", "global"], "peak_u": [1.0, 1.0, 1.0], "rate_ratio": [math.nan] * 2 + [0.9],
                          "status": ["computed"] * 3, "reason": [""] * 3})
    got = findings(frame, {})["plants"]["p"]
    assert got["no_certificate_can_exist"] == ["a"] and got["no_certificate_found"] == ["b"]
    assert got["best"]["rate_ratio"] == 0.9


def test_pipeline_rows_say_why(catalog_constants):
    from bench.pipeline import RunOptions, evaluate_pair

    rows = {}
    for pid in ("pendulum_v1", "flexible_joint_v1"):
        plant = PLANTS.create(pid)
        rows[pid] = evaluate_pair(plant, "lqr+lqe", catalog_constants(pid), RunOptions(fail_fast=True)).record
    pend, joint = rows["pendulum_v1"], rows["flexible_joint_v1"]
    assert not pend["certified"] and "equilibrium" in pend["witness"] and "linear member" in pend["witness"]
    assert "no global certificate exists" in pend["reason"] and "up to r = " in pend["reason"]
    assert joint["certified"] and joint["cert_scope"] == "from x0" and joint["converged"] and joint["in_region"]
    assert 0 < joint["rate_ratio"] <= 1 + 0.03 and "equilibrium" in joint["witness"]


def _scalar(c: float):
    """x' = -x + u + c sin x, y = x: with F = K = 0 the equilibria are the roots of x = c sin x (x_hat = x)."""
    from plants import Plant
    return Plant(id=f"scalar_sine_{c}", A=[[-1.0]], B=[[1.0]], C=[[1.0]], f=lambda x: c * np.sin(x),
                 x0=[0.5], x_hat0=[0.0], jacobian=lambda x: np.array([[c * np.cos(x[0])]]),
                 channels=Channels(G=[[1.0]], H=[[1.0]], phi=lambda s: c * np.sin(s), lo=-abs(c), hi=abs(c)))


@pytest.mark.parametrize("c, root", [(0.9, None), (2.0, 1.895494267)])
def test_no_equilibrium_proof_agrees_with_the_closed_form(c, root):
    from bench.witness import equilibrium_witness, no_equilibrium
    plant = _scalar(c)
    K, F = np.zeros((1, 1)), np.zeros((1, 1))
    know = Knowledge.trusting(plant)
    # |c sin x| <= |c| |x| < |x| for |c| < 1: the origin is the only root of x = c sin x; for c = 2 there is 1.8955
    assert no_equilibrium(plant, K, F, know) is (root is None)
    eq = equilibrium_witness(plant, K, F, know)
    if root is None:
        assert eq is None
    else:
        # x and x_hat = x - e are each a root of s = c sin s (the loops decouple with F = K = 0)
        x, xh = eq.z[0], eq.z[0] - eq.z[1]
        assert all(min(abs(v), abs(abs(v) - root)) < 1e-6 for v in (x, xh)) and max(abs(x), abs(xh)) > 1


def test_pendulum_equilibrium_is_not_disproved_by_the_vertex_test(pendulum):
    from bench.witness import no_equilibrium
    plant, K, F, _ = pendulum
    assert not no_equilibrium(plant, K, F, Knowledge.trusting(plant))  # it has one at x1 = 3.5072


def test_an_equilibrium_rules_out_global_levels_without_a_solve(pendulum, monkeypatch):
    import bench.witness as W
    plant, K, F, _ = pendulum
    monkeypatch.setattr(W, "linear_witness", lambda *a, **k: None)  # as if every straight line were stable
    cert = certify(plant, K, F, Knowledge.trusting(plant))
    assert cert.equilibria_searched and [w.kind for w in cert.witnesses] == ["equilibrium"]
    ruled = [r for r in cert.levels.values() if r.status != "inapplicable"]
    assert ruled and all(r.status == "not certified" and r.n_solves == 0 and "equilibrium" in r.reason for r in ruled)
    assert "ruled out without a solve by the equilibrium" in cert.reason(witnessed=True)
