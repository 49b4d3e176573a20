"""The published examples of Nguyen, Pathirana & Trinh (Eur. J. Control 2018) and their printed gains.

Every number typed here is the paper's (Examples 1-2, read in its accepted manuscript; docs/literature.md):
the continuous matrices, ts = 1 ms, the printed K (``u = -K x_hat``) and L, the attenuation levels mu. The
expectations are derived here with numpy and python-control, not taken from the suite's output.
"""

from __future__ import annotations

import numpy as np
import pytest

from bench.registry import DESIGNS, PLANTS

TS = 0.001

#: Example 1, eq. (64): Ac, Bc, Wc, Cc, Dc; the printed K and the eight printed entries of L; mu (Theorem 3).
EX1 = dict(Ac=[[0, 1, 0, 0], [-48.6, -1.25, 48.6, 0], [0, 0, 0, 1], [19.5, 0, -19.5, 0]], Bc=[[0], [21.6], [0], [0]],
           Wc=[[1], [0], [0], [0]], C=[[1, 0, 0, 0], [0, 1, 0, 0]], D=[[1], [0]],
           K=[[5705.0767, 33.3035, -3310.2808, 401.3578]],
           L_entries=[0.0010, -0.0857, 0.0000, 0.6452, 0.0000, 0.3858, 0.0000, 0.2444], mu=1.0100,
           x0=[0.1, -0.1, 0.2, -0.2], x_hat0=[0.2, -0.2, 0.1, -0.1])
#: Example 2: Ac, Bc, Wc, Cc, D; the printed K, L; mu (Theorem 1).
EX2 = dict(Ac=[[-1, 1], [1.5, -0.5]], Bc=[[0], [-1]], Wc=[[2], [1]], C=[[0, 1]], D=[[1]],
           K=[[-5.8992, -637.0308]], L=[[0.0020], [0.0010]], mu=1.9956, x0=[0.1, -0.1], x_hat0=[-0.1, 0.1])

PIDS = {"ex1": "nguyen2018_ex1_flexible_joint_v1", "ex2": "nguyen2018_ex2_moving_object_v1"}


def _euler(ex):
    A = np.eye(len(ex["Ac"])) + TS * np.array(ex["Ac"], dtype=float)
    return A, TS * np.array(ex["Bc"], dtype=float), TS * np.array(ex["Wc"], dtype=float)


def _L(ex):
    return np.array(ex["L"]) if "L" in ex else np.array(ex["L_entries"]).reshape(4, 2)  # row by row


def _radius(M):
    return float(np.abs(np.linalg.eigvals(M)).max())


@pytest.mark.parametrize("key,ex", [("ex1", EX1), ("ex2", EX2)])
def test_the_catalog_plant_is_the_papers_euler_model(key, ex):
    p = PLANTS.create(PIDS[key])
    A, B, W = _euler(ex)
    assert p.dt == TS and p.discrete and p.t_final == 50.0
    assert np.allclose(p.A, A, rtol=0, atol=1e-15) and np.allclose(p.B, B, rtol=0, atol=1e-15)
    assert np.array_equal(p.C, np.array(ex["C"], dtype=float))
    assert np.allclose(p.Bw, W, rtol=0, atol=1e-15) and np.array_equal(p.Dw, np.array(ex["D"], dtype=float))
    assert np.array_equal(p.x0, ex["x0"]) and np.array_equal(p.x_hat0, ex["x_hat0"])
    assert "Nguyen" in p.source and ("Example 1" if key == "ex1" else "Example 2") in p.source
    x = np.array(ex["x0"]) * 3
    fc = (np.array([0, 0, 0, -3.33 * np.sin(x[2])]) if key == "ex1" else -x * (x @ x))
    assert np.allclose(p.f(x), TS * fc, rtol=1e-14, atol=0)


