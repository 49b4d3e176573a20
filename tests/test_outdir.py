"""Report folders are written whole or not at all (bench.outdir):

- an I/O error on the last move leaves the previous report byte-identical, and says so truly;
- two writers into one folder both succeed (no writer deletes another's temporary folder);
- a writer killed in the middle of the swap is rolled back by the next writer;
- ``check_out_dir`` refuses an empty path, a file and an unwritable folder.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pandas as pd
import pytest

from bench import outdir
from bench import report as report_mod
from bench.cli import main
from bench.harness import RunOptions, run
from bench.outdir import OutDirError, check_out_dir, locked, publish, staged
from bench.report import write_report
from bench.studies._common import write_study

ROOT = Path(__file__).resolve().parents[1]
FAST = RunOptions(n_samples=500)


def _snapshot(folder: Path) -> dict[str, bytes]:
    """Every file's bytes (but the lock file, present only while a writer holds it)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != outdir.LOCK_NAME}


def _leftovers(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if p.name.startswith(".tmp-") or p.name == outdir.JOURNAL_NAME]


def _fail_first_move_of(monkeypatch, name: str) -> list[str]:
    """os.replace fails (OSError) the first time it moves ``name`` out of a temporary folder."""
    real = os.replace
    failed: list[str] = []

    def replace(src, dst, *a, **k):
        s = Path(src)
        if not failed and s.name == name and s.parent.name.startswith(".tmp-"):
            failed.append(str(src))
            raise OSError(28, "No space left on device (injected)")
        return real(src, dst, *a, **k)

    monkeypatch.setattr(os, "replace", replace)
    return failed


@pytest.fixture(scope="module")
def small_result():
    return run(["flexible_link"], ["paper_gains", "lqr+lqe"], FAST)


# -- an error on the last move --------------------------------------------------------------------
def test_failing_last_move_keeps_the_previous_report_byte_identical(tmp_path, monkeypatch, capsys):
    out = tmp_path / "rep"
    base = ["run", "-q", "-j", "1", "--no-cache", "--plant", "flexible_link", "--out", str(out)]
    assert main([*base, "--design", "paper_gains"]) == 0
    before = _snapshot(out)
    assert "figures/flexible_link__paper_gains.png" in before
    failed = _fail_first_move_of(monkeypatch, "REPORT.md")
    # a different selection: every file (and the set of figures) would change
    rc = main([*base, "--design", "lqr+lqe"])
    err = capsys.readouterr().err
    assert failed, "the injected failure never happened"
    assert rc == 1 and "No space left on device (injected)" in err and "unchanged" in err
    assert _snapshot(out) == before  # REPORT.md, results.csv, gains.json, run.json and every figure
    assert not _leftovers(tmp_path)


def test_write_report_propagates_the_error_and_restores_everything(tmp_path, monkeypatch, small_result):
    write_report(small_result, tmp_path, {"command": "first"}, figures=True)
    (tmp_path / "figures" / "flexible_link__gone_design.png").write_bytes(b"stale figure of the main report")
    before = _snapshot(tmp_path)
    _fail_first_move_of(monkeypatch, "REPORT.md")
    with pytest.raises(OSError, match="injected"):
        write_report(small_result, tmp_path, {"command": "second"}, figures=False)  # would delete every figure
    assert _snapshot(tmp_path) == before
    assert not _leftovers(tmp_path)


def test_write_study_failing_last_move_keeps_the_previous_files(tmp_path, monkeypatch):
    def draw(text):
        return lambda path: path.write_text(text)

    write_study(tmp_path, "x", "# first\n", {"study_x": pd.DataFrame({"a": [1]})}, {"study_x_p": draw("fig 1")})
    before = _snapshot(tmp_path)
    _fail_first_move_of(monkeypatch, "STUDY_x.md")
    with pytest.raises(OSError, match="injected"):
        write_study(tmp_path, "x", "# second\n", {"study_x": pd.DataFrame({"a": [2]})}, {"study_x_p": draw("fig 2")})
    assert _snapshot(tmp_path) == before
    assert not _leftovers(tmp_path)


def test_ctrl_c_in_the_middle_of_the_swap_restores_everything(tmp_path, monkeypatch):
    out = tmp_path
    for name in ("a.txt", "b.txt"):
        (out / name).write_text(f"old {name}")
    before = _snapshot(out)
    real = os.replace

    def replace(src, dst, *a, **k):
        if Path(src).name == "b.txt" and Path(src).parent.name.startswith(".tmp-w"):
            raise KeyboardInterrupt
        return real(src, dst, *a, **k)

    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(KeyboardInterrupt):
        with staged(out, "w") as st:
            for name in ("a.txt", "b.txt", "c.txt"):
                (st / name).write_text(f"new {name}")
            publish(out, st, ["c.txt", "a.txt", "b.txt"])
    assert _snapshot(out) == before  # c.txt, which had no previous version, is gone again
    assert not _leftovers(out)


