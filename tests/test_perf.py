"""``python -m bench perf`` writes its report; the figures themselves are measurements, not asserted."""

from bench.cli import main


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
