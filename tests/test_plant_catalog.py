"""The literature plants of the catalog, the random families, and the constants machinery
they rely on (claimed region, report flags). Expected values are derived by hand here."""

import json
import math

import numpy as np
import pytest

from bench.constants import compute_constants
from bench.registry import PLANTS
from plants import Constants, Plant, PlantError
from plants.moving_object import moving_object
from plants.random_families import (
    is_detectable,
    is_stabilizable,
    pbh_margin,
    random_lipschitz_plant,
    random_lti,
    random_osl_plant,
)


def ctrb_rank(A, B):
    n = A.shape[0]
    K = np.hstack([np.linalg.matrix_power(A, k) @ B for k in range(n)])
    return np.linalg.matrix_rank(K)


def pbh_ok(A, B, rtol=1e-8):
    """Independent PBH test: rank [lambda I - A, B] = n for every eigenvalue with Re >= 0."""
    n = A.shape[0]
    scale = max(1.0, np.linalg.norm(np.hstack([A, B]), 2))
    for lam in np.linalg.eigvals(A):
        if lam.real >= 0:
            s = np.linalg.svd(np.hstack([lam * np.eye(n) - A, B]), compute_uv=False)
            if s[-1] <= rtol * scale:
                return False
    return True


def ratios(f, x1, x2, gamma=0.0):
    """Lipschitz, one-sided Lipschitz and QIB (at gamma) ratios of one pair, computed here."""
    dx, df = np.asarray(x1, float) - np.asarray(x2, float), f(np.asarray(x1, float)) - f(np.asarray(x2, float))
    nx2 = dx @ dx
    return np.sqrt(df @ df / nx2), (dx @ df) / nx2, (df @ df - gamma * (dx @ df)) / nx2


def assert_tight(f, closed, pairs):
    """Each closed-form constant is approached (from below) by the pair given for it."""
    for name, (x1, x2) in pairs.items():
        got = dict(zip(("alpha", "rho", "beta"), ratios(f, x1, x2)))[name]
        want = getattr(closed, name)
        assert got <= want * (1 + 1e-12) and got >= want * (1 - 1e-6), (name, got, want)


@pytest.fixture(scope="module")
def reports(catalog_constants):
    """``reports(pid)``: ``compute_constants(PLANTS.create(pid), seed=0)``, computed once per session."""
    return catalog_constants


# -- plant 2: flexible-joint robot, unscaled ------------------------------------------------------
def test_flexible_joint_matches_plants_md(reports):
    p = PLANTS.create("flexible_joint_v1")
    np.testing.assert_array_equal(
        p.A, [[0, 1, 0, 0], [-48.6, -1.25, 48.6, 0], [0, 0, 0, 1], [19.5, 0, -19.5, 0]])
    np.testing.assert_array_equal(p.B.ravel(), [0, 21.6, 0, 0])
    np.testing.assert_array_equal(p.C, [[1, 0, 0, 0], [0, 1, 0, 0]])
    np.testing.assert_array_equal(p.x0, [0.1, -0.1, 0.2, -0.2])
    np.testing.assert_array_equal(p.x_hat0, [0.2, -0.2, 0.1, -0.1])
    x = np.array([0.3, -0.2, 0.7, 0.1])
    np.testing.assert_allclose(p.f(x), [0, 0, 0, -3.33 * np.sin(0.7)])
    rep = reports("flexible_joint_v1")
    # alpha = c, rho = c/2, beta = c^2 at gamma = 0 (same argument as the flexible link), all tight
    assert abs(rep.sampled.alpha - 3.33) <= 0.01 * 3.33
    assert abs(rep.sampled.rho - 3.33 / 2) <= 0.01 * 3.33 / 2
    assert abs(rep.sampled.beta - 3.33**2) <= 0.01 * 3.33**2
    assert p.claimed.alpha == 3.33 and rep.violations == [] and rep.disproved == []
    # the claim belongs to the source's c: another c carries no claim
    assert PLANTS.create("flexible_joint_v1", c=1.0).claimed == Constants()


