"""A parallel run sends each family of plants (same A, B, C, dt) to one worker (bench.executors.AffinePool): it
makes exactly the serial run's SDP solves, with the serial run's results; a stuck task or a dead worker holds no
other task back."""

import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor

import pytest

from bench.executors import AffinePool
from bench.harness import RunOptions, _Run
from tests.test_executors import _same, serial_and_parallel_frames

FAMILY = (["flexible_link", "flexible_link_printed", "pendulum_v1"], ["thm1_sep", "cor1_sep", "lqr+lqe"])


@pytest.fixture(scope="module")
def serial_and_parallel():
    """FAMILY serially and with 2 worker processes, in a fresh interpreter."""
    return serial_and_parallel_frames(*FAMILY)


def test_a_parallel_run_makes_the_serial_runs_solves_and_results(serial_and_parallel):
    ser, par = serial_and_parallel
    assert len(ser) == 9 and ser["sdp_solves"].sum() > 0
    _same(ser, par, exact=True)
    # the two flexible link plants share A, B, C and their scalar constants: lqr+lqe has the same gains on both,
    # and its scalar levels the same programs, which the second plant's pair takes from the memo in one process
    by = ser.set_index(["plant", "design"])["sdp_solves"]
    assert by["flexible_link_printed", "lqr+lqe"] < by["flexible_link", "lqr+lqe"]
    assert par["sdp_solves"].sum() == ser["sdp_solves"].sum()


def test_families_group_plants_by_their_linear_part():
    state = _Run(["flexible_link", "pendulum_v1", "flexible_link_printed", "flexible_link_d10ms_v1"], ["lqr+lqe"],
                 RunOptions(), None, None)
    assert state.family("flexible_link") == state.family("flexible_link_printed") == "flexible_link"
    assert state.family("pendulum_v1") == "pendulum_v1"
    assert state.family("flexible_link_d10ms_v1") == "flexible_link_d10ms_v1"  # its own A, B and dt


def _pid_after(seconds: float) -> int:
    time.sleep(seconds)
    return os.getpid()


def _exit_now() -> int:
    os._exit(3)


def _pool(steal_after: float) -> AffinePool:
    ctx = multiprocessing.get_context("fork")
    return AffinePool([ProcessPoolExecutor(max_workers=1, mp_context=ctx) for _ in range(2)], steal_after=steal_after)


def test_the_tasks_of_a_key_run_in_one_worker_and_keys_spread():
    pool = _pool(steal_after=60.0)
    try:
        a = [pool.submit_to("a", _pid_after, 0.05) for _ in range(4)]
        b = [pool.submit_to("b", _pid_after, 0.05) for _ in range(4)]
        pa, pb = {f.result(timeout=60) for f in a}, {f.result(timeout=60) for f in b}
    finally:
        pool.shutdown(cancel_futures=True)
    assert len(pa) == 1 and len(pb) == 1 and pa != pb


def test_a_stuck_task_lets_the_other_worker_take_what_queues_behind_it():
    pool = _pool(steal_after=0.5)
    try:
        slow = pool.submit_to("a", _pid_after, 8.0)
        pool.submit_to("b", _pid_after, 0.0).result(timeout=60)  # the other worker is up (and owns key b)
        t0 = time.monotonic()
        quick = pool.submit_to("a", _pid_after, 0.0)
        other = quick.result(timeout=60)
        waited = time.monotonic() - t0
        assert other != slow.result(timeout=60)
    finally:
        pool.shutdown(cancel_futures=True)
    assert waited < 6.0  # it did not wait for the slow task (8 s)


def test_the_tasks_of_a_dead_worker_run_elsewhere():
    from concurrent.futures.process import BrokenProcessPool

    pool = _pool(steal_after=60.0)
    try:
        dying = pool.submit_to("a", _exit_now)
        after = [pool.submit_to("a", _pid_after, 0.0) for _ in range(2)]
        with pytest.raises(BrokenProcessPool):
            dying.result(timeout=60)
        pids = {f.result(timeout=60) for f in after}
    finally:
        pool.shutdown(cancel_futures=True)
    assert len(pids) == 1 and os.getpid() not in pids
