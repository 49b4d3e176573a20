"""The package as a notebook sees it: the public names of ``bench``, the order of the table, the
short reason beside the full text, and the run's summary line."""

from __future__ import annotations

import math

import pandas as pd

import bench
from bench.cli import summary_line
from bench.registry import DESIGNS, PLANTS
from bench.report import REASON_CHARS, results_table, short_reason


def test_public_names_import_and_are_listed():
    public = {"run", "Results", "Plant", "Constants", "Channels", "Design", "DesignResult", "register_design",
              "register_plant", "OslbenchError", "PlantError", "DesignError", "PluginError", "RegistryError",
              "UnknownIdError", "StudyError", "OutDirError", "ExecutorError"}
    assert public <= set(dir(bench))
    assert set(bench.__all__) == public
    from bench import Design, DesignResult, Plant, register_design, register_plant, run  # noqa: F401
    import designs
    import plants
    from bench.registry import register_design as rd

    assert bench.Plant is plants.Plant and bench.Design is designs.Design and bench.register_design is rd
    assert callable(run) and DesignResult is designs.DesignResult and register_plant is not None


def test_select_keeps_the_order_asked_for():
    ids = PLANTS.ids()
    first, last = ids[0], ids[-1]
    assert PLANTS.select([last, first], keep_order=True) == [last, first]
    assert PLANTS.select([last, first]) == [first, last]  # the registry's order by default
    # a glob expands in the registry's order, at the place it was given; repeats collapse
    lqr = [d for d in DESIGNS.ids() if d.startswith("lqr+")]
    assert DESIGNS.select(["thm1", "lqr+*", "cor1", "thm1"], keep_order=True) == ["thm1", *lqr, "cor1"]


def test_short_reason():
    assert short_reason("") == "" and short_reason(None) == "" and short_reason(math.nan) == ""
    text = "infeasible: a short one; with a second clause"
    assert short_reason(text) == text  # short enough: kept whole
    long = "corrected Theorem 1: not strictly feasible (best margin t = -4.32, -0.769 there; homogeneous in Q, R)" \
           "; the joint LMI is feasible iff both sides are; " + "more words " * 20
    assert short_reason(long) == "corrected Theorem 1: not strictly feasible"
    words = "word " * 60
    cut = short_reason(words)
    assert len(cut) <= REASON_CHARS and cut.endswith("...") and not cut.endswith(" ...")
    assert cut[:-3] == ("word " * 60)[: len(cut) - 3]  # cut at a word boundary
    assert all(len(short_reason("x " * k + "; y")) <= REASON_CHARS for k in range(0, 200, 7))
    # a "; " inside parentheses does not end the first clause
    assert short_reason("a (b; c) d; " + "e" * 200) == "a (b; c) d"


def test_results_table_has_short_reason_and_full_details():
    full = "a " * 100 + "; and more"
    df = pd.DataFrame({"plant": ["p", "p"], "design": ["b", "a"], "reason": [full, ""]})
    out = results_table(df)
    assert list(out.columns) == ["plant", "design", "reason", "details"]
    assert list(out["design"]) == ["b", "a"]
    assert out.loc[0, "details"] == full and len(out.loc[0, "reason"]) <= REASON_CHARS
    assert out.loc[1, "reason"] == "" and out.loc[1, "details"] == ""
    assert df["reason"].iloc[0] == full  # the records are not changed


def test_summary_line_counts_what_each_pair_got():
    df = pd.DataFrame({
        "status": ["feasible", "computed", "computed", "given", "infeasible", "inapplicable", "error"],
        "certified": [True, True, False, True, False, False, False],
        "converged": [True, True, True, False, False, False, False],
    })
    line = summary_line(df)
    assert line.startswith("7 pairs: 4 with gains (1 feasible, 2 computed, 1 given), 3 without ")
    assert "(1 infeasible, 1 inapplicable, 1 error)" in line
    assert line.endswith("of the 4 with gains, 3 certified and 3 converged")
    assert summary_line(pd.DataFrame({"status": ["infeasible"] * 2, "certified": [False] * 2,
                                      "converged": [False] * 2})) == "2 pairs: 0 with gains, 2 without (2 infeasible)"
