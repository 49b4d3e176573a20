"""The Riccati route (designs/_riccati_route.py), checked against expectations derived here.

Every certificate is rebuilt in the test from the returned K, F, P, R, s, t, mu with numpy (the
full (x, e, psi(Hx), dpsi) matrix, not the module's reduced one), the side LMIs are checked in
their original synthesis form (Q = P^-1, Y = F Q; Kh = R K), and the closed loop is simulated.
"""

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import solve_continuous_are

from bench.registry import PLANTS
from bench import joint
from bench.joint import equilibrated_max_eig, min_mu
from designs._riccati_route import (
    solve_are,
    solve_e_side,
    solve_x_side,
    structured_riccati,
)
from plants.chain import chain_plant
from plants.random_families import random_lipschitz_plant
from tests.conftest import closed_loop


def max_eig(M):
    return float(np.linalg.eigvalsh((M + M.T) / 2).max())


def jacobi(M):
    s = 1 / np.sqrt(np.abs(np.diag(M)))
    return M * s[:, None] * s[None, :]


def full_joint(A0, B, C, G, H, r, F, K, P, R, s, t, mu, lam):
    """The joint matrix of the brief, in (x, e, psi(Hx), dpsi), written out from the S-procedure."""
    n, q = A0.shape[0], G.shape[1]
    DH = r[:, None] * H
    Ax, Ae = A0 + B @ F, A0 - K @ C
    Z = np.zeros
    return np.block([
        [Ax.T @ P + P @ Ax + 2 * lam * P + DH.T @ DH / s, -P @ B @ F, P @ G, Z((n, q))],
        [(-P @ B @ F).T, mu * (Ae.T @ R + R @ Ae + 2 * lam * R + t * DH.T @ DH), Z((n, q)), mu * R @ G],
        [G.T @ P, Z((q, n)), -np.eye(q) / s, Z((q, q))],
        [Z((q, n)), mu * G.T @ R, Z((q, q)), -mu * t * np.eye(q)],
    ])


def plants_small():
    out = [PLANTS.create("flexible_link"), PLANTS.create("chain_v1"), chain_plant(N=6)]
    out += [random_lipschitz_plant(n=n, c=0.2, seed=s) for n, s in ((4, 0), (8, 0), (8, 3), (16, 0), (16, 5))]
    return out


PLANTS_SMALL = plants_small()
IDS = [f"{p.id}" for p in PLANTS_SMALL]


def joint_matrix(A0, B, C, F, K, P, R, G, H, r, *, s, t, mu, lam=0.0, reduced=True):
    """The joint matrix for the loop data A0 and half widths r (centre 0): reduced by bench.joint's side
    matrices, or full ((2n + 2q) square in (x, e, psi(Hx), dpsi)) written out here from its definition
    (bench.joint's module docstring), for the Schur-complement checks."""
    lp = joint.loop(A0, B, C, G, H, -np.asarray(r, float), np.asarray(r, float))
    PBF = P @ B @ F
    if reduced:
        Mx, Me = joint.side_matrices(lp, F, K, P, R, s, t, lam)
        return np.block([[Mx, -PBF], [-PBF.T, mu * Me]])
    q = lp.G.shape[1]
    s, t = np.broadcast_to(np.asarray(s, float), (q,)), np.broadcast_to(np.asarray(t, float), (q,))
    Ax, Ae = A0 + B @ F, A0 - K @ C
    Xb = Ax.T @ P + P @ Ax + 2 * lam * P + lp.DH.T @ np.diag(1 / s) @ lp.DH
    Eb = Ae.T @ R + R @ Ae + 2 * lam * R + lp.DH.T @ np.diag(t) @ lp.DH
    Z = np.zeros
    n = A0.shape[0]
    M = np.block([[Xb, -PBF, P @ lp.G, Z((n, q))],
                  [-PBF.T, mu * Eb, Z((n, q)), mu * R @ lp.G],
                  [(P @ lp.G).T, Z((q, n)), -np.diag(1 / s), Z((q, q))],
                  [Z((q, n)), mu * (R @ lp.G).T, Z((q, q)), -mu * np.diag(t)]])
    return (M + M.T) / 2


def route(p, **kw):
    ch = p.channels
    return structured_riccati(p.A, p.B, p.C, ch.G, ch.H, ch.lo, ch.hi, **kw)


