"""A parallel run takes each family of plants (same A, B, C, dt) as one worker task (bench.harness.BATCH_PLANTS):
it makes exactly the serial run's SDP solves, with the serial run's results; the fixed-eps grid of thm1 is walked
from its middle (designs.thm1._unimodal_walk) and finds the whole grid's best point when the values are unimodal."""

import math

import numpy as np
import pytest

from bench.harness import RunOptions, _Run
from designs.thm1 import _unimodal_walk
from tests.test_executors import _in_fresh_process, _same

FAMILY = (["flexible_link", "flexible_link_printed", "pendulum_v1"], ["thm1_sep", "cor1_sep", "lqr+lqe"])


@pytest.fixture(scope="module")
def serial_and_batched():
    """FAMILY with 2 worker processes, then serially, in a fresh interpreter (as test_executors does)."""
    got = _in_fresh_process(f"""
        import pickle
        from bench.harness import RunOptions, run
        opts = RunOptions(n_samples=500, t_final=5.0)
        par = run({FAMILY[0]!r}, {FAMILY[1]!r}, opts, jobs=2).frame()
        ser = run({FAMILY[0]!r}, {FAMILY[1]!r}, opts, jobs=1).frame()
        with open(OUT, "wb") as fh:
            pickle.dump((ser, par), fh)
    """, timeout=600)
    assert got is not None, "the run with 2 worker processes did not finish"
    return got


def test_a_parallel_run_makes_the_serial_runs_solves_and_results(serial_and_batched):
    ser, par = serial_and_batched
    assert len(ser) == 9 and ser["sdp_solves"].sum() > 0
    _same(ser, par, exact=True)
    # the two flexible link plants share A, B, C and their scalar constants: lqr+lqe has the same gains on both,
    # and its scalar levels the same programs, which the second plant's pair takes from the memo in one process
    by = ser.set_index(["plant", "design"])["sdp_solves"]
    assert by["flexible_link_printed", "lqr+lqe"] < by["flexible_link", "lqr+lqe"]
    assert par["sdp_solves"].sum() == ser["sdp_solves"].sum()


def test_families_group_plants_by_their_linear_part():
    state = _Run(["flexible_link", "pendulum_v1", "flexible_link_printed", "flexible_link_d10ms_v1"], ["lqr+lqe"],
                 RunOptions(), None, None, batched=True)
    assert state._family("flexible_link") == ["flexible_link", "flexible_link_printed"]
    assert state._family("flexible_link_printed") == ["flexible_link", "flexible_link_printed"]
    assert state._family("pendulum_v1") == ["pendulum_v1"]
    assert state._family("flexible_link_d10ms_v1") == ["flexible_link_d10ms_v1"]  # its own A, B and dt


def _walk(values):
    seen = []

    def value(i):
        seen.append(i)
        return values[i]

    _unimodal_walk(value, len(values))
    return seen


@pytest.mark.parametrize("values", [
    [0.1, 0.5, 0.9, 0.3, 0.2],     # peak in the middle
    [0.9, 0.5, 0.4, 0.3, 0.2],     # decreasing: the walk goes down to the first point
    [-3.0, -2.0, -1.0, 0.0, 1.0],  # increasing: up to the last
    [0.1, 0.8, 0.5, 0.2, 0.1],     # peak beside the middle
])
def test_the_walk_visits_the_grids_best_point_of_unimodal_values(values):
    seen = _walk(values)
    assert int(np.argmax(values)) in seen and len(seen) == len(set(seen))


def test_the_walk_stops_where_the_values_fall():
    assert sorted(_walk([0.1, 0.5, 0.9, 0.3, 0.2])) == [1, 2, 3]  # the middle beats both neighbours: 3 searches
    assert _walk([0.2, 0.9, 0.5, 0.3, 0.1]) == [2, 1, 3, 0]  # up to index 1, one past it


def test_the_walk_solves_the_whole_grid_when_the_first_three_have_no_value():
    assert sorted(_walk([0.3, -math.inf, -math.inf, -math.inf, 0.1])) == [0, 1, 2, 3, 4]
