"""Compiled once, solved many times: LMI programs are cached per structure and re-parameterised.

The reference for every reused solve is a fresh build of the same problem (cache cleared): a
reused program must give the same status, the same gains (to solver tolerance) and verified
certificates; only the compile seconds may differ.
"""

import threading

import numpy as np
import pytest

from bench.certify import certify
from bench.registry import DESIGNS, PLANTS
from bench import lmi as _lmi
from bench.limits import DeadlineExceeded

LMI_DESIGNS = ("thm1", "thm1_sep", "cor1", "cor1_sep", "thm1_printed", "cor1_printed", "lqr+rajamani",
               "lqr+zhang_osl")


def _fresh(design_id, plant):
    _lmi.clear_program_cache()
    return DESIGNS.create(design_id).design(plant, plant.bounds)


def _same(a, b):
    assert a.status == b.status, (a.reason, b.reason)
    if a.has_gains:
        for g in ("K", "F"):
            x, y = getattr(a, g), getattr(b, g)
            assert np.allclose(x, y, rtol=1e-5, atol=1e-7 * max(1.0, float(np.abs(y).max()))), g


@pytest.mark.parametrize("design_id", LMI_DESIGNS)
def test_a_bisection_over_the_scale_reuses_one_program_and_matches_a_fresh_build(design_id):
    """Knob values 0.2 then 0.35 then 0.2 again: the later calls reuse the program built for the
    first (same A, B, C; only rho, beta, gamma / alpha change) and agree with fresh builds."""
    design = DESIGNS.create(design_id)
    plants = [PLANTS.create("flexible_link", c=c) for c in (0.2, 0.35, 0.2)]
    fresh = [_fresh(design_id, p) for p in plants[:2]]
    fresh.append(fresh[0])  # the same plant as the first: its fresh build is the first's
    _lmi.clear_program_cache()
    reused = []
    for p in plants:
        reused.append(design.design(p, p.bounds))
    for a, b in zip(reused, fresh):
        _same(a, b)


def _compiled_forms():
    """cvxpy's compiled (parameterised) form of every cached problem, by identity."""
    out = set()
    for prog in _lmi._cache().values():
        for prob in prog.problems.values():
            pp = getattr(prob._cache, "param_prog", None)
            if pp is not None:
                out.add(id(pp))
    return out


@pytest.mark.parametrize("design_id", ("thm1", "thm1_sep", "cor1", "lqr+zhang_osl"))
def test_later_calls_compile_nothing(design_id):
    """After the first call, calls at other knob values leave cvxpy's compiled forms untouched
    (no new program, no recompiled problem)."""
    design = DESIGNS.create(design_id)
    _lmi.clear_program_cache()
    p = PLANTS.create("flexible_link", c=0.2)
    design.design(p, p.bounds)
    programs, forms = set(map(id, _lmi._cache().values())), _compiled_forms()
    assert forms
    for c in (0.3, 0.1):
        p = PLANTS.create("flexible_link", c=c)
        design.design(p, p.bounds)
    assert set(map(id, _lmi._cache().values())) == programs
    assert _compiled_forms() == forms


def test_switching_solvers_keeps_one_compiled_problem_per_solver():
    """SCS then Clarabel then SCS on one program (the separated sides' fallback): each solver's
    problem is compiled once and both give a verified point."""
    plant = PLANTS.create("random_lipschitz_v1", n=6, m=2, p=2, c=0.1, seed=3)
    _lmi.clear_program_cache()
    DESIGNS.create("thm1_sep").design(plant, plant.bounds)
    prog = next(iter(_lmi._cache().values()))
    seen = {}
    for solver in ("SCS", "CLARABEL", "SCS", "CLARABEL"):
        prog.solve(solver=solver)
        assert prog.verified(), solver
        prob = prog._problem_for(solver)
        form = id(prob._cache.param_prog)
        assert seen.setdefault(solver, form) == form
    assert len(prog.problems) == 2


