"""Solver answers kept by problem data (bench.lmi._solve_problem): two cvxpy problems that compile to the same data
cost one solve, and the second gets exactly the answer a cold solve gives it.

Independent references: the least-trace P with A'P + PA <= -I is the Lyapunov solution of A'P + PA = -I
(scipy's solve_continuous_lyapunov), and min t s.t. [[t, 1], [1, a]] >= 0 is t = 1/a.
"""

import cvxpy as cp
import numpy as np
import pytest
from scipy.linalg import solve_continuous_lyapunov

from bench import lmi

A = np.array([[0.0, 1.0], [-2.0, -3.0]])


def _lyapunov_problem():
    """A new problem (new variable objects) that compiles to the same data each time."""
    P = cp.Variable((2, 2), symmetric=True)
    return cp.Problem(cp.Minimize(cp.trace(P)), [A.T @ P + P @ A << -np.eye(2), P >> 0]), P


def _schur_problem(a):
    t, p = cp.Variable(), cp.Parameter(nonneg=True, value=a)
    return cp.Problem(cp.Minimize(t), [cp.bmat([[cp.reshape(t, (1, 1), order="F"), np.ones((1, 1))],
                                                 [np.ones((1, 1)), cp.reshape(p, (1, 1), order="F")]]) >> 0]), t


@pytest.mark.parametrize("solver", ["CLARABEL", "SCS"])
def test_a_second_problem_with_the_same_data_is_answered_from_the_memo_with_the_cold_answer(solver):
    lmi.clear_program_cache()
    opts = {"eps": 1e-9} if solver == "SCS" else {}
    first, P1 = _lyapunov_problem()
    before = lmi.solve_tally()
    out1 = lmi.solve_timed(first, solver, **opts)
    mid = lmi.solve_tally()
    assert (mid["n"] - before["n"], mid["reused"] - before["reused"]) == (1, 0)
    second, P2 = _lyapunov_problem()
    out2 = lmi.solve_timed(second, solver, **opts)
    after = lmi.solve_tally()
    assert (after["n"] - mid["n"], after["reused"] - mid["reused"]) == (0, 1)
    assert out2.solver_s == 0.0  # no solver time spent on an answer taken again
    cold, P3 = _lyapunov_problem()
    cold.solve(solver=solver, **opts)  # cvxpy's own solve, outside the memo
    assert out1.status == out2.status == cold.status == "optimal"
    assert np.array_equal(P2.value, P1.value) and np.array_equal(P2.value, P3.value)
    assert out2.value == out1.value == cold.value
    tol = 1e-6 if solver == "CLARABEL" else 1e-4
    assert np.allclose(P2.value, solve_continuous_lyapunov(A.T, -np.eye(2)), atol=tol)


def test_an_unpacked_value_changed_in_place_does_not_change_the_kept_answer():
    """SCS answers with arrays that cvxpy may unpack as views: a caller scribbling on its result must not reach the
    answer kept for the next problem with the same data (min sum x s.t. x >= 1 and x <= 2: x = 1)."""
    lmi.clear_program_cache()

    def problem():
        x = cp.Variable(3)
        return cp.Problem(cp.Minimize(cp.sum(x)), [x >= 1, x <= 2]), x

    first, x1 = problem()
    lmi.solve_timed(first, "SCS")
    if x1.value.flags.writeable:
        x1.value[...] = 7.0
    second, x2 = problem()
    lmi.solve_timed(second, "SCS")
    assert lmi.solve_tally()["reused"] >= 1
    assert np.allclose(x2.value, 1.0, atol=1e-3)


def test_a_different_parameter_value_or_solver_option_is_solved_anew():
    lmi.clear_program_cache()
    n0 = lmi.solve_tally()["n"]
    p2, t2 = _schur_problem(2.0)
    lmi.solve_timed(p2)
    p4, t4 = _schur_problem(4.0)
    lmi.solve_timed(p4)
    assert lmi.solve_tally()["n"] - n0 == 2
    assert t2.value == pytest.approx(0.5, abs=1e-6) and t4.value == pytest.approx(0.25, abs=1e-6)
    again, _ = _schur_problem(2.0)
    lmi.solve_timed(again, "CLARABEL", max_iter=7)  # other options: another solve
    assert lmi.solve_tally()["n"] - n0 == 3


def test_cleared_with_the_program_cache():
    lmi.clear_program_cache()
    lmi.solve_timed(_lyapunov_problem()[0])
    lmi.clear_program_cache()
    n0 = lmi.solve_tally()["n"]
    lmi.solve_timed(_lyapunov_problem()[0])
    assert lmi.solve_tally()["n"] - n0 == 1


def test_an_injected_solver_fault_is_not_masked_by_a_kept_answer(monkeypatch):
    """A test that replaces cvxpy's Problem.solve (on the class or on one problem) gets its fault even for data
    whose answer is kept."""
    lmi.clear_program_cache()
    lmi.solve_timed(_lyapunov_problem()[0])

    def broken(*args, **kwargs):
        raise cp.error.SolverError("injected")

    one = _lyapunov_problem()[0]
    one.solve = broken  # on the instance
    out = lmi.solve_timed(one)
    assert out.status == "solver_error" and "injected" in out.error
    monkeypatch.setattr(cp.Problem, "solve", broken)  # on the class
    out = lmi.solve_timed(_lyapunov_problem()[0])
    assert out.status == "solver_error" and "injected" in out.error
