import numpy as np
import pytest

from bench.certify import certify
from bench.registry import DESIGNS
from designs import DesignError
from tests.conftest import hurwitz


@pytest.mark.parametrize("did", ["thm1", "cor1"])
def test_corrected_designs_feasible_verified_and_hurwitz(flex, designed, did):
    r = designed[did]
    assert r.status == "feasible", r.reason
    assert r.margin < 0
    assert all(v > 0 for v in r.min_eig.values())
    assert r.K.shape == (4, 2) and r.F.shape == (1, 4)
    assert hurwitz(flex.A + flex.B @ r.F)
    assert hurwitz(flex.A - r.K @ flex.C)
    assert r.solver == "CLARABEL" and r.solver_status in ("optimal", "optimal_inaccurate")


@pytest.mark.parametrize("did", ["thm1", "cor1"])
def test_corrected_designs_certified_by_the_independent_analysis_lmi(flex, flex_constants, designed, did):
    r = designed[did]
    cert = certify(flex, r.K, r.F, flex_constants.valid)
    assert cert.certified and cert.margin < 0


def test_thm1_printed_not_feasible_on_flexible_link(designed):
    r = designed["thm1_printed"]
    assert r.status in ("infeasible", "inapplicable")
    assert "zeta" in r.reason and r.K is None


def test_cor1_printed_not_feasible_on_flexible_link(designed):
    r = designed["cor1_printed"]
    assert r.status != "feasible" and r.reason


def test_thm1_fixed_phi_outside_the_feasible_range_is_infeasible(flex, flex_constants):
    # MATH.md: infeasible for phi1 >= 0.07 on this plant; a large phi1 must not be reported feasible
    r = DESIGNS.create("thm1", phi1=5.0).design(flex, flex_constants.valid)
    assert r.status == "infeasible" and "phi1 = 5" in r.reason
    assert r.margin >= 0


def test_thm1_reports_its_search_scalars(designed):
    p = designed["thm1"].params
    assert 1e-4 <= p["phi1"] <= 0.07
    assert p["rho"] == 0.333 / 2 and p["gamma"] == 0.0


@pytest.mark.parametrize("kw, name", [(dict(phi1=-1.0), "phi1"), (dict(phi1_range=(1.0, 0.1)), "phi1_range"),
                                      (dict(cap=0.0), "cap"), (dict(phi1=float("nan")), "phi1")])
def test_bad_design_parameters_named(kw, name):
    with pytest.raises(DesignError, match=name):
        DESIGNS.create("thm1", **kw)


def test_cor1_printed_xi_must_be_in_unit_interval():
    with pytest.raises(DesignError, match="xis"):
        DESIGNS.create("cor1_printed", xis=(1.5,))


def test_paper_gains_only_for_flexible_link(flex, flex_constants):
    from dataclasses import replace

    d = DESIGNS.create("paper_gains")
    assert d.applicable(flex, flex_constants.valid) is None
    other = replace(flex, id="other", family="other")
    assert "flexible link" in d.applicable(other, flex_constants.valid)
