"""Separated solves: same feasibility as the joint LMI, a verified joint certificate.

"Joint feasible iff both sides are" is tested in both directions on plants whose side
infeasibility is proven here in closed form, and every separated gain pair is checked against
the joint matrix of docs/paper.md rebuilt in the test (tests/conftest.py), not against the code's
own rebuild.

Closed forms used (A = diag(-sigma, 1), gamma = 0, beta_eff = beta):

- x-side of Theorem 1, ``[[S11 + kappa I, Q], [Q, -(kappa/beta) I]] < 0`` (a principal block of
  the joint 6n matrix): at a left eigenvector w of A with ``w'B = 0`` (an uncontrollable mode at
  -sigma), ``w'(S11 + kappa I + (beta/kappa) Q^2) w >= -2 sigma q + kappa + beta q^2 / kappa >=
  2 (sqrt(beta) - sigma) q`` with ``q = w'Qw > 0``: not strictly feasible when ``sigma <= sqrt(beta)``
  (Corollary 1: the same with alpha for sqrt(beta)).
- e-side, ``[[S22, R - eps3 I], [*, -2 eps4 I]] < 0``: at a right eigenvector v of A with
  ``Cv = 0`` (an unobservable mode at -sigma), with ``r = v'Rv``, the Schur complement gives
  ``-2 sigma r + 2 eps3 rho + 2 sqrt(beta) |r - eps3| < 0``, whose minimum over eps3 >= 0 is
  ``2 r (min(rho, sqrt(beta)) - sigma)``: not strictly feasible when ``sigma <= min(rho, sqrt(beta))``.
"""

import re

import numpy as np
import pytest

from bench.certify import certify
from bench.registry import DESIGNS, PLANTS
from designs import DesignError
from plants import Constants, Plant
from tests.conftest import gains_satisfy_joint_lmi, hurwitz

# f = 0.5 tanh(x): slopes in (0, 0.5], so alpha = 0.5, rho = 0.5, (beta, gamma) = (0.25, 0)
TANH = Constants(alpha=0.5, rho=0.5, beta=0.25, gamma=0.0)
I2, E2 = np.eye(2), np.array([[0.0], [1.0]])


def two_state(sigma, B, C):
    """A = diag(-sigma, 1): one unstable mode, and a stable one at -sigma that B or C may miss."""
    return Plant(id="two_state", A=np.diag([-sigma, 1.0]), B=B, C=C, f=lambda x: 0.5 * np.tanh(np.asarray(x)),
                 x0=[0.3, -0.2], x_hat0=[0.0, 0.0], bounds=TANH)


def uncontrollable_left_vector(A, B):
    lam, W = np.linalg.eig(A.T)
    k = int(np.argmin(np.abs(W.T @ B).sum(axis=1)))
    assert np.allclose(W[:, k] @ B, 0)
    return lam[k].real


def unobservable_right_vector(A, C):
    lam, V = np.linalg.eig(A)
    k = int(np.argmin(np.abs(C @ V).sum(axis=0)))
    assert np.allclose(C @ V[:, k], 0)
    return lam[k].real


@pytest.mark.parametrize("did, kind", [("thm1_sep", "thm1"), ("cor1_sep", "cor1")])
def test_separated_feasible_certified_on_flexible_link(flex, flex_constants, flex_knowledge, did, kind):
    r = DESIGNS.create(did).design(flex, flex_constants.used)
    assert r.status == "feasible", r.reason
    assert r.margin < 0 and r.lmi_size == 24
    assert r.params["raw_joint_margin"] < 0
    assert hurwitz(flex.A + flex.B @ r.F) and hurwitz(flex.A - r.K @ flex.C)
    # the joint matrix of docs/paper.md, rebuilt here, holds for these gains
    assert gains_satisfy_joint_lmi(kind, flex, r.K, r.F, flex_constants.used)
    assert not gains_satisfy_joint_lmi(kind, flex, r.K, -r.F, flex_constants.used)  # the check can fail
    assert certify(flex, r.K, r.F, flex_knowledge, rates=False).certified


# -- both sides feasible => joint feasible ------------------------------------------------------------
@pytest.mark.parametrize("sigma, B", [(0.3, I2), (0.7, E2)])
@pytest.mark.parametrize("kind", ["thm1", "cor1"])
def test_both_sides_feasible_so_joint_feasible(sigma, B, kind):
    p = two_state(sigma, B, I2)
    if B is E2:  # the uncontrollable mode decays faster than sqrt(beta) = alpha = 0.5: the x-side bound allows it
        assert uncontrollable_left_vector(p.A, p.B) == -sigma and sigma > 0.5
    sep = DESIGNS.create(f"{kind}_sep").design(p, TANH)
    joint = DESIGNS.create(kind).design(p, TANH)
    assert sep.status == "feasible", sep.reason
    assert sep.params["x_margin"] < 0 and sep.params["e_margin"] < 0
    assert joint.status == "feasible", joint.reason
    for r in (sep, joint):
        assert gains_satisfy_joint_lmi(kind, p, r.K, r.F, TANH)