@pytest.mark.parametrize("c", [3.33, -2.0])
def test_flexible_joint_analytic_bounds_are_the_closed_forms(c):
    """f4 = -c sin(x3): |df| = |c| |sin a - sin b| <= |c| |d3| (alpha = |c|, beta = c^2 at gamma = 0);
    <df, dx> = -c (sin a - sin b) d4 <= |c| |d3| |d4| <= (|c|/2)(d3^2 + d4^2) (rho = |c|/2), attained by
    dx = (0, 0, -d, d) near 0 (for c > 0; (0, 0, d, d) for c < 0), alpha and beta by dx = (0, 0, d, 0)."""
    p = PLANTS.create("flexible_joint_v1", c=c)
    closed = Constants(alpha=abs(c), rho=abs(c) / 2, beta=c**2, gamma=0.0)
    assert p.bounds == closed and compute_constants(p, seed=0, n_samples=500).analytic == closed
    d, z = 1e-4, np.zeros(4)
    s = 1.0 if c > 0 else -1.0
    assert_tight(p.f, closed, {"alpha": ([0, 0, d, 0], z), "beta": ([0, 0, d, 0], z),
                               "rho": ([0, 0, -s * d, d], z)})


# -- plant 3: the moving object ---------------------------------------------------------------------
def test_moving_object_matches_plants_md():
    p = PLANTS.create("moving_object_v1")
    np.testing.assert_array_equal(p.A, [[-1, 1], [1.5, -0.5]])
    np.testing.assert_array_equal(p.B.ravel(), [0, -1])
    np.testing.assert_array_equal(p.C, [[0, 1]])
    np.testing.assert_array_equal(p.x0, [0.1, -0.1])
    np.testing.assert_array_equal(p.x_hat0, [-0.1, 0.1])
    x = np.array([0.3, -1.2])
    np.testing.assert_allclose(p.f(x), -x * (0.09 + 1.44))
    # characteristic polynomial s^2 + 1.5 s - 1 = (s - 0.5)(s + 2): open-loop unstable
    np.testing.assert_allclose(sorted(np.linalg.eigvals(p.A).real), [-2.0, 0.5])
    assert ctrb_rank(p.A, p.B) == 2 and ctrb_rank(p.A.T, p.C.T) == 2
    assert p.bounds.radius == 10.0 and p.claimed.radius == 10.0


def test_moving_object_shows_the_point_of_osl(reports):
    r = 10.0
    rep = reports("moving_object_v1")
    # rho = 0 (f = -grad of the convex ||x||^4 / 4): samples approach 0 from below, never above
    assert -1e-3 <= rep.sampled.rho <= 1e-9
    # Lipschitz on the ball: 3 r^2 = 300, attained at the boundary
    assert 0.99 * 3 * r**2 <= rep.sampled.alpha <= 3 * r**2 * (1 + 1e-9)
    assert rep.used.rho == 0.0 and rep.used.alpha == 300.0
    # QIB with beta = 0 at gamma = -3 r^2: no sample above 0
    assert rep.sampled.gamma == -3 * r**2 and rep.sampled.beta <= 1e-9
    assert rep.violations == []  # the sources' gamma = -4 r^2 is valid (looser)
    assert rep.sampled.radius == r


def test_moving_object_gamma_is_tight():
    """A pair on the boundary gives ||df||^2 / (-<dx, df>) -> 3 r^2, so gamma = -2.9 r^2 fails."""
    p = moving_object(r=1.0)
    x1, x2 = np.array([1.0, 0.0]), np.array([1.0 - 1e-4, 0.0])
    dx, df = x1 - x2, p.f(x1) - p.f(x2)
    ratio = (df @ df) / (-(dx @ df))
    assert 2.9 < ratio <= 3.0
    assert (df @ df) - (-2.9) * (dx @ df) > 0  # beta = 0 with gamma = -2.9 r^2 is violated


def hinf_floor(A, B, omegas=np.linspace(0.0, 20.0, 401)):
    """A closed-form obstruction to Lipschitz state feedback, computed here.

    For w with w*B = 0, w*(sI - A - BF) = w*(sI - A) for every F, so ||(sI - A - BF)^-1|| >=
    |w| / |(sI - A)* w|: every F has ||(sI - A - BF)^-1||_inf >= 1 / min_w sigma_min((jw I - A)* N),
    N a basis of null(B'). Returns that min over the frequency grid (any frequency gives a valid bound).
    """
    from scipy.linalg import null_space

    N = null_space(B.T)
    n = A.shape[0]
    return min(np.linalg.svd((1j * w * np.eye(n) - A).conj().T @ N, compute_uv=False)[-1] for w in omegas)


