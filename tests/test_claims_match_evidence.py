"""A record claims no more than its evidence: disproved or sampled constants never certify, an f that
breaks the plant contract is a PlantError naming it, a plant no controller stabilizes is inapplicable,
a margin within the tolerance is marginal, an infeasible reason states the normalisation, the solver
column names the solver of the point, given and computed gains are not "feasible".

Each test builds the situation (a wrong declaration, a broken f, an unstabilizable plant) and checks
the record :func:`bench.pipeline.evaluate_pair` writes for it; where trusting the declaration as it
is can be shown, the test shows it first.
"""

import math
import re
from dataclasses import dataclass

import numpy as np
import pytest

from bench import lmi
from bench.certify import Knowledge, certify
from bench.constants import compute_constants
from bench.pipeline import RunOptions, evaluate_pair
from bench.registry import DESIGNS, PLANTS
from designs import Design, DesignResult
from plants import Constants, Plant, PlantError
from plants.random_families import random_lipschitz_plant
from tests.conftest import jacobian_at_zero

# a double integrator, y = x1; F and K place both loops' eigenvalues at -1 and -2
A2 = np.array([[0.0, 1.0], [0.0, 0.0]])
B2 = np.array([[0.0], [1.0]])
C2 = np.array([[1.0, 0.0]])
F2 = np.array([[-2.0, -3.0]])
K2 = np.array([[3.0], [2.0]])
FAST = RunOptions(n_samples=2000)


@dataclass(frozen=True, kw_only=True)
class FixedGains(Design):
    """Printed gains for the double integrator (like paper_gains: nothing solved)."""

    def design(self, plant, constants):
        return DesignResult(status="given", route="given", reason="fixed gains", K=K2.copy(), F=F2.copy())


def double_integrator(f, **kw):
    return Plant(id=kw.pop("id", "double_integrator"), A=A2, B=B2, C=C2, f=f, x0=[0.5, 0.0], x_hat0=[0.0, 0.0],
                 **kw)


def sine_on_x1(k):
    """f = (0, k sin(x1)): alpha = |k|, rho = |k|/2, beta = k^2 at gamma = 0 (pairs (d, 0) and (d, d) near 0)."""
    return lambda x: np.stack([0 * np.asarray(x, dtype=float)[0], k * np.sin(np.asarray(x, dtype=float)[0])])


def ratios(f, x1, x2):
    dx, df = np.asarray(x1) - np.asarray(x2), f(np.asarray(x1)) - f(np.asarray(x2))
    return {"alpha": math.sqrt(df @ df / (dx @ dx)), "rho": dx @ df / (dx @ dx), "beta": df @ df / (dx @ dx)}


# -- "Disproved bounds still certify" -----------------------------------------------------------------------
def test_disproved_bounds_never_certify(monkeypatch):
    f = sine_on_x1(10.0)
    wrong = Constants(alpha=0.01, rho=0.005, beta=1e-4, gamma=0.0)
    plant = double_integrator(f, id="wrong_bounds", bounds=wrong)
    # the declaration is wrong, computed here: the pair (d, 0), (0, 0) gives alpha -> 10, beta -> 100, and
    # (d, d), (0, 0) gives rho -> 5
    d, z = 1e-3, np.zeros(2)
    assert ratios(f, [d, 0], z)["alpha"] > 9.99 and ratios(f, [d, d], z)["rho"] > 4.99
    # and the loop with the fixed gains is not even locally stable: A + Df(0) + BF has an eigenvalue > 0
    assert np.linalg.eigvals(A2 + jacobian_at_zero(f, 2) + B2 @ F2).real.max() > 0
    # trusting the declaration as it is, the LMI alone certifies this loop (the old behaviour) ...
    import bench.witness
    with monkeypatch.context() as m:
        m.setattr(bench.witness, "equilibrium_witness", lambda *a, **k: None)
        assert certify(plant, K2, F2, Knowledge.trusting(plant), rates=False).certified
    # ... but the true loop has an equilibrium besides the origin, found before any global LMI: its
    # right-hand side, recomputed here with the true f in (x, x_hat), vanishes there
    cert = certify(plant, K2, F2, Knowledge.trusting(plant), rates=False)
    eq = next(w for w in cert.witnesses if w.kind == "equilibrium")
    assert not cert.certified
    x, xh = eq.z[:2], eq.z[:2] - eq.z[2:]
    dx = A2 @ x + B2 @ (F2 @ xh) + f(x)
    dxh = A2 @ xh + B2 @ (F2 @ xh) + f(xh) + K2 @ (C2 @ (x - xh))
    assert np.linalg.norm(eq.z) > 0.1 and np.abs(np.concatenate([dx, dxh])).max() < 1e-8

    rep = compute_constants(plant, seed=0, n_samples=2000)
    assert {v.name for v in rep.disproved} == {"alpha", "rho", "beta"}
    for v in rep.disproved:  # each violating pair is real, recomputed here
        assert ratios(f, v.x1, v.x2)[v.name] > getattr(wrong, v.name)
    know = rep.knowledge(plant)
    assert (know.constants.alpha, know.constants.rho, know.constants.beta) == (None, None, None)
    assert any("not used by certificates" in note for note in know.notes)
    assert not certify(plant, K2, F2, know, rates=False).certified

    for design in (FixedGains(), "lqr+lqe"):
        rec = evaluate_pair(plant, design, rep, FAST).record
        assert rec["status"] in ("given", "computed") and not rec["certified"] and rec["cert_level"] == ""
        assert all(rec[f"cert_{lv}"] == "inapplicable" for lv in ("paper", "full", "structured"))
        assert "DISPROVED" in rec["constants"]
        assert "analytic alpha = 0.01 is violated" in rec["reason"]