# -- the ARE solver -----------------------------------------------------------------------------
def test_scalar_are_closed_form():
    # 2 a x - x^2 / rr b^2 + q = 0, stabilizing root x = rr (a + sqrt(a^2 + b^2 q / rr)) / b^2
    a, b, rr, q = 0.7, 1.3, 0.4, 2.0
    want = rr * (a + math.sqrt(a * a + b * b * q / rr)) / b**2
    for method in ("sign", "scipy"):
        X, info = solve_are(np.array([[a]]), np.array([[b]]), np.array([rr]), np.array([[q]]), method=method)
        assert X is not None, info.reason
        assert X[0, 0] == pytest.approx(want, rel=1e-12)
        assert info.closed_loop_max_re == pytest.approx(a - b * b / rr * want, rel=1e-9)


def test_no_real_solution_is_reported():
    # x^2 + 1 = 0 (a = 0, M = -1, q = 1): Hamiltonian eigenvalues +-j
    X, info = solve_are(np.zeros((1, 1)), np.ones((1, 1)), np.array([-1.0]), np.ones((1, 1)))
    assert X is None and "imaginary axis" in info.reason


@pytest.mark.parametrize("n", [5, 12, 30])
def test_indefinite_are_matches_scipy_and_has_a_small_residual(n):
    p = random_lipschitz_plant(n=n, c=0.2, seed=1)
    G, H = p.channels.G, p.channels.H
    b = np.hstack([p.B, G])
    rr = np.concatenate([np.full(p.m, 0.5), np.full(n, -1 / 0.2)])
    q = H.T @ H * 0.2 + 0.01 * np.eye(n)
    Xs = solve_continuous_are(p.A, b, q, np.diag(rr))
    M = b @ np.diag(1 / rr) @ b.T
    X, info = solve_are(p.A, b, rr, q, method="sign")
    assert X is not None, info.reason
    res = p.A.T @ X + X @ p.A - X @ M @ X + q
    assert np.abs(res).max() <= 1e-10 * max(1.0, np.abs(X).max() ** 2)
    assert np.linalg.eigvals(p.A - M @ X).real.max() < 0
    np.testing.assert_allclose(X, Xs, rtol=1e-7, atol=1e-9 * np.abs(Xs).max())


def test_lyapunov_by_the_sign_function_matches_scipy():
    from scipy.linalg import solve_continuous_lyapunov

    from designs._riccati_route import _lyap_sign

    rng = np.random.default_rng(3)
    n = 40
    A = rng.standard_normal((n, n)) / math.sqrt(n)
    A -= (np.linalg.eigvals(A).real.max() + 0.1) * np.eye(n)  # Hurwitz, slowest mode at -0.1
    Q = rng.standard_normal((n, n))
    Q = Q + Q.T
    want = solve_continuous_lyapunov(A.T, -Q)  # A' X + X A + Q = 0
    got = _lyap_sign(A, Q)
    assert np.abs(got - want).max() <= 1e-4 * np.abs(want).max()  # single precision
    assert _lyap_sign(A + 0.2 * np.eye(n), Q) is None  # a mode at +0.1: no sign -I, no answer


def test_newton_steps_refine_a_perturbed_solution_to_scipys():
    from designs._riccati_route import _newton

    p = random_lipschitz_plant(n=20, c=0.2, seed=2)
    b = np.hstack([p.B, p.channels.G])
    rr = np.concatenate([np.full(p.m, 0.5), np.full(p.n, -5.0)])
    q = p.channels.H.T @ p.channels.H * 0.2 + 0.01 * np.eye(p.n)
    want = solve_continuous_are(p.A, b, q, np.diag(rr))
    M = b @ np.diag(1 / rr) @ b.T
    E = np.random.default_rng(0).standard_normal(want.shape)
    X0 = want + 1e-4 * np.abs(want).max() * (E + E.T)
    got, _ = _newton(p.A, M, q, X0, 1e-8)
    assert got is not None
    np.testing.assert_allclose(got, want, rtol=1e-7, atol=1e-9 * np.abs(want).max())
    assert _newton(p.A, M, q, X0, 1e-8, steps=0)[0] is None  # X0 alone is not within 1e-8


