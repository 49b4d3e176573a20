"""The ladder's numerics (issue 34): balanced coordinates, a second solver, the verification-aligned normalisation,
the cascade rung, regions chosen for x0, and the bracketed rate search.

Every certificate here is checked by a computation of the test's own: the loops have one sine channel
(``f = G phi(H x)``, slope in ``[-c, c]``), so with ``w = d H z`` the closed loop is the linear differential
inclusion ``z' = Acl(d_x, d_e) z``, ``Acl = [[A + B F + d_x G H, -B F], [0, A - K C + d_e G H]]`` over the four
vertices of ``(d_x, d_e)``; a quadratic ``V = z' P z`` with ``Acl' P + P Acl + 2 lam P < 0`` at the vertices proves
the rate lam for the nonlinear loop (the matrix is affine in d), by numpy eigenvalues alone.
"""

import math

import numpy as np
import pytest
import scipy.linalg as sla

from bench import checks, lmi, lyapunov
from bench.certify import certify, explain
from bench.constants import Knowledge
from bench.registry import PLANTS
from bench.pipeline import certificate_scope

#: Printed high-gain gains for the flexible joint (F places A + B F at -30, -40, -50, -60, ||F|| = 8.06e3; K places
#: A - K C at -3, -4, -5, -6, ||K|| = 51). At commit 854b53c the ladder says: paper not certified, full
#: "undecided" (CLARABEL solver_error), structured "marginal" (max eig -5.1e-07, within the tolerance).
HIGH_F = np.array([[-547.77, -8.2755, -7999.2, -803.63]])
HIGH_K = np.array([[5.0, 1.0], [-45.147, 11.75], [0.62666, 0.70996], [19.387, -3.7346]])


def _vertices(plant, K, F):
    """The loop's matrices at the vertices of the channel's slope box (one channel)."""
    ch = plant.channels
    E = ch.G @ ch.H
    BF = plant.B @ F
    out = []
    for dx in (ch.lo[0], ch.hi[0]):
        for de in (ch.lo[0], ch.hi[0]):
            out.append(np.block([[plant.A + BF + dx * E, -BF], [np.zeros_like(E), plant.A - K @ plant.C + de * E]]))
    return out


def _vertex_margin(plant, K, F, P, lam):
    """The largest eigenvalue, over the vertices, of ``Acl' P + P Acl + 2 lam P`` relative to ``||P|| ||Acl||``."""
    worst = -math.inf
    for A in _vertices(plant, K, F):
        S = A.T @ P + P @ A + 2 * lam * P
        worst = max(worst, float(np.linalg.eigvalsh((S + S.T) / 2)[-1]) / (np.linalg.norm(P, 2) * np.linalg.norm(A, 2)))
    return worst


@pytest.fixture(scope="module")
def joint():
    return PLANTS.create("flexible_joint_v1")


def _side_lyapunov(A, E, ds):
    """A P > 0 with ``(A + d E)' P + P (A + d E) < 0`` at the vertices ``ds`` (a vertex LMI of the test's own)."""
    import cvxpy as cp

    n = A.shape[0]
    P, t = cp.Variable((n, n), symmetric=True), cp.Variable()
    cons = [P >> t * np.eye(n), cp.trace(P) == 1]
    cons += [(A + d * E).T @ P + P @ (A + d * E) << -t * np.eye(n) for d in ds]
    cp.Problem(cp.Maximize(t), cons).solve(solver="CLARABEL")
    return np.array(P.value)


def test_the_high_gain_loop_has_a_cascade_certificate_by_numpy_alone(joint):
    """Independent of the suite: each side has a common Lyapunov matrix at both slope vertices (a vertex LMI of the
    test's own, checked by numpy), and V = x' Px x + mu e' Pe e then holds at all four vertices of the loop for a
    large mu (the cascade: the x side sees B F e as an input)."""
    ch = joint.channels
    E = ch.G @ ch.H
    ds = (ch.lo[0], ch.hi[0])
    Ax, Ae = joint.A + joint.B @ HIGH_F, joint.A - HIGH_K @ joint.C
    Px, Pe = _side_lyapunov(Ax, E, ds), _side_lyapunov(Ae, E, ds)
    for P, A in ((Px, Ax), (Pe, Ae)):
        assert np.linalg.eigvalsh(P)[0] > 0
        for d in ds:
            assert np.linalg.eigvalsh((A + d * E).T @ P + P @ (A + d * E))[-1] < 0
    ok = [mu for mu in 10.0 ** np.arange(0, 16)
          if _vertex_margin(joint, HIGH_K, HIGH_F, sla.block_diag(Px, mu * Pe), 0.0) < 0]
    assert ok, "no weight mu makes the cascade a joint certificate"


