"""The batched checks of bench.witness agree with the one-matrix rules they replace, each expectation
derived here: the OSL constant of f = L x is the largest eigenvalue of sym(L) (scipy's eigh), its QIB margin
the largest eigenvalue of L'L - gamma sym(L) - beta I, its Lipschitz constant the largest singular value
(numpy's SVD with vectors); boundary members are built at a known distance from the constants, in units of
the tolerance 1e-12 max(1, max |L_ij|). The vertex test, the loops' rates and the equilibrium search's
right-hand side are checked against closed forms and the loop written out in (x, x_hat)."""

from __future__ import annotations

import itertools
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.linalg

from bench import witness
from bench.registry import DESIGNS, PLANTS
from bench.witness import admits, admitted, no_equilibrium, slowest_loop
from plants import Constants

ORDERS = [("osl",), ("qib",), ("lip",), ("osl", "qib"), ("lip", "osl"), ("qib", "lip", "osl"), ("osl", "qib", "lip")]


def _osl(L):
    return float(scipy.linalg.eigh((L + L.T) / 2, eigvals_only=True).max())


def _qib(L, c):
    return float(scipy.linalg.eigh(L.T @ L - c.gamma * (L + L.T) / 2, eigvals_only=True).max()) - c.beta


def _lip(L):
    return float(np.linalg.svd(L)[1][0])


def _tol(L):
    return 1e-12 * max(1.0, float(np.abs(L).max()))


def _expected(L, scalars, c):
    ok = {"osl": _osl(L) - c.rho <= _tol(L), "qib": _qib(L, c) <= _tol(L), "lip": _lip(L) <= c.alpha + _tol(L)}
    return all(ok[k] for k in scalars)


def _random_stack(rng, n, N=40):
    """Random members, sizes from 1e-3 to 1e3 (so the tolerance scales with some of them)."""
    return rng.standard_normal((N, n, n)) * 10.0 ** rng.uniform(-3, 3, size=(N, 1, 1))


@pytest.mark.parametrize("n", [1, 2, 3, 5, 8])
def test_batched_and_single_admits_follow_the_three_constants_on_random_members(n):
    rng = np.random.default_rng(n)
    Ls = _random_stack(rng, n)
    gamma = float(rng.uniform(-2, 2))
    # constants at the stack's medians: about half the members meet each one, not the same half
    rho = float(np.median([_osl(L) for L in Ls]))
    beta = float(np.median([_qib(L, Constants(beta=0.0, gamma=gamma)) for L in Ls]))
    alpha = float(np.median([_lip(L) for L in Ls]))
    c = Constants(alpha=alpha, rho=rho, beta=beta, gamma=gamma)
    for scalars in ORDERS:
        want = np.array([_expected(L, scalars, c) for L in Ls])
        assert 0 < want.sum() < len(Ls) or len(scalars) == 3
        assert np.array_equal(admitted(Ls, scalars, c), want), scalars
        assert [admits(L, scalars, c) for L in Ls] == want.tolist(), scalars
    assert admitted(Ls, (), c).all() and admitted(Ls[:0], ("osl",), c).shape == (0,)


