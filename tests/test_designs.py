"""The corrected and printed Theorem 1 / Corollary 1 on the flexible link.

Expectations come from docs/paper.md and from the tests' own rebuilds (tests/conftest.py): the joint
matrices of the corrected forms written from docs/paper.md, solved and verified with numpy in the test.
"""

import numpy as np
import pytest

from bench.certify import certify
from bench.registry import DESIGNS
from designs import DesignError
from tests.conftest import gains_satisfy_joint_lmi, hurwitz, thm1_synthesis_margin


@pytest.mark.parametrize("did", ["thm1", "cor1"])
def test_corrected_designs_feasible_verified_and_hurwitz(flex, designed, did):
    r = designed[did]
    assert r.status == "feasible", r.reason
    assert r.route == "sdp" and r.margin < 0
    assert all(v > 0 for v in r.min_eig.values())
    assert r.K.shape == (4, 2) and r.F.shape == (1, 4)
    assert hurwitz(flex.A + flex.B @ r.F)
    assert hurwitz(flex.A - r.K @ flex.C)
    assert r.solver == "CLARABEL" and r.solver_status in ("optimal", "optimal_inaccurate")


@pytest.mark.parametrize("did", ["thm1", "cor1"])
def test_corrected_gains_satisfy_math_md_and_the_ladder(flex, flex_constants, flex_knowledge, designed, did):
    r = designed[did]
    # docs/paper.md's joint matrix, rebuilt in the test, is negative definite for these gains
    assert gains_satisfy_joint_lmi(did, flex, r.K, r.F, flex_constants.used)
    cert = certify(flex, r.K, r.F, flex_knowledge, rates=False)
    assert cert.certified and cert.best.margin < 0


def test_thm1_printed_infeasible_on_flexible_link(flex_constants, designed):
    """As printed, S3 holds -zeta I with zeta = 1/(eps2 gamma - eps1); the flexible link has gamma = 0, so
    zeta = -1/eps1 < 0 for every eps1 > 0 and S < 0 is impossible (docs/paper.md): decided without a solve."""
    assert flex_constants.used.gamma == 0.0
    r = designed["thm1_printed"]
    assert r.status == "infeasible" and r.K is None and r.n_solves == 0
    assert "zeta" in r.reason and "gamma = 0" in r.reason


def test_cor1_printed_infeasible_on_flexible_link(designed):
    # docs/paper.md: Corollary 1 + Remarks 2-3 is infeasible as printed on the flexible link
    r = designed["cor1_printed"]
    assert r.status == "infeasible", r.reason
    assert "under the normalisation" in r.reason and r.margin > 0 and r.K is None


def test_cor1_printed_solves_only_its_largest_xi_which_no_other_xi_beats(flex, flex_constants):
    """xi enters W only as -xi I / alpha^2 (and mu1 < min(1, 1/xi) = 1): each xi solved on its own, the best
    slack is at the largest; where that slack proves the LMI infeasible (the flexible link), the grid design makes
    that one solve and reports it."""
    c = flex_constants.used
    alone = {xi: DESIGNS.create("cor1_printed", xis=(xi,)).design(flex, c).params["slack"] for xi in (0.1, 0.5, 0.9)}
    assert alone[0.1] <= alone[0.5] + 1e-7 and alone[0.5] <= alone[0.9] + 1e-7, alone
    grid = DESIGNS.create("cor1_printed", xis=(0.5, 0.9, 0.1)).design(flex, c)
    assert grid.n_solves == 1 and grid.params["xi"] == 0.9
    assert grid.params["slack"] == pytest.approx(max(alone.values()), abs=1e-7)


def test_thm1_feasibility_in_phi1_matches_the_tests_own_solve(flex, flex_constants):
    """docs/paper.md: feasible for phi1 in [1e-4, 0.06], infeasible from 0.07 on. The test's own solve of the
    6n LMI (written from docs/paper.md) agrees with the design at a feasible and an infeasible phi1."""
    c = flex_constants.used
    assert thm1_synthesis_margin(flex, c, 0.01) > 0
    ok = DESIGNS.create("thm1", phi1=0.01).design(flex, c)
    assert ok.status == "feasible" and ok.params["phi1"] == 0.01
    assert thm1_synthesis_margin(flex, c, 1.0) < 0
    r = DESIGNS.create("thm1", phi1=1.0).design(flex, c)
    # not strictly feasible: the best point has a positive max eig; the label is infeasible or, when
    # that margin is within the verification tolerance, marginal, never feasible nor an error
    assert r.status in ("infeasible", "marginal") and "phi1 = 1" in r.reason, r.reason
    assert "under the normalisation" in r.reason and r.margin > 0 and r.K is None


def test_thm1_reports_its_search_scalars(designed, flex_constants):
    p = designed["thm1"].params
    assert 1e-4 <= p["phi1"] <= 0.07
    # docs/paper.md: rho = c/2 for f4 = -c sin(x3), and gamma = 0 is the best QIB pair
    assert p["rho"] == 0.333 / 2 and p["gamma"] == 0.0 and p["beta"] == pytest.approx(0.333**2)


@pytest.mark.parametrize("kw, name", [(dict(phi1=-1.0), "phi1"), (dict(phi1_range=(1.0, 0.1)), "phi1_range"),
                                      (dict(cap=0.0), "cap"), (dict(phi1=float("nan")), "phi1")])
def test_bad_design_parameters_named(kw, name):
    with pytest.raises(DesignError, match=f"^{name}:"):
        DESIGNS.create("thm1", **kw)


def test_cor1_printed_xi_must_be_in_unit_interval():
    with pytest.raises(DesignError, match="^xis:"):
        DESIGNS.create("cor1_printed", xis=(1.5,))


def test_paper_gains_only_for_flexible_link(flex, flex_constants):
    from dataclasses import replace

    d = DESIGNS.create("paper_gains")
    assert d.applicable(flex, flex_constants.used) is None
    other = replace(flex, id="other", family="other")
    assert "flexible link" in d.applicable(other, flex_constants.used)
    r = d.design(flex, flex_constants.used)
    assert r.status == "given" and r.route == "given"
    # docs/paper.md's printed gains (37)-(38)
    np.testing.assert_array_equal(r.F, [[-11.7561, -1.8562, 6.4643, -14.2175]])
    np.testing.assert_array_equal(r.K[0], [1.2907, -24.3525])


@pytest.mark.parametrize("alpha, expected", [(0.5, "feasible"), (2.0, "infeasible")])
def test_lipschitz_observer_lmi_decided_by_its_closed_form(alpha, expected):
    # x' = -x + f(x), nothing measured (C = 0): A - KC = -1 whatever K, and the Rajamani LMI
    # [-2P + eps alpha^2, P; P, -eps] < 0 holds for some P, eps > 0 iff min_eps (eps alpha^2 + P^2/eps) = 2 alpha P
    # < 2P, i.e. iff alpha < 1. Infeasible (alpha = 2) is a proof, not 'marginal'.
    from designs.lmi_observers import RajamaniLMI
    from plants import Constants, Plant

    plant = Plant(id="scalar", A=[[-1.0]], B=[[1.0]], C=[[0.0]], f=lambda x: alpha * np.sin(x),
                  x0=[1.0], x_hat0=[0.0], bounds=Constants(alpha=alpha))
    res = RajamaniLMI().compute(plant, Constants(alpha=alpha))
    assert res.status == expected, res.reason
    if expected == "infeasible":
        assert "I << P" in res.reason and res.K is None
