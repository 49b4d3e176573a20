import json
from dataclasses import dataclass

import pandas as pd
import pytest

from bench import report as report_mod
from bench.cli import main
from bench.harness import COLUMNS, RunOptions, run
from bench.registry import DESIGNS, PLANTS, RegistryError, UnknownIdError
from designs import Design


def test_list(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for i in PLANTS.ids() + DESIGNS.ids():
        assert i in out


@pytest.mark.parametrize("args, name", [(["--design", "thm2"], "thm1"), (["--plant", "flexible_lnk"], "flexible_link")])
def test_unknown_ids_exit_2_with_suggestion(capsys, tmp_path, args, name):
    assert main(["run", "--out", str(tmp_path), *args]) == 2
    err = capsys.readouterr().err
    assert "unknown" in err and "did you mean" in err and name in err
    assert not (tmp_path / "REPORT.md").exists()


def test_bad_option_exits_2(capsys, tmp_path):
    assert main(["run", "--out", str(tmp_path), "--t-final", "-3"]) == 2
    assert "t-final" in capsys.readouterr().err


def test_run_small_selection_writes_the_whole_report(tmp_path):
    rc = main(["run", "-q", "--plant", "flexible_link", "--design", "paper_gains", "--design", "thm1_printed",
               "--out", str(tmp_path)])
    assert rc == 0
    df = pd.read_csv(tmp_path / "results.csv")
    assert list(df.columns) == COLUMNS + ["details"]  # the full reason beside the short one
    assert list(df["design"]) == ["paper_gains", "thm1_printed"]  # the order asked for
    assert df["reason"].fillna("").str.len().max() <= 120
    assert (df["details"].fillna("").str.len() >= df["reason"].fillna("").str.len()).all()
    assert (tmp_path / "tables_standalone.tex").read_text().count(r"\input{tables.tex}") == 1
    row = df.set_index("design").loc["paper_gains"]
    assert bool(row["certified"]) and bool(row["converged"]) and row["final_x"] < 1e-6
    assert df.set_index("design").loc["thm1_printed", "status"] == "infeasible"
    gains = json.loads((tmp_path / "gains.json").read_text())
    assert [g["design"] for g in gains] == ["paper_gains"] and gains[0]["decay_rate"] > 0
    info = json.loads((tmp_path / "run.json").read_text())
    assert info["seed"] == 0 and "cvxpy" in info["versions"] and info["command"].startswith("python -m bench run")
    # the SDP solves of the run, per pair (thm1_printed is infeasible without a solve; a solve this process made
    # before, at the same parameter values, is not made again)
    assert info["sdp_solves"]["total"] == df["sdp_solves"].sum() and info["sdp_solves"]["pairs"] == 2
    assert df.set_index("design")["sdp_solves"].to_dict()["thm1_printed"] == 0
    md = (tmp_path / "REPORT.md").read_text()
    for heading in ("## Feasibility", "## Convergence", "## Timing", "## Constants", "## Figures"):
        assert heading in md
    assert "VIOLATED" in md  # the paper's rho
    assert (tmp_path / "figures" / "flexible_link__paper_gains.png").stat().st_size > 1000
    assert not list(tmp_path.glob(".tmp-*"))


@dataclass(frozen=True, kw_only=True)
class _Boom(Design):
    """A design that raises."""

    def design(self, plant, constants):
        raise RuntimeError("boom inside the design")


def test_a_failing_pair_becomes_an_error_row_and_the_run_goes_on():
    DESIGNS.register("_boom_test", _Boom)
    try:
        res = run(["flexible_link"], ["_boom_test", "paper_gains"], RunOptions(n_samples=500))
    finally:
        DESIGNS.unregister("_boom_test")
    df = res.frame().set_index("design")
    assert df.loc["_boom_test", "status"] == "error"
    assert "boom inside the design" in df.loc["_boom_test", "reason"]
    assert df.loc["paper_gains", "converged"]


def test_report_written_whole_or_not_at_all(tmp_path, monkeypatch, capsys):
    assert main(["run", "-q", "--design", "thm1_printed", "--plant", "flexible_link", "--out", str(tmp_path)]) == 0
    before = (tmp_path / "REPORT.md").read_text()
    csv_before = (tmp_path / "results.csv").read_text()

    def broken(*a, **k):
        raise RuntimeError("renderer crashed")

    monkeypatch.setattr(report_mod, "render_markdown", broken)
    rc = main(["run", "-q", "--design", "paper_gains", "--plant", "flexible_link", "--out", str(tmp_path)])
    assert rc == 1
    assert "renderer crashed" in capsys.readouterr().err
    assert (tmp_path / "REPORT.md").read_text() == before
    assert (tmp_path / "results.csv").read_text() == csv_before
    assert not list(tmp_path.glob(".tmp-*"))


def test_registry_rules():
    with pytest.raises(RegistryError, match="duplicate"):
        DESIGNS.register("thm1", _Boom)
    with pytest.raises(UnknownIdError, match="did you mean"):
        DESIGNS["cor2"]
    assert PLANTS.select(["flexible_link*"]) == ["flexible_link", "flexible_link_printed", "flexible_link_w_v1",
                                                 "flexible_link_d10ms_v1"]


def test_every_module_registers_something():
    import importlib
    import pkgutil

    from designs._parts import ESTIMATORS, FEEDBACKS

    for package, regs in (("plants", (PLANTS,)), ("designs", (DESIGNS, FEEDBACKS, ESTIMATORS))):
        pkg = importlib.import_module(package)
        modules = {f"{package}.{m.name}" for m in pkgutil.iter_modules(pkg.__path__) if not m.name.startswith("_")}
        registered = {reg[i].module for reg in regs for i in reg.ids()}
        assert modules <= registered, f"modules that registered nothing: {modules - registered}"


def test_a_run_removes_only_its_own_stale_files_and_names_them(tmp_path, caplog):
    """The user's files stay (even named like the suite's figures); the figure an earlier run wrote and
    this run does not is removed and named; one the user changed since stays."""
    figs = tmp_path / "figures"
    figs.mkdir()
    mine = {"figures/holiday__photo.png": b"holiday", "figures/thesis__fig3.pdf": b"thesis",
            "figures/study_noise_x.png": b"study", "notes.txt": b"notes"}
    for rel, data in mine.items():
        (tmp_path / rel).write_bytes(data)
    base = ["run", "-q", "-j", "1", "--plant", "flexible_link", "--out", str(tmp_path)]
    assert main([*base, "--design", "paper_gains", "--design", "lqr+lqe", "--design", "cor1_sep"]) == 0
    assert (figs / "flexible_link__lqr+lqe.png").exists() and (figs / "flexible_link__cor1_sep.png").exists()
    (figs / "flexible_link__cor1_sep.png").write_bytes(b"annotated by the user")
    caplog.clear()
    with caplog.at_level("WARNING", logger="bench.outdir"):
        assert main([*base, "--design", "paper_gains"]) == 0
    for rel, data in mine.items():
        assert (tmp_path / rel).read_bytes() == data, rel
    assert not (figs / "flexible_link__lqr+lqe.png").exists()
    assert (figs / "flexible_link__cor1_sep.png").read_bytes() == b"annotated by the user"
    assert (figs / "flexible_link__paper_gains.png").exists()
    text = caplog.text
    assert "removed 1 file" in text and "figures/flexible_link__lqr+lqe.png" in text
    assert "kept figures/flexible_link__cor1_sep.png" in text and "holiday" not in text


def test_stale_temp_folders_of_a_killed_writer_are_removed(tmp_path):
    stale = tmp_path / ".tmp-killed"
    stale.mkdir()
    (stale / "REPORT.md").write_text("half")
    assert main(["run", "-q", "--plant", "flexible_link", "--design", "thm1_printed", "--out", str(tmp_path)]) == 0
    assert not stale.exists() and (tmp_path / "REPORT.md").exists()