@pytest.mark.parametrize("size", [0.01, 1.0, 500.0])
def test_members_at_the_tolerance_are_kept_and_beyond_it_are_not(size):
    """Each constant met within k tol for k in (-3, 0.5) and unmet for k in (2, 5), tol = 1e-12 max(1, max |L_ij|)
    of each member: OSL alone (L0 shifted by a multiple of I: its OSL constant moves by as much), Lipschitz alone
    and QIB alone (L0 scaled; gamma = 0, so the QIB margin is ||L||^2 - beta). QIB only up to size 1: beyond, the
    rounding of ||L||^2 outgrows a tolerance that scales with max |L_ij|, not with its square."""
    rng = np.random.default_rng(7)
    n, ks = 4, (-3.0, 0.5, 2.0, 5.0)
    loose = dict(alpha=1e9, rho=1e9, beta=1e18, gamma=0.0)
    for L0 in (size * rng.standard_normal((n, n)) for _ in range(6)):
        rho, alpha, beta = _osl(L0) + 0.3 * size, 0.7 * _lip(L0), 1.3 * _lip(L0) ** 2
        groups = [("osl", Constants(**{**loose, "rho": rho}),
                   lambda t: L0 + (t - _osl(L0)) * np.eye(n), rho),
                  ("lip", Constants(**{**loose, "alpha": alpha}), lambda t: L0 * (t / _lip(L0)), alpha)]
        if size <= 1.0:
            groups.append(("qib", Constants(**{**loose, "beta": beta}), lambda t: L0 * np.sqrt(t) / _lip(L0), beta))
        for name, c, move, target in groups:
            Ls = []
            for k in ks:
                L = move(target)
                Ls.append(move(target + k * _tol(L)))  # the constant reads target + k tol
            want = [k < 1 for k in ks]
            assert [admits(L, (name,), c) for L in Ls] == want, name
            assert admitted(np.stack(Ls), (name,), c).tolist() == want, name  # each member its own tol
            # after other constants they all meet (each checked on the survivors of the ones before)
            others = tuple(k for k in ("osl", "qib", "lip") if k != name)
            assert admitted(np.stack(Ls), others + (name,), c).tolist() == want, name


def test_each_constant_flips_alone():
    """Four members, each breaking at most one constant: every order of checks keeps the right ones."""
    c = Constants(alpha=2.0, rho=0.5, beta=5.0, gamma=4.0)
    Ls = np.stack([np.diag([0.4, -0.5]),                        # meets all
                   np.diag([0.6, -0.5]),                        # OSL 0.6 > 0.5
                   2.1 * np.array([[0.0, 1.0], [-1.0, 0.0]]),   # ||L|| = 2.1 > 2 (skew: OSL 0, L'L = 4.41 I)
                   np.diag([0.4, -1.5])])                       # QIB: 1.5^2 + 4 * 1.5 = 8.25 > 5
    flags = [(_osl(L) <= c.rho, _qib(L, c) <= 0, _lip(L) <= c.alpha) for L in Ls]  # (osl, qib, lip) met
    assert flags == [(True, True, True), (False, True, True), (True, True, False), (True, False, True)]
    for r in (1, 2, 3):
        for scalars in itertools.permutations(("osl", "qib", "lip"), r):
            want = [all(f[("osl", "qib", "lip").index(k)] for k in scalars) for f in flags]
            assert admitted(Ls, scalars, c).tolist() == want, scalars
            assert [admits(L, scalars, c) for L in Ls] == want, scalars


@pytest.mark.filterwarnings("ignore:invalid value:RuntimeWarning")
def test_a_non_finite_member_is_not_admitted_and_spares_the_others():
    c = Constants(alpha=10.0, rho=10.0, beta=100.0, gamma=0.0)
    Ls = np.stack([np.eye(2), np.array([[np.nan, 0.0], [0.0, 1.0]]), np.array([[np.inf, 0.0], [0.0, 1.0]]), -np.eye(2)])
    assert admitted(Ls, ("osl", "qib", "lip"), c).tolist() == [True, False, False, True]
    assert admitted(Ls, ("qib", "lip"), c).tolist() == [True, False, False, True]


@pytest.mark.parametrize("crossing, expected", [(0.5, True), (0.999, True), (1.0, False), (2.0, False)])
def test_vertex_test_over_many_batches_matches_the_determinant(crossing, expected):
    """Five channels (4^5 = 1024 vertices, several batches) on a block-triangular loop (F = 0): det M =
    prod(d1_i - 1) prod(d2_i - 10) with G = H = I, A = -I, A - K C = -10 I, slopes in [0, hi]; only channel 0
    reaches ``crossing``, and only d1_0 can make the determinant vanish or change sign, at the vertices
    with d1_0 = hi: the second half of the vertex order, batches after the first."""
    n = 5
    plant = SimpleNamespace(A=-np.eye(n), B=np.eye(n), C=np.eye(n), n=n, dt=0.0)
    K, F = 9.0 * np.eye(n), np.zeros((n, n))
    hi = np.array([crossing, 0.5, 0.5, 0.5, 0.5])
    know = SimpleNamespace(channels=SimpleNamespace(G=np.eye(n), H=np.eye(n), lo=np.zeros(n), hi=hi, radius=None))
    assert 4 ** n > 2 * witness.VERTEX_BATCH
    assert no_equilibrium(plant, K, F, know) is expected


