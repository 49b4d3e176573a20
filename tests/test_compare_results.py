"""The CI's comparison of a regenerated results.csv with the committed one (.ci/compare_results.py)."""

import importlib.util
import math
from pathlib import Path

import pandas as pd

_spec = importlib.util.spec_from_file_location("compare_results",
                                               Path(__file__).parent.parent / ".ci" / "compare_results.py")
compare_results = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(compare_results)


def _table(**kw):
    row = {"plant": "p", "design": "d", "status": "feasible", "certified": True, "decay_rate": 0.5,
           "settling_x_s": 3.0, "final_x": 1e-11}
    row.update(kw)
    return pd.DataFrame([row])


def test_equal_tables_agree_and_round_off_is_tolerated():
    assert compare_results.compare(_table(), _table(decay_rate=0.5 * 1.01, final_x=3e-11)) == []


def test_a_changed_verdict_or_a_rate_beyond_its_tolerance_is_a_difference():
    diffs = compare_results.compare(_table(), _table(certified=False, decay_rate=0.5 * 2 ** (1 / 8)))
    assert len(diffs) == 2 and any("certified" in d for d in diffs) and any("decay_rate" in d for d in diffs)
    assert compare_results.compare(_table(), _table(settling_x_s=math.nan)) != []
    assert "only in the fresh table" in compare_results.compare(_table(), pd.concat([_table(), _table(design="e")]))[0]


def test_the_committed_results_agree_with_themselves():
    path = Path(__file__).parent.parent / "reports" / "results.csv"
    assert compare_results.main([str(path), str(path)]) == 0