@pytest.mark.parametrize("pid", ["moving_object_v1", "random_osl_v1"])
def test_theorem1_admits_more_than_corollary1_on_an_osl_plant(pid):
    """The paper's headline, fast: on an OSL plant corrected Theorem 1 is feasible and Corollary 1 is not.

    Why Corollary 1 fails (closed form): its x-side block [[S11 + kappa I, Q], [Q, -(kappa/alpha^2) I]]
    (a principal block of the 6n matrix) is the bounded-real inequality of ||(sI - A - BF)^-1||_inf < 1/alpha
    (X = (kappa/alpha^2) Q^-1 gives Acl'X + XAcl + alpha^2 X^2 + I < 0), and :func:`hinf_floor` shows every F
    has ||(sI - A - BF)^-1||_inf >= 1/floor with floor <= alpha: the Lipschitz constant on the region is far
    too large, while the OSL constant rho = 0 costs Theorem 1 nothing.
    """
    from bench.registry import DESIGNS
    from tests.conftest import paper20_certificate

    p = PLANTS.create(pid)
    b = p.bounds
    assert b.rho == 0.0 and b.beta == 0.0 and b.gamma < 0  # f = -grad of a convex function: OSL with rho = 0
    floor = hinf_floor(p.A, p.B)
    assert b.alpha >= floor, (b.alpha, floor)
    cor = DESIGNS.create("cor1").design(p, b)
    assert cor.status == "infeasible" and "under the normalisation" in cor.reason, cor.reason
    assert cor.margin > 0 and cor.K is None and cor.F is None
    cor_sep = DESIGNS.create("cor1_sep").design(p, b)
    assert cor_sep.status in ("infeasible", "marginal") and "x-side" in cor_sep.reason and cor_sep.K is None
    thm = DESIGNS.create("thm1").design(p, b)
    assert thm.status == "feasible", thm.reason
    assert thm.params["gamma"] == b.gamma and thm.margin < 0
    # Theorem 1's gains satisfy the paper's (20) with the OSL/QIB constants, rebuilt and verified here
    margin, pmin, rmin = paper20_certificate(p, thm.K, thm.F, b, 0.0)
    assert margin < -1e-7 and pmin > 0 and rmin > 0
    # and Corollary 1's own condition cannot hold for them: ||(jwI - A - BF)^-1|| >= 1/floor >= 1/alpha
    Acl = p.A + p.B @ thm.F
    peak = max(np.linalg.norm(np.linalg.inv(1j * w * np.eye(p.n) - Acl), 2) for w in np.linspace(0, 20, 401))
    assert peak * b.alpha >= 1