def _loops(plant, K, F, L):
    """Eigenvalues of the whole 2n x 2n loop with f = L x, in (x, x_hat) coordinates."""
    A, B, C = plant.A, plant.B, plant.C
    M = np.block([[A + L, B @ F], [K @ C, A + L + B @ F - K @ C]])
    return np.linalg.eigvals(M)


@pytest.mark.parametrize("pid", ["pendulum_v1", "flexible_link_d10ms_v1", "chain_v1"])
def test_slowest_loop_and_one_member_rate_match_the_whole_loop(pid):
    plant = PLANTS.create(pid)
    res = DESIGNS.create("lqr+lqe").design(plant, plant.bounds)
    K, F = np.asarray(res.K, float), np.asarray(res.F, float)
    rng = np.random.default_rng(3)
    Ls = [s * rng.standard_normal((plant.n, plant.n)) for s in (0.0, 0.1, 1.0, 3.0, 10.0)]
    dt = float(getattr(plant, "dt", 0.0) or 0.0)

    def rate(L):
        eig = _loops(plant, K, F, L)
        return -np.log(np.abs(eig).max()) / dt if dt > 0 else -eig.real.max()

    rates = [rate(L) for L in Ls]
    i, r, eig = slowest_loop(plant, K, F, Ls)
    assert i == int(np.argmin(rates)) and r == pytest.approx(min(rates), rel=1e-9, abs=1e-9)
    parts = witness._loop_parts(plant, K, F)
    for L, want in zip(Ls, rates):
        assert witness._rate1(parts, L) == pytest.approx(want, rel=1e-9, abs=1e-9)
        assert witness._rate1(parts, L) == slowest_loop(plant, K, F, [L])[1]


@pytest.mark.parametrize("pid", ["pendulum_v1", "flexible_joint_v1", "nguyen2018_ex1_flexible_joint_v1"])
def test_the_root_search_function_is_the_loop_in_x_and_e_and_its_jacobian(pid):
    """rhs(z) = z' (continuous) or z_{k+1} - z (discrete) of the loop written in (x, x_hat) here, e = x - x_hat;
    jac = its derivative (central differences)."""
    plant = PLANTS.create(pid)
    res = DESIGNS.create("lqr+lqe").design(plant, plant.bounds)
    K, F = np.asarray(res.K, float), np.asarray(res.F, float)
    n, dt = plant.n, float(getattr(plant, "dt", 0.0) or 0.0)
    rhs, jac = witness._loop_fns(plant, K, F)
    rng = np.random.default_rng(11)
    for _ in range(5):
        z = rng.standard_normal(2 * n)
        x, xh = z[:n], z[:n] - z[n:]
        u = F @ xh
        dx = plant.A @ x + plant.B @ u + plant.f(x)
        dxh = plant.A @ xh + plant.B @ u + plant.f(xh) + K @ (plant.C @ x - plant.C @ xh)
        step = np.concatenate([dx, dx - dxh])  # (x, e)' or (x, e)_{k+1}
        want = step - z if dt > 0 else step
        assert np.allclose(rhs(z), want, rtol=1e-12, atol=1e-12 * max(1.0, np.abs(want).max()))
        h = 1e-6
        fd = np.column_stack([(rhs(z + h * v) - rhs(z - h * v)) / (2 * h) for v in np.eye(2 * n)])
        assert np.allclose(jac(z), fd, rtol=1e-6, atol=1e-6 * max(1.0, np.abs(fd).max()))
