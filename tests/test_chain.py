"""The chain plant family (plants/chain.py), checked against expectations derived here.

Expected values are derived independently of the module: the matrices from Newton's law written
out mass by mass, the undamped frequencies from the closed form of tridiag(-1, 2, -1), the
instability threshold from the compliance of the fixed-fixed chain, the constants by sampling.
"""

import math

import numpy as np
import pytest

from bench.registry import PLANTS
from plants import PlantError
from plants.chain import chain_plant, default_masses
from plants.random_families import is_detectable, is_stabilizable


def newton_matrices(N, m, k, d, b, ins, outs):
    """A, B, C from m q_i'' = sum of the spring/damper forces of the neighbours (walls at 0, N+1)."""
    n = 2 * N
    A = np.zeros((n, n))
    for i in range(N):
        A[2 * i, 2 * i + 1] = 1.0
        for j in (i - 1, i + 1):  # spring and damper to each neighbour (a wall: q = v = 0)
            A[2 * i + 1, 2 * i] -= k / m
            A[2 * i + 1, 2 * i + 1] -= d / m
            if 0 <= j < N:
                A[2 * i + 1, 2 * j] += k / m
                A[2 * i + 1, 2 * j + 1] += d / m
        A[2 * i + 1, 2 * i + 1] -= b / m
    B = np.zeros((n, len(ins)))
    for col, i in enumerate(ins):
        B[2 * i + 1, col] = 1.0 / m
    C = np.zeros((len(outs), n))
    for row, i in enumerate(outs):
        C[row, 2 * i] = 1.0
    return A, B, C


