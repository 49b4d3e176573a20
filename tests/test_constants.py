import numpy as np

from bench.constants import compute_constants, resolve_constants
from bench.registry import PLANTS


def test_tight_rho_within_one_percent(flex_constants):
    # analytic: <df, dx> = -c (sin a - sin b) d4 <= c |da| |d4| <= (c/2)(da^2 + d4^2), tight as dx -> 0
    tight = 0.333 / 2
    assert abs(flex_constants.sampled.rho - tight) <= 0.01 * tight
    assert flex_constants.used.rho == tight


def test_claimed_rho_flagged_with_a_violating_pair(flex, flex_constants):
    v = flex_constants.violated("rho")
    assert v is not None and v.claimed == 0.1109
    x1, x2 = np.array(v.x1), np.array(v.x2)
    dx, df = x1 - x2, flex.f(x1) - flex.f(x2)
    assert dx @ df / (dx @ dx) > 0.1109  # recomputed here, independently of the sampler
    assert flex_constants.violated("beta") is None  # beta = c^2 is right


def test_sampled_values_never_exceed_the_analytic_bounds(flex_constants):
    s, a = flex_constants.sampled, flex_constants.analytic
    assert s.alpha <= a.alpha * (1 + 1e-9)
    assert s.rho <= a.rho * (1 + 1e-9)
    assert s.beta <= a.beta * (1 + 1e-9)
    # and they come close: the bounds are tight for this f
    assert s.alpha >= 0.99 * a.alpha and s.beta >= 0.99 * a.beta


def test_sampler_is_reproducible():
    p = PLANTS.create("flexible_link_printed")
    r1 = compute_constants(p, seed=3, n_samples=2000)
    r2 = compute_constants(p, seed=3, n_samples=2000)
    assert r1.sampled == r2.sampled


def test_claimed_option(flex_constants):
    c = resolve_constants(flex_constants, use_claimed=True)
    assert c.rho == 0.1109 and c.beta == 0.1109 and c.gamma == 0.0
    assert resolve_constants(flex_constants).rho == 0.333 / 2


def test_report_round_trips_through_json_and_reads_the_former_field_name(flex_constants):
    import json

    from bench.constants import ConstantsReport

    doc = json.loads(json.dumps(flex_constants.to_dict()))
    assert ConstantsReport.from_dict(doc) == flex_constants
    doc["valid"] = doc.pop("used")  # written before the field was renamed
    assert ConstantsReport.from_dict(doc).used == flex_constants.used
