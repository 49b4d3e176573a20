"""Executors (issue 6): identical results whatever runs the pairs; failures become rows."""

import os
import time
from dataclasses import dataclass

import numpy as np
import pytest

from bench.cli import main
from bench.executors import ExecutorError, executor
from bench.harness import COLUMNS, RunOptions, run
from bench.registry import DESIGNS
from designs._core import Design

TIMING = {"compile_s", "solve_s", "design_s", "cert_s", "sim_s"}
SMALL = (["flexible_link"], ["thm1_printed", "paper_gains", "lqr+lqe"])
OPTS = RunOptions(n_samples=500, t_final=5.0)


def _same(a, b):
    cols = [c for c in COLUMNS if c not in TIMING]
    pa, pb = a.frame()[cols], b.frame()[cols]
    assert list(pa["design"]) == list(pb["design"])
    for c in cols:
        x, y = pa[c].to_numpy(), pb[c].to_numpy()
        if x.dtype.kind == "f":
            np.testing.assert_array_equal(x, y, err_msg=c)
        else:
            assert list(x) == list(y), c


def test_processes_give_identical_results():
    _same(run(*SMALL, OPTS, jobs=1), run(*SMALL, OPTS, jobs=2))


def test_dask_local_cluster_gives_identical_results():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        res = run(*SMALL, OPTS, scheduler=cluster.scheduler_address)
    _same(run(*SMALL, OPTS, jobs=1), res)


def test_unreachable_scheduler_fails_fast(capsys, tmp_path):
    pytest.importorskip("distributed")
    t0 = time.perf_counter()
    rc = main(["run", "-q", "--plant", "flexible_link", "--design", "paper_gains", "--out", str(tmp_path),
               "--scheduler", "tcp://127.0.0.1:9"])
    assert rc == 2 and time.perf_counter() - t0 < 30
    assert "scheduler" in capsys.readouterr().err


@pytest.mark.parametrize("jobs", ["0", "-2", "two"])
def test_bad_jobs_exit_2(capsys, tmp_path, jobs):
    assert main(["run", "--jobs", jobs, "--out", str(tmp_path)]) == 2
    assert "jobs" in capsys.readouterr().err


def test_executor_rejects_bad_jobs():
    with pytest.raises(ExecutorError, match="jobs"):
        with executor(0):
            pass


@dataclass(frozen=True, kw_only=True)
class _Die(Design):
    """A design whose worker process dies."""

    def design(self, plant, constants):
        os._exit(3)


def test_a_worker_that_dies_becomes_error_rows_and_the_run_completes():
    DESIGNS.register("_die_test", _Die)
    try:
        res = run(["flexible_link"], ["_die_test", "paper_gains"], OPTS, jobs=2)
    finally:
        DESIGNS.unregister("_die_test")
    df = res.frame().set_index("design")
    assert df.loc["_die_test", "status"] == "error" and "worker" in df.loc["_die_test", "reason"]
    assert len(df) == 2  # every pair has a row


class _Stream:
    def __init__(self, tty):
        self.tty, self.text = tty, ""

    def isatty(self):
        return self.tty

    def write(self, s):
        self.text += s

    def flush(self):
        pass


def test_progress_bar_quiet_off_a_terminal_and_drawn_on_one():
    from bench.harness import ProgressBar

    off = ProgressBar(_Stream(False), min_seconds=0)
    off(1, 2, "a")
    off(2, 2, "b")
    off.close()
    assert off.stream.text == ""
    on = ProgressBar(_Stream(True), min_seconds=0)
    on(1, 2, "flexible_link x thm1")
    on(2, 2, "done")
    on.close()
    assert "1/2" in on.stream.text and "2/2" in on.stream.text and on.stream.text.endswith("\n")