def test_random_family_members_of_one_shape_share_one_program():
    """Dense A, B, C (a random family) enter as Parameters: another seed is another parameter value."""
    design = DESIGNS.create("thm1_sep")
    a, b = (PLANTS.create("random_lipschitz_v1", n=6, m=2, p=2, c=0.1, seed=s) for s in (1, 2))
    _lmi.clear_program_cache()
    design.design(a, a.bounds)
    n_programs = len(_lmi._cache())
    rb = design.design(b, b.bounds)
    assert len(_lmi._cache()) == n_programs  # nothing new was built
    _same(rb, _fresh("thm1_sep", b))
    assert rb.status == "feasible"
    assert max(np.linalg.eigvals(b.A + b.B @ rb.F).real) < 0
    assert max(np.linalg.eigvals(b.A - rb.K @ b.C).real) < 0


def test_sparse_matrices_enter_by_pattern_and_key_the_program_by_it():
    """A mostly-zero A enters by its sparsity pattern: another A of the same pattern (a rescaled
    plant) shares the program, another pattern gets its own, and a dense A is a Parameter."""
    A1 = np.diag([-1.0, -2.0, -3.0])
    A2 = np.diag([-1.0, -2.0, -4.0])
    A3 = A1 + np.diag([1.0, 0.0], 1)
    dense = np.arange(1.0, 10.0).reshape(3, 3)
    m1, m2, m3, md = (_lmi.matrices(A=M) for M in (A1, A2, A3, dense))
    assert m1.dense == frozenset() and md.dense == frozenset({"A"})
    assert m1.key == m2.key and m1.key != m3.key
    assert md.key == _lmi.matrices(A=dense + 1.0).key  # same shape, parameter: same program
    assert md.settable().keys() == {"A"} and m1.settable().keys() == {"A"}
    assert _lmi.matrices(A=np.zeros((3, 3))).settable() == {}  # all zero: baked in


def _lyapunov_program(mats):
    import cvxpy as cp

    def build():
        v = {"P": cp.Variable((3, 3), symmetric=True), "slack": cp.Variable()}

        def blocks(d):
            return [[d["A"].T @ d["P"] + d["P"] @ d["A"]]]

        return _lmi.margin_program(blocks, v, mats.parameters(), ("P",))

    return build


def test_a_pattern_program_reused_for_another_matrix_matches_a_baked_constant():
    """The program built for A1 and re-set to A2 (same pattern) solves the Lyapunov LMI of A2 as a
    program with A2 baked in as a constant does (the same margin), and hands the solver no more
    nonzeros than the constant (no explicit zeros)."""
    import cvxpy as cp

    A1 = np.array([[-1.0, 2.0, 0.0], [0.0, -2.0, 0.0], [0.0, 0.0, -3.0]])
    A2 = np.array([[-1.0, 5.0, 0.0], [0.0, -0.5, 0.0], [0.0, 0.0, -3.0]])
    _lmi.clear_program_cache()
    m1, m2 = _lmi.matrices(A=A1), _lmi.matrices(A=A2)
    prog = _lmi.cached_program(("test.pattern", m1.key), _lyapunov_program(m1))
    prog.solve(**m1.settable())
    again = _lmi.cached_program(("test.pattern", m2.key), _lyapunov_program(m2))
    assert again is prog and again.reused
    t_reused = again.solve(**m2.settable())
    assert again.verified() and np.allclose(again.values()["A"], A2)

    P, t = cp.Variable((3, 3), symmetric=True), cp.Variable()
    baked = cp.Problem(cp.Maximize(t), [_lmi.sym(A2.T @ P + P @ A2) << -t * np.eye(3), P >> t * np.eye(3),
                                        P << 1e3 * np.eye(3), t <= 1])
    baked.solve(solver="CLARABEL")
    assert t_reused == pytest.approx(baked.value, rel=1e-5)
    nnz = lambda prob: prob.get_problem_data(cp.CLARABEL)[0]["A"].nnz  # noqa: E731
    assert nnz(again.problem) == nnz(baked)
    with pytest.raises(ValueError, match="outside the sparsity pattern"):
        again.set(A=np.ones((3, 3)))


