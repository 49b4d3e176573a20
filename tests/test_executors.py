"""Executors (issue 6): identical results whatever runs the pairs; failures become rows."""

import os
import pickle
import signal
import subprocess
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from bench.certify import LEVELS
from bench.cli import main
from bench.executors import ExecutorError, executor
from bench.harness import COLUMNS, RunOptions, run
from bench.pipeline import COST_COLUMNS
from bench.registry import DESIGNS
from designs import Design

ROOT = Path(__file__).resolve().parents[1]
TIMING = set(COST_COLUMNS)
SMALL = (["flexible_link"], ["thm1_printed", "paper_gains", "lqr+lqe"])
OPTS = RunOptions(n_samples=500, t_final=5.0)
#: the certificate's rate bisection stops within this relative tolerance (certify's rate_rtol)
RATE_RTOL = 0.03
#: Numbers that come out of an SDP solve (design LMI or certificate ladder). A compiled program is
#: reused by later pairs of the same process (bench.lmi.cached_program); every solve starts cold
#: (warm_start=False), so they are bit for bit the same whichever pairs a worker solved before
#: (test_a_certificate_does_not_depend_on_what_the_process_solved_before); the tolerant branches
#: of _same are for comparisons across machines.
SDP_MARGINS = {"lmi_margin", "cert_margin"}
SDP_RATES = {"decay_rate", *[f"decay_{lv}" for lv in LEVELS]}
SDP_P = {"level_set", "level_x0"}  # V at x0 and the certified level: P is the last verified point


def _same(a, b, *, exact: bool = False):
    """Same rows, statuses, verdicts and numbers; SDP numbers to solver / bisection tolerance
    (``exact``: every non-timing column bit for bit, the executors' documented promise)."""
    cols = [c for c in COLUMNS if c not in TIMING]
    pa, pb = a[cols], b[cols]
    assert list(pa["design"]) == list(pb["design"])
    for c in cols:
        x, y = pa[c].to_numpy(), pb[c].to_numpy()
        if x.dtype.kind == "f" and (exact or c not in SDP_MARGINS | SDP_RATES | SDP_P):
            np.testing.assert_array_equal(x, y, err_msg=c)
        elif x.dtype.kind == "f" and c in SDP_MARGINS:
            np.testing.assert_allclose(x, y, rtol=1e-6, atol=1e-9, err_msg=c)
        elif x.dtype.kind == "f" and c in SDP_RATES:  # each run brackets the same rate within rtol
            np.testing.assert_allclose(x, y, rtol=2 * RATE_RTOL, atol=0, err_msg=c)
        elif x.dtype.kind == "f":
            np.testing.assert_array_equal(np.isnan(x), np.isnan(y), err_msg=c)
        else:
            assert list(x) == list(y), c


def _in_fresh_process(code: str, timeout: float, *, drop_env: tuple[str, ...] = ()):
    """Run ``code`` in a new interpreter (own session, so a hung worker is killed with it; without
    the variables ``drop_env``) and return what it pickled to ``OUT``; None when it did not finish
    within ``timeout`` seconds."""
    import tempfile

    env = {k: v for k, v in os.environ.items() if k not in drop_env}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.pkl"
        proc = subprocess.Popen([sys.executable, "-c", f"OUT = {str(out)!r}\n" + textwrap.dedent(code)], cwd=ROOT,
                                env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True)
        try:
            _, err = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)  # the interpreter and its pool workers
            proc.communicate()
            return None
        assert proc.returncode == 0, err
        return pickle.loads(out.read_bytes())


def serial_and_parallel_frames(plants: list[str], designs: list[str]):
    """``(serial, parallel)`` frames of a run of ``plants`` x ``designs`` in a fresh interpreter: with 2 worker
    processes first, then serially (this pytest process has run many solves already; the case of forking after a
    solve is test_workers_forked_after_a_solve_in_the_parent_finish)."""
    frames = _in_fresh_process(f"""
        import pickle
        from bench.harness import RunOptions, run
        opts = RunOptions(n_samples=500, t_final=5.0)
        par = run({plants!r}, {designs!r}, opts, jobs=2).frame()
        ser = run({plants!r}, {designs!r}, opts, jobs=1).frame()
        with open(OUT, "wb") as fh:
            pickle.dump((ser, par), fh)
    """, timeout=600)
    assert frames is not None, "the run with 2 worker processes did not finish"
    return frames


