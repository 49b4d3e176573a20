"""What a new user met on the command line (issue 35): --version and the program's name, the installed form of
the optional dependency, --strict and a run where every pair fails, a blank ``converged`` without gains, a first
screen cut at word boundaries, a legend in short items, the progress bar's count, ``list`` without markup, the
options a study shares with a run, a glob that matches nothing, and the cache folder (where, info, clear)."""

import csv
import re
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pytest

import bench
from bench import cli
from bench.cli import main
from bench.registry import DESIGNS
from designs import Design

ROOT = Path(__file__).resolve().parents[1]
FAST = ["-q", "-j", "1", "--no-figures"]


@dataclass(frozen=True, kw_only=True)
class _Raises(Design):
    """A design whose design() raises."""

    def design(self, plant, constants):
        raise RuntimeError("raised inside the design on purpose")


@pytest.fixture
def raising_design():
    DESIGNS.register("raises_on_purpose", _Raises)
    yield "raises_on_purpose"
    DESIGNS.unregister("raises_on_purpose")


def test_version_names_the_package_its_place_and_pyproject_agrees(capsys):
    assert main(["--version"]) == 0
    out = capsys.readouterr().out.strip()
    declared = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["version"]
    assert bench.__version__ == declared
    assert out.startswith(f"oslbench {declared} ") and str(Path(bench.__file__).resolve().parents[1]) in out
    assert "\n" not in out


@pytest.mark.parametrize("argv0, prog", [("/venv/bin/oslbench", "oslbench"), ("/x/bench/__main__.py", "python -m bench")])
def test_help_shows_the_program_as_invoked(capsys, monkeypatch, argv0, prog):
    monkeypatch.setattr(sys, "argv", [argv0])
    assert main(["--help"]) == 0
    assert capsys.readouterr().out.startswith(f"usage: {prog} ")
    assert main(["run", "--plant", "nothing*"]) == 2
    assert capsys.readouterr().err.startswith(f"{prog} run: error: ")


