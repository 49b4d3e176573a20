"""Workers start by fork, forkserver or spawn with the same results (issue 35): the default per platform, the
registries a fresh worker rebuilds (plugins, objects given to bench.run), and the tasks that stay in the parent."""

import csv
import os
import subprocess
import sys
import threading
import warnings
from pathlib import Path

import numpy as np
import pytest

from bench.errors import ExecutorError
from bench.executors import default_start_method, executor, use_start_method, worker_setup
from bench.pipeline import COST_COLUMNS
from bench.registry import DESIGNS, PLANTS
from tests import _worker_helpers
from tests._plugin_helpers import clean_registries  # noqa: F401 - autouse: registries restored after each test

ROOT = Path(__file__).resolve().parents[1]
TIMING = set(COST_COLUMNS)
LINUX = sys.platform.startswith("linux")


def _cli(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "bench", *args], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=900)


def _rows(path: Path) -> list[dict]:
    with open(path, newline="", encoding="utf-8") as fh:
        return [{k: v for k, v in r.items() if k not in TIMING} for r in csv.DictReader(fh)]


def test_a_spawned_run_gives_the_serial_results(tmp_path):
    """`--jobs 2 --start-method spawn` and `--jobs 1` write the same results.csv: statuses, verdicts and every
    number but the timings (spawned workers rebuild plants and designs by id in fresh interpreters)."""
    pairs = ["--plant", "flexible_link", "--design", "thm1_printed", "--design", "paper_gains", "--design", "lqr+lqe"]
    common = [*pairs, "--no-cache", "--no-figures", "-q"]
    spawned = _cli(["run", *common, "--jobs", "2", "--start-method", "spawn", "--out", "spawned"], tmp_path)
    serial = _cli(["run", *common, "--jobs", "1", "--out", "serial"], tmp_path)
    assert spawned.returncode == 0, spawned.stderr
    assert serial.returncode == 0, serial.stderr
    a, b = _rows(tmp_path / "spawned" / "results.csv"), _rows(tmp_path / "serial" / "results.csv")
    assert [r["design"] for r in a] == ["thm1_printed", "paper_gains", "lqr+lqe"]
    assert {r["status"] for r in a} >= {"given", "computed", "infeasible"}  # not a table of errors
    assert a == b


@pytest.mark.skipif(not LINUX, reason="the fork default is for Linux (spawn elsewhere)")
def test_default_is_fork_alone_and_forkserver_beside_a_thread():
    """A process running one thread forks its workers; one running another thread (a notebook kernel, a solver's
    pool) starts them from a fork server instead (forking a multi-threaded process may deadlock)."""
    release = threading.Event()
    helper = threading.Thread(target=release.wait, daemon=True)
    helper.start()
    try:
        assert default_start_method() == "forkserver"
    finally:
        release.set()
        helper.join()
    alone = len(os.listdir("/proc/self/task")) == 1  # this test session may run other threads (a solver's pool)
    assert (default_start_method() == "fork") == alone


def test_start_method_checked():
    with pytest.raises(ExecutorError, match="start_method: expected one of fork, forkserver, spawn"):
        with executor(2, start_method="thread"):
            pass
    with pytest.raises(ExecutorError, match="start_method"):
        with use_start_method("posix_spawn"):
            pass


def test_cli_refuses_an_unknown_start_method(capsys):
    from bench.cli import main

    assert main(["run", "--start-method", "thread", "--plant", "flexible_link"]) == 2
    assert "--start-method" in capsys.readouterr().err


@pytest.mark.parametrize("method", ["spawn", "forkserver"])
def test_fresh_workers_rebuild_the_registries(method, tmp_path):
    """A plugin file and a registered Design object reach a fresh worker; a factory that cannot be pickled (a
    lambda) is not sent: its tasks run in this process, with a warning naming it, and give the same answer."""
    from designs.paper_gains import PaperGains

    plugin = tmp_path / "fresh_plugin.py"
    plugin.write_text(
        "import numpy as np\n"
        "from bench.registry import register_plant\n"
        "from plants import Plant\n"
        "@register_plant('fresh_plant')\n"
        "def make():\n"
        "    '''Three states.'''\n"
        "    return Plant(id='fresh_plant', A=-np.eye(3), B=np.ones((3, 1)), C=np.eye(1, 3), f=np.zeros_like,\n"
        "                 x0=np.ones(3), x_hat0=np.zeros(3))\n", encoding="utf-8")
    from bench.plugins import load_plugin

    load_plugin(plugin)
    obj = PaperGains()
    factory = lambda obj=obj: obj  # noqa: E731 - a closure: not picklable
    factory._bench_object = obj  # as bench.api registers an object: sent pickled
    DESIGNS.register("paper_gains_object", factory, "an object", order=200)
    PLANTS.register("lambda_plant", lambda: PLANTS.create("pendulum_v1"), "a lambda", order=200)
    setup = worker_setup()
    assert setup.local == {"lambda_plant"}
    assert str(plugin.resolve()) in setup.plugins
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        with executor(2, start_method=method) as ex:
            ids = ex.submit(_worker_helpers.design_ids).result()
            fresh = ex.submit(_worker_helpers.pid_and_size, "fresh_plant").result()
            here = ex.submit(_worker_helpers.pid_and_size, "lambda_plant").result()
    assert "paper_gains_object" in ids and "thm1" in ids
    assert fresh[0] != os.getpid() and fresh[1] == 3  # built in a worker from the plugin file
    assert here == (os.getpid(), 2)  # the pendulum, built here
    assert any("lambda_plant" in str(w.message) and "this process" in str(w.message) for w in seen)