def test_moving_object_gamma_negative_theorem1_feasible_certified_converges():
    """The gamma < 0 branch of Theorem 1 (gamma = -3 r^2, r = 10), judged by the pipeline and re-checked here."""
    from scipy.integrate import solve_ivp

    from bench.pipeline import RunOptions, evaluate_pair
    from tests.conftest import closed_loop, linearised_rate, paper20_certificate

    p = PLANTS.create("moving_object_v1")
    r = 10.0
    rep = compute_constants(p, seed=0, n_samples=2000)
    assert rep.knowledge(p).constants.gamma == -3 * r**2  # trusted: analytic and not disproved
    out = evaluate_pair(p, "thm1", rep, RunOptions(n_samples=2000))
    rec = out.record
    assert rec["status"] == "feasible" and rec["feasible"] and rec["stabilizing"], rec["reason"]
    assert json.loads(rec["params"])["form"].startswith("fixed eps") and json.loads(rec["params"])["gamma"] == -300
    assert rec["certified"] and rec["converged"] and rec["cert_scope"] == "from x0" and rec["in_region"]
    K, F = out.result.K, out.result.F
    # the certificate is local (the constants hold on ||x|| <= 10): the level set of V through (x0, e0) must
    # keep x and x_hat = x - e in the ball. Largest |Tz| on {z'Pz <= v} is sqrt(v lmax(T P^-1 T')).
    best = out.certificate.best
    P = best.P
    Pi = np.linalg.inv(P)
    Tx, Th = np.hstack([np.eye(2), np.zeros((2, 2))]), np.hstack([np.eye(2), -np.eye(2)])
    v_max = r**2 / max(np.linalg.eigvalsh(T @ Pi @ T.T)[-1] for T in (Tx, Th))
    z0 = np.concatenate([p.x0, p.x0 - p.x_hat0])
    assert z0 @ P @ z0 <= v_max
    # rate: below the linearisation's (Df(0) = 0 for the cubic f), and positive
    assert 0 < rec["decay_rate"] <= linearised_rate(p, K, F) * (1 + 1e-9)
    # the paper's (20), rebuilt here with the trusted constants, certifies the gains too
    margin, pmin, rmin = paper20_certificate(p, K, F, rep.knowledge(p).constants, 0.0)
    assert margin < -1e-7 and pmin > 0 and rmin > 0
    # own integration: the loop stays in the ball and converges
    sol = solve_ivp(closed_loop(p, K, F), (0, 20.0), np.concatenate([p.x0, p.x_hat0]), method="DOP853",
                    rtol=1e-10, atol=1e-14)
    x, xh = sol.y[:2], sol.y[2:]
    assert sol.success and np.linalg.norm(x, axis=0).max() <= r and np.linalg.norm(xh, axis=0).max() <= r
    peak = np.linalg.norm(np.vstack([x, x - xh]), axis=0).max()
    assert np.linalg.norm(x[:, -1]) <= 1e-3 * peak and np.linalg.norm(x[:, -1] - xh[:, -1]) <= 1e-3 * peak


@pytest.mark.parametrize("r", [0.0, -1.0, float("nan"), float("inf"), "ten"])
def test_moving_object_bad_radius(r):
    with pytest.raises(PlantError, match=r"^r: "):
        moving_object(r=r)


def test_moving_object_region_must_hold_the_initial_conditions():
    with pytest.raises(PlantError, match="r: .*x0"):
        moving_object(r=0.1)  # ||x0|| = 0.1414


# -- plant 4: pendulum ---------------------------------------------------------------------------------
def test_pendulum(reports):
    p = PLANTS.create("pendulum_v1")
    np.testing.assert_array_equal(p.A, [[0, 1], [0, -0.1]])
    np.testing.assert_array_equal(p.B.ravel(), [0, 1])
    np.testing.assert_array_equal(p.C, [[1, 0]])
    np.testing.assert_allclose(p.f(np.array([0.4, 2.0])), [0, -9.81 * np.sin(0.4)])
    rep = reports("pendulum_v1")
    assert abs(rep.sampled.alpha - 9.81) <= 0.01 * 9.81
    assert abs(rep.sampled.rho - 9.81 / 2) <= 0.01 * 9.81 / 2
    assert rep.violations == [] and rep.disproved == []
    # closed forms of f2 = -k sin(x1), k = g/l: alpha = k, rho = k/2 (<df, dx> = -k (sin a - sin b) d2 <=
    # k |d1| |d2|), beta = k^2 at gamma = 0; attained near 0 by dx = (d, 0) and, for rho, dx = (d, -d)
    k = 9.81
    closed = Constants(alpha=k, rho=k / 2, beta=k**2, gamma=0.0)
    assert rep.analytic == closed
    d, z = 1e-4, np.zeros(2)
    assert_tight(p.f, closed, {"alpha": ([d, 0], z), "beta": ([d, 0], z), "rho": ([d, -d], z)})
    with pytest.raises(PlantError, match="g_over_l"):
        PLANTS.create("pendulum_v1", g_over_l=-1.0)


# -- plant 5: Chua's circuit --------------------------------------------------------------------------
def chua_field(x, a=9.0, b=14.28, m0=-1 / 7, m1=2 / 7):
    h = m1 * x[0] + (m0 - m1) * (abs(x[0] + 1) - abs(x[0] - 1)) / 2
    return np.array([a * (x[1] - x[0] - h), x[0] - x[1] + x[2], -b * x[1]])


