"""The report shows the ladder's two new axes: the attenuation table (certified L2 gains beside the measured ratios),
the discrete-time plants' own section (contraction per step, rate per second), their LaTeX tables, and run.json's
count of INCONSISTENT attenuation rows (checked with a certificate whose gain was falsified on purpose)."""

import dataclasses
import json

import pandas as pd
import pytest

import bench
from bench import certify
from bench.findings import findings

PAIRS = (["moving_object_v1", "flexible_link_d10ms_v1"], ["lqr+lqe"])


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    out = tmp_path_factory.mktemp("measures")
    res = bench.run(*PAIRS, progress=False, jobs=1)
    res.write(out, figures=False)
    return res, out


def test_the_report_shows_the_gains_and_the_discrete_rows(small):
    res, out = small
    table = pd.read_csv(out / "results.csv").set_index("plant")
    mo, d10 = table.loc["moving_object_v1"], table.loc["flexible_link_d10ms_v1"]
    assert mo["disturbance"] == 0.1 and d10["disturbance"] == 0.0  # the run's default, plants with inputs only
    assert mo["l2_measured_x"] <= mo["l2_gain_x"] and mo["l2_radius"] == 10.0
    text = (out / "REPORT.md").read_text()
    attenuation = text[text.index("## Attenuation (L2 gains)"):text.index("## Discrete-time plants")]
    row = next(line for line in attenuation.splitlines() if line.startswith("| moving_object_v1 | lqr+lqe"))
    for col in ("l2_gain_e", "l2_gain_x", "l2_measured_e", "l2_measured_x"):
        assert f" {mo[col]:.3g} " in row
    assert "flexible_link_d10ms_v1" not in attenuation  # no disturbance inputs
    discrete = text[text.index("## Discrete-time plants"):text.index("## Convergence")]
    row = next(line for line in discrete.splitlines() if line.startswith("| flexible_link_d10ms_v1 | lqr+lqe"))
    assert f" {d10['contraction']:.6g} " in row and f" {d10['decay_rate']:.3g} " in row
    assert d10["contraction"] == pytest.approx(2.718281828459045 ** (-d10["decay_rate"] * d10["dt"]), rel=1e-12)
    assert "moving_object_v1" not in discrete
    tex = (out / "tables.tex").read_text()
    assert r"\label{tab:oslbench-attenuation}" in tex and r"\label{tab:oslbench-discrete}" in tex
    assert f"{d10['contraction']:.6g}" in tex
    counts = json.loads((out / "run.json").read_text())["findings"]["counts"]
    assert counts["inconsistent_attenuation"] == 0


def test_run_json_counts_a_false_gain_as_an_inconsistent_attenuation(monkeypatch):
    """A certified gain falsified to a twentieth of its value falls below the measured ratio: the row says
    INCONSISTENT and the findings count it among the attenuation rows."""
    real = certify.l2_gain

    def shrunk(spec, plant, loop, know, zeta):
        g = real(spec, plant, loop, know, zeta)
        return dataclasses.replace(g, gain=g.gain / 20)

    monkeypatch.setattr(certify, "l2_gain", shrunk)
    res = bench.run(["moving_object_v1"], ["lqr+lqe"], progress=False, jobs=1)
    row = res.table.iloc[0]
    assert "INCONSISTENT with the certificate: the measured L2 ratio" in row["details"]
    found = findings(res.run_result.frame(), res.run_result.constants)
    assert found["counts"]["inconsistent_attenuation"] == 1 == found["counts"]["inconsistent"]


def test_the_first_screen_names_the_smallest_certified_gain_per_plant():
    """Per plant and per zeta, the design whose certified L2 gain is smallest (ties named together, blank gains
    ignored); a plant with no certified gain has none; the summary line says it."""
    from bench.report import _summary

    nan = float("nan")
    frame = pd.DataFrame([
        {"plant": "p", "design": "a", "certified": True, "converged": True, "witness": "", "decay_rate": 1.0,
         "cert_level": "full", "cert_scope": "global", "peak_u": 1.0, "rate_ratio": 0.5,
         "l2_gain_e": 3.0, "l2_gain_x": 1.5},
        {"plant": "p", "design": "b", "certified": True, "converged": True, "witness": "", "decay_rate": 0.5,
         "cert_level": "full", "cert_scope": "global", "peak_u": 1.0, "rate_ratio": 0.5,
         "l2_gain_e": 0.25, "l2_gain_x": 2.0},
        {"plant": "p", "design": "c", "certified": False, "converged": True, "witness": "", "decay_rate": nan,
         "cert_level": "", "cert_scope": "", "peak_u": 1.0, "rate_ratio": nan, "l2_gain_e": nan, "l2_gain_x": nan},
        {"plant": "p", "design": "d", "certified": True, "converged": True, "witness": "", "decay_rate": 0.5,
         "cert_level": "full", "cert_scope": "global", "peak_u": 1.0, "rate_ratio": 0.5,
         "l2_gain_e": 0.25 * (1 + 1e-6), "l2_gain_x": 1.6},
        {"plant": "q", "design": "a", "certified": True, "converged": True, "witness": "", "decay_rate": 1.0,
         "cert_level": "full", "cert_scope": "global", "peak_u": 1.0, "rate_ratio": 0.5,
         "l2_gain_e": nan, "l2_gain_x": nan},
    ]).assign(status="feasible", reason="")
    found = findings(frame, {})
    assert found["plants"]["p"]["best_gains"] == {"e": {"design": "b, d", "gain": 0.25},
                                                  "x": {"design": "a", "gain": 1.5}}
    assert found["plants"]["q"]["best_gains"] == {}
    text = _summary(found)
    line_p = next(ln for ln in text.splitlines() if ln.startswith("- **p**"))
    assert "w to e: 0.25 (b, d)" in line_p and "w to x: 1.5 (a)" in line_p
    assert "L2" not in next(ln for ln in text.splitlines() if ln.startswith("- **q**"))