def test_example2_claims_the_papers_constants():
    """rho = 0, QIB beta = 0, gamma = -4 r^2 ts, Lipschitz 3 r^2 ts on ||x|| <= r = 10 (the paper, citing [23])."""
    c = PLANTS.create(PIDS["ex2"]).claimed
    r = 10.0
    assert (c.rho, c.beta, c.gamma, c.alpha, c.radius) == pytest.approx((0, 0, -4 * r * r * TS, 3 * r * r * TS, r))


@pytest.mark.parametrize("key,ex", [("ex1", EX1), ("ex2", EX2)])
def test_the_printed_gains_loops_are_stable(key, ex):
    """Spectral radii of A - B K and A - L C below 1 (numpy), and L's first column cancels W (W - L D = 0)."""
    A, B, W = _euler(ex)
    C, D, K = (np.array(ex[k], dtype=float) for k in ("C", "D", "K"))
    L = _L(ex)
    assert _radius(A - B @ K) < 1 and _radius(A - L @ C) < 1
    assert _radius(A) >= 1 - 1e-12  # the open loop is not already stable: the gains do the work
    assert np.allclose(W - L @ D, 0, atol=1e-12)


def test_example1_L_is_read_row_by_row():
    """The column-by-column reading of the eight printed entries gives an unstable observer."""
    A, _, W = _euler(EX1)
    C = np.array(EX1["C"], dtype=float)
    rows = np.array(EX1["L_entries"]).reshape(4, 2)
    cols = np.array(EX1["L_entries"]).reshape(2, 4).T
    assert _radius(A - rows @ C) < 1 < _radius(A - cols @ C)


@pytest.mark.parametrize("key,ex", [("ex1", EX1), ("ex2", EX2)])
def test_the_design_returns_the_printed_gains_in_oslbench_notation(key, ex, catalog_constants):
    p = PLANTS.create(PIDS[key])
    d = DESIGNS.create("nguyen2018_gains")
    res = d.design(p, catalog_constants(PIDS[key], n_samples=2000).used)
    assert res.status == "given"
    assert np.array_equal(res.F, -np.array(ex["K"])) and np.array_equal(res.K, _L(ex))


def test_the_printed_gains_apply_to_the_two_examples_only(catalog_constants):
    d = DESIGNS.create("nguyen2018_gains")
    for pid in ("flexible_joint_v1", "moving_object_v1", "flexible_link_d10ms_v1"):
        p = PLANTS.create(pid)
        assert d.applicable(p, p.claimed) is not None
    ex1 = PLANTS.create(PIDS["ex1"])
    assert d.applicable(ex1, ex1.claimed) is None
    assert d.applicable(ex1.scaled(2.0), ex1.claimed) is None  # same A, B, C: the scaled class
    other = PLANTS.create("flexible_joint_v1").discretise(0.002, "euler")
    assert d.applicable(other, other.claimed) is not None


def _linear_member_hinf(ex, delta):
    """H-infinity norm from w to x of the printed gains' loop with the linear member f = ts * delta (entry
    (4, 3) for Example 1, 0 for Example 2), by python-control (discrete, dt = ts)."""
    import control

    A, B, W = _euler(ex)
    C, D, K = (np.array(ex[k], dtype=float) for k in ("C", "D", "K"))
    L = _L(ex)
    n = A.shape[0]
    M = np.zeros((n, n))
    if n == 4:
        M[3, 2] = TS * delta
    Acl = np.block([[A - B @ K + M, B @ K], [np.zeros((n, n)), A - L @ C + M]])
    Bd = np.vstack([W, W - L @ D])
    Cz = np.hstack([np.eye(n), np.zeros((n, n))])
    Bd = np.hstack([Bd, np.zeros((2 * n, n - 1))])  # square (python-control 0.10.2 sizes by the outputs)
    return float(control.norm(control.ss(Acl, Bd, Cz, np.zeros((n, n)), TS), "inf"))


