"""A report folder read back (issue 35): ``bench.Results.load(folder)`` returns what ``bench.run`` returned, and
``python -m bench report FOLDER`` draws REPORT.md, report.html, tables.tex and the figures again from the folder's
files, computing nothing, equal to the originals byte for byte."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import bench
from bench.cli import main
from bench.outdir import MANIFEST_NAME, TMP_PREFIX
from bench.report import FIGURE_DATA

PAGES = ("REPORT.md", "report.html", "tables.tex", "tables_standalone.tex")
RESULTS = ("results.csv", "gains.json", "run.json", FIGURE_DATA)


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """A small run (states figures of the flexible link, a norms figure per plant, an infeasible printed form, an
    inapplicable pair, a pair without a certificate) and its report folder."""
    res = bench.run(plants=["flexible_link", "pendulum_v1"], designs=["paper_gains", "lqr+lqe", "thm1_printed"],
                    jobs=1, progress=False, command="a small run")
    folder = tmp_path_factory.mktemp("report")
    res.write(folder)
    return res, folder


def _files(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _forbid_computing(monkeypatch):
    """Make every solve, constants computation and simulation fail: what follows computes nothing."""
    import bench.constants
    import bench.harness
    import bench.pipeline

    def boom(*a, **k):
        raise AssertionError("computed something")

    for mod, name in ((bench.harness, "run"), (bench.pipeline, "evaluate_pair"), (bench.constants, "compute_constants"),
                      (bench.harness, "compute_constants"), (bench.pipeline, "simulate_controller")):
        if hasattr(mod, name):
            monkeypatch.setattr(mod, name, boom)


def test_report_folder_redraws_byte_for_byte(written, tmp_path, monkeypatch):
    _, original = written
    folder = tmp_path / "r"
    shutil.copytree(original, folder)
    before = _files(original)
    assert set(PAGES) | set(RESULTS) <= set(before)
    figures = sorted(k for k in before if k.startswith("figures/"))
    assert "figures/flexible_link__norms.png" in figures and "figures/flexible_link__lqr+lqe.png" in figures
    for name in ("REPORT.md", "report.html", "tables.tex"):
        (folder / name).unlink()
    shutil.rmtree(folder / "figures")
    _forbid_computing(monkeypatch)
    assert main(["report", str(folder), "-q"]) == 0
    after = _files(folder)
    for name in [*PAGES, *RESULTS, *figures]:  # REPORT.md and tables.tex are deterministic; so are the PNGs here
        assert after[name] == before[name], name
    assert set(after) == set(before)  # nothing more (no temporary folder), nothing less
    manifest = json.loads((folder / MANIFEST_NAME).read_text())["writers"]["report"]
    assert set(RESULTS) | set(PAGES) | set(figures) == set(manifest)  # the result files stay the report's own
    assert not [p for p in folder.iterdir() if p.name.startswith(TMP_PREFIX)]


def test_results_load_returns_what_run_returned(written, monkeypatch):
    res, folder = written
    _forbid_computing(monkeypatch)
    loaded = bench.Results.load(folder)
    pd.testing.assert_frame_equal(loaded.table, res.table)  # values and the kinds of the columns
    assert loaded.command == "a small run" and loaded.info == res.info and loaded.source == Path(folder)
    assert json.dumps(loaded.findings, sort_keys=True) == json.dumps(res.findings, sort_keys=True)
    assert {p: c.to_dict() for p, c in loaded.constants.items()} == {p: c.to_dict() for p, c in res.constants.items()}
    assert set(loaded.gains) == set(res.gains) and res.gains  # every pair with a controller
    for key, g in res.gains.items():
        mine = loaded.gains[key]
        np.testing.assert_array_equal(mine["K"], g["K"])
        np.testing.assert_array_equal(mine["F"], g["F"])
        for level, lr in g["certificate"].levels.items():
            if lr.P is None:
                assert mine["certificate"][level]["P"] is None
            else:
                np.testing.assert_array_equal(mine["certificate"][level]["P"], lr.P)
                assert not mine["certificate"][level]["P"].flags.writeable
        assert not mine["K"].flags.writeable and not mine["F"].flags.writeable
        assert mine["plant"] is None and mine["trajectory"] is None
    with pytest.raises(ValueError, match="no plant object"):
        loaded.controller(*next(iter(loaded.gains)))


def test_loaded_results_write_the_same_report_elsewhere(written, tmp_path):
    res, folder = written
    out = tmp_path / "copy"
    path = bench.Results.load(folder).write(out)
    assert path == out / "REPORT.md"
    for name in [*PAGES, *RESULTS]:
        assert (out / name).read_bytes() == (Path(folder) / name).read_bytes(), name


def test_report_options_and_errors(written, tmp_path, capsys):
    _, original = written
    folder = tmp_path / "r"
    shutil.copytree(original, folder)
    out = tmp_path / "elsewhere"
    assert main(["report", str(folder), "--out", str(out), "--no-figures", "-q"]) == 0
    assert not list((out / "figures").glob("*"))
    assert "No converging pair to plot." in (out / "REPORT.md").read_text()
    assert (out / "results.csv").read_bytes() == (folder / "results.csv").read_bytes()
    assert _files(folder) == _files(original)  # --out: the folder read is untouched
    # not a report folder: bad usage; figure data missing: the figures cannot be drawn (with --no-figures they are not)
    assert main(["report", str(tmp_path / "nothing")]) == 2
    assert "not a folder" in capsys.readouterr().err
    assert main(["report", str(tmp_path)]) == 2
    assert "not a report folder (no results.csv, gains.json, run.json)" in capsys.readouterr().err
    (folder / FIGURE_DATA).unlink()
    assert main(["report", str(folder)]) == 1
    assert f"no {FIGURE_DATA}" in capsys.readouterr().err
    assert main(["report", str(folder), "--no-figures", "-q"]) == 0
    # a damaged results.csv is named
    (folder / "results.csv").write_text("plant,design,certified\np,d,maybe\n", encoding="utf-8")
    assert main(["report", str(folder), "--no-figures"]) == 1
    assert "results.csv, line 2, column 'certified'" in capsys.readouterr().err