@pytest.mark.parametrize("N", [1, 2, 3, 7, 40])
def test_shapes_and_matrices_match_newtons_law(N):
    p = chain_plant(N=N, m=2.0, k=3.0, d=0.1, b=0.05, c=1.5)
    lay = default_masses(N)
    assert p.n == 2 * N and p.m == len(lay) and p.p == len(lay)
    assert p.channels.q == len(lay)
    A, B, C = newton_matrices(N, 2.0, 3.0, 0.1, 0.05, lay, lay)
    np.testing.assert_allclose(p.A, A, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(p.B, B)
    np.testing.assert_array_equal(p.C, C)
    assert p.x0.shape == (p.n,) and p.x_hat0.shape == (p.n,)


def test_default_layout():
    assert default_masses(3) == (1,)
    assert default_masses(1) == (0,)
    assert default_masses(12) == (2, 7)
    assert default_masses(10, stride=1) == tuple(range(10))


def test_undamped_frequencies_closed_form():
    N, m, k = 9, 1.5, 2.0
    p = chain_plant(N=N, m=m, k=k, d=0.0, b=0.0, nonlinear=(), inputs=(0,), outputs=(N - 1,))
    w = np.sort(np.abs(np.linalg.eigvals(p.A).imag))[::2]
    want = np.sqrt(k / m) * 2 * np.sin(np.arange(1, N + 1) * np.pi / (2 * (N + 1)))
    np.testing.assert_allclose(w, want, rtol=1e-9)
    assert np.abs(np.linalg.eigvals(p.A).real).max() < 1e-9


def test_open_loop_is_lightly_damped_and_the_linearisation_unstable():
    p = PLANTS.create("chain_v1")
    eA = np.linalg.eigvals(p.A)
    assert eA.real.max() < 0 and eA.real.max() > -0.05  # A alone: lightly damped
    lin = p.A + p.jacobian(np.zeros(p.n))
    assert np.linalg.eigvals(lin).real.max() > 0.5  # the inverted pendulum: unstable


@pytest.mark.parametrize("N, i", [(3, 1), (6, 0), (6, 2), (11, 5)])
def test_instability_threshold_is_the_compliance_of_the_chain(N, i):
    # static stiffness seen at mass i of the fixed-fixed chain: 1/[K^-1]_ii, with
    # [K^-1]_ii = (i+1)(N-i)/(N+1) for K = tridiag(-1, 2, -1) (0-based i), times k
    k = 1.7
    thr = k * (N + 1) / ((i + 1) * (N - i))
    for c, unstable in ((0.97 * thr, False), (1.03 * thr, True)):
        p = chain_plant(N=N, k=k, d=0.05, c=c, nonlinear=(i,), inputs=(0,), outputs=(0,))
        re = np.linalg.eigvals(p.A + p.jacobian(np.zeros(p.n))).real.max()
        assert (re > 0) == unstable, (c, thr, re)


@pytest.mark.parametrize("N, ins, outs", [(3, (0,), (2,)), (8, (3,), (5,)), (20, (0, 10), (19,)),
                                          (30, (2, 7, 12, 17, 22, 27), (2, 7, 12, 17, 22, 27))])
def test_pbh(N, ins, outs):
    p = chain_plant(N=N, inputs=ins, outputs=outs)
    assert is_stabilizable(p.A, p.B) and is_detectable(p.A, p.C)


def test_unstabilizable_layout_is_refused():
    # undamped chain of 3, force on the middle mass: mode 2 (shape (1, 0, -1)) has a node there
    with pytest.raises(PlantError, match="inputs"):
        chain_plant(N=3, d=0.0, b=0.0, inputs=(1,), outputs=(0,))
    with pytest.raises(PlantError, match="outputs"):
        chain_plant(N=3, d=0.0, b=0.0, inputs=(0,), outputs=(1,))
    # with damping that mode is stable: stabilizable/detectable
    p = chain_plant(N=3, d=0.02, inputs=(1,), outputs=(1,))
    assert is_stabilizable(p.A, p.B) and is_detectable(p.A, p.C)


@pytest.mark.parametrize("c", [2.0, -0.7])
def test_slopes_closed_form_and_sampled(c):
    p = chain_plant(N=10, c=c, m=1.3)
    ch = p.channels
    np.testing.assert_array_equal(ch.lo, -abs(c) * np.ones(ch.q))
    np.testing.assert_array_equal(ch.hi, abs(c) * np.ones(ch.q))
    rng = np.random.default_rng(0)
    a = rng.uniform(-10, 10, (ch.q, 20000))
    b = a + 10.0 ** rng.uniform(-6, 1, a.shape) * rng.choice([-1, 1], a.shape)
    slope = (ch.phi(a) - ch.phi(b)) / (a - b)
    assert slope.min() >= -abs(c) * (1 + 1e-9) and slope.max() <= abs(c) * (1 + 1e-9)
    assert slope.min() < -0.999 * abs(c) and slope.max() > 0.999 * abs(c)  # tight


def test_channels_reproduce_f_and_the_structure():
    p = chain_plant(N=12, c=1.1, m=0.8)
    ch = p.channels
    rng = np.random.default_rng(1)
    X = rng.standard_normal((p.n, 50)) * 3
    np.testing.assert_allclose(ch.apply(X), p.f(X), atol=1e-14)
    for col, i in enumerate(default_masses(12)):
        g = np.zeros(p.n)
        g[2 * i + 1] = 1 / 0.8
        h = np.zeros(p.n)
        h[2 * i] = 1.0
        np.testing.assert_array_equal(ch.G[:, col], g)
        np.testing.assert_array_equal(ch.H[col], h)


def test_f_contract_and_jacobian():
    p = chain_plant(N=15, c=2.0)
    rng = np.random.default_rng(2)
    X = rng.standard_normal((p.n, 5))
    X0 = X.copy()
    batch = p.f(X)
    np.testing.assert_array_equal(X, X0)  # no write into the argument
    for j in range(5):
        np.testing.assert_allclose(batch[:, j], p.f(X[:, j].copy()), rtol=0, atol=0)
    x = X[:, 0]
    h = 1e-6
    fd = np.column_stack([(p.f(x + h * e) - p.f(x - h * e)) / (2 * h) for e in np.eye(p.n)])
    np.testing.assert_allclose(p.jacobian(x), fd, atol=1e-8)


def sample_ratios(f, n, rng, N=40000):
    x1 = rng.standard_normal((n, N)) * 10.0 ** rng.uniform(-3, 1, N)
    d = rng.standard_normal((n, N))
    d /= np.linalg.norm(d, axis=0)
    x2 = x1 + d * 10.0 ** rng.uniform(-6, 0.5, N)
    dx, df = x1 - x2, f(x1) - f(x2)
    nx2 = np.sum(dx * dx, axis=0)
    return np.sqrt(np.sum(df * df, axis=0) / nx2), np.sum(dx * df, axis=0) / nx2, np.sum(df * df, axis=0) / nx2


@pytest.mark.parametrize("c, m", [(2.0, 1.0), (-0.5, 2.0), (3.0, 0.5)])
def test_constants_sampled_never_exceed_the_analytic_ones(c, m):
    p = chain_plant(N=3, c=c, m=m, nonlinear=(0, 1, 2), inputs=(0,), outputs=(2,))
    b = p.bounds
    # derived here: alpha = |c|/m, rho = |c|/(2m), (beta, gamma) = (c^2/m^2, 0)
    assert b.alpha == pytest.approx(abs(c) / m) and b.rho == pytest.approx(abs(c) / (2 * m))
    assert b.beta == pytest.approx(c * c / (m * m)) and b.gamma == 0.0
    assert p.claimed == b
    a, rho, beta = sample_ratios(p.f, p.n, np.random.default_rng(3))
    assert a.max() <= b.alpha * (1 + 1e-9) and rho.max() <= b.rho * (1 + 1e-9) and beta.max() <= b.beta * (1 + 1e-9)
    # tightness, at the pairs the derivation names (near the origin)
    dd = 1e-4
    x1 = np.zeros(p.n)
    x2 = np.zeros(p.n)
    x2[0] = dd
    assert np.linalg.norm(p.f(x1) - p.f(x2)) / dd == pytest.approx(b.alpha, rel=1e-6)
    x2[1] = np.sign(c) * dd
    assert np.dot(x1 - x2, p.f(x1) - p.f(x2)) / (2 * dd * dd) == pytest.approx(b.rho, rel=1e-6)


def test_no_pendulum_is_linear():
    p = chain_plant(N=4, nonlinear=(), inputs=(0,), outputs=(3,))
    assert p.channels is None and p.bounds.alpha == 0.0
    np.testing.assert_array_equal(p.f(np.ones(p.n)), np.zeros(p.n))


def test_initial_conditions_are_deterministic():
    a, b = chain_plant(N=5), chain_plant(N=5)
    np.testing.assert_array_equal(a.x0, b.x0)
    want = np.zeros(10)
    want[0::2] = 0.5 * np.sin(np.pi * np.arange(1, 6) / 6)
    np.testing.assert_allclose(a.x0, want)
    np.testing.assert_array_equal(a.x_hat0, np.zeros(10))


def test_registered_member():
    p = PLANTS.create("chain_v1")
    assert p.id == "chain_v1" and p.n == 6 and p.params["version"] == 1 and p.family == "chain"
    assert p.m == 1 and p.p == 1 and p.channels.q == 1
    assert p.source.strip()
    q = PLANTS.create("chain_v1", N=5)
    assert q.n == 10


@pytest.mark.parametrize("kw, name", [
    ({"N": 0}, "N"), ({"N": 2.5}, "N"), ({"m": 0.0}, "m"), ({"k": -1.0}, "k"), ({"d": -0.1}, "d"),
    ({"c": math.nan}, "c"), ({"inputs": (7,)}, "inputs"), ({"outputs": (0, 0)}, "outputs"),
    ({"nonlinear": "01"}, "nonlinear"), ({"inputs": ()}, "inputs"), ({"stride": 0}, "stride"),
])
def test_bad_arguments_name_the_parameter(kw, name):
    with pytest.raises(PlantError, match=rf"^{name}:"):
        chain_plant(**{"N": 3, **kw})


def test_large_chain_builds():
    p = chain_plant(N=200)
    assert p.n == 400 and p.channels.q == 40
    assert np.count_nonzero(p.A) == 7 * 200 - 4