def test_chua_reproduces_the_circuit(reports):
    p = PLANTS.create("chua_v1")
    rng = np.random.default_rng(0)
    for x in rng.uniform(-3, 3, size=(20, 3)):
        np.testing.assert_allclose(p.A @ x + p.f(x), chua_field(x), atol=1e-12)
    np.testing.assert_array_equal(p.B.ravel(), [1, 0, 0])
    np.testing.assert_array_equal(p.C, [[1, 0, 0]])
    assert ctrb_rank(p.A, p.B) == 3 and ctrb_rank(p.A.T, p.C.T) == 3
    k = 9 * 3 / 7  # a |m0 - m1|
    assert math.isclose(p.claimed.alpha, k)
    rep = reports("chua_v1")
    assert abs(rep.sampled.alpha - k) <= 0.01 * k
    assert abs(rep.sampled.rho - k) <= 0.01 * k  # the saturation has slope 1 inside |x1| < 1
    assert rep.violations == [] and rep.disproved == []
    # closed forms: f1 = k sat(x1) with k = -a (m0 - m1) = 27/7 > 0 and sat's slopes in [0, 1]:
    # |df| <= k |d1| (alpha = k), <df, dx> = k s d1^2 <= k |dx|^2 (rho = k), beta = k^2 at gamma = 0;
    # all attained by dx = (d, 0, 0) inside |x1| < 1
    assert math.isclose(-9 * (-1 / 7 - 2 / 7), k)
    closed = Constants(alpha=k, rho=k, beta=k**2, gamma=0.0)
    for name in ("alpha", "rho", "beta", "gamma"):
        assert math.isclose(getattr(rep.analytic, name), getattr(closed, name), rel_tol=1e-12, abs_tol=0), name
    z = np.array([0.2, 0.1, -0.3])
    pair = (z + [1e-3, 0, 0], z)
    assert_tight(p.f, closed, {"alpha": pair, "rho": pair, "beta": pair})
    # outside the saturation's slope-1 zone the pair gives 0: the constants are global suprema, not everywhere
    assert ratios(p.f, [2.0, 0, 0], [1.5, 0, 0])[0] == 0.0


# -- random families -------------------------------------------------------------------------------------
@pytest.mark.parametrize("n, m, p", [(1, 1, 1), (2, 1, 1), (3, 2, 1), (8, 1, 3), (64, 1, 1), (64, 4, 4)])
def test_random_lti_is_stabilizable_and_detectable(n, m, p):
    for seed in range(3):
        A, B, C = random_lti(n, m, p, seed=seed)
        assert A.shape == (n, n) and B.shape == (n, m) and C.shape == (p, n)
        assert pbh_ok(A, B) and pbh_ok(A.T, C.T)
        assert is_stabilizable(A, B) and is_detectable(A, C)
        # open-loop unstable by default: the largest real part is max_re = 0.5
        assert abs(np.linalg.eigvals(A).real.max() - 0.5) < 1e-8
        if n <= 8:
            assert ctrb_rank(A, B) == n and ctrb_rank(A.T, C.T) == n


def test_pbh_detects_an_unstabilizable_pair():
    A = np.diag([1.0, -1.0])
    B = np.array([[0.0], [1.0]])  # the unstable mode is not reachable
    assert not is_stabilizable(A, B) and pbh_margin(A, B) < 1e-12
    assert is_stabilizable(np.diag([-1.0, -2.0]), B)  # Hurwitz: stabilizable whatever B
    assert not is_detectable(A, B.T)


def test_random_families_are_seeded():
    p1, p2 = random_lipschitz_plant(n=6, seed=3), random_lipschitz_plant(n=6, seed=3)
    q = random_lipschitz_plant(n=6, seed=4)
    x = np.linspace(-1, 1, 6)
    np.testing.assert_array_equal(p1.A, p2.A)
    np.testing.assert_array_equal(p1.f(x), p2.f(x))
    assert not np.allclose(p1.A, q.A)


@pytest.mark.parametrize("make", [random_lipschitz_plant, random_osl_plant])
def test_scale_knob_c(make):
    base, big = make(n=5, seed=2, c=1.0), make(n=5, seed=2, c=2.5)
    np.testing.assert_array_equal(base.A, big.A)
    np.testing.assert_array_equal(base.B, big.B)
    X = np.random.default_rng(0).uniform(-0.5, 0.5, size=(5, 4))
    np.testing.assert_allclose(big.f(X), 2.5 * base.f(X), rtol=1e-12)
    assert big.bounds.alpha == pytest.approx(2.5 * base.bounds.alpha)
    zero = make(n=5, seed=2, c=0.0)
    np.testing.assert_array_equal(zero.f(X), 0 * X)