def test_single_precision_start_refined_by_newton_matches_scipy(monkeypatch):
    # from SINGLE_FROM_N states the sign iteration runs in single precision and Newton steps refine
    # it; lowered here so that a 40-state chain takes that path
    import designs._riccati_route as route

    monkeypatch.setattr(route, "SINGLE_FROM_N", 2)
    p = chain_plant(N=20)
    n, G, H = p.n, p.channels.G, p.channels.H
    b = np.hstack([p.C.T, H.T])
    rr = np.concatenate([np.full(p.p, 0.5), np.full(H.shape[0], -1.0)])
    a = (p.A + 0.05 * np.eye(n)).T
    q = G @ G.T + 0.01 * np.eye(n)
    want = solve_continuous_are(a, b, q, np.diag(rr))
    M = b @ np.diag(1 / rr) @ b.T
    X32 = route._sign_are(a, M, q, tol=1e-2, single=True)[0]
    assert 1e-12 < np.abs(X32 - want).max() / np.abs(want).max() < 1e-3  # single precision alone
    refined, _ = route._newton(a, M, q, X32, 1e-8)  # the path solve_are takes
    assert refined is not None
    np.testing.assert_allclose(refined, want, rtol=1e-7, atol=1e-9 * np.abs(want).max())
    X, info = solve_are(a, b, rr, q)
    assert X is not None, info.reason
    assert info.residual <= 1e-8
    np.testing.assert_allclose(X, want, rtol=1e-7, atol=1e-9 * np.abs(want).max())


# -- the sides ----------------------------------------------------------------------------------
@pytest.mark.parametrize("p", PLANTS_SMALL[:4], ids=IDS[:4])
def test_side_lmis_in_their_synthesis_form(p):
    res = route(p)
    assert res.ok, res.reason
    ch = p.channels
    c0, r = ch.center, ch.spread
    A0 = p.A + ch.G @ np.diag(c0) @ ch.H
    Dr = np.diag(r)
    q = ch.q
    # x-side: Q = P^-1, Y = F Q, S = s I
    Q = np.linalg.inv(res.P)
    Y = res.F @ Q
    X11 = A0 @ Q + Q @ A0.T + p.B @ Y + Y.T @ p.B.T + res.s * ch.G @ ch.G.T + 2 * res.lam * Q
    Lx = np.block([[X11, Q @ ch.H.T @ Dr], [Dr @ ch.H @ Q, -res.s * np.eye(q)]])
    assert max_eig(jacobi(Lx)) < 0
    # e-side: Kh = R K, T = t I
    R = res.R
    Kh = R @ res.K
    E11 = A0.T @ R + R @ A0 - Kh @ p.C - p.C.T @ Kh.T + res.t * ch.H.T @ Dr @ Dr @ ch.H + 2 * res.lam * R
    Le = np.block([[E11, R @ ch.G], [ch.G.T @ R, -res.t * np.eye(q)]])
    assert max_eig(jacobi(Le)) < 0
    assert np.linalg.eigvalsh(res.P).min() > 0 and np.linalg.eigvalsh(R).min() > 0
    # the structure of the gains the route promises: F = -tau B'P, K = tau' R^-1 C' (up to the normalisation)
    Pn = res.P
    ratio = res.F / -(p.B.T @ Pn)
    assert np.allclose(ratio, ratio.flat[0], rtol=1e-6) and ratio.flat[0] > 0
    ratio_e = res.K / (np.linalg.inv(R) @ p.C.T)
    assert np.allclose(ratio_e, ratio_e.flat[0], rtol=1e-6) and ratio_e.flat[0] > 0


def test_side_solvers_direct():
    p = PLANTS.create("flexible_link")
    ch = p.channels
    xs, why = solve_x_side(p.A, p.B, ch.G, ch.H, ch.spread, 0.0, 1.0, 1.0, 0.01)
    assert xs is not None, why
    assert xs.are.residual < 1e-10 and xs.min_eig > 0
    es, why = solve_e_side(p.A, p.C, ch.G, ch.H, ch.spread, 0.0, 1.0, 1.0, 0.01)
    assert es is not None, why
    assert es.are.residual < 1e-10 and es.min_eig > 0
    # at an exact ARE solution the x-side matrix (channels eliminated) is -eps I in P coordinates
    np.testing.assert_allclose(xs.side_matrix, -0.01 * np.eye(4), atol=1e-8)
    # and the e-side one is -eps R^2
    np.testing.assert_allclose(es.side_matrix, -0.01 * es.P @ es.P, atol=1e-8 * np.abs(es.P).max() ** 2)
    # tau too small for the unstable chain: the reason is given in words
    c = PLANTS.create("chain_v1").channels
    bad, why = solve_x_side(PLANTS.create("chain_v1").A, PLANTS.create("chain_v1").B, c.G, c.H, c.spread,
                            0.0, 2.0, 1e-3, 0.04)
    assert bad is None and why