def test_printed_high_gain_gains_are_certified_and_the_certificate_holds_at_the_vertices(joint):
    """The structured level certifies the high-gain pair (at 854b53c: marginal): its trace-normalised optimum is
    within the tolerance, the normalisation by the matrix's entries (the verification's own scale) verifies."""
    assert np.linalg.norm(HIGH_F) >= 1e3
    loop = checks.closed_loop(joint, HIGH_K, HIGH_F)
    cert = certify(joint, HIGH_K, HIGH_F, Knowledge.trusting(joint), loop=loop)
    st = cert.levels["structured"]
    assert st.certified, st.reason
    assert "within the verification tolerance" in st.reason and "|M_ij|" in st.reason
    assert 0 < st.decay_rate < loop.linearised_rate
    assert cert.levels["full"].status != "certified" or cert.levels["full"].decay_rate <= st.decay_rate
    # the certificate itself, checked by numpy on the vertex inclusion: at the certified rate and at rate 0
    assert _vertex_margin(joint, HIGH_K, HIGH_F, st.P, st.decay_rate) < 0
    assert np.linalg.eigvalsh(st.P)[0] > 0


def test_when_the_joint_lmi_fails_the_cascade_rung_certifies(joint, monkeypatch):
    """Every solve of the level's joint LMI made to fail (both solvers): the cascade rung builds V from the two
    sides (their own, smaller LMIs) and the level's matrix verifies it; numpy confirms it at the vertices."""
    r = PLANTS.create("flexible_joint_v1")
    K = np.array([[5.0, 1.0], [-45.147, 11.75], [0.62666, 0.70996], [19.387, -3.7346]])
    F = np.array([[-12.35648, -1.33102, 5.17699, -2.52849]])  # places A + B F at -6, -7, -8, -9
    assert np.all(np.linalg.eigvals(r.A + r.B @ F).real < 0)
    orig = lmi.solve_timed

    def failing(problem, solver="CLARABEL", **opts):  # a joint program: its P is 2n x 2n
        if max((v.shape[0] for v in problem.variables() if v.ndim == 2), default=0) == 2 * r.n:
            return lmi.SolveOutcome("solver_error", 0.0, 0.0, "the joint LMI made to fail")
        return orig(problem, solver, **opts)

    monkeypatch.setattr(lmi, "solve_timed", failing)
    cert = certify(r, K, F, Knowledge.trusting(r), levels=("structured",))
    st = cert.levels["structured"]
    assert st.certified and st.reason.startswith("cascade certificate"), st.reason
    n = r.n
    assert np.allclose(st.P[:n, n:], 0)  # V = x' Px x + mu e' Pe e
    assert _vertex_margin(r, K, F, st.P, st.decay_rate) < 0


def test_a_failing_first_solver_falls_back_to_the_second_and_the_verdict_is_the_suites(monkeypatch):
    """Clarabel made to raise: every solve goes to SCS, and the level is still decided by the rebuilt matrix."""
    import cvxpy as cp

    plant = PLANTS.create("flexible_link")
    from bench.registry import DESIGNS

    d = DESIGNS.create("lqr+lqe").design(plant, plant.bounds)
    used = []
    orig = lmi.solve_timed

    def no_clarabel(problem, solver="CLARABEL", **opts):
        used.append(solver.upper())
        if solver.upper() == "CLARABEL":
            raise_in = problem.solve

            def boom(*a, **k):
                raise cp.error.SolverError("Clarabel made to fail")

            problem.solve = boom
            try:
                return orig(problem, solver, **opts)
            finally:
                problem.solve = raise_in
        return orig(problem, solver, **opts)

    monkeypatch.setattr(lmi, "solve_timed", no_clarabel)
    lmi.clear_program_cache()
    cert = certify(plant, d.K, d.F, Knowledge.trusting(plant), levels=("structured",), rates=False)
    st = cert.levels["structured"]
    assert "SCS" in used and "CLARABEL" in used
    assert st.certified, st.reason  # SCS's point, verified by the suite's check; numpy agrees at the vertices
    assert _vertex_margin(plant, d.K, d.F, st.P, 0.0) < 0
    lmi.clear_program_cache()


