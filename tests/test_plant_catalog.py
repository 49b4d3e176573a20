"""The literature plants 2-5 of PLANTS.md, the random families, and the constants machinery
they rely on (claimed region, report flags). Expected values are derived by hand here."""

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


@pytest.fixture(scope="module")
def reports():
    cache = {}

    def get(pid):
        if pid not in cache:
            cache[pid] = compute_constants(PLANTS.create(pid), seed=0)
        return cache[pid]

    return get


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
    assert p.claimed.alpha == 3.33 and rep.violations == []
    # the claim belongs to the source's c: another c carries no claim
    assert PLANTS.create("flexible_joint_v1", c=1.0).claimed == Constants()


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
    assert rep.valid.rho == 0.0 and rep.valid.alpha == 300.0
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
    assert rep.violations == []
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
    assert rep.violations == []


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
    with pytest.raises(PlantError) as info:
        make(**kw)
    assert str(info.value).startswith(f"{name}: "), str(info.value)


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
    assert "ANALYTIC BOUND EXCEEDED" in rows[0]
    assert not any("EXCEEDED" in r for r in table.splitlines() if "moving_object_v1" in r)
    region = [r for r in table.splitlines() if r.startswith("| moving_object_v1 | region")][0]
    # pipes of ||x|| are escaped, so the row keeps its 7 cells
    assert region.replace("\\|", "").count("|") == 8 and "<= 10" in region


@pytest.mark.slow
@pytest.mark.parametrize("n", [2, 5, 16, 64, 128, 256])
def test_random_lti_sweep_many_seeds(n):
    for seed in range(20):
        for m, p in ((1, 1), (min(3, n), min(2, n))):
            A, B, C = random_lti(n, m, p, seed=seed)
            assert pbh_ok(A, B) and pbh_ok(A.T, C.T)