# -- a side infeasible => joint infeasible --------------------------------------------------------------
@pytest.mark.parametrize("kind", ["thm1", "cor1"])
@pytest.mark.parametrize("side, B, C", [("x-side", E2, I2), ("e-side", I2, E2.T)])
def test_a_side_infeasible_so_joint_infeasible(kind, side, B, C):
    p = two_state(0.3, B, C)
    # the closed forms of the module docstring: the mode at -0.3 is missed by B (or C) and 0.3 <= 0.5
    if side == "x-side":
        assert uncontrollable_left_vector(p.A, p.B) == -0.3
    else:
        assert unobservable_right_vector(p.A, p.C) == -0.3
    other = "e-side" if side == "x-side" else "x-side"
    sep = DESIGNS.create(f"{kind}_sep").design(p, TANH)
    joint = DESIGNS.create(kind).design(p, TANH)
    for r in (sep, joint):
        assert r.status in ("infeasible", "marginal"), r.reason  # never feasible, never an error
        assert r.K is None and r.F is None
    assert re.search(rf"the {side} (is|are) (not strictly feasible|within the verification tolerance)", sep.reason)
    assert other not in sep.reason.split("(max eig")[0]
    assert sep.params[f"{other[0]}_margin"] < 0  # the other side alone is strictly feasible
    if joint.status == "infeasible":
        assert "under the normalisation" in joint.reason and joint.margin > 0


@pytest.mark.parametrize("side, B, C", [("x-side", E2, I2), ("e-side", I2, E2.T)])
def test_provably_infeasible_side_is_labelled_infeasible(side, B, C):
    p = two_state(0.3, B, C)
    assert DESIGNS.create("thm1_sep").design(p, TANH).status == "infeasible"
    assert DESIGNS.create("thm1").design(p, TANH).status == "infeasible"


def test_side_on_the_boundary_is_marginal():
    """sigma = sqrt(beta) = 0.5: the x-side's bound 2 (sqrt(beta) - sigma) q is 0, the best margin is 0."""
    p = two_state(0.5, E2, I2)
    for did in ("thm1_sep", "thm1"):
        r = DESIGNS.create(did).design(p, TANH)
        assert r.status == "marginal" and "within the verification tolerance of zero" in r.reason, r.reason
        assert r.K is None


@pytest.mark.parametrize("c, expect", [(0.1, "feasible"), (3.0, "not feasible")])
def test_separated_and_joint_agree_on_random_plants(c, expect):
    p = PLANTS.create("random_lipschitz_v1", n=6, m=2, p=2, c=c, seed=6)
    cst = p.bounds
    joint = DESIGNS.create("thm1").design(p, cst)
    sep = DESIGNS.create("thm1_sep").design(p, cst)
    if expect == "feasible":
        assert joint.status == sep.status == "feasible", (joint.reason, sep.reason)
        assert gains_satisfy_joint_lmi("thm1", p, sep.K, sep.F, cst)
        assert gains_satisfy_joint_lmi("thm1", p, joint.K, joint.F, cst)
    else:
        assert joint.status == "infeasible" and joint.margin > 0, joint.reason
        assert sep.status in ("infeasible", "marginal") and sep.K is None, sep.reason


def test_separated_infeasible_when_a_side_is(flex, flex_constants):
    from dataclasses import replace

    # an enormous nonlinearity: Lipschitz 1e3 on a plant whose A is O(50); the joint design fails clearly
    big = replace(flex_constants.used, rho=1e3, beta=1e6, alpha=1e3)
    joint = DESIGNS.create("thm1").design(flex, big)
    assert joint.status == "infeasible" and joint.margin > 0 and "under the normalisation" in joint.reason
    r = DESIGNS.create("thm1_sep").design(flex, big)
    assert r.status in ("infeasible", "marginal") and r.K is None and r.F is None
    assert "feasible iff both sides are" in r.reason


@pytest.mark.parametrize("kw, name", [(dict(method="both"), "method"), (dict(solver="MOSEK"), "solver")])
def test_bad_method_or_solver_named(kw, name):
    with pytest.raises(DesignError, match=f"^{name}:"):
        DESIGNS.create("thm1", **kw)
