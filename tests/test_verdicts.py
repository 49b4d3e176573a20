"""The pure judgements of :mod:`bench.verdicts`: the horizon rule, the certified horizon, the scope
of a certificate, and the convergence note.

Each expectation is derived here by hand from the rule's definition (a pair has converged when it
has decayed by 1000, ``||z(t)|| <= sqrt(cond P) e^{-lam t} ||z(0)||``; a sublevel set of
``V = z' P z`` with ``z = (x, x - x_hat)``), never copied from the code's output.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench import verdicts

LN1000 = math.log(1000.0)  # the convergence threshold: decayed by a factor 1000


def _horizon(t_plant=20.0, *, fixed=None, cap_factor=10.0, cert_rate=math.nan, cond_p=1.0, linear_rate=math.nan):
    return verdicts.simulation_horizon(t_plant, fixed=fixed, cap_factor=cap_factor, cert_rate=cert_rate, cond_p=cond_p,
                            linear_rate=linear_rate)


# -- the horizon rule ----------------------------------------------------------------------------
def test_a_fixed_horizon_is_used_as_it_is():
    assert _horizon(fixed=7.0, cert_rate=0.01, linear_rate=0.1) == (7.0, "fixed")


def test_the_certified_rate_sets_the_horizon_with_its_transient():
    # (ln 1000 + ln(100) / 2) / 0.1 = (6.9078 + 2.3026) / 0.1 = 92.10 s, rounded up to whole seconds
    assert _horizon(cert_rate=0.1, cond_p=100.0) == (93.0, "certified rate")


def test_the_certified_rate_wins_over_the_linearised_one():
    # certified: ln 1000 / 0.1 = 69.08 -> 70 s; the linearised rate alone would ask 2 ln 1000 / 0.01 = 1382 s
    assert _horizon(cert_rate=0.1, linear_rate=0.01) == (70.0, "certified rate")


def test_an_uncertified_pair_gets_twice_its_linearised_need():
    # 2 ln 1000 / 0.1 = 138.16 -> 139 s (margin 2: no bound on the transient)
    assert _horizon(linear_rate=0.1) == (139.0, "linearised rate")
    assert _horizon(cert_rate=0.0, linear_rate=0.1) == (139.0, "linearised rate")  # a zero rate certifies no decay


def test_a_short_need_gives_the_plants_horizon():
    assert _horizon(cert_rate=2.0) == (20.0, "plant")  # ln 1000 / 2 = 3.45 s < 20 s
    assert _horizon(linear_rate=-1.0) == (20.0, "plant")  # unstable linearisation: no need
    assert _horizon() == (20.0, "plant")


def test_a_long_need_is_cut_at_the_cap():
    T, rule = _horizon(cert_rate=1e-3, cap_factor=10.0)  # ln 1000 / 1e-3 = 6908 s > 10 x 20 s
    assert T == 200.0
    assert rule.startswith("cut at cap") and "certified rate" in rule and "6.91e+03" in rule
    T, rule = _horizon(linear_rate=1e-3, cap_factor=3.0)  # 13 816 s > 3 x 20 s
    assert T == 60.0 and "linearised rate" in rule
    assert _horizon(cert_rate=LN1000 / 300.0)[0] == 200.0  # 300 s, just above the cap of 200 s
    assert _horizon(cert_rate=LN1000 / 199.5) == (200.0, "certified rate")  # 199.5 s, rounded up to the cap


# -- the certified horizon -------------------------------------------------------------------------
@pytest.mark.parametrize("rate, cond", [(0.5, 1.0), (0.5, math.e**2), (2.0, 1e6), (0.03, 40.0)])
def test_the_certified_horizon_is_when_the_bound_reaches_one_thousandth(rate, cond):
    T = verdicts.certified_horizon(rate, cond)
    assert math.sqrt(cond) * math.exp(-rate * T) == pytest.approx(1e-3, rel=1e-12)


def test_the_certified_horizon_closed_form():
    assert verdicts.certified_horizon(0.5, math.e**2) == pytest.approx(2 * LN1000 + 2.0, rel=1e-14)


def test_a_condition_number_below_one_or_unknown_counts_as_one():
    for cond in (0.5, math.nan, math.inf):
        assert verdicts.certified_horizon(0.25, cond) == pytest.approx(4 * LN1000, rel=1e-14)


@pytest.mark.parametrize("rate", [0.0, -1.0, math.nan])
def test_no_positive_rate_no_certified_horizon(rate):
    assert math.isnan(verdicts.certified_horizon(rate, 10.0))


# -- the scope of a certificate --------------------------------------------------------------------
def test_no_certificate_no_scope():
    out = verdicts.certificate_scope(None, 1.0, np.array([1.0]), np.array([0.0]))
    assert out["cert_scope"] == "" and all(math.isnan(out[k]) for k in ("cert_radius", "level_set", "level_x0"))


def test_a_global_certificate_and_its_value_at_the_initial_condition():
    # z0 = (x0, x0 - x_hat0) = (1, 0.5); V = 2 + 2 * 1 * 0.5 + 3 * 0.25 = 3.75 (with e = x_hat - x: 1.75)
    P = np.array([[2.0, 1.0], [1.0, 3.0]])
    out = verdicts.certificate_scope(P, None, np.array([1.0]), np.array([0.5]))
    assert out["cert_scope"] == "global"
    assert out["level_x0"] == pytest.approx(3.75, rel=1e-14)
    assert math.isnan(out["cert_radius"])


@pytest.mark.parametrize("x0, x_hat0, scope", [(1.0, 1.0, "from x0"), (1.5, 1.5, "local"), (1.0, -0.4, "local")])
def test_a_local_certificate_proves_convergence_from_x0_only_inside_its_level_set(x0, x_hat0, scope):
    # P = I, n = 1: on z'z <= v the largest |x| = |z1| is sqrt(v), the largest |x_hat| = |z1 - z2| is
    # sqrt(2 v); both <= r = 2 for v <= r^2 / 2 = 2. V(z0) = x0^2 + (x0 - x_hat0)^2: 1, 2.25, 1.96 + 1 = 2.96
    out = verdicts.certificate_scope(np.eye(2), 2.0, np.array([x0]), np.array([x_hat0]))
    assert out["level_set"] == pytest.approx(2.0, rel=1e-12)
    assert out["cert_radius"] == 2.0
    assert out["cert_scope"] == scope


def test_a_region_given_by_H_scales_the_level_set():
    # |2 x|, |2 x_hat| <= 2 with P = I: the rows (2, 0) and (2, -2) give a' a = 4 and 8, v = r^2 / 8 = 0.5
    out = verdicts.certificate_scope(np.eye(2), 2.0, np.array([0.5]), np.array([0.5]), H=np.array([[2.0]]))
    assert out["level_set"] == pytest.approx(0.5, rel=1e-12)
    assert out["cert_scope"] == "from x0"  # V(z0) = 0.25
    out = verdicts.certificate_scope(np.eye(2), 2.0, np.array([0.8]), np.array([0.8]), H=np.array([[2.0]]))
    assert out["cert_scope"] == "local"  # V(z0) = 0.64 > 0.5


# -- the convergence note --------------------------------------------------------------------------
def _rec(**kw):
    rec = dict(converged=False, sim_status="ok", certified=False, cert_scope="", cert_horizon_s=math.nan,
               in_region=None, horizon_rule="plant", horizon_s=20.0, tail_rate=math.nan, sim_witness="t = 3 s",
               decay_rate=math.nan)
    rec.update(kw)
    return rec


CERTIFIED = dict(certified=True, cert_scope="global", cert_horizon_s=10.0, decay_rate=0.7)


def test_a_converged_pair_has_no_note():
    assert verdicts.convergence_note(_rec(converged=True, **CERTIFIED, sim_status="diverged")) == ""


def test_an_uncertified_divergence_is_reported_not_judged():
    note = verdicts.convergence_note(_rec(sim_status="diverged"))
    assert note == "not converged: the simulation diverged"


@pytest.mark.parametrize("scope", ["global", "from x0"])
def test_a_certified_pair_that_diverges_is_inconsistent(scope):
    note = verdicts.convergence_note(_rec(**{**CERTIFIED, "cert_scope": scope}, sim_status="diverged"))
    assert "INCONSISTENT" in note and "diverged" in note and "t = 3 s" in note


def test_a_local_certificate_is_not_contradicted_by_a_divergence():
    note = verdicts.convergence_note(_rec(**{**CERTIFIED, "cert_scope": "local"}, sim_status="diverged"))
    assert "INCONSISTENT" not in note


def test_a_certified_pair_that_leaves_its_region_is_inconsistent():
    note = verdicts.convergence_note(_rec(**CERTIFIED, in_region=False))
    assert "left the region" in note and "left the certified region" in note and "INCONSISTENT" in note


def test_unconverged_after_the_certified_horizon_is_inconsistent():
    note = verdicts.convergence_note(_rec(**CERTIFIED, horizon_s=10.0))  # T = need: the rate had its time
    assert "INCONSISTENT" in note and "not converged after 10 s" in note


def test_a_horizon_shorter_than_the_certified_need_is_too_short_not_inconsistent():
    note = verdicts.convergence_note(_rec(**CERTIFIED, horizon_s=9.0))
    assert "horizon too short" in note and "INCONSISTENT" not in note and "0.7" in note


def test_a_stopped_simulator_contradicts_nothing():
    note = verdicts.convergence_note(_rec(**CERTIFIED, sim_status="budget", horizon_s=50.0))
    assert note == "not converged: the simulation budget"


@pytest.mark.parametrize("tail, word", [(0.2, "(decaying)"), (-0.2, "(not decaying)"), (0.0, "(not decaying)")])
def test_the_tail_rate_says_whether_the_state_still_decays(tail, word):
    note = verdicts.convergence_note(_rec(tail_rate=tail))
    assert note.endswith(f"tail rate {tail:.3g} /s {word}")


def test_a_cut_horizon_is_named():
    note = verdicts.convergence_note(_rec(horizon_rule="cut at cap (certified rate asks for 500 s)", horizon_s=200.0))
    assert "the horizon was cut at cap (certified rate asks for 500 s) at 200 s" in note


def test_no_reason_known_says_within_the_horizon():
    assert verdicts.convergence_note(_rec()) == "not converged within the horizon"