# -- the joint certificate ----------------------------------------------------------------------
@pytest.mark.parametrize("p", PLANTS_SMALL, ids=IDS)
def test_joint_certificate_rebuilt_independently(p):
    res = route(p)
    assert res.status == "feasible", res.reason
    assert -1 <= res.margin < -1e-7 and res.rate >= 0
    ch = p.channels
    A0 = p.A + ch.G @ np.diag(ch.center) @ ch.H
    M = full_joint(A0, p.B, p.C, ch.G, ch.H, ch.spread, res.F, res.K, res.P, res.R, res.s, res.t, res.mu, res.rate)
    assert max_eig(M) < 0
    assert max_eig(jacobi(M)) < 0
    np.linalg.cholesky(-jacobi(M))
    # the module's full form is the same matrix
    Mm = joint_matrix(A0, p.B, p.C, res.F, res.K, res.P, res.R, ch.G, ch.H, ch.spread, s=res.s, t=res.t,
                      mu=res.mu, lam=res.rate, reduced=False)
    np.testing.assert_allclose(Mm, M, rtol=1e-12, atol=1e-12 * np.abs(M).max())


@pytest.mark.parametrize("p", PLANTS_SMALL[:5], ids=IDS[:5])
def test_schur_complement_and_min_mu(p):
    """Full and reduced matrices agree in sign on both sides of mu_min, found here by bisection."""
    res = route(p)
    ch = p.channels
    A0 = p.A + ch.G @ np.diag(ch.center) @ ch.H

    def signs(mu):
        Mf = full_joint(A0, p.B, p.C, ch.G, ch.H, ch.spread, res.F, res.K, res.P, res.R, res.s, res.t, mu, res.lam)
        Mr = joint_matrix(A0, p.B, p.C, res.F, res.K, res.P, res.R, ch.G, ch.H, ch.spread, s=res.s, t=res.t,
                          mu=mu, lam=res.lam)
        return max_eig(jacobi(Mf)) < 0, max_eig(jacobi(Mr)) < 0

    lp = joint.loop(A0, p.B, p.C, ch.G, ch.H, -ch.spread, ch.spread)
    Mx, Me = joint.side_matrices(lp, res.F, res.K, res.P, res.R, res.s, res.t, res.lam)
    mu_min = min_mu(p.B, res.F, res.P, Mx, Me)
    lo, hi = 0.0, 10 * mu_min
    assert signs(hi) == (True, True)
    for _ in range(60):
        mid = math.sqrt(lo * hi) if lo > 0 else hi / 1e6
        ok_full, ok_red = signs(mid)
        assert ok_full == ok_red
        lo, hi = (lo, mid) if ok_red else (mid, hi)
        if hi / max(lo, 1e-300) < 1 + 1e-4:
            break
    assert mu_min == pytest.approx(hi, rel=1e-3)
    assert signs(0.9 * mu_min) == (False, False)
    assert signs(1.1 * mu_min) == (True, True)


@pytest.mark.parametrize("p", [PLANTS.create("flexible_link"), chain_plant(N=5)], ids=["flexible_link", "chain_N5"])
def test_linear_channels_reduce_to_a_lyapunov_test(p):
    """lo = hi: f is linear and inside A0; the certificate is a Lyapunov matrix of the linear loop."""
    ch = p.channels
    c0 = 0.5 * ch.hi
    res = structured_riccati(p.A, p.B, p.C, ch.G, ch.H, c0, c0)
    assert res.ok, res.reason
    A0 = p.A + ch.G @ np.diag(c0) @ ch.H
    assert np.linalg.eigvals(A0 + p.B @ res.F).real.max() < 0
    assert np.linalg.eigvals(A0 - res.K @ p.C).real.max() < 0
    n = p.n
    Acl = np.block([[A0 + p.B @ res.F, -p.B @ res.F], [np.zeros((n, n)), A0 - res.K @ p.C]])
    Pj = np.block([[res.P, np.zeros((n, n))], [np.zeros((n, n)), res.mu * res.R]])
    assert max_eig(jacobi(Acl.T @ Pj + Pj @ Acl)) < 0
    # no channel is left: the module's reduced matrix is exactly that Lyapunov matrix
    Mr = joint_matrix(A0, p.B, p.C, res.F, res.K, res.P, res.R, ch.G, ch.H, np.zeros(ch.q), s=res.s, t=res.t,
                      mu=res.mu)
    np.testing.assert_allclose(Mr, Acl.T @ Pj + Pj @ Acl, atol=1e-9 * np.abs(Mr).max())


