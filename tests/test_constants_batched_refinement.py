"""The constants sampler's local refinement evaluates a value and its forward-difference gradient in one batch.

It must take the path scipy's L-BFGS-B takes with its own finite differences (one call per point), so the
sampled constants stay what they were: the references here are scipy's ``approx_derivative`` with L-BFGS-B's
step (``abs_step = eps = 1e-8``) and the former refinement, written out below.
"""

import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.optimize._numdiff import approx_derivative

import bench.constants as C

A = np.array([0.5, -2.0, 1.3])  # f(x) = A * sin(x) componentwise: alpha = max |A| = 2, rho = max(A) = 1.3


def sine(X):
    return A[:, None] * np.sin(X)


def former_neg(f, which, gamma, radius, n):
    """The refinement's objective before batching: one pair per call."""

    def neg(z):
        a, b = C._project(z[:n, None], radius), C._project((z[:n] + z[n:])[:, None], radius)
        if np.linalg.norm(a - b) < 1e-12:
            return 0.0
        val = C._ratios(f, a, b, gamma)[which][0]
        return -val if np.isfinite(val) else 0.0

    return neg


def former_local_max(f, which, gamma, x1, x2, radius, n, maxfun=15000):
    """The refinement before batching: L-BFGS-B on scipy's own finite differences."""
    neg = former_neg(f, which, gamma, radius, n)
    z0 = np.concatenate([x1, x2 - x1])
    box = None if radius is not None else [(-b, b) for b in [1e3 * max(1.0, float(np.abs(z0).max()))] * (2 * n)]
    try:
        z = minimize(neg, z0, method="L-BFGS-B", bounds=box, options={"maxiter": 200, "maxfun": maxfun}).x
    except Exception:
        z = z0
    a, b = C._project(z[:n, None], radius), C._project((z[:n] + z[n:])[:, None], radius)
    return a[:, 0], b[:, 0], -neg(z)


def _points(rng):
    """Points z = (x1, x2 - x1) with entries at 0, negative, large (where z + 1e-8 == z) and at the box's faces."""
    z = rng.normal(0, 2, (5, 6))
    z[1, [0, 4]] = 0.0
    z[2] = -np.abs(z[2])
    z[3, [1, 5]] = [3e8, -2e8]
    z[4, [0, 3]] = [1e9, -1e9]  # on the faces of the box +-1e9 below
    return z


@pytest.mark.parametrize("box", [False, True], ids=["unbounded", "box"])
@pytest.mark.parametrize("radius", [None, 2.0])
@pytest.mark.parametrize("which", [0, 1, 2])
def test_batched_gradient_is_scipys_finite_difference(which, radius, box):
    n, gamma = 3, 0.7
    lb, ub = (np.full(2 * n, -1e9), np.full(2 * n, 1e9)) if box else (None, None)
    neg = former_neg(sine, which, gamma, radius, n)
    for z in _points(np.random.default_rng(which)):
        value, grad = C._neg_and_gradient(sine, which, gamma, z, radius, n, lb, ub)
        ref = approx_derivative(neg, z, method="2-point", abs_step=1e-8,
                                bounds=(lb, ub) if box else (-np.inf, np.inf))
        assert value == neg(z)
        np.testing.assert_array_equal(grad, ref)  # bit for bit: the same steps, points and differences


def test_a_box_turns_the_step_back_at_its_face():
    n, z = 3, np.array([1.0, 0.5, -0.2, 0.3, 1e-3, 0.1])
    lb, ub = np.full(6, -5.0), np.array([1.0, 5, 5, 5, 5, 5])
    _, grad = C._neg_and_gradient(sine, 0, 0.0, z, None, n, lb, ub)
    _, free = C._neg_and_gradient(sine, 0, 0.0, z, None, n, None, None)
    assert grad[0] != free[0] and np.array_equal(grad[1:], free[1:])  # a backward difference in x1[0] only