def test_lipschitz_family_closed_form_is_tight():
    c = 0.7
    p = random_lipschitz_plant(n=64, seed=1, c=c)
    # at x = 0 the Jacobian is c G H with G, H orthogonal: all singular values equal c
    np.testing.assert_allclose(np.linalg.svd(p.jacobian(np.zeros(64)), compute_uv=False), c, rtol=1e-10)
    assert (p.bounds.alpha, p.bounds.rho, p.bounds.beta, p.bounds.gamma, p.bounds.radius) == (c, c, c**2, 0.0, None)
    rng = np.random.default_rng(5)
    x1 = rng.standard_normal((64, 2000)) * 3
    x2 = x1 + rng.standard_normal((64, 2000)) * 10.0 ** rng.uniform(-4, 0.5, 2000)
    dx, df = x1 - x2, p.f(x1) - p.f(x2)
    assert (np.linalg.norm(df, axis=0) / np.linalg.norm(dx, axis=0)).max() <= c * (1 + 1e-12)


def test_osl_family_closed_form():
    c, r = 0.8, 1.5
    p = random_osl_plant(n=64, seed=1, c=c, r=r)
    b = p.bounds
    assert (b.alpha, b.rho, b.beta, b.gamma, b.radius) == (3 * c * r**2, 0.0, 0.0, -3 * c * r**2, r)
    J = p.jacobian(np.full(64, 0.1))
    assert np.allclose(J, J.T) and np.linalg.eigvalsh(J).max() <= 1e-12  # -grad of a convex function
    rng = np.random.default_rng(6)
    for radius in (r, 10 * r):  # rho = 0 holds globally
        d = rng.standard_normal((64, 3000))
        x1 = d / np.linalg.norm(d, axis=0) * radius * rng.uniform(0, 1, 3000)
        x2 = x1 + rng.standard_normal((64, 3000)) * 0.1
        dx, df = x1 - x2, p.f(x1) - p.f(x2)
        inner = np.sum(dx * df, axis=0)
        assert inner.max() <= 1e-12 * np.abs(inner).max()
    # on the ball: ||df||^2 <= 3 c r^2 (-<dx, df>)
    x2 = x2 * np.minimum(1.0, r / np.linalg.norm(x2, axis=0))
    x1 = x1 * np.minimum(1.0, r / np.linalg.norm(x1, axis=0))
    dx, df = x1 - x2, p.f(x1) - p.f(x2)
    lhs, rhs = np.sum(df * df, axis=0), -3 * c * r**2 * np.sum(dx * df, axis=0)
    assert np.all(lhs <= rhs + 1e-9)
    assert np.linalg.norm(p.x0) == pytest.approx(r / 2) and np.linalg.norm(p.x_hat0) == 0


@pytest.mark.parametrize(
    "kw, name",
    [
        (dict(n=0), "n"), (dict(n=-3), "n"), (dict(n=2.5), "n"), (dict(n="4"), "n"), (dict(n=True), "n"),
        (dict(n=3, m=0), "m"), (dict(n=3, m=4), "m"), (dict(n=3, p=0), "p"), (dict(n=3, p=5), "p"),
        (dict(c=-1.0), "c"), (dict(c=float("nan")), "c"), (dict(seed=-1), "seed"),
        (dict(n=3, n_unstable=4), "n_unstable"), (dict(max_re=float("inf")), "max_re"),
    ],
)
@pytest.mark.parametrize("make", [random_lipschitz_plant, random_osl_plant])
def test_generator_bad_input_names_the_parameter(make, kw, name):
    with pytest.raises(PlantError, match=rf"^{name}: "):
        make(**kw)


@pytest.mark.parametrize("r", [0.0, -2.0, float("nan")])
def test_osl_family_bad_radius(r):
    with pytest.raises(PlantError, match=r"^r: "):
        random_osl_plant(r=r)


def test_registered_random_members():
    a = PLANTS.create("random_lipschitz_v1")
    b = PLANTS.create("random_osl_v1", n=16, seed=7)
    assert a.id == "random_lipschitz_v1" and a.n == 4 and a.params["seed"] == 0
    assert b.id == "random_osl_v1" and b.n == 16 and b.params["seed"] == 7