def test_program_fallback_and_memo():
    """A program whose first solver fails is solved by the second; the same solve again is answered from memory."""
    import cvxpy as cp

    P = cp.Variable((2, 2), symmetric=True)
    s = cp.Variable()
    A = cp.Parameter((2, 2))
    prob = lmi.margin_program(lambda d: [[d["A"].T @ d["P"] + d["P"] @ d["A"]]], {"P": P, "slack": s}, {"A": A},
                              ("P",))
    prob.set(A=np.array([[-1.0, 2.0], [0.0, -3.0]]))
    prob.problems["CLARABEL"] = prob.problem
    prob.problems["SCS"] = cp.Problem(prob.problem.objective, prob.problem.constraints)

    def boom(*a, **k):
        raise cp.error.SolverError("made to fail")

    prob.problem.solve = boom
    n0 = lmi.solve_tally()["n"]
    prob.solve(fallback=True)
    assert prob.tried.startswith("CLARABEL:solver_error -> SCS:"), prob.tried
    assert prob.verified() and prob.solver == "SCS"
    # independent: the Lyapunov inequality at the point, by numpy
    Pv, Av = prob.values()["P"], np.array([[-1.0, 2.0], [0.0, -3.0]])
    assert np.linalg.eigvalsh(Av.T @ Pv + Pv @ Av)[-1] < 0 and np.linalg.eigvalsh(Pv)[0] > 0
    solved = lmi.solve_tally()["n"] - n0
    before = {k: np.array(v.value) for k, v in prob.variables.items()}
    prob.solve(solver="SCS", solver_opts=lmi.FALLBACK_SCS_OPTS)
    assert lmi.solve_tally()["n"] - n0 == solved and prob.n_reused >= 1
    assert all(np.array_equal(before[k], prob.variables[k].value) for k in before)


def test_balancing_is_a_congruence_the_verdict_is_taken_in_the_original_coordinates(joint):
    """The level's program solves in balanced coordinates; mapped back, its point rebuilds the same matrix as
    ``S^-T M~ S^-1`` (a congruence), and the verdict is classify's on the original matrix."""
    spec = lyapunov.Spec("structured", 4, 1, True, (), True)
    data = lyapunov.level_data(spec, joint.A, joint.B, joint.C, HIGH_K, HIGH_F, Knowledge.trusting(joint))
    lv = lyapunov.Level(spec, data)
    t = np.diag(lv.T)
    assert np.all(np.log2(t) == np.round(np.log2(t)))  # powers of 2: the change is exact
    verdict, margin = lv.solve(0.0)
    vals = lv.prog.values()
    Mt = lyapunov.matrix(spec, {**vals, "Acl": lv._vals["Acl"], "Gb": lv._vals["Gb"], "Pi": lv._vals["Pi"]})[0][0]
    M = lv.prog.numeric_matrix()
    S = np.diag(np.concatenate([t, [1.0, 1.0]]))
    assert np.allclose(np.linalg.inv(S).T @ Mt @ np.linalg.inv(S), M, rtol=1e-9, atol=1e-9 * np.abs(M).max())
    assert verdict == lmi.classify(lmi.max_eig(M), M) and margin == lmi.max_eig(M)