def test_scheduler_help_gives_the_installed_form(capsys):
    assert main(["run", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "pip install 'oslbench[dist]'" in text and "'.[dist]'" not in text


def test_a_glob_that_matches_nothing_says_so(capsys, tmp_path):
    assert main(["run", "--plant", "nothing*", "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert "plant glob 'nothing*' matches nothing" in err and "unknown" not in err
    assert main(["run", "--design", "thm9", "--out", str(tmp_path / "r")]) == 2
    assert "unknown design 'thm9'" in capsys.readouterr().err


def test_strict_and_a_run_where_every_pair_fails(capsys, tmp_path, raising_design):
    base = ["run", *FAST, "--no-cache", "--plant", "flexible_link"]
    # one error beside a good pair: the report is written; exit 0, or 1 under --strict naming the pair
    assert main([*base, "--design", raising_design, "--design", "paper_gains", "--out", str(tmp_path / "a")]) == 0
    capsys.readouterr()
    assert main([*base, "--design", raising_design, "--design", "paper_gains", "--strict",
                 "--out", str(tmp_path / "b")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("python -m bench run: error: --strict: 1 of 2 pairs") and raising_design in err[-1]
    assert (tmp_path / "b" / "REPORT.md").exists()
    # every pair an error: said on the last line (even with -q); exit 1 under --strict
    assert main([*base, "--design", raising_design, "--out", str(tmp_path / "c")]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("python -m bench run: warning: every pair is an error or a timeout (1 of 1")
    assert "raised inside the design" in err[-1]
    assert main([*base, "--design", raising_design, "--strict", "--out", str(tmp_path / "c")]) == 1
    assert capsys.readouterr().err.strip().splitlines()[-1].startswith(
        "python -m bench run: error: every pair is an error or a timeout")


def test_converged_is_blank_without_gains(tmp_path):
    assert main(["run", *FAST, "--plant", "flexible_link", "--design", "thm1_printed", "--design", "paper_gains",
                 "--out", str(tmp_path)]) == 0
    with open(tmp_path / "results.csv", newline="") as fh:
        rows = {r["design"]: r for r in csv.DictReader(fh)}
    assert rows["thm1_printed"]["status"] == "infeasible" and rows["thm1_printed"]["converged"] == ""
    assert rows["paper_gains"]["converged"] == "True"


def test_summary_counts_converged_without_the_blank_rows():
    import pandas as pd

    df = pd.DataFrame({"status": ["feasible", "infeasible", "error"], "certified": [True, False, False],
                       "converged": [True, None, None]})
    assert cli.summary_line(df).endswith("of the 1 with gains, 1 certified and 1 converged")


@pytest.mark.parametrize("limit", [20, 37, 60, 120])
def test_clip_words_cuts_at_a_word_boundary(limit):
    from bench.report import clip_words

    text = ("as printed, S3 holds -zeta I with zeta = 1/(eps2 gamma - eps1); with gamma = 0 <= 0, eps2 gamma - "
            "eps1 < 0 for every eps1, eps2 > 0, so -zeta I is positive definite, which the statement omits")
    cut = clip_words(text, limit)
    assert len(cut) <= limit and cut.endswith("...")
    kept = cut[:-3]
    assert text.startswith(kept) and text[len(kept)] in " ,;:("  # the next character ends a word
    assert clip_words("short", limit) == "short"


def test_first_screen_never_cuts_a_finding_mid_word():
    from bench.report import _summary

    long = "word " * 100
    found = {"inconsistent": [], "plants": {}, "violated_claims": [], "disproved": [],
             "printed_infeasible": [{"plant": "p1", "design": "d", "reason": "alpha " + long},
                                    {"plant": "p2", "design": "d", "reason": "beta " + long}]}
    line = _summary(found)
    head = line.split(" (each plant's reason")[0]
    assert head.endswith("word...") and len(head.split("on p1: ")[1]) <= 240


def test_how_to_read_a_row_is_a_list_of_short_items():
    from bench.report import _LEGEND

    items = [ln for ln in _LEGEND.splitlines() if ln.startswith("- ")]
    assert _LEGEND.startswith("**How to read a row**") and len(items) >= 8
    assert max(len(ln) for ln in _LEGEND.splitlines()) < 330  # a few lines each, not one paragraph
    assert any("blank for a pair without gains" in ln for ln in items)


def test_progress_bar_counts_the_constants_and_the_pairs(monkeypatch, tmp_path, capsys):
    """The bar's text names what it counts: one constants task per plant and one per pair (6 for 1 plant and 5
    designs), and every task it counts is reported; the report-writing stage is announced."""
    import bench.progress

    seen: dict = {"calls": []}

    class Recorder:
        def __init__(self, total=None, desc="", **kw):
            seen["desc"] = desc

        def __call__(self, done, total, label=""):
            seen["calls"].append((done, total))

        def close(self):
            pass

    monkeypatch.setattr(bench.progress, "Progress", Recorder)
    designs = ["paper_gains", "thm1_printed", "cor1_printed", "lqr+lqe", "thm1_sep"]
    args = ["run", "-j", "1", "--no-figures", "--no-cache", "--plant", "flexible_link", "--out", str(tmp_path)]
    assert main([*args, *(a for d in designs for a in ("--design", d))]) == 0
    assert seen["desc"] == "constants of 1 plant + 5 pairs"
    assert seen["calls"][-1] == (6, 6) and len(seen["calls"]) == 6
    assert "writing the report into" in capsys.readouterr().err


def test_list_shows_plain_text(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert not re.search(r":[a-z]+:`", out) and "``" not in out
    assert cli.plain_summary("The member of :func:`random_lipschitz_plant` (n = 4)") == \
        "The member of random_lipschitz_plant (n = 4)"
    assert cli.plain_summary("A :class:`~plants.Plant` and ``x0``") == "A Plant and `x0`"
    assert cli.plain_summary("See :meth:`bench.api.Results.write`") == "See bench.api.Results.write"


@pytest.mark.parametrize("study", ["admissible", "sampling", "montecarlo", "noise"])
def test_studies_share_the_run_options(study):
    """Each study takes --seed, --no-figures, --jobs, --start-method, --quiet and --plugin, as run does."""
    parser = cli._build_parser()
    shared = ["--seed", "3", "--no-figures", "--jobs", "2", "--start-method", "spawn", "-q"]
    args = parser.parse_args(["study", study, "--plant", "flexible_link", *shared])
    assert (args.seed, args.no_figures, args.jobs, args.start_method, args.quiet) == (3, True, 2, "spawn", True)
    run_args = parser.parse_args(["run", *shared])
    assert (run_args.seed, run_args.no_figures, run_args.jobs, run_args.start_method) == (3, True, 2, "spawn")
    from bench.studies.cli import _options

    assert _options(args)["seed"] == 3


def test_a_study_without_figures_writes_no_figure(tmp_path):
    from bench.studies._common import write_plant_study
    from bench.report import pyplot

    def draw(pid, rows):
        fig = pyplot().figure()
        return fig

    rows = [{"plant": "p", "design": "d", "x": 1.0}]
    path = write_plant_study(tmp_path, "demo", ["# demo", "", "![p](figures/study_demo_p.png)"], {"study_demo": rows},
                             rows, draw, figures=False)
    assert "![" not in path.read_text() and not (tmp_path / "figures").exists()
    write_plant_study(tmp_path, "demo", ["# demo"], {"study_demo": rows}, rows, draw)
    assert (tmp_path / "figures" / "study_demo_p.png").exists()


def test_cache_folder_where_info_and_clear(capsys, tmp_path):
    out = tmp_path / "r"
    args = ["run", *FAST, "--plant", "flexible_link", "--design", "paper_gains"]
    assert main([*args, "--out", str(out)]) == 0
    cache = tmp_path / ".bench-cache"  # beside the report folder
    assert list((cache / "pairs").glob("*.npz")) and list((cache / "constants").glob("*.npz"))
    assert not (out / ".oslbench.lock").exists()  # no empty lock file stays in the report folder
    capsys.readouterr()
    assert main(["cache", "info", "--out", str(out)]) == 0
    assert capsys.readouterr().out.startswith(f"{cache}: 1 pair, the constants of 1 plant, ")
    (cache / "notes.txt").write_text("mine")  # not the cache's: left alone
    assert main(["cache", "clear", "--out", str(out)]) == 0
    assert "removed 2 entries" in capsys.readouterr().out
    assert sorted(p.name for p in cache.iterdir()) == ["notes.txt"]
    # --cache-dir: the run and the commands use that folder instead
    elsewhere = tmp_path / "cache-here"
    assert main([*args, "--out", str(out), "--cache-dir", str(elsewhere)]) == 0
    assert list((elsewhere / "pairs").glob("*.npz")) and not (cache / "pairs").exists()
    assert main(["cache", "clear", "--cache-dir", str(elsewhere)]) == 0
    assert not elsewhere.exists()