# -- two writers ----------------------------------------------------------------------------------
def test_two_report_writers_into_one_folder_both_succeed(tmp_path, monkeypatch, small_result):
    """Writer A renders slowly; writer B starts and finishes meanwhile. B must not delete A's
    temporary folder (it did: A then failed with FileNotFoundError); the later one wins whole."""
    out = tmp_path / "rep"
    write_report(small_result, out, {"command": "first"}, figures=False)
    entered, gate = threading.Event(), threading.Event()
    render = report_mod.render_markdown

    def slow(result, figures, info):
        if info["command"] == "A":
            entered.set()
            assert gate.wait(60)
        return render(result, figures, info)

    monkeypatch.setattr(report_mod, "render_markdown", slow)
    errors: list[BaseException] = []

    def writer_a():
        try:
            write_report(small_result, out, {"command": "A"}, figures=False)
        except BaseException as exc:  # noqa: BLE001 - reported by the assertion below
            errors.append(exc)

    t = threading.Thread(target=writer_a)
    t.start()
    try:
        assert entered.wait(60)
        write_report(small_result, out, {"command": "B"}, figures=False)
        assert json.loads((out / "run.json").read_text())["command"] == "B"
    finally:
        gate.set()
        t.join(60)
    assert not errors, f"writer A failed: {errors[0]!r}"
    assert json.loads((out / "run.json").read_text())["command"] == "A"
    assert not _leftovers(out)


WRITER = r"""
import sys
sys.path.insert(0, sys.argv[1])
from pathlib import Path
from bench.outdir import publish, staged

out, tag = Path(sys.argv[2]), sys.argv[3]
for i in range(int(sys.argv[4])):
    with staged(out, "stress") as st:
        (st / "figures").mkdir()
        (st / "figures" / "p__fig.png").write_text(f"{tag} {i}")
        (st / "data.csv").write_text(f"{tag} {i}")
        (st / "INDEX.md").write_text(f"{tag} {i}")
        publish(out, st, ["figures/p__fig.png", "data.csv", "INDEX.md"], writer="stress")
print("ok")
"""


