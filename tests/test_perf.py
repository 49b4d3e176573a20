"""``python -m bench perf`` writes its report; the figures themselves are measurements, not asserted."""

import sys

from bench import cli
from bench.cli import main

sys.path.insert(0, str(cli._BENCHMARKS_DIR))  # the report code is a script of the checkout


def test_perf_small_writes_report(tmp_path):
    # perf now also measures the structured design's routes on the chain family (up to n = 1024) and
    # simulations at n = 1000 / 100 by default: --route-sizes '' and --no-sims keep this test small
    assert main(["perf", "--sizes", "4", "--no-run", "--no-sweeps", "--route-sizes", "", "--no-sims",
                 "--out", str(tmp_path)]) == 0
    md = (tmp_path / "PERF.md").read_text()
    # the design-time section is now titled "Corrected Theorem 1: time vs n"; perf.csv is new
    assert "Theorem 1: time vs n" in md and "Compile overhead in a sweep" in md
    assert (tmp_path / "figures" / "perf_scaling.png").exists() and (tmp_path / "perf.csv").exists()
    assert not list(tmp_path.glob(".tmp-*"))


def test_perf_bad_sizes_exit_2(tmp_path, capsys):
    assert main(["perf", "--sizes", "4,x", "--out", str(tmp_path)]) == 2
    assert "--sizes" in capsys.readouterr().err


def test_breakdown_parts_account_for_the_work_and_the_floor_is_a_lower_bound():
    # one plant, two designs: the parts are timed, not asserted; what must hold whatever the machine:
    # the SDP parts come from a real tally (thm1 solves, LQR + LQE solves none in its design), the
    # solver's own time is part of the solves, and the floor is at most the serial total's share
    from perf_report import default_run_breakdown

    b = default_run_breakdown(["flexible_link"], ["thm1", "lqr+lqe"], cores=2, timeout=300)
    assert b["status"] == "ok" and b["pairs"] == 2 and b["n_solves"] > 0
    assert 0 < b["solver_s"] and b["cvxpy_solve_s"] >= 0 and b["compile_s"] > 0
    sdp = b["solver_s"] + b["cvxpy_solve_s"] + b["compile_s"]
    assert sdp <= b["design_s"] + b["cert_s"] + 1e-6  # every solve happens inside a design or a certificate
    serial = b["imports_s"] + b["constants_s"] + b["design_s"] + b["cert_s"] + b["sim_s"] + b["figures_s"]
    assert b["imports_s"] < b["floor_s"] <= serial


def test_perf_outside_a_checkout_exits_2_and_says_why(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(cli, "_BENCHMARKS_DIR", tmp_path / "benchmarks")  # an installed package: no benchmarks/
    assert main(["perf", "--sizes", "4", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "developer command" in err and "checkout" in err
    assert not (tmp_path / "PERF.md").exists()