def test_the_papers_mu_bounds_the_linear_members_gains():
    """mu bounds ||x||_l2 / ||w||_l2 over the whole class, so over its linear members: Example 1's LPV vertices
    (A(4,3) + -ts 3.33) and f's linearisation, Example 2's f = 0 (rho = 0, QIB (0, gamma <= 0) contain it)."""
    g1 = [_linear_member_hinf(EX1, d) for d in (-3.33, 0.0, 3.33)]
    assert max(g1) <= EX1["mu"] and max(g1) > 0.99 * EX1["mu"]  # the bound holds, tight within 1 %
    g2 = _linear_member_hinf(EX2, 0.0)
    assert g2 <= EX2["mu"] and g2 > 0.99 * EX2["mu"]


@pytest.mark.parametrize("key", ["ex1", "ex2"])
def test_the_printed_gains_converge_and_attenuate_in_the_suites_run(key, catalog_constants):
    """Through the pipeline: the printed gains converge from the paper's x0, x_hat0 over 50 s (50,000 steps), and
    with the seeded disturbance (from z(0) = 0) the measured ||x|| / ||w|| stays below the paper's mu."""
    from bench.pipeline import RunOptions, evaluate_pair

    p = PLANTS.create(PIDS[key])
    rec = evaluate_pair(p, "nguyen2018_gains", catalog_constants(PIDS[key], n_samples=2000),
                        RunOptions(n_samples=2000, disturbance=0.1)).record
    assert rec["status"] == "given" and rec["stabilizing"] and rec["converged"]
    mu = (EX1 if key == "ex1" else EX2)["mu"]
    assert 0 < rec["l2_measured_x"] <= mu
    assert rec["l2_measured_e"] == pytest.approx(0.0, abs=1e-9)  # W - L D = 0: w never reaches e


def test_the_papers_own_disturbance_is_attenuated_below_mu():
    """The paper's omega(k) = 0.1 cos(0.5 ts k) in the last 3 s of every 20 s, from z(0) = 0 over the 50 s: the
    stepped loop of the printed gains (true f) gives ||x||_l2 / ||w||_l2 below mu, and e = 0 throughout."""
    from bench.disturbance import measured_attenuation
    from bench.simulate import simulate_controller
    from plants.nguyen2018 import paper_disturbance

    t = np.array([16.999, 17.001, 19.999, 20.0, 20.001, 40.0])
    assert np.allclose(paper_disturbance(t)[0], [0, 0.1 * np.cos(0.5 * 17.001), 0.1 * np.cos(0.5 * 19.999),
                                                 0.1 * np.cos(10.0), 0, 0.1 * np.cos(20.0)])
    for key, ex in (("ex1", EX1), ("ex2", EX2)):
        p = PLANTS.create(PIDS[key])
        z = np.zeros(p.n)
        tr = simulate_controller(p, -np.array(ex["K"]), K=_L(ex), t_final=50.0, x0=z, x_hat0=z,
                                 disturbance=paper_disturbance)
        assert tr.status == "ok" and tr.x.shape[1] == 50001
        ratio_e, ratio_x = measured_attenuation(tr.t, tr.x, tr.x_hat, paper_disturbance(tr.t), p.dt)
        assert 0.5 < ratio_x <= ex["mu"] and ratio_e < 1e-9


def test_the_1ms_plants_run_only_on_request(capsys):
    """Registered with default=False: out of the default selection (run, studies), in when a glob names them."""
    from bench.cli import main
    from bench.registry import Registry

    assert set(PIDS.values()) <= set(PLANTS.ids())
    assert not set(PIDS.values()) & set(PLANTS.select(None)) and "flexible_link_d10ms_v1" in PLANTS.select(None)
    assert PLANTS.select(["nguyen2018*"]) == sorted(PIDS.values()) and set(PIDS.values()) <= set(PLANTS.select(["*"]))
    reg = Registry("plant", "plants")
    reg._discovered = True
    reg.register("a", lambda: None)
    reg.register("b", lambda: None, default=False)
    assert reg.select(None) == reg.defaults() == ["a"] and reg.select([]) == ["a"] and reg.ids() == ["a", "b"]
    assert main(["list"]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if PIDS["ex1"] in ln)
    assert "on request" in line