def test_infeasible_case_says_why():
    p = random_lipschitz_plant(n=4, c=1.0)
    res = route(p)
    assert res.status == "infeasible" and not res.ok
    assert res.K is None and res.F is None
    assert "grid" in res.reason and res.tries


def test_equilibration_keeps_the_inertia():
    rng = np.random.default_rng(0)
    for _ in range(20):
        V = rng.standard_normal((6, 6))
        M = V @ np.diag(rng.choice([-1.0, 1.0], 6) * 10.0 ** rng.uniform(-3, 3, 6)) @ V.T
        assert (equilibrated_max_eig(M) < 0) == (max_eig(M) < 0)
    M = -np.diag([1e-8, 1.0, 1e8])
    assert equilibrated_max_eig(M) == pytest.approx(-1.0)


def test_methods_agree():
    p = PLANTS.create("chain_v1")
    out = {m: route(p, method=m) for m in ("sign", "scipy")}
    for m, res in out.items():
        assert res.ok, (m, res.reason)
        assert res.methods == (m, m)
    np.testing.assert_allclose(out["sign"].F, out["scipy"].F, rtol=1e-6)
    np.testing.assert_allclose(out["sign"].K, out["scipy"].K, rtol=1e-6)


class CurveSide:
    """A side for :func:`designs._riccati_route._search` whose gain estimate is ``gain(lam)``; it counts the
    stages and marks the targets a companion side is estimated at."""

    max_gain = 20.0

    def __init__(self, gain):
        self.gain, self.est, self.stages = gain, {}, 0

    def estimate(self, lams, also=None):
        self.stages += 1
        self.est.update({la: self.gain(la) for la in lams})
        if also is not None:
            also[0].est.update({la: 0.0 for la in also[1]})


@pytest.mark.parametrize("kappa, wall", [(20.0, math.inf), (3.0, math.inf), (20.0, 0.08), (400.0, math.inf),
                                         (60.0, math.inf)])
def test_target_search_stops_at_the_gain_bound(kappa, wall):
    # a side whose gain is g(l) = 2 exp(kappa l) and which has no solution above `wall`: the largest
    # target within max_gain = 20 is min(ln(10) / kappa, wall)
    from designs._riccati_route import _search

    side = CurveSide(lambda la: 2 * math.exp(kappa * la) if la <= wall else math.inf)
    got = _search(side, 10.0, 0.05)
    best = min(math.log(10) / kappa, wall)
    assert best / 1.05 <= got <= best
    assert side.stages <= (8 if math.isfinite(wall) else 5)


@pytest.mark.parametrize("with_companion", [False, True])
def test_target_search_on_a_gain_with_a_flat_start(with_companion):
    # g(l) = 2 + 1000 max(0, l - 0.006)^1.4 (flat, then a power law, as the chain's observer side): the
    # largest target within 20 is 0.006 + (18 / 1000)^(1 / 1.4), found in a few stages, with the
    # other side estimated at each next target (a companion) or a second target beside it
    from designs._riccati_route import _search

    def gain(la):
        return 2 + 1000 * max(0.0, la - 0.006) ** 1.4

    side, other = CurveSide(gain), CurveSide(gain)
    got = _search(side, 10.0, 0.05, companion=other if with_companion else None)
    best = 0.006 + (18 / 1000) ** (1 / 1.4)
    assert best / 1.05 <= got <= best
    assert side.stages <= 4
    assert set(other.est) == (set(side.est) - {0.125, 0.125 / 8} if with_companion else set())


def test_the_slower_side_sets_the_pairs_target():
    # e-side gain 2 exp(20 l), x-side gain 2 exp(40 l): within max_gain = 20 the e-side alone reaches
    # ln(10)/20, the pair only ln(10)/40, where both sides are solved
    from designs._riccati_route import SideSolution, _Side, _targets

    def side(label, kappa):
        def gain(lam):
            return 2 * math.exp(kappa * lam)

        def solve(lam, tau, eps, X0):
            sol = SideSolution(P=np.eye(1), gain=np.array([[gain(lam)]]), side_matrix=-np.eye(1), min_eig=1.0,
                               tau=tau, are=None, lam=lam)
            return sol, ""

        sd = _Side(label, 1, None, None, solve, [(1.0, 1.0)], 20.0)
        sd._scan = lambda lam, first, last: [(0, gain(lam), None, "")]
        return sd

    xs, es = side("x", 40.0), side("e", 20.0)
    target, x, e = _targets(xs, es, None, 10.0, 0.05)
    best = math.log(10) / 40
    assert best / 1.05 <= target <= best
    assert x.lam == e.lam == target and max(x.gain_norm, e.gain_norm) <= 20.0