def test_sampled_constants_never_certify():
    f = sine_on_x1(0.01)
    plant = double_integrator(f, id="sampled_only")  # no bounds: the constants can only be sampled
    rep = compute_constants(plant, seed=0, n_samples=2000)
    assert set(rep.source.values()) == {"sampled"}
    # the sampled values are close to the truth (0.01, 0.005, 1e-4) and would certify if trusted...
    assert certify(plant, K2, F2, Knowledge(constants=rep.used), rates=False).certified
    # ...but a sample is a lower bound: nothing is trusted
    for design in (FixedGains(), "lqr+lqe"):
        out = evaluate_pair(plant, design, rep, FAST)
        rec = out.record
        assert not rec["certified"] and "sampled" in rec["constants"]
        for lv in out.certificate.levels.values():
            assert lv.status == "inapplicable" and "sampled" in lv.reason, lv


# -- "f that breaks the contract" -----------------------------------------------------------------------------
def _writes(x):
    x = np.asarray(x)
    x *= 0.5  # in place: changes the caller's state
    return np.zeros_like(x)


def _nan_far(x):
    x = np.asarray(x, dtype=float)
    with np.errstate(invalid="ignore"):
        return np.where(np.abs(x) > 20, np.nan, -np.sin(x))


def _complex_far(x):
    # real (0 at 0) while |x_i| <= 5, complex beyond: only the sampler, which goes to ||x|| ~ 30, meets it
    return np.emath.sqrt(25 - np.asarray(x, dtype=float) ** 2) - 5


@pytest.mark.parametrize("f, pattern", [
    (_writes, r"^f: writes into its (batch )?argument"),
    (lambda x: -np.linalg.norm(x) ** 2 * np.asarray(x), r"^f: the batch form mixes columns: column \d"),
    (lambda x: -np.asarray(x, dtype=float).T, r"^f: f\(batch\) must have shape \(2, 3\), got \(3, 2\)"),
    (_nan_far, r"^f: not finite at"),
    (lambda x: np.asarray(x, dtype=float) * (1 + 0j), r"(?i)^f: .*complex"),
    (_complex_far, r"(?i)^f: .*complex"),
], ids=["writes_argument", "mixes_columns", "transposes_a_batch", "nan_far_away", "complex", "complex_far_away"])
def test_f_breaking_the_contract_is_a_plant_error(f, pattern):
    with pytest.raises(PlantError, match=pattern) as info:
        plant = double_integrator(f, id="broken")
        compute_constants(plant, seed=0, n_samples=2000)
    msg = str(info.value)
    if "not finite at" in msg:  # the message names a state, and f is indeed not finite there
        x = np.array([float(v) for v in re.search(r"x = \[([^\]]+)\]", msg).group(1).split(",")])
        assert np.abs(x).max() > 20 and not np.all(np.isfinite(_nan_far(x)))


def test_f_transposing_a_square_batch_is_a_plant_error():
    """With n = 3 the first (3, 3) batch keeps its shape when transposed; the contract's batch of
    probe points must catch it (hypothesis found this one: a ValueError from numpy escaped)."""
    from plants import Plant

    with pytest.raises(PlantError, match=r"^f: a batch of shape \(3, \d+\) gave shape \(\d+, 3\)"):
        Plant(id="transposes", A=np.zeros((3, 3)), B=np.zeros((3, 1)), C=np.zeros((1, 3)), x0=np.zeros(3),
              x_hat0=np.zeros(3), t_final=20.0, f=lambda x: np.asarray(x).T)


