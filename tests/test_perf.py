"""``python -m bench perf`` writes its report; the figures themselves are measurements, not asserted."""

from bench.cli import main


def test_perf_small_writes_report(tmp_path):
    assert main(["perf", "--sizes", "4", "--no-run", "--no-sweeps", "--out", str(tmp_path)]) == 0
    md = (tmp_path / "PERF.md").read_text()
    assert "Design time vs n" in md and "Compile overhead in a sweep" in md
    assert (tmp_path / "figures" / "perf_scaling.png").exists()
    assert not list(tmp_path.glob(".tmp-*"))


def test_perf_bad_sizes_exit_2(tmp_path, capsys):
    assert main(["perf", "--sizes", "4,x", "--out", str(tmp_path)]) == 2
    assert "--sizes" in capsys.readouterr().err
