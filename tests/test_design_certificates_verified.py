"""A certificate a design hands over is used only once the suite's own numerics verify it at its level
(bench.certify.adopt / verify_certificate): P positive definite, the rate at most the linearised loop's
and the class's ceiling, the level's matrix inequality at that P and rate. The expectations are
derived here: the linearised rate from central differences of f, the ladder's own rate from a run of
the same gains without a certificate."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from bench import checks
from bench.certify import certify, verify_certificate
from bench.pipeline import RunOptions, evaluate_pair
from bench.registry import DESIGNS, PLANTS
from designs import Design, DesignResult
from tests.conftest import linearised_rate

OPTS = RunOptions(n_samples=2000, simulate=False)


@dataclass(frozen=True, kw_only=True)
class _OwnCertificate(Design):
    """LQR/LQE gains with a certificate of the design's own making: ``sign * I`` at ``rate``."""

    sign: float = 1.0
    rate: float = 2.5
    multipliers: dict | None = None

    def applicable(self, plant, constants):
        return None

    def design(self, plant, constants):
        base = DESIGNS.create("lqr+lqe").design(plant, constants)
        cert = {"level": "structured", "P": self.sign * np.eye(2 * plant.n), "decay_rate": self.rate,
                "margin": -1.0, "radius": None, "how": "the plugin's own certificate"}
        if self.multipliers is not None:
            cert["multipliers"] = self.multipliers
        return DesignResult(status="computed", K=base.K, F=base.F, certificate=cert)


@dataclass(frozen=True, kw_only=True)
class _Handing(Design):
    """The structured design's gains with a certificate built by the test (``edit(certificate, plant)``)."""

    edit: object = None

    def applicable(self, plant, constants):
        return None

    def design(self, plant, constants):
        res = DESIGNS.create("structured").design(plant, constants)
        return DesignResult(status="computed", K=res.K, F=res.F, certificate=self.edit(dict(res.certificate), plant))


@pytest.fixture(scope="module")
def flex_setup(catalog_constants):
    plant = PLANTS.create("flexible_link")
    rep = catalog_constants("flexible_link", n_samples=2000)
    plain = evaluate_pair(plant, "lqr+lqe", rep, OPTS).record  # the same gains, no certificate of their own
    return plant, rep, plain


def test_a_rate_above_the_linearised_loop_is_refused_and_the_ladder_stands(flex_setup):
    plant, rep, plain = flex_setup
    out = evaluate_pair(plant, _OwnCertificate(), rep, OPTS)
    rec = out.record
    top = linearised_rate(plant, out.loop.K, out.loop.F)
    assert top < 2.5  # no certificate of these gains can prove 2.5
    assert rec["certified"] and rec["decay_rate"] == plain["decay_rate"] <= top
    assert "the design's certificate is refused" in rec["reason"] and "linearised" in rec["reason"]


def test_a_negative_p_with_an_infinite_rate_never_certifies(flex_setup):
    plant, rep, plain = flex_setup
    rec = evaluate_pair(plant, _OwnCertificate(sign=-1.0, rate=math.inf), rep, OPTS).record
    assert rec["decay_rate"] == plain["decay_rate"] and math.isfinite(rec["decay_rate"])
    assert "refused" in rec["reason"]
    own = evaluate_pair(plant, _OwnCertificate(sign=-1.0, rate=math.inf), rep, RunOptions(
        n_samples=2000, simulate=False, certificate="own")).record  # no ladder: nothing else certifies
    assert not own["certified"] and math.isnan(own["decay_rate"]) and "refused" in own["reason"]
    neg = evaluate_pair(plant, _OwnCertificate(sign=-1.0, rate=0.1), rep, RunOptions(
        n_samples=2000, simulate=False, certificate="own")).record
    assert not neg["certified"] and "P is not positive definite" in neg["reason"]


def test_the_ladders_own_certificate_handed_over_is_verified_and_zero_multipliers_are_not(flex_setup):
    plant, rep, _ = flex_setup
    res = DESIGNS.create("lqr+lqe").design(plant, rep.used)
    lv = certify(plant, res.K, res.F, rep.knowledge(plant), levels=("structured",)).levels["structured"]
    assert lv.certified
    loop = checks.closed_loop(plant, res.K, res.F)
    cand = {"level": "structured", "P": lv.P, "decay_rate": lv.decay_rate, "how": "test"}
    ok, why = verify_certificate(cand, plant, loop, rep.knowledge(plant))  # multipliers found by the suite
    assert ok is not None and ok.decay_rate == lv.decay_rate and ok.margin < 0, why
    # with every multiplier 0 the channel blocks are 0: the matrix cannot be negative definite
    zero = {"ch_x": np.zeros(1), "ch_e": np.zeros(1)}
    bad, why = verify_certificate({**cand, "multipliers": zero}, plant, loop, rep.knowledge(plant))
    assert bad is None and "LMI" in why
    unknown, why = verify_certificate({**cand, "multipliers": {"tau": 1.0}}, plant, loop, rep.knowledge(plant))
    assert unknown is None and "multipliers" in why


def test_the_structured_designs_joint_certificate_is_checked_not_trusted(catalog_constants):
    plant = PLANTS.create("pendulum_v1")
    rep = catalog_constants("pendulum_v1", n_samples=2000)
    own = RunOptions(n_samples=2000, simulate=False, certificate="own")
    honest = evaluate_pair(plant, _Handing(edit=lambda c, p: c), rep, own).record
    res = DESIGNS.create("structured").design(plant, rep.used)
    assert honest["certified"] and honest["decay_rate"] == res.certificate["decay_rate"]
    # the same joint multipliers at a rate well above the largest this certificate proves (its generalised
    # eigenvalue bound, params["rate_bound"]) but below the linearised loop's: the joint matrix fails there
    loop = checks.closed_loop(plant, res.K, res.F)
    lam = min(1.5 * res.params["rate_bound"], 0.99 * linearised_rate(plant, loop.K, loop.F))
    assert lam > res.params["rate_bound"]
    bad = evaluate_pair(plant, _Handing(edit=lambda c, p: {**c, "decay_rate": lam}), rep, own).record
    assert not bad["certified"] and "refused" in bad["reason"]


def test_beyond_the_ladder_a_certificate_without_multipliers_is_unverifiable_and_a_joint_one_is_checked():
    from bench.constants import Knowledge

    plant = PLANTS.create("chain_v1", N=9)  # n = 18 > LADDER_MAX_N
    res = DESIGNS.create("structured").design(plant, plant.bounds)
    assert res.certificate is not None and plant.n > 16
    loop, know = checks.closed_loop(plant, res.K, res.F), Knowledge.trusting(plant)
    ok, why = verify_certificate(res.certificate, plant, loop, know)
    assert ok is not None and ok.decay_rate == res.certificate["decay_rate"], why
    bare = {k: v for k, v in res.certificate.items() if k != "joint"}
    none, why = verify_certificate(bare, plant, loop, know)
    assert none is None and why.startswith("unverifiable")