def test_two_writer_processes_never_mix_and_never_fail(tmp_path):
    procs = [subprocess.Popen([sys.executable, "-c", WRITER, str(ROOT), str(tmp_path), tag, "40"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for tag in ("A", "B")]
    for p in procs:
        stdout, stderr = p.communicate(timeout=120)
        assert p.returncode == 0 and stdout.strip() == "ok", stderr
    texts = {(tmp_path / rel).read_text() for rel in ("figures/p__fig.png", "data.csv", "INDEX.md")}
    assert len(texts) == 1 and texts.pop() in ("A 39", "B 39")  # one writer's whole set
    assert not _leftovers(tmp_path)
    assert not (tmp_path / outdir.LOCK_NAME).exists()  # each holder deletes the lock file before releasing it


COUNTER = r"""
import sys, time
sys.path.insert(0, sys.argv[1])
from pathlib import Path
from bench import outdir

out = Path(sys.argv[2])
for _ in range(int(sys.argv[3])):
    with outdir.locked(out):  # read, wait, write: a second holder at the same time would lose an increment
        n = int((out / "count").read_text())
        time.sleep(0.001)
        (out / "count").write_text(str(n + 1))
print("ok")
"""


def test_the_lock_excludes_while_its_file_comes_and_goes(tmp_path):
    """Three processes increment a counter under :func:`locked`, whose holder deletes the lock file on release:
    no increment is lost (a waiter that locked a deleted file locks the new one), and no lock file stays."""
    (tmp_path / "count").write_text("0")
    procs = [subprocess.Popen([sys.executable, "-c", COUNTER, str(ROOT), str(tmp_path), "60"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(3)]
    for p in procs:
        stdout, stderr = p.communicate(timeout=120)
        assert p.returncode == 0 and stdout.strip() == "ok", stderr
    assert (tmp_path / "count").read_text() == "180"
    assert not (tmp_path / outdir.LOCK_NAME).exists()


def test_a_second_writer_waits_for_the_lock_then_gives_a_clear_error(tmp_path):
    with staged(tmp_path, "w") as st:
        (st / "a.txt").write_text("new")
        with locked(tmp_path):  # another writer in the middle of its swap
            t0 = time.monotonic()
            with pytest.raises(OutDirError, match="another oslbench process") as info:
                publish(tmp_path, st, ["a.txt"], timeout=0.3)
            assert time.monotonic() - t0 >= 0.3
            assert str(tmp_path) in str(info.value)
        assert not (tmp_path / "a.txt").exists()
        # the lock released while it waits: the second writer goes on
        done: list[Path] = []
        with locked(tmp_path):
            t = threading.Thread(target=lambda: done.extend(publish(tmp_path, st, ["a.txt"], timeout=30)))
            t.start()
            time.sleep(0.3)
            assert not done  # still waiting
        t.join(30)
        assert done == [tmp_path / "a.txt"] and (tmp_path / "a.txt").read_text() == "new"


# -- a writer killed in the middle of the swap ---------------------------------------------------
KILLED = r"""
import os, sys
sys.path.insert(0, sys.argv[1])
from pathlib import Path
from bench import outdir

out = Path(sys.argv[2])
real, moved = os.replace, []

def dying(src, dst):
    if any(part.startswith(".tmp-killed") for part in Path(src).parts):  # a new file moving in from the stage
        moved.append(src)
        if len(moved) == 5:  # the manifest, figure, c.txt, a.txt are in; b.txt is next
            os._exit(9)  # killed: no handler, no finally
    return real(src, dst)

os.replace = dying
with outdir.staged(out, "killed") as st:
    (st / "figures").mkdir()
    (st / "figures" / "p__new.png").write_text("new figure")
    for name in ("a.txt", "b.txt", "c.txt"):
        (st / name).write_text("new " + name)
    outdir.publish(out, st, ["figures/p__new.png", "c.txt", "a.txt", "b.txt"], writer="w")
"""


def test_a_writer_killed_mid_swap_is_rolled_back_by_the_next_writer(tmp_path):
    out = tmp_path
    (out / "figures").mkdir()
    (out / "figures" / "p__old.png").write_text("old figure")  # stale: the killed writer deletes it
    digest = hashlib.sha256(b"old figure").hexdigest()  # as the writer's previous publish recorded it
    (out / outdir.MANIFEST_NAME).write_text(json.dumps({"format": 1, "writers": {"w": {"figures/p__old.png": digest}}}))
    for name in ("a.txt", "b.txt"):
        (out / name).write_text("old " + name)
    before = _snapshot(out)
    proc = subprocess.run([sys.executable, "-c", KILLED, str(ROOT), str(out)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 9, proc.stderr
    # killed half-way: new figure and c.txt in, a.txt new, b.txt old, the stale figure moved away
    assert (out / outdir.JOURNAL_NAME).exists()
    assert (out / "a.txt").read_text() == "new a.txt" and (out / "b.txt").read_text() == "old b.txt"
    assert not (out / "figures" / "p__old.png").exists()
    # the next writer (here: of other files) first rolls the half-done swap back
    with staged(out, "next") as st:
        (st / "other.txt").write_text("other")
        publish(out, st, ["other.txt"])
    after = _snapshot(out)
    assert after.pop("other.txt") == b"other"
    assert after == before
    assert not _leftovers(out)  # the killed writer's stage and backup are gone too


def test_temporary_folders_are_removed_only_when_their_owner_is_dead(tmp_path):
    with staged(tmp_path, "probe") as st:
        host = st.name.split(".")[3]
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    try:
        alive_dir = tmp_path / f".tmp-report.{sleeper.pid}.{host}.abc"
        dead_dir = tmp_path / f".tmp-report.{dead.pid}.{host}.def"
        foreign = tmp_path / f".tmp-report.{dead.pid}.0ther0st.ghi"  # another machine: cannot tell
        for d in (alive_dir, dead_dir, foreign):
            d.mkdir()
            (d / "REPORT.md").write_text("half")
        with staged(tmp_path, "w") as st:
            (st / "a.txt").write_text("new")
            publish(tmp_path, st, ["a.txt"])
        assert alive_dir.exists() and foreign.exists() and not dead_dir.exists()
    finally:
        sleeper.kill()
        sleeper.wait()


# -- check_out_dir --------------------------------------------------------------------------------
def test_check_out_dir(tmp_path):
    with pytest.raises(OutDirError, match="^--out: an empty path is not a folder$"):
        check_out_dir("")
    f = tmp_path / "file.txt"
    f.write_text("x")
    with pytest.raises(OutDirError, match="is a file, not a folder") as info:
        check_out_dir(f)
    assert str(f) in str(info.value)
    with pytest.raises(OutDirError, match="cannot create the folder") as info:
        check_out_dir(f / "sub")
    assert str(f / "sub") in str(info.value)
    new = tmp_path / "a" / "b"
    assert check_out_dir(new) == new and new.is_dir() and not list(new.iterdir())
    assert isinstance(OutDirError("x"), ValueError)


def test_check_out_dir_refuses_an_unwritable_folder(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        if os.access(ro, os.W_OK):
            pytest.skip("running as root: chmod does not make a folder unwritable")
        with pytest.raises(OutDirError, match="not writable") as info:
            check_out_dir(ro)
        assert str(ro) in str(info.value)
    finally:
        ro.chmod(0o700)