@pytest.mark.parametrize("radius", [None, 1.5])
@pytest.mark.parametrize("which", [0, 1, 2])
def test_refinement_takes_the_former_path(which, radius):
    rng = np.random.default_rng(10 + which)
    for _ in range(3):
        x1 = rng.uniform(-1, 1, 3)
        x2 = C._project((x1 + rng.normal(0, 0.5, 3))[:, None], radius)[:, 0]
        new, old = C._local_max(sine, which, 0.4, x1, x2, radius, 3), former_local_max(sine, which, 0.4, x1, x2,
                                                                                       radius, 3)
        for got, want in zip(new, old):
            np.testing.assert_array_equal(got, want)


def test_the_evaluation_budget_stops_where_it_did(monkeypatch):
    """The former budget counted 2n + 1 evaluations per point: a budget that binds stops both at the same point."""
    n, x1, x2 = 3, np.array([0.9, -1.1, 0.4]), np.array([0.2, 0.3, -0.8])
    monkeypatch.setattr(C, "_MAXFUN", 7 * 5)  # 5 points
    new = C._local_max(sine, 1, 0.0, x1, x2, None, n)
    old = former_local_max(sine, 1, 0.0, x1, x2, None, n, maxfun=7 * 5)
    full = former_local_max(sine, 1, 0.0, x1, x2, None, n)
    assert not np.array_equal(old[0], full[0])  # the budget binds
    for got, want in zip(new, old):
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("radius", [None, 1.0])
def test_refinement_reaches_the_known_supremum(radius):
    # sup of the difference quotients of A_i sin = sup of the derivatives A_i cos, at x = 0 as dx -> 0: alpha = max |A|
    # (along e2), rho = max A (along e3), beta at gamma = 0 is alpha^2
    general, along_e3 = ([0.3, -0.2, 0.4], [0.35, -0.1, 0.45]), ([0.3, -0.2, 0.4], [0.3, -0.2, 0.45])
    for which, sup, (x1, x2) in ((0, 2.0, general), (1, 1.3, along_e3), (2, 4.0, general)):
        x1, x2 = np.array(x1), np.array(x2)
        a, b, val = C._local_max(sine, which, 0.0, x1, x2, radius, 3)
        start = C._ratios(sine, x1[:, None], x2[:, None], 0.0)[which][0]
        assert start < sup - 0.05  # the refinement had work to do
        assert sup * (1 - 1e-6) <= val <= sup * (1 + 1e-12)
        assert val == C._ratios(sine, a[:, None], b[:, None], 0.0)[which][0]  # the pair returned gives the value


@pytest.mark.parametrize("how", ["raises", "nan"])
def test_an_f_failing_at_one_column_keeps_the_sample(how):
    """x1[0] = 0.5 is the edge of f's domain: the gradient's first column (x1[0] + 1e-8) leaves it."""
    def f(X):
        X = np.asarray(X, dtype=float)
        if how == "raises" and np.any(X[0] > 0.5):
            raise ValueError("outside")
        return np.where(X[0] > 0.5, np.nan, sine(X))

    x1, x2 = np.array([0.5, 0.2, -0.3]), np.array([0.1, 0.25, -0.2])
    kept = x1 + (x2 - x1)  # the sample as the refinement holds it, (x1, x2 - x1)
    for which in range(3):
        a, b, val = C._local_max(f, which, 0.0, x1, x2, None, 3)
        assert np.array_equal(a, x1) and np.array_equal(b, kept)
        assert val == C._ratios(f, x1[:, None], kept[:, None], 0.0)[which][0]
        for got, want in zip((a, b, val), former_local_max(f, which, 0.0, x1, x2, None, 3)):
            np.testing.assert_array_equal(got, want)


def test_coinciding_pairs_are_zero_and_not_evaluated():
    seen = []

    def f(X):
        seen.append(X.shape[1])
        if np.any(np.all(X == 7.0, axis=0)):
            raise AssertionError("f evaluated at a coinciding pair")
        return sine(X)

    Z = np.array([[7.0, 0.1, 7.0], [7.0, 0.2, 7.0], [7.0, 0.3, 7.0],
                  [0.0, 0.5, 1e-13], [0.0, -0.5, 0.0], [0.0, 0.1, 0.0]])
    out = C._neg_ratios(f, 0, 0.0, Z, None, 3)
    assert out[0] == 0.0 and out[2] == 0.0 and out[1] < 0
    assert seen == [1, 1]  # only the one pair that does not coincide
