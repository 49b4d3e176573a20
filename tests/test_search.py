"""The grid search of bench.search: the answer is a grid point within the tolerance of the threshold,
the same whatever the start, and a last-bit change of the threshold does not move it."""

import math

import pytest

from bench.search import grid_floor, largest_passing


def _count(threshold):
    calls = []

    def passes(x):
        calls.append(x)
        return x <= threshold

    return passes, calls


@pytest.mark.parametrize("threshold", [math.pi, 0.0123, 812.5])
@pytest.mark.parametrize("rtol", [0.01, 0.05])
def test_answer_is_the_grid_point_below_the_threshold_whatever_the_start(threshold, rtol):
    answers = set()
    for kw in ({"start": 1.0}, {"start": 1e3}, {"start": 1e-3}, {"hi": 1e4}, {"lo": 1e-4}):
        passes, calls = _count(threshold)
        out = largest_passing(passes, rtol=rtol, max_moves=40, **kw)
        assert out["kind"] == "bracketed"
        assert out["lo"] <= threshold < out["hi"] <= out["lo"] * (1 + rtol)
        answers.add(out["lo"])
        assert len(calls) == len(set(calls))
    assert len(answers) == 1
    # the grid is (1 + rtol)^k: the answer is the largest such power at or below the threshold
    k = math.floor(math.log(threshold) / math.log1p(rtol))
    assert answers.pop() == pytest.approx((1 + rtol) ** k, rel=1e-9)


def test_last_bit_changes_of_the_threshold_do_not_move_the_answer():
    base = 0.8155
    outs = {largest_passing(_count(base * (1 + d))[0], start=0.5)["lo"] for d in (-1e-13, 0.0, 1e-13)}
    assert len(outs) == 1


def test_out_of_range_and_stop():
    out = largest_passing(lambda x: True, start=1.0, max_moves=3)
    assert out["kind"] == "above_range" and math.isnan(out["hi"]) and out["lo"] == pytest.approx(8.0, rel=0.02)
    out = largest_passing(lambda x: False, start=1.0, max_moves=3)
    assert out["kind"] == "below_range" and math.isnan(out["lo"])
    seen = []
    out = largest_passing(lambda x: seen.append(x) or False, hi=1.0, stop=lambda: len(seen) == 2)
    assert out["kind"] == "below_range" and out["hi"] == pytest.approx(seen[0])  # the invalid probe is not hi
    assert grid_floor(1.0) == 1.0 and grid_floor(1.0101, 0.01) == pytest.approx(1.01)


def test_secant_estimate_is_the_crossing_of_a_linear_margin():
    """For a margin m(lam) = s (lam - r) the secant through any passing and failing probe, or through two failing
    ones, crosses -SECANT_AIM tol at r - SECANT_AIM tol / s (the line itself); with fewer than two probes, None."""
    from bench.search import SECANT_AIM, secant_estimate

    s, r, tol = 4.7, 0.3, 1e-4

    def probe(lam):
        m = s * (lam - r)
        return (m < -tol, m, tol)

    expected = r - SECANT_AIM * tol / s
    assert secant_estimate({0.1: probe(0.1), 0.9: probe(0.9)}) == pytest.approx(expected, rel=1e-12)
    assert secant_estimate({0.5: probe(0.5), 0.8: probe(0.8)}) == pytest.approx(expected, rel=1e-12)
    assert secant_estimate({0.05: probe(0.05), 0.2: probe(0.2)}) == pytest.approx(expected, rel=1e-12)
    assert secant_estimate({0.9: probe(0.9)}) is None and secant_estimate({}) is None


@pytest.mark.parametrize("threshold", [math.pi, 0.0123])
def test_an_aim_only_chooses_the_probes(threshold):
    """A secant aim over a linear margin finds the grid point of plain bisection, in fewer probes; an aim that
    points anywhere (here always at 1) changes the probes but not the answer."""
    from bench.search import secant_estimate

    def run(aim_kind):
        curve, calls = {}, []

        def passes(x):
            calls.append(x)
            m = x - threshold  # failing above the threshold
            curve[x] = (m <= 0, m, 0.0)
            return m <= 0

        aim = {"secant": lambda: secant_estimate(curve), "wrong": lambda: 1.0, None: None}[aim_kind]
        out = largest_passing(passes, rtol=0.01, hi=1e3, factor=4.0, aim=aim)
        return out["lo"], len(calls)

    (plain, n_plain), (aimed, n_aimed), (wrong, _) = run(None), run("secant"), run("wrong")
    assert plain == aimed == wrong and plain <= threshold < plain * 1.01
    assert n_aimed < n_plain


@pytest.mark.parametrize("threshold", [math.pi, 0.0123])
def test_aim_next_probes_the_passing_end_s_next_point_once(threshold):
    """``aim_next``: an aim at the passing end (the threshold within a grid step of it) probes its next grid point
    once. A bent margin whose secant trails the threshold (here a margin flat below it, steep above) ends in fewer
    probes than bisection; an aim stuck below the passing end costs at most that one probe; the answer is the same."""
    from bench.search import secant_estimate

    def run(aim_kind, aim_next):
        curve, calls = {}, []

        def passes(x):
            calls.append(x)
            m = (x - threshold) * (1.0 if x <= threshold else 100.0)
            curve[x] = (m <= 0, m, 0.0)
            return m <= 0

        aim = {"secant": lambda: secant_estimate(curve), "stuck": lambda: 1e-9, None: None}[aim_kind]
        out = largest_passing(passes, rtol=0.01, hi=1e3, factor=4.0, aim=aim, aim_next=aim_next)
        return out["lo"], len(calls)

    plain, n_plain = run(None, False)
    (sec, n_sec), (sec_next, n_next) = run("secant", False), run("secant", True)
    (stuck, n_stuck), (stuck_next, n_stuck_next) = run("stuck", False), run("stuck", True)
    assert plain == sec == sec_next == stuck == stuck_next and plain <= threshold < plain * 1.01
    assert n_next < n_sec
    assert n_stuck_next <= n_stuck + 1


def test_an_aim_below_the_range_does_not_end_the_search():
    """Bracketing down stops below ``down_until``; an aim pointing there must not stop it early."""
    passes, calls = _count(0.5)
    out = largest_passing(passes, rtol=0.01, hi=100.0, factor=4.0, down_until=1e-3, aim=lambda: 1e-9)
    assert out["lo"] <= 0.5 < out["lo"] * 1.01 and min(calls) >= 1e-3