@pytest.fixture(scope="module")
def serial_and_processes():
    """The SMALL run serially and with 2 worker processes (:func:`serial_and_parallel_frames`)."""
    return serial_and_parallel_frames(*SMALL)


def test_processes_give_identical_results(serial_and_processes):
    ser, par = serial_and_processes
    assert len(ser) == 3 and set(ser["status"]) >= {"given", "computed"}  # the rows are not all errors
    _same(ser, par, exact=True)


def test_a_certificate_does_not_depend_on_what_the_process_solved_before(flex, flex_constants, flex_knowledge):
    """What makes results identical whatever the executor: the same pair gives the same
    certificate, bit for bit, whichever pairs the worker certified before it."""
    from bench import lmi
    from bench.certify import certify

    given = DESIGNS.create("paper_gains").design(flex, flex_constants.used)
    other = DESIGNS.create("lqr+lqe").design(flex, flex_constants.used)
    lmi.clear_program_cache()
    cold = certify(flex, given.K, given.F, flex_knowledge)
    certify(flex, other.K, other.F, flex_knowledge)
    warm = certify(flex, given.K, given.F, flex_knowledge)
    for lv in LEVELS:
        a, b = cold.levels[lv], warm.levels[lv]
        assert (a.status, a.margin, a.decay_rate) == (b.status, b.margin, b.decay_rate), lv


_DEADLOCK = """
    import pickle
    from bench.certify import certify
    from bench.constants import compute_constants
    from bench.executors import executor
    from bench.registry import DESIGNS, PLANTS

    def certified():
        p = PLANTS.create("flexible_link")
        rep = compute_constants(p, seed=0, n_samples=500)
        g = DESIGNS.create("paper_gains").design(p, rep.used)
        return certify(p, g.K, g.F, rep.knowledge(p)).certified

    first = certified()  # the parent solves the certificate's SDPs (Clarabel runs multi-threaded)
    with executor(2, start_method="fork") as ex:  # forked on purpose: the default would be forkserver now
        second = ex.submit(certified).result()
    with open(OUT, "wb") as fh:
        pickle.dump((first, second), fh)
"""


def test_workers_forked_after_a_solve_in_the_parent_finish():
    """A library user (or a test session) that solved an SDP in-process and then runs pairs with
    jobs > 1 and the fork start method: the workers must finish (the task takes ~2 s; 20 s is the hang
    guard). The process runs as a user's would: without a RAYON_NUM_THREADS the test session may set for
    itself."""
    assert _in_fresh_process(_DEADLOCK, timeout=20, drop_env=("RAYON_NUM_THREADS",)) == (True, True)


def _frozen() -> int:
    import gc

    return gc.get_freeze_count()


@pytest.mark.skipif(sys.platform in ("win32", "darwin"), reason="fork is the default start method elsewhere")
def test_forked_workers_inherit_frozen_objects_and_the_parent_unfreezes_after():
    # gc.freeze before forking: a worker's full collections skip what it inherits. The parent's objects must
    # not stay frozen once the pool is gone (cycles created before the run would never be collected)
    import gc

    before = gc.get_freeze_count()
    with executor(2, start_method="fork") as ex:
        in_worker = ex.submit(_frozen).result()
    assert in_worker > 1000  # the imports of every module a worker needs, at least
    assert gc.get_freeze_count() == before


def test_dask_local_cluster_gives_identical_results():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        res = run(*SMALL, OPTS, scheduler=cluster.scheduler_address)
    _same(run(*SMALL, OPTS, jobs=1).frame(), res.frame(), exact=True)


def test_unreachable_scheduler_fails_fast(capsys, tmp_path):
    pytest.importorskip("distributed")
    rc = main(["run", "-q", "--plant", "flexible_link", "--design", "paper_gains", "--out", str(tmp_path),
               "--scheduler", "tcp://127.0.0.1:9"])
    assert rc == 2
    # "fast" without asserting a time: the error says the executor gave up after its connect timeout
    err = capsys.readouterr().err
    assert "scheduler" in err and "within 5 s" in err


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


def test_constants_are_reported_in_the_order_asked_whatever_finishes_first():
    # flexible_link's constants take longer than pendulum_v1's (more refinement): with two workers the
    # pendulum's finish first, and the report (findings, run.json) must not depend on that
    res = run(["flexible_link", "pendulum_v1"], ["paper_gains"], OPTS, jobs=2)
    assert list(res.constants) == ["flexible_link", "pendulum_v1"]
