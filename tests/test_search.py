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