def test_moving_object_printed_gains_are_certified_from_x0():
    """The issue's moving-object design (Nguyen et al., Euler-discretised at 1 ms; continuous equivalents
    F = [5.8992, 637.0308], K = L / ts = [2, 1]): at 854b53c certified only locally (level set 0.0103 < V(z0)
    = 0.0388); the level set through z0 is now chosen inside ||x||, ||x_hat|| <= 10. Checked here: the ellipsoid's
    reach by its own eigenvalues, and V decaying at the certified rate along the simulated nonlinear loop."""
    from scipy.integrate import solve_ivp

    plant = PLANTS.create("moving_object_v1")
    F, K = np.array([[5.8992, 637.0308]]), np.array([[2.0], [1.0]])
    loop = checks.closed_loop(plant, K, F)
    know = Knowledge.trusting(plant)
    cert = explain(certify(plant, K, F, know, loop=loop), plant, K, F, know, loop=loop)
    best = cert.best
    assert best is not None and best.radius == 10.0 and best.decay_rate > 0
    assert certificate_scope(best.P, best.radius, plant.x0, plant.x_hat0)["cert_scope"] == "from x0"
    z0 = np.concatenate([plant.x0, plant.x0 - plant.x_hat0])
    v0 = z0 @ best.P @ z0
    Pi = np.linalg.inv(best.P)
    n = plant.n
    for T in (np.hstack([np.eye(n), np.zeros((n, n))]), np.hstack([np.eye(n), -np.eye(n)])):  # x and x_hat
        assert math.sqrt(v0 * np.linalg.eigvalsh(T @ Pi @ T.T)[-1]) <= best.radius

    def rhs(t, z):
        x, e = z[:n], z[n:]
        xh = x - e
        u = F @ xh
        f = plant.f
        return np.concatenate([plant.A @ x + plant.B @ u + f(x), (plant.A - K @ plant.C) @ e + f(x) - f(xh)])

    sol = solve_ivp(rhs, (0, 5.0), z0, method="LSODA", rtol=1e-10, atol=1e-12, dense_output=True)
    ts = np.linspace(0, 5.0, 200)
    V = np.einsum("it,ij,jt->t", sol.sol(ts), best.P, sol.sol(ts))
    assert np.all(V <= v0 * np.exp(-2 * best.decay_rate * ts) * (1 + 1e-6) + 1e-14)


def test_the_bracketed_search_agrees_with_a_bisection_and_a_level_no_better_than_below_costs_one_solve():
    """The search's answer is a plain bisection's on the same program, within one grid step; a level whose rate is
    the level below's costs one solve (the grid rate just above it fails); a level whose rate is within a grid step
    of its class ceiling costs two (the grid rate just below the ceiling, then the one above the level below)."""
    from bench.registry import DESIGNS
    from bench.search import largest_passing

    plant = PLANTS.create("random_lipschitz_v1")
    d = DESIGNS.create("thm1_sep").design(plant, plant.bounds)
    know = Knowledge.trusting(plant)
    loop = checks.closed_loop(plant, d.K, d.F)
    spec = lyapunov.Spec("structured", plant.n, know.channels.q, True, ("osl", "qib", "lip"), True)
    data = lyapunov.level_data(spec, plant.A, plant.B, plant.C, d.K, d.F, know)
    lv = lyapunov.Level(spec, data)
    assert lv.solve(0.0)[0] == "verified"
    guided = lv.search(lv.reach_grid(0.0, loop.linearised_rate), loop.linearised_rate, seen=(0.0, lv.margin(0.0)),
                       above_lo=False)
    lmi.clear_program_cache()  # a fresh program: no solve answered from the first one's memory
    ref = lyapunov.Level(spec, data)
    plain = largest_passing(lambda x: ref.solve(x)[0] == "verified", rtol=0.01, hi=loop.linearised_rate, factor=4.0)
    assert abs(math.log(guided / plain["lo"])) <= math.log(1.01) * 1.01
    cert = certify(plant, d.K, d.F, know, loop=loop)
    assert cert.levels["full"].decay_rate == cert.levels["paper"].decay_rate
    assert cert.levels["full"].n_solves == 1
    thm1 = DESIGNS.create("thm1").design(plant, plant.bounds)
    cert = certify(plant, thm1.K, thm1.F, know)
    st = cert.levels["structured"]
    from bench.witness import rate_ceiling

    ceil, _ = rate_ceiling(plant, thm1.K, thm1.F, know, channels=True, scalars=("osl", "qib", "lip"))
    assert st.decay_rate < ceil <= st.decay_rate * 1.01**2 and st.n_solves == 2