# -- closed loop --------------------------------------------------------------------------------
@pytest.mark.parametrize("p", PLANTS_SMALL[:5], ids=IDS[:5])
def test_closed_loop_decays(p):
    res = route(p)
    n = p.n
    # the horizon from the loop linearised at the origin (f'(0) included): 10 time constants
    J0 = p.jacobian(np.zeros(n))
    lin = np.block([[p.A + J0 + p.B @ res.F, -p.B @ res.F], [np.zeros((n, n)), p.A + J0 - res.K @ p.C]])
    sigma = np.linalg.eigvals(lin).real.max()
    assert sigma < 0
    T = 10 / abs(sigma)
    z0 = np.concatenate([p.x0, p.x_hat0])
    ts = np.linspace(0, T, 400)
    sol = solve_ivp(closed_loop(p, res.K, res.F), (0, T), z0, t_eval=ts, method="LSODA", rtol=1e-9, atol=1e-12)
    assert sol.success
    x, e = sol.y[:n], sol.y[:n] - sol.y[n:]
    assert np.linalg.norm(x[:, -1]) < 1e-2 * np.linalg.norm(p.x0)
    assert np.linalg.norm(e[:, -1]) < 1e-2 * np.linalg.norm(p.x0 - p.x_hat0)
    # the certificate's V never increases
    V = np.einsum("it,ij,jt->t", x, res.P, x) + res.mu * np.einsum("it,ij,jt->t", e, res.R, e)
    assert np.all(np.diff(V) <= 1e-7 * V[0])


def test_certified_decay_rate_holds_along_the_trajectory():
    """With lam > 0, V = x'Px + mu e'Re must satisfy V(t) <= exp(-2 lam t) V(0) on the simulation."""
    p = PLANTS.create("flexible_link")
    res = route(p, lam=0.5)
    assert res.ok, res.reason
    lam = res.rate
    assert lam > 0.4  # designed for 0.5: each side proves more, the joint certificate nine tenths of the slower
    n = p.n
    z0 = np.concatenate([p.x0, p.x_hat0])
    ts = np.linspace(0, 10, 201)
    sol = solve_ivp(closed_loop(p, res.K, res.F), (0, 10), z0, t_eval=ts, method="LSODA", rtol=1e-10, atol=1e-13)
    x = sol.y[:n]
    e = x - sol.y[n:]
    V = np.einsum("it,ij,jt->t", x, res.P, x) + res.mu * np.einsum("it,ij,jt->t", e, res.R, e)
    assert np.all(V <= np.exp(-2 * lam * ts) * V[0] * (1 + 1e-6) + 1e-12 * V[0])


def test_min_mu_requires_negative_sides():
    with pytest.raises(np.linalg.LinAlgError):
        min_mu(np.ones((2, 1)), np.ones((1, 2)), np.eye(2), np.eye(2), -np.eye(2))


def test_joint_verdicts():
    assert joint.verdict(-np.diag([1.0, 1e-9, 1e9])) == "verified"
    assert joint.verdict(np.array([[-1.0, 1.0], [1.0, -1.0]])) == "marginal"  # singular: eigenvalues 0, -2
    assert joint.verdict(np.array([[-1.0, 2.0], [2.0, -1.0]])) == "violated"  # eigenvalues 1, -3


def test_bad_shapes_name_the_matrix():
    p = PLANTS.create("flexible_link")
    ch = p.channels
    with pytest.raises(ValueError, match="^H:"):
        structured_riccati(p.A, p.B, p.C, ch.G, ch.H.T, ch.lo, ch.hi)
    with pytest.raises(ValueError, match="^C:"):
        structured_riccati(p.A, p.B, p.C.T, ch.G, ch.H, ch.lo, ch.hi)
    with pytest.raises(ValueError, match="lo/hi"):
        structured_riccati(p.A, p.B, p.C, ch.G, ch.H, 1.0, -1.0)