def test_bench_run_objects_under_spawn_match_fork(tmp_path):
    """bench.run with Design objects (one the registered design, one with a changed hyperparameter: an overlay entry,
    sent pickled) and a Plant object (whose f is a closure) under spawn: same table as in-process; only the plant's
    pairs stay in the parent, with a warning naming it; and the call runs again."""
    code = f"""
import dataclasses, pickle, warnings, bench
from bench.registry import DESIGNS, PLANTS
from designs.paper_gains import PaperGains
if __name__ == "__main__":
    mine = dataclasses.replace(PLANTS.create("flexible_link"), id="my_flex")
    lqr = DESIGNS.create("lqr+lqe")
    heavier = dataclasses.replace(lqr, feedback=dataclasses.replace(lqr.feedback, R=4.0))
    kw = dict(plants=[mine, "flexible_link"], designs=[PaperGains(), heavier], progress=False)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        spawned = bench.run(jobs=2, start_method="spawn", **kw).table
        again = bench.run(jobs=2, start_method="spawn", **kw).table
    serial = bench.run(jobs=1, **kw).table
    with open({str(tmp_path / "out.pkl")!r}, "wb") as fh:
        pickle.dump((spawned, again, serial, [str(w.message) for w in seen]), fh)
"""
    script = tmp_path / "objects.py"
    script.write_text(code, encoding="utf-8")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr
    import pickle

    spawned, again, serial, messages = pickle.loads((tmp_path / "out.pkl").read_bytes())
    cols = [c for c in serial.columns if c not in TIMING]
    assert list(spawned["plant"]) == ["my_flex", "my_flex", "flexible_link", "flexible_link"]
    assert list(spawned["design"]) == ["paper_gains", "lqr+lqe[feedback.R=4.0]"] * 2
    assert set(spawned["status"]) == {"given", "computed"}
    for table in (spawned, again):
        for c in cols:
            x, y = table[c].to_numpy(), serial[c].to_numpy()
            if x.dtype.kind == "f":
                np.testing.assert_array_equal(x, y, err_msg=c)
            else:
                assert list(x) == list(y), c
    stayed = [m for m in messages if "this process" in m]
    assert stayed and all("my_flex" in m and "lqr+lqe[" not in m for m in stayed)  # the design object was sent


_ORPHANS = r'''
import time
from bench.executors import executor
with executor(2, start_method="forkserver") as ex:
    futs = [ex.submit(time.sleep, 120) for _ in range(2)]
    time.sleep(2)
    print(" ".join(str(p) for p in ex._processes), flush=True)
    time.sleep(120)
'''


@pytest.mark.skipif(not LINUX, reason="/proc")
def test_forkserver_workers_die_with_a_killed_parent():
    """A forkserver's worker is not its parent's child: it watches the parent itself, and leaves once the parent is
    killed, even before anyone reaps it (a zombie still answers signal 0)."""
    import signal
    import time

    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-c", _ORPHANS], stdout=subprocess.PIPE, text=True, env=env,
                            start_new_session=True)
    try:
        pids = [int(x) for x in proc.stdout.readline().split()]
        assert len(pids) == 2
        os.kill(proc.pid, signal.SIGKILL)  # not reaped until proc.wait() below
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and any(os.path.exists(f"/proc/{p}") for p in pids):
            time.sleep(0.2)
        assert not [p for p in pids if os.path.exists(f"/proc/{p}")]
    finally:
        proc.kill()
        proc.wait()
        try:  # the fork server and anything left of the group
            os.killpg(proc.pid, signal.SIGKILL)
        except OSError:
            pass