def test_complex_value_error_names_the_state():
    with pytest.raises(PlantError, match=r"complex.*x = \["):
        compute_constants(double_integrator(_complex_far, id="broken"), seed=0, n_samples=2000)


# -- "Pre-checks" ---------------------------------------------------------------------------------------------
def _zero(x):
    return np.zeros_like(np.asarray(x, dtype=float))


@pytest.mark.parametrize("A, B, C, pattern", [
    # B = 0 and A with eigenvalues 1 +- 1j: nothing reaches the unstable modes
    ([[1.0, -1.0], [1.0, 1.0]], [[0.0], [0.0]], [[1.0, 0.0]],
     r"\(A, B\) is not stabilizable: eigenvalue 1 \+- 1j of A is uncontrollable"),
    # the unstable mode 2 (x1) is invisible in y = x2
    ([[2.0, 0.0], [0.0, -1.0]], [[1.0], [1.0]], [[0.0, 1.0]],
     r"\(A, C\) is not detectable: eigenvalue 2 of A is unobservable"),
], ids=["B_zero", "unobservable"])
def test_no_controller_for_an_unstabilizable_plant(A, B, C, pattern):
    A, B, C = np.array(A), np.array(B), np.array(C)
    # PBH, here: an eigenvalue with Re >= 0 where [lam I - A, B] (or [lam I - A; C]) loses rank
    lam = np.linalg.eigvals(A)
    bad = [l for l in lam if l.real >= 0 and (np.linalg.matrix_rank(np.hstack([l * np.eye(2) - A, B])) < 2
                                              or np.linalg.matrix_rank(np.vstack([l * np.eye(2) - A, C])) < 2)]
    assert bad
    plant = Plant(id="unstabilizable", A=A, B=B, C=C, f=_zero, x0=[1.0, 0.0], x_hat0=[0.0, 0.0])
    rep = compute_constants(plant, seed=0, n_samples=500)
    assert len(rep.prechecks) == 1 and re.search(pattern, rep.prechecks[0])
    gains = FixedGains()  # even given gains: the pre-check comes first
    for design in ("thm1", "thm1_sep", "cor1", "lqr+lqe", "lqr+rh_riccati", gains):
        rec = evaluate_pair(plant, design, rep, FAST).record
        assert rec["status"] == "inapplicable" and re.search(pattern, rec["reason"]), (design, rec["reason"])
        assert not rec["feasible"] and not rec["certified"] and not rec["converged"] and rec["sim_status"] == ""


def _cubic(x):
    x = np.asarray(x, dtype=float)
    return np.stack([0 * x[0], -x[0] ** 3])


def test_global_cubic_without_bounds_is_not_lipschitz():
    # computed here: along (a + h, a) the Lipschitz ratio is ((a + h)^3 - a^3) / h ~ 3 a^2, unbounded in a
    for a in (1.0, 10.0, 100.0):
        assert ratios(_cubic, [a + 1e-6, 0], [a, 0])["alpha"] == pytest.approx(3 * a**2, rel=1e-4)
    plant = Plant(id="cubic", A=[[0.0, 1.0], [-1.0, -1.0]], B=B2, C=C2, f=_cubic, x0=[0.5, 0.0], x_hat0=[0.0, 0.0])
    rep = compute_constants(plant, seed=0, n_samples=2000)
    assert "alpha" in rep.unbounded and rep.source["alpha"] == "unbounded" and rep.used.alpha is None
    assert re.search(r"not globally Lipschitz .*declare bounds with a radius", rep.unbounded["alpha"])
    rec = evaluate_pair(plant, "cor1", rep, FAST).record
    assert rec["status"] == "inapplicable"
    assert re.search(r"needs the constant\(s\) alpha.*not globally Lipschitz .*declare bounds with a radius",
                     rec["reason"]), rec["reason"]
    # declared on a ball (alpha = 3 r^2 on ||x|| <= r, the sup of 3 x1^2 there), nothing is unbounded
    local = Plant(id="cubic_local", A=[[0.0, 1.0], [-1.0, -1.0]], B=B2, C=C2, f=_cubic, x0=[0.5, 0.0],
                  x_hat0=[0.0, 0.0], bounds=Constants(alpha=3.0, radius=1.0))
    rep_local = compute_constants(local, seed=0, n_samples=2000)
    assert rep_local.unbounded == {} and rep_local.disproved == [] and rep_local.used.alpha == 3.0


