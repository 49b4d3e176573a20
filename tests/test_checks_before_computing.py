"""Ids and output paths are checked before anything is computed:

- a plant or design id that is unsafe in a file name ("a/b") or too long for one is refused where it is
  registered or built, with a message naming the id and the allowed characters or the limit (not after
  the run, on the figure);
- ``--out ""``, a file, a path under a file, or an unwritable folder exits 2 with one line before
  anything is computed (``run`` and ``study``).
"""

from __future__ import annotations

import importlib
import os
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

import bench.harness
from bench.cli import main
from bench.registry import DESIGNS, PLANTS, RegistryError, check_id
from plants import Constants, Plant, PlantError
from tests._plugin_helpers import clean_registries  # noqa: F401 - autouse: registries restored after each test


@pytest.fixture
def no_computing(monkeypatch):
    """Any computing fails the test: the checks must come first."""

    def forbidden(*a, **k):
        raise AssertionError("computing started before the arguments were checked")

    monkeypatch.setattr(bench.harness, "run", forbidden)
    monkeypatch.setattr(importlib.import_module("bench.studies.montecarlo"), "run_montecarlo", forbidden)


def _plant(id_: str) -> Plant:
    return Plant(id=id_, A=[[0.0, 1.0], [-1.0, -0.5]], B=[[0.0], [1.0]], C=[[1.0, 0.0]],
                 f=lambda x: np.stack([0.0 * x[0], -0.5 * np.sin(x[0])]), x0=[1.0, 0.0], x_hat0=[0.0, 0.0],
                 bounds=Constants(alpha=0.5, rho=0.25, beta=0.25, gamma=0.0))


# -- ids ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("bad", ["my/plant", "a\\b", "x y", "a*", "tab\there", "é", "a:b", "..", "-x", ".hidden"])
def test_unsafe_ids_are_refused_by_the_registry_and_by_plant(bad):
    with pytest.raises(RegistryError) as info:
        PLANTS.register(bad, lambda: None)
    msg = str(info.value)
    assert repr(bad) in msg and "'+'" in msg and "digits" in msg
    assert bad not in PLANTS._entries
    with pytest.raises(RegistryError, match="design id"):
        DESIGNS.register(bad, lambda: None)
    with pytest.raises(PlantError) as info:
        _plant(bad)
    assert str(info.value).startswith("id: ") and repr(bad) in str(info.value) and "'+'" in str(info.value)


@pytest.mark.parametrize("good", ["lqr+lqe", "flexible_link", "random_osl_v1_n4_s0", "a.b-c_1", "_private", "0x"])
def test_safe_ids_are_accepted(good):
    assert check_id(good) == good
    assert _plant(good).id == good


def test_an_id_too_long_for_a_file_name_is_refused_naming_the_limit(tmp_path):
    from bench.registry import ID_MAX_CHARS

    longest = "p" * ID_MAX_CHARS
    assert check_id(longest) == longest and _plant(longest).id == longest
    # the longest file name a report writes, <plant>__<design>.png, fits a 255-byte file name
    (tmp_path / f"{longest}__{'d' * ID_MAX_CHARS}.png").write_bytes(b"")
    bad = "p" * 300
    with pytest.raises(RegistryError, match=f"300 characters.*at most {ID_MAX_CHARS} characters"):
        PLANTS.register(bad, lambda: None)
    with pytest.raises(PlantError, match=f"at most {ID_MAX_CHARS} characters"):
        _plant(bad)
    with pytest.raises(RegistryError, match="design id"):
        DESIGNS.register("d" * (ID_MAX_CHARS + 1), lambda: None)


def test_every_registered_id_is_safe():
    for reg in (PLANTS, DESIGNS):
        for i in reg.ids():
            check_id(i, reg.kind)


SLASH_PLUGIN = '''
import numpy as np
from bench.registry import register_plant
from plants import Constants, Plant


@register_plant("my/plant")
def my_plant(*, c: float = 0.5) -> Plant:
    """An id with a slash."""
    return Plant(id="my/plant", A=[[0.0, 1.0], [-1.0, -0.5]], B=[[0.0], [1.0]], C=[[1.0, 0.0]],
                 f=lambda x: np.stack([0.0 * x[0], -c * np.sin(x[0])]), x0=[1.0, 0.0], x_hat0=[0.0, 0.0],
                 bounds=Constants(alpha=c, rho=c / 2, beta=c**2, gamma=0.0))
'''


def test_a_plugin_plant_id_with_a_slash_exits_2_before_computing(tmp_path, capsys, no_computing):
    plugin = tmp_path / "slash.py"
    plugin.write_text(SLASH_PLUGIN)
    out = tmp_path / "rep"
    rc = main(["run", "-q", "-j", "1", "--plugin", str(plugin), "--plant", "my/plant", "--design", "cor1",
               "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "'my/plant'" in err and "'/'" in err and "'+'" in err and str(plugin) in err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert "my/plant" not in PLANTS.ids()


# -- --out ----------------------------------------------------------------------------------------
RUN = ["run", "-q", "-j", "1", "--no-figures", "--plant", "flexible_link", "--design", "paper_gains"]
STUDY = ["study", "montecarlo", "-q", "-j", "1", "--plant", "flexible_link", "--design", "paper_gains", "--n", "4"]


@pytest.mark.parametrize("argv", [RUN, STUDY], ids=["run", "study"])
def test_empty_out_exits_2_and_writes_nothing(argv, tmp_path, monkeypatch, capsys, no_computing):
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    rc = main([*argv, "--out", ""])
    err = capsys.readouterr().err
    assert rc == 2 and "--out: an empty path is not a folder" in err and len(err.strip().splitlines()) == 1
    assert not list(work.iterdir()) and not (tmp_path / ".bench-cache").exists()


@pytest.mark.parametrize("argv", [RUN, STUDY], ids=["run", "study"])
def test_out_that_is_a_file_exits_2(argv, tmp_path, capsys, no_computing):
    f = tmp_path / "report.txt"
    f.write_text("not a folder")
    for target, words in ((f, "is a file, not a folder"), (f / "sub", "cannot create the folder")):
        rc = main([*argv, "--out", str(target)])
        err = capsys.readouterr().err
        assert rc == 2 and words in err and str(target) in err, err
        assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert f.read_text() == "not a folder"


def _unwritable(tmp_path: Path) -> Path:
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    if os.access(ro, os.W_OK):
        ro.chmod(0o700)
        pytest.skip("running as root: chmod 0o500 leaves the folder writable")
    return ro


@pytest.mark.parametrize("argv", [RUN, STUDY], ids=["run", "study"])
def test_unwritable_out_exits_2_before_computing(argv, tmp_path, capsys, no_computing):
    ro = _unwritable(tmp_path)
    try:
        rc = main([*argv, "--out", str(ro)])
        err = capsys.readouterr().err
        assert rc == 2 and "not writable" in err and str(ro) in err, err
    finally:
        ro.chmod(0o700)


def test_unwritable_out_exits_2_even_as_root(capsys, no_computing):
    """/sys refuses new files even to root (chmod does not): the same check, where it exists."""
    if not sys.platform.startswith("linux") or not Path("/sys").is_dir():
        pytest.skip("no /sys")
    try:
        fd, probe = tempfile.mkstemp(dir="/sys")
    except OSError:
        pass
    else:  # pragma: no cover - a writable /sys
        os.close(fd)
        os.unlink(probe)
        pytest.skip("/sys is writable here")
    rc = main([*RUN, "--out", "/sys"])
    err = capsys.readouterr().err
    assert rc == 2 and "'/sys'" in err and "not writable" in err, err
