"""Interrupted runs (Ctrl-C, a killed process) keep the previous report and resume from the on-disk cache;
cache keys follow what a result depends on; the same seed gives the same tables."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bench import report as report_mod
from bench.cache import Cache, default_cache_dir
from bench.cli import main
from bench.harness import RunOptions, run
from bench.pipeline import COST_COLUMNS
from bench.registry import DESIGNS, PLANTS
from designs import Design, DesignResult

ROOT = Path(__file__).resolve().parents[1]
TIMING = list(COST_COLUMNS)
FAST = RunOptions(n_samples=500)


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _no_temporaries(*folders: Path) -> None:
    for folder in folders:
        left = [p for p in folder.rglob("*") if p.name.startswith(".tmp-")]
        assert not left, f"temporary files left behind: {left}"


# -- interrupted runs and the cache --------------------------------------------------------------
@dataclasses.dataclass(frozen=True, kw_only=True)
class _CtrlC(Design):
    """A design during which the user presses Ctrl-C."""

    def design(self, plant, constants):
        raise KeyboardInterrupt


@dataclasses.dataclass(frozen=True, kw_only=True)
class _Quick(Design):
    """A design that finishes at once (the same id as _CtrlC, after the user fixed it)."""

    def design(self, plant, constants):
        return DesignResult(status="infeasible", reason="nothing to design")


def test_ctrl_c_keeps_the_report_and_a_rerun_resumes_from_the_cache(tmp_path, capsys, paper_gains_report):
    out = paper_gains_report(tmp_path)  # a finished run of paper_gains, its cache beside it
    base = ["run", "-j", "1", "--no-figures", "--plant", "flexible_link", "--out", str(out)]
    before = _snapshot(out)
    DESIGNS.register("_ctrl_c", _CtrlC, order=99)  # after lqr+lqe (order 50)
    try:
        rc = main([*base, "--design", "paper_gains", "--design", "lqr+lqe", "--design", "_ctrl_c"])
    finally:
        DESIGNS.unregister("_ctrl_c")
    err = capsys.readouterr().err
    assert rc == 130 and "interrupted" in err and "unchanged" in err and "Traceback" not in err
    assert _snapshot(out) == before  # byte-identical, figures included
    _no_temporaries(tmp_path)
    DESIGNS.register("_ctrl_c", _Quick, order=99)
    try:
        assert main([*base, "--design", "paper_gains", "--design", "lqr+lqe", "--design", "_ctrl_c"]) == 0
    finally:
        DESIGNS.unregister("_ctrl_c")
    info = json.loads((out / "run.json").read_text())
    assert info["cache"]["hits"] == 2 and info["cache"]["misses"] == 1  # paper_gains, lqr+lqe were kept
    assert "2 from the cache" in capsys.readouterr().err
    # a cached pair gives the same row, byte for byte (timings included: they are the cached ones)
    def row(text):
        return next(line for line in text.splitlines() if line.startswith("flexible_link,paper_gains,"))

    assert row((out / "results.csv").read_text()) == row(before["results.csv"].decode())


def test_a_cached_rerun_writes_an_identical_report(tmp_path):
    out = tmp_path / "rep"
    args = ["run", "-q", "-j", "1", "--plant", "flexible_link", "--design", "paper_gains", "--out", str(out)]
    assert main(args) == 0
    first = _snapshot(out)
    assert main(args) == 0
    second = _snapshot(out)
    assert json.loads(second.pop("run.json"))["cache"]["hits"] == 1
    first.pop("run.json")
    for snap in (first, second):  # the folder's record of the files written (run.json's digest among them)
        snap.pop(".oslbench.manifest.json")
    assert second == first  # REPORT.md, results.csv, gains.json and every figure, byte for byte


def test_ctrl_c_while_writing_the_report_leaves_the_old_one(tmp_path, monkeypatch, capsys):
    args = ["run", "-q", "-j", "1", "--plant", "flexible_link", "--design", "paper_gains", "--out", str(tmp_path)]
    assert main(args) == 0
    before = _snapshot(tmp_path / "figures"), (tmp_path / "REPORT.md").read_bytes()

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(report_mod, "render_markdown", interrupted)
    assert main(args) == 130
    assert "while writing the report" in capsys.readouterr().err
    assert (_snapshot(tmp_path / "figures"), (tmp_path / "REPORT.md").read_bytes()) == before
    _no_temporaries(tmp_path)


PLUGIN = '''
import os, pathlib, time
from dataclasses import dataclass
from bench.registry import register_design
from designs import Design, DesignResult


@register_design("zz_stuck", order=1000)
@dataclass(frozen=True, kw_only=True)
class Stuck(Design):
    """Signals that it started, then waits to be interrupted (when OSLBENCH_TEST_STUCK=1)."""

    def design(self, plant, constants):
        if os.environ.get("OSLBENCH_TEST_STUCK") == "1":
            pathlib.Path(os.environ["OSLBENCH_TEST_MARK"]).write_text(str(os.getpid()))
            time.sleep(3600)  # longer than any test: only a signal ends it
        return DesignResult(status="infeasible", reason="nothing to design")
'''

#: Safety nets only: every wait below ends on an event (a file written, a process gone), long before.
_GUARD_S = 600


def _children(pid: int) -> set[int]:
    """Ids of the live (not zombie) processes whose parent is ``pid`` (from /proc)."""
    out = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[1]) == pid and fields[0] != "Z":
            out.add(int(stat.parent.name))
    return out


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


def _start(args, mark: Path, pairs: Path, n_cached: int):
    """Start the CLI in its own session; return once the stuck design runs and ``n_cached`` pairs are cached."""
    env = {**os.environ, "OSLBENCH_TEST_STUCK": "1", "OSLBENCH_TEST_MARK": str(mark)}
    proc = subprocess.Popen([sys.executable, "-m", "bench", *args], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            # a shell's background job ignores SIGINT and its children inherit that: a Python
                            # started so never sees Ctrl-C; the run under test is started as a terminal would
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))

    def whole():  # entries written whole: a ".tmp-*.npz" is a write still under way
        return [p for p in pairs.glob("*.npz") if not p.name.startswith(".tmp-")]

    deadline = time.monotonic() + _GUARD_S
    try:
        while not (mark.exists() and mark.read_text() and len(whole()) >= n_cached):
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, (f"the stuck design never started (mark {mark.exists()}, "
                                                 f"whole entries {len(whole())} of {n_cached})")
            time.sleep(0.05)
    except BaseException:  # a failed wait leaves no run behind (the stuck worker sleeps an hour)
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        raise
    return proc


def _gone_soon(pids: set[int], within: float) -> set[int]:
    """The processes of ``pids`` still alive after ``within`` seconds (killed then, so none is left behind)."""
    deadline = time.monotonic() + within
    while any(_alive(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    left = {p for p in pids if _alive(p)}
    for p in left:
        os.kill(p, signal.SIGKILL)
    return left


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")
def test_sigint_and_sigkill_mid_run(tmp_path, monkeypatch, capsys, paper_gains_report):
    """Real signals to a real process: the report survives, finished pairs survive, no worker outlives its
    parent (SIGKILL included), a re-run resumes."""
    out = paper_gains_report(tmp_path)  # a finished run of paper_gains, its cache beside it
    plugin = tmp_path / "stuck.py"
    plugin.write_text(PLUGIN)
    base = ["run", "--no-figures", "--plant", "flexible_link", "--out", str(out)]
    pairs = default_cache_dir(out) / "pairs"
    before = _snapshot(out)
    stuck = [*base, "--plugin", str(plugin), "--design", "paper_gains", "--design", "lqr+lqe", "--design", "zz_stuck"]

    # Ctrl-C in a terminal: SIGINT to the whole process group, two worker processes busy
    mark = tmp_path / "mark1"
    # the plugin is in every key of its runs: paper_gains and lqr+lqe are cached (again) by now
    proc = _start([*stuck, "-j", "2"], mark, pairs, 3)
    workers = _children(proc.pid)
    assert int(mark.read_text()) in workers
    os.killpg(proc.pid, signal.SIGINT)
    # the stuck worker sleeps an hour: the run ends only if the parent stops its workers
    stdout, stderr = proc.communicate(timeout=_GUARD_S)
    assert proc.returncode == 130, stderr
    assert "interrupted" in stderr and "unchanged" in stderr and "resume" in stderr and "Traceback" not in stderr
    assert not _gone_soon(workers, 10.0)
    assert _snapshot(out) == before
    _no_temporaries(tmp_path)

    # SIGKILL of the parent: no handler runs at all; its workers, one stuck, follow it within seconds
    mark = tmp_path / "mark2"
    proc = _start([*stuck, "-j", "2", "--design", "lqr+rh_riccati"], mark, pairs, 4)
    workers = _children(proc.pid)
    assert int(mark.read_text()) in workers
    proc.kill()
    assert proc.wait(timeout=_GUARD_S) == -signal.SIGKILL  # not communicate: a live worker holds the pipes
    assert not _gone_soon(workers, 5.0), "workers outlived their killed parent"
    proc.communicate(timeout=_GUARD_S)
    assert _snapshot(out) == before
    for entry in (default_cache_dir(out) / "pairs").iterdir():  # every entry whole and readable
        if entry.name.startswith(".tmp-"):  # a write the kill cut short: never read as an entry
            continue
        assert entry.suffix == ".npz"
        with np.load(entry, allow_pickle=False) as z:
            assert "meta" in z.files

    monkeypatch.setenv("OSLBENCH_TEST_STUCK", "0")
    try:
        assert main([*stuck, "-j", "1", "--design", "lqr+rh_riccati"]) == 0
    finally:
        DESIGNS.unregister("zz_stuck")
    info = json.loads((out / "run.json").read_text())
    # paper_gains, lqr+lqe (the interrupted run) and lqr+rh_riccati (the killed run)
    assert info["cache"] == {"dir": str(default_cache_dir(out)), "hits": 3, "misses": 1}
    assert pd.read_csv(out / "results.csv").set_index("design").loc["zz_stuck", "status"] == "infeasible"


def test_cache_keys_follow_content(tmp_path, monkeypatch):
    cache = Cache(tmp_path)
    flex = PLANTS.create("flexible_link")
    thm1 = DESIGNS.create("thm1")
    key = cache.pair_key(flex, "flexible_link", thm1, "thm1", FAST)
    assert key == Cache(tmp_path).pair_key(PLANTS.create("flexible_link"), "flexible_link", DESIGNS.create("thm1"),
                                           "thm1", FAST)
    assert key == cache.pair_key(flex, "flexible_link", thm1, "thm1", dataclasses.replace(FAST, timeout=5.0))
    changed = [
        cache.pair_key(PLANTS.create("flexible_link", c=0.3), "flexible_link", thm1, "thm1", FAST),
        cache.pair_key(flex, "flexible_link", DESIGNS.create("thm1", cap=100.0), "thm1", FAST),
        cache.pair_key(flex, "flexible_link", thm1, "thm1", dataclasses.replace(FAST, seed=1)),
        cache.pair_key(flex, "flexible_link", thm1, "thm1", dataclasses.replace(FAST, noise=0.01)),
        cache.pair_key(flex, "flexible_link", DESIGNS.create("lqr+lqe", estimator_params={"RN": 2.0}), "lqr+lqe",
                       FAST),
        cache.pair_key(flex, "flexible_link", DESIGNS.create("lqr+lqe"), "lqr+lqe", FAST),
    ]
    assert len({key, *changed}) == len(changed) + 1
    # a closure value that is in no field (here c, seen only by f) still changes the key
    plain = dataclasses.replace(flex, jacobian=None)  # (a Jacobian must match f: none on either side)
    hidden = dataclasses.replace(plain, f=PLANTS.create("flexible_link", c=0.5).f,
                                 channels=PLANTS.create("flexible_link", c=0.5).channels)
    assert cache.pair_key(hidden, "flexible_link", thm1, "thm1", FAST) != \
        cache.pair_key(plain, "flexible_link", thm1, "thm1", FAST)
    # package versions and the source of the modules are part of the key
    from bench import report

    monkeypatch.setattr(report, "package_versions", lambda: {"numpy": "0.0"})
    assert Cache(tmp_path).pair_key(flex, "flexible_link", thm1, "thm1", FAST) != key
    monkeypatch.undo()
    # the options that change results: every field but the wall-clock limits
    for opt in (dict(horizon_cap=5.0), dict(certificate="none"), dict(simulate=False), dict(use_claimed=True)):
        assert cache.pair_key(flex, "flexible_link", thm1, "thm1", dataclasses.replace(FAST, **opt)) != key, opt


def test_a_damaged_or_unwritable_cache_costs_a_recomputation_only(tmp_path):
    cache = Cache(tmp_path / "c")
    res = run(["flexible_link"], ["paper_gains"], FAST, cache=cache)
    assert res.cache_misses == 1 and cache.stored == 2  # the pair and the constants
    for p in (tmp_path / "c").rglob("*.*"):
        p.write_bytes(b"garbage")
    again = Cache(tmp_path / "c")
    res2 = run(["flexible_link"], ["paper_gains"], FAST, cache=again)
    assert res2.cache_hits == 0 and again.errors and res2.frame()["converged"].all()
    blocked = tmp_path / "file"
    blocked.write_text("not a folder")
    broken = Cache(blocked / "cache")
    res3 = run(["flexible_link"], ["paper_gains"], FAST, cache=broken)
    assert res3.frame()["converged"].all() and broken.errors and broken.stored == 0


# -- reproducibility ----------------------------------------------------------------------------
def test_same_seed_same_tables_and_run_json_records_the_run(tmp_path):
    sel = ["--plant", "flexible_link", "--plant", "pendulum_v1", "--design", "paper_gains", "--design", "cor1_sep",
           "--design", "lqr+lqe"]
    for name in ("a", "b"):
        assert main(["run", "-q", "-j", "1", "--no-cache", "--no-figures", "--seed", "3", *sel,
                     "--out", str(tmp_path / name)]) == 0
    a = pd.read_csv(tmp_path / "a" / "results.csv")
    b = pd.read_csv(tmp_path / "b" / "results.csv")
    assert len(a) == 6 and a["converged"].sum() >= 3
    pd.testing.assert_frame_equal(a.drop(columns=TIMING), b.drop(columns=TIMING))
    assert (tmp_path / "a" / "gains.json").read_bytes() == (tmp_path / "b" / "gains.json").read_bytes()
    info = json.loads((tmp_path / "a" / "run.json").read_text())
    assert info["command"].startswith("python -m bench run") and "--seed 3" in info["command"]
    assert info["seed"] == 3 and info["plants"] == ["flexible_link", "pendulum_v1"]
    assert sorted(info["designs"]) == ["cor1_sep", "lqr+lqe", "paper_gains"]
    for key in ("versions", "timeout", "noise", "t_final_override", "n_samples_constants", "use_claimed_constants",
                "sim", "git_commit", "git_dirty", "cache", "jobs", "platform", "executable"):
        assert key in info
    assert "scs" in info["versions"] and info["sim"]["max_nfev"] > 0
    assert info["git_commit"] is None or re.fullmatch(r"[0-9a-f]{40}", info["git_commit"])
    assert info["cache"]["dir"] is None  # --no-cache