def test_pairing_needing_alpha_explains_the_unbounded_constant():
    plant = Plant(id="cubic", A=[[0.0, 1.0], [-1.0, -1.0]], B=B2, C=C2, f=_cubic, x0=[0.5, 0.0], x_hat0=[0.0, 0.0])
    rep = compute_constants(plant, seed=0, n_samples=2000)
    rec = evaluate_pair(plant, "lqr+rh_riccati", rep, FAST).record
    assert rec["status"] == "inapplicable" and "not globally Lipschitz" in rec["reason"]


# -- "Labels" -------------------------------------------------------------------------------------------------
def test_classify_a_margin_within_the_tolerance_is_marginal():
    for top, want in ((1e-12, "marginal"), (-1e-12, "marginal"), (0.0, "marginal"), (-1e-3, "verified"),
                      (1e-3, "violated")):
        M = np.diag([-1.0, top])
        margin = float(np.linalg.eigvalsh(M)[-1])
        assert margin == top
        assert lmi.classify(margin, M) == want, (top, want)
    assert lmi.classify(float("nan"), np.eye(2)) == "violated"
    # the tolerance is relative to the matrix's entries: -1e-3 is no evidence on a matrix of size 1e6
    big = np.diag([-1e6, -1e-3])
    assert lmi.classify(float(np.linalg.eigvalsh(big)[-1]), big) == "marginal"


def test_design_on_the_boundary_is_a_marginal_row():
    """A = diag(-0.5, 1), B = e2, f = 0.5 tanh(x) (beta = 0.25, gamma = 0): the uncontrollable mode decays at
    exactly sqrt(beta), where Theorem 1's x-side has best margin 0 (tests/test_separated.py derives it)."""
    plant = Plant(id="boundary", A=np.diag([-0.5, 1.0]), B=[[0.0], [1.0]], C=np.eye(2),
                  f=lambda x: 0.5 * np.tanh(np.asarray(x, dtype=float)), x0=[0.3, -0.2], x_hat0=[0.0, 0.0],
                  bounds=Constants(alpha=0.5, rho=0.5, beta=0.25, gamma=0.0))
    rep = compute_constants(plant, seed=0, n_samples=2000)
    assert rep.prechecks == [] and rep.disproved == []
    rec = evaluate_pair(plant, "thm1_sep", rep, FAST).record
    assert rec["status"] == "marginal" and "within the verification tolerance of zero" in rec["reason"], rec["reason"]
    assert not rec["feasible"] and not rec["certified"] and rec["sim_status"] == ""


def test_infeasible_reason_states_the_normalisation():
    plant = PLANTS.create("moving_object_v1")
    rep = compute_constants(plant, seed=0, n_samples=2000)
    rec = evaluate_pair(plant, "cor1", rep, RunOptions(n_samples=2000, simulate=False)).record
    assert rec["status"] == "infeasible" and not rec["feasible"]
    # the joint LMI's normalisation, or (decided by a side before the Young weight search) the side's
    assert re.search(r"infeasible.* under the normalisation (Q, R << 1000 I|I << Q << 1000 I)", rec["reason"]), \
        rec["reason"]


@pytest.mark.parametrize("solver", ["SCS", "CLARABEL"])
def test_solver_column_names_the_solver_of_the_point(solver):
    plant = random_lipschitz_plant(n=8, c=0.1)
    rep = compute_constants(plant, seed=0, n_samples=2000)
    opts = RunOptions(n_samples=2000, simulate=False, certificate="none")
    rec = evaluate_pair(plant, DESIGNS.create("thm1_sep", solver=solver), rep, opts, design_id="thm1_sep").record
    assert rec["status"] == "feasible", rec["reason"]
    assert rec["solver"] == solver
    assert rec["solver_status"] == f"x {solver}:optimal; e {solver}:optimal"


def test_given_and_computed_gains_are_not_feasible(flex, flex_constants):
    opts = RunOptions(simulate=False)
    paper = evaluate_pair(flex, "paper_gains", flex_constants, opts).record
    assert paper["status"] == "given" and paper["feasible"] is False and paper["route"] == "given"
    assert paper["certified"]  # certified by the ladder, not "feasible": nothing was solved
    lq = evaluate_pair(flex, "lqr+lqe", flex_constants, opts).record
    assert lq["status"] == "computed" and lq["feasible"] is False and lq["route"] == "formula"
    thm = evaluate_pair(flex, "thm1", flex_constants, opts).record
    assert thm["status"] == "feasible" and thm["feasible"] is True and thm["route"] == "sdp"