def test_a_parameter_left_unset_fails_loudly_instead_of_reusing_a_stale_value():
    import cvxpy as cp

    def build():
        v = {"P": cp.Variable((2, 2), symmetric=True), "slack": cp.Variable()}
        prm = {"a": cp.Parameter(name="a")}

        def blocks(d):
            return [[-d["P"] * 1.0 + d["a"] * np.eye(2)]]

        return _lmi.margin_program(blocks, v, prm, ("P",))

    prog = _lmi.cached_program(("test.unset",), build)
    prog.solve(a=-1.0)
    assert prog.verified()
    again = _lmi.cached_program(("test.unset",), build)
    assert again is prog and again.reused
    from cvxpy.error import ParameterError

    with pytest.raises(ParameterError, match="(?i)parameter.*'a'.*value"):
        again.solve()


def test_threads_never_share_a_program():
    """A cvxpy problem holds its last solution: each thread has its own cache."""
    def build():
        import cvxpy as cp

        return _lmi.margin_program(lambda d: [[-d["P"]]], {"P": cp.Variable((2, 2), symmetric=True),
                                                           "slack": cp.Variable()}, {}, ("P",))

    mine = _lmi.cached_program(("test.thread",), build)
    other = []
    th = threading.Thread(target=lambda: other.append(_lmi.cached_program(("test.thread",), build)))
    th.start()
    th.join()
    assert other and other[0] is not mine


def test_certificates_reuse_the_analysis_program_and_agree_with_a_fresh_one(flex, flex_constants, flex_knowledge):
    """Certifying two gain pairs of the same size: the second reuses the program and both agree
    with fresh builds, level by level (certified or not, decay rate to the bisection tolerance)."""
    c = flex_constants.used
    pairs = []
    for did in ("paper_gains", "thm1_sep"):
        r = DESIGNS.create(did).design(flex, c)
        pairs.append((r.K, r.F))
    rtol = 0.03  # certify's rate_rtol: each rate is bisected to this relative tolerance
    # the certificate now takes what is trusted about f (Knowledge), not a Constants object
    warm = [certify(flex, K, F, flex_knowledge, rate_rtol=rtol) for K, F in pairs]
    cold = []
    for K, F in pairs:
        _lmi.clear_program_cache()
        cold.append(certify(flex, K, F, flex_knowledge, rate_rtol=rtol))
    assert any(w.certified for w in warm)  # the comparison is not vacuous
    for w, k in zip(warm, cold):
        assert w.certified == k.certified
        assert w.levels.keys() == k.levels.keys()
        for lv in w.levels:
            a, b = w.levels[lv], k.levels[lv]
            assert a.status == b.status, (lv, a.reason, b.reason)
            if a.certified:
                # both bracket the same largest rate to within rtol: they differ by at most ~2 rtol
                assert abs(a.decay_rate - b.decay_rate) <= 2 * rtol * max(a.decay_rate, b.decay_rate), lv


def test_a_program_cut_short_by_a_timeout_is_dropped_from_the_cache(monkeypatch):
    import cvxpy as cp

    def build():
        return _lmi.margin_program(lambda d: [[-d["P"]]], {"P": cp.Variable((2, 2), symmetric=True),
                                                           "slack": cp.Variable()}, {}, ("P",))

    prog = _lmi.cached_program(("test.timeout",), build)

    def boom(*a, **k):
        raise DeadlineExceeded("a test")

    monkeypatch.setattr(_lmi, "solve_timed", boom)
    with pytest.raises(DeadlineExceeded, match="a test"):
        prog.solve()
    monkeypatch.undo()
    assert _lmi.cached_program(("test.timeout",), build) is not prog
