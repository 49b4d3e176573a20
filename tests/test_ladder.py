"""The certificate ladder (bench.certify): each level against an independently derived expectation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.certify import LEVELS, certify, level_set
from bench.constants import Knowledge
from bench.registry import DESIGNS, PLANTS
from plants import Channels, Constants, Plant
from plants.flexible_link import PAPER_F, PAPER_K


def _abscissa(M: np.ndarray) -> float:
    return float(np.linalg.eigvals(M).real.max())


def _linear_link(k: float) -> Plant:
    """The flexible link with its channel made linear: f4 = -k x3 exactly (slopes lo = hi = -k)."""
    base = PLANTS.create("flexible_link")
    G, H = np.eye(4)[:, [3]], np.eye(4)[[2]]
    return Plant(id="linear_link", A=base.A, B=base.B, C=base.C, f=lambda x: G @ (-k * (H @ np.asarray(x))),
                 x0=base.x0, x_hat0=base.x_hat0, channels=Channels(G=G, H=H, phi=lambda z: -k * z, lo=-k, hi=-k))


def test_with_lo_equal_hi_the_structured_level_is_a_lyapunov_test_of_the_linear_loop():
    """f linear: the quadratic certificate's best rate is the linear loop's decay rate (its spectral abscissa)."""
    k = 0.333
    plant = _linear_link(k)
    A = plant.A - k * np.outer(np.eye(4)[3], np.eye(4)[2])  # A + G diag(lo) H, built here from the model
    want = min(-_abscissa(A + plant.B @ PAPER_F), -_abscissa(A - PAPER_K @ plant.C))
    cert = certify(plant, PAPER_K, PAPER_F, Knowledge(channels=plant.channels), levels=("structured",))
    lv = cert.levels["structured"]
    assert lv.certified
    assert 0.96 * want <= lv.decay_rate <= want * (1 + 1e-6)


def test_a_destabilising_linear_channel_is_not_certified():
    k = -20.0  # f4 = +20 x3: the loop with the paper's gains is unstable (checked here)
    plant = _linear_link(k)
    A = plant.A - k * np.outer(np.eye(4)[3], np.eye(4)[2])
    assert max(_abscissa(A + plant.B @ PAPER_F), _abscissa(A - PAPER_K @ plant.C)) > 0
    cert = certify(plant, PAPER_K, PAPER_F, Knowledge(channels=plant.channels), levels=("structured",))
    assert not cert.certified and cert.levels["structured"].status in ("not certified", "marginal")


def _circle_bound(plant, K, F) -> float:
    """c at which c * max(|H (jw - A - BF)^-1 G|, |H (jw - A + KC)^-1 G|) reaches 1 (one channel [-c, c])."""
    G, H = np.eye(4)[:, [3]], np.eye(4)[[2]]
    peak = 0.0
    for M in (plant.A + plant.B @ F, plant.A - K @ plant.C):
        ws = np.linspace(0, 40, 8001)
        peak = max(peak, float(np.abs(H @ np.linalg.solve(1j * ws[:, None, None] * np.eye(4) - M, G)).max()))
    return 1.0 / peak


def test_structured_level_of_fixed_gains_follows_the_circle_criterion():
    """One symmetric channel and fixed K, F: certified iff both sides pass the circle criterion (a cascade)."""
    base = PLANTS.create("flexible_link")
    d = DESIGNS.create("lqr+lqe").design(base, base.bounds)
    c_sg = _circle_bound(base, d.K, d.F)
    for factor, expected in ((0.9, True), (1.1, False)):
        plant = PLANTS.create("flexible_link", c=factor * c_sg)
        cert = certify(plant, d.K, d.F, Knowledge(channels=plant.channels), levels=("structured",), rates=False)
        assert cert.certified is expected, (factor, cert.levels["structured"])


@pytest.mark.parametrize("pid,did", [("flexible_link", "paper_gains"), ("flexible_link", "thm1_sep"),
                                     ("flexible_link", "lqr+lqe"), ("random_lipschitz_v1", "cor1_sep")])
def test_the_ladder_is_monotone(pid, did):
    """Each level's knowledge contains the one below: certified below => certified above, rate no smaller
    (each level's own LMI, without inheriting, to the bisection's tolerance)."""
    plant = PLANTS.create(pid)
    r = DESIGNS.create(did).design(plant, plant.bounds)
    cert = certify(plant, r.K, r.F, Knowledge.trusting(plant), inherit=False)
    rates = [cert.levels[lv].decay_rate if cert.levels[lv].certified else -1.0 for lv in LEVELS]
    for lower, upper in zip(rates, rates[1:]):
        if lower >= 0:
            assert upper >= lower * (1 - 0.06), rates


def test_issue_figures_for_the_flexible_link():
    """The independent prototype's figures (issue 11, docs/structured.md): paper gains 0.09-0.11 under (20) and
    1.1-1.3 structured; every LQR pairing 0.7-0.9 structured and not certified by (20)."""
    plant = PLANTS.create("flexible_link")
    know = Knowledge.trusting(plant)
    cert = certify(plant, PAPER_K, PAPER_F, know)
    assert 0.09 <= cert.levels["paper"].decay_rate <= 0.11
    assert 1.1 <= cert.levels["structured"].decay_rate <= 1.3
    for did in ("lqr+lqe", "lqr+rh_riccati", "lqr+rajamani", "lqr+zhang_osl"):
        r = DESIGNS.create(did).design(plant, plant.bounds)
        c = certify(plant, r.K, r.F, know)
        assert not c.levels["paper"].certified
        assert 0.7 <= c.levels["structured"].decay_rate <= 0.9, did


def test_levels_say_why_they_do_not_apply():
    plant = PLANTS.create("moving_object_v1")  # no channel structure
    r = DESIGNS.create("lqr+lqe").design(plant, plant.bounds)
    cert = certify(plant, r.K, r.F, Knowledge.trusting(plant))
    assert cert.levels["structured"].status == "inapplicable"
    assert "channel" in cert.levels["structured"].reason
    none = certify(plant, r.K, r.F, Knowledge(constants=Constants()))
    assert all(lv.status == "inapplicable" for lv in none.levels.values())
    assert not none.certified


def test_level_set_closed_form():
    """P = I (2n): x = [I 0] z reaches sqrt(v), x_hat = [I -I] z reaches sqrt(2 v): v_max = r^2 / 2."""
    for n, r in ((2, 1.0), (4, 3.0)):
        assert level_set(np.eye(2 * n), r) == pytest.approx(r**2 / 2)
    P = np.diag([4.0, 1.0])  # n = 1: x = z1 with z1^2 <= v / 4; x_hat = z1 - z2, max over the ellipse sqrt(v (1/4 + 1))
    assert level_set(P, 2.0) == pytest.approx(4.0 / 1.25)


def test_a_certificate_rate_never_beats_the_linearisation():
    plant = PLANTS.create("random_lipschitz_v1")
    r = DESIGNS.create("thm1_sep").design(plant, plant.bounds)
    J = plant.jacobian(np.zeros(plant.n))
    bound = min(-_abscissa(plant.A + J + plant.B @ r.F), -_abscissa(plant.A + J - r.K @ plant.C))
    cert = certify(plant, r.K, r.F, Knowledge.trusting(plant))
    assert cert.certified
    for lv in cert.levels.values():
        if lv.certified:
            assert lv.decay_rate <= bound + 1e-9
            assert math.isfinite(lv.margin) and lv.margin < 0