@pytest.mark.parametrize("field", ["alpha", "rho", "beta", "gamma"])
def test_non_finite_constant_is_rejected(field):
    kw = {"beta": 1.0, "gamma": 0.0}
    kw[field] = float("inf")
    with pytest.raises(PlantError, match=f"constants.{field}"):
        Constants(**kw)


@pytest.mark.parametrize("r", [0.0, -1.0])
def test_region_radius_must_be_positive(r):
    with pytest.raises(PlantError, match="radius"):
        Constants(alpha=1.0, radius=r)


# -- constants machinery ------------------------------------------------------------------------------
def _cubic(claimed, bounds):
    return Plant(id="cubic", A=-np.eye(2), B=np.eye(2)[:, :1], C=np.eye(2)[:1],
                 f=lambda x: -np.sum(np.asarray(x) ** 2, axis=0) * np.asarray(x),
                 x0=[0.5, 0.0], x_hat0=[0.0, 0.0], claimed=claimed, bounds=bounds)


def test_claims_are_checked_on_the_claimed_region():
    bounds = Constants(alpha=3.0, rho=0.0, beta=0.0, gamma=-3.0, radius=1.0)
    # the same Lipschitz constant claimed globally is wrong: f is cubic
    rep = compute_constants(_cubic(Constants(alpha=3.0), bounds), seed=0, n_samples=3000)
    v = rep.violated("alpha")
    assert v is not None
    x1, x2 = np.array(v.x1), np.array(v.x2)
    assert max(np.linalg.norm(x1), np.linalg.norm(x2)) > 1.0  # found outside the ball
    f = lambda x: -(x @ x) * x  # noqa: E731
    assert np.linalg.norm(f(x1) - f(x2)) / np.linalg.norm(x1 - x2) > 3.0
    # claimed on the ball, it holds; the sampled constants stay on the analytic region
    rep2 = compute_constants(_cubic(Constants(alpha=3.0, radius=1.0), bounds), seed=0, n_samples=3000)
    assert rep2.violations == [] and rep.sampled.radius == 1.0 and rep.sampled.alpha <= 3.0 + 1e-9


def test_report_flags_a_wrong_analytic_bound_and_shows_the_region():
    from bench.harness import RunOptions, RunResult
    from bench.report import _constants_table

    wrong = _cubic(Constants(), Constants(alpha=2.0, rho=0.0, beta=0.0, gamma=-3.0, radius=1.0))
    moving = PLANTS.create("moving_object_v1")
    consts = {"cubic": compute_constants(wrong, seed=0, n_samples=3000),
              "moving_object_v1": compute_constants(moving, seed=0, n_samples=3000)}
    table = _constants_table(RunResult([], consts, {}, RunOptions(), 0.0))
    rows = [r for r in table.splitlines() if r.startswith("| cubic | alpha")]
    assert "ANALYTIC BOUND DISPROVED" in rows[0] and "sampled (analytic disproved)" in rows[0]
    assert not any("DISPROVED" in r for r in table.splitlines() if "moving_object_v1" in r)
    # the violating pair in the row is real: recomputed here, its Lipschitz ratio exceeds the declared 2
    v = next(v for v in consts["cubic"].disproved if v.name == "alpha")
    assert ratios(wrong.f, v.x1, v.x2)[0] > 2.0 and max(np.linalg.norm(v.x1), np.linalg.norm(v.x2)) <= 1 + 1e-9
    header = table.splitlines()[0]
    moving_rows = [r for r in table.splitlines() if r.startswith("| moving_object_v1 |")]
    assert moving_rows
    for row in moving_rows:
        # the region column holds ||x|| <= 10, its pipes escaped so the row keeps the header's cells
        assert row.replace("\\|", "").count("|") == header.count("|") and "<= 10" in row


@pytest.mark.slow
@pytest.mark.parametrize("n", [2, 5, 16, 64, 128, 256])
def test_random_lti_sweep_many_seeds(n):
    for seed in range(20):
        for m, p in ((1, 1), (min(3, n), min(2, n))):
            A, B, C = random_lti(n, m, p, seed=seed)
            assert pbh_ok(A, B) and pbh_ok(A.T, C.T)
