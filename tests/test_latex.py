"""bench.latex: booktabs tables of a results frame (structure, escaping, and a pdflatex build when available)."""

from __future__ import annotations

import math
import re
import shutil
import subprocess

import numpy as np
import pandas as pd
import pytest

from bench.latex import PACKAGES, escape_tex, format_cell, minimal_document, tables_tex

NAN = math.nan


@pytest.fixture
def frame() -> pd.DataFrame:
    """Two plants with underscores, a design with '+', a status with specials, NaNs and bools, and
    certificate levels that are certified, not certified, marginal and inapplicable."""
    rows = [
        # plant, design, status, decay_paper, decay_full, decay_structured, cert_level, converged,
        # settling_x_s, settling_e_s, peak_u, horizon_s, design_s, cert_s, sim_s,
        # cert_paper, cert_full, cert_structured, cert_scope
        ("flexible_link", "thm1", "feasible", 0.0151694, 0.02, NAN, "full", True, 2.75, 1.18, 81.0286, 20.0,
         0.2359, 0.2195, 0.197, "certified", "certified", "inapplicable", "global"),
        ("flexible_link", "lqr+rh_riccati", "infeasible", NAN, NAN, NAN, NAN, False, NAN, NAN, 1.5e6, 20.0,
         1.0, NAN, 3.0, "", "", "", ""),
        ("random_osl_v1", "thm1", "timeout", NAN, NAN, 0.5, "structured", np.bool_(True), 12.0, 3.0, 2.0, 20,
         100.0, 2.0, 1e-4, "marginal", "not certified", "certified", "from x0"),
        ("random_osl_v1", "weird_{#1}", "odd 50%_&$~^\\", NAN, 1.0, NAN, "a_b", True, 1.0, 1.0, 1.0, 20.0,
         1.0, 1.0, 1.0, "not certified", "certified", "undecided", "local"),
    ]
    cols = ["plant", "design", "status", "decay_paper", "decay_full", "decay_structured", "cert_level",
            "converged", "settling_x_s", "settling_e_s", "peak_u", "horizon_s", "design_s", "cert_s", "sim_s",
            "cert_paper", "cert_full", "cert_structured", "cert_scope"]
    return pd.DataFrame(rows, columns=cols)


def tabulars(tex: str) -> list[tuple[str, list[list[str]]]]:
    """(column spec, rows split at unescaped '&') of every tabular; asserts begin/end pair up."""
    tex = re.sub(r"\\begin\{tabular\}\[b\]\{@\{\}c@\{\}\}(.*?)\\end\{tabular\}",
                 lambda m: m.group(1).replace("\\\\{}", " "), tex)  # two-line headers -> one line
    begins = [m.start() for m in re.finditer(r"\\begin\{tabular\}", tex)]
    ends = [m.start() for m in re.finditer(r"\\end\{tabular\}", tex)]
    assert len(begins) == len(ends) > 0
    out = []
    for b, e in zip(begins, ends):
        assert b < e
        body = tex[b:e]
        spec = re.match(r"\\begin\{tabular\}\{([^}]*)\}", body).group(1)
        inner = body[body.index("\n") + 1:]
        rows = []
        for line in inner.splitlines():
            line = line.strip()
            if line in ("\\toprule", "\\midrule", "\\bottomrule", "\\addlinespace", ""):
                continue
            heading = re.fullmatch(r"\\multicolumn\{(\d+)\}\{@\{\}l\}\{\\emph\{(.*)\}\} \\\\", line)
            if heading:  # a plant's heading spans the table
                assert int(heading.group(1)) == len(spec)
                rows.append([f"# {heading.group(2)}"])
                continue
            assert line.endswith(r"\\"), line
            rows.append([c.strip() for c in re.split(r"(?<!\\)&", line[:-2])])
        out.append((spec, rows))
    return out


def test_structure_and_column_counts(frame):
    tex = tables_tex(frame)
    assert tex.count(r"\begin{table}") == tex.count(r"\end{table}") == 4
    for rule in ("toprule", "midrule", "bottomrule"):
        assert tex.count("\\" + rule) == 4
    for spec, rows in tabulars(tex):
        assert re.fullmatch(r"[lcr]+", spec)
        assert rows, spec
        for row in rows:
            assert row[0].startswith("# ") or len(row) == len(spec), (spec, row)
    # environments nest: no table ends before its tabular
    for b, e in zip(re.finditer(r"\\begin\{table\}", tex), re.finditer(r"\\end\{table\}", tex)):
        chunk = tex[b.start():e.start()]
        assert chunk.count(r"\begin{tabular}{") == chunk.count(r"\end{tabular}") - chunk.count(r"\begin{tabular}[b]")
    # never scaled, and the packages it needs are named at its top
    assert r"\resizebox" not in tex and r"\small" not in tex and r"\scalebox" not in tex
    assert tex.startswith("%") and r"\usepackage{booktabs}" in tex.split(r"\begin{table}")[0]
    assert PACKAGES == ("booktabs",)


def test_feasibility_matrix(frame):
    spec, rows = tabulars(tables_tex(frame))[0]
    assert spec == "l" + "c" * 3  # three distinct designs
    header, body = rows[0], rows[1:]
    assert header == ["plant", "thm1", r"lqr+rh\_riccati", r"weird\_\{\#1\}"]
    assert body[0] == [r"flexible\_link", "yes", "no", ""]  # a pair not run is blank
    assert body[1][:2] == [r"random\_osl\_v1", "t/o"]
    assert body[1][2] == ""
    assert body[1][3] == r"odd 50\%\_\&\$\textasciitilde{}\textasciicircum{}\textbackslash{}"


def test_decay_table_prints_marginal_and_not_certified_apart_and_has_a_scope(frame):
    tex = tables_tex(frame)
    (_, decay) = tabulars(tex)[1]
    assert decay[0] == ["design", "paper", "full", "structured", "level", "scope"]
    assert decay[1] == [r"# flexible\_link"]  # the plant heads its rows
    assert decay[2] == ["thm1", "0.0152", "0.02", "n/a", "full", "global"]  # .3g; inapplicable is n/a
    assert decay[3] == [r"lqr+rh\_riccati", "", "", "", "", ""]  # no gains: nothing to certify
    assert decay[5] == ["thm1", "marginal", "no", "0.5", "structured", "from x0"]
    assert decay[6] == [r"weird\_\{\#1\}", "no", "1", "undecided", r"a\_b", "local"]
    caption = tex.split(r"\label{tab:oslbench-decay}")[0].rsplit(r"\caption{", 1)[1]
    assert "no: not certified" in caption and "marginal: margin within" in caption and "local" in caption


def test_row_tables_format_and_escape(frame):
    tex = tables_tex(frame)
    (_, conv), (_, timing) = tabulars(tex)[2:]
    assert conv[0] == ["design", "converged", "settling x [s]", "settling e [s]", r"peak \textbar{}u\textbar{}",
                       "horizon [s]"]
    assert [r[1] for r in conv[1:] if not r[0].startswith("#")] == ["yes", "no", "yes", "yes"]  # numpy bools too
    assert conv[3][4] == "1.5e+06"
    assert conv[5][5] == "20"  # an integer column value stays an integer
    assert timing[0] == ["design", "design [s]", "certificate [s]", "simulation [s]"]
    assert timing[5][3] == "0.0001"
    # no raw special character left in any cell
    for _, rows in tabulars(tex):
        for row in rows:
            for cell in ([row[0][2:]] if row[0].startswith("# ") else row):
                stripped = re.sub(r"\\(textbackslash|textasciitilde|textasciicircum|textless|textgreater|textbar)\{\}"
                                  r"|\\[&%$#_{}]", "", cell)
                assert not re.search(r"[&%$#_{}~^\\]", stripped), cell


def test_missing_columns_are_skipped(frame):
    tex = tables_tex(frame[["plant", "design", "status", "sim_s", "converged"]])
    assert tex.count(r"\begin{tabular}{") == 3  # feasibility, convergence (1 column), timing
    assert "settling x" not in tex and "Certified decay" not in tex
    conv = tabulars(tex)[1][1]
    assert conv[0] == ["design", "converged"]
    only_ids = tables_tex(frame[["plant", "design"]])
    assert r"\begin{tabular}" not in only_ids
    # a results.csv with decay_rate but no per-level columns: fall back to it
    legacy = frame[["plant", "design", "cert_level"]].assign(decay_rate=[0.015, NAN, 0.5, 1.0])
    spec, rows = tabulars(tables_tex(legacy))[0]
    assert rows[0] == ["design", "decay rate", "level"] and rows[2][1] == "0.015"


def test_caption_prefix_label_and_wide_matrix_split(frame):
    tex = tables_tex(frame, caption_prefix=r"\textbf{A}: ")
    assert tex.count(r"\caption{\textbf{A}: ") == 4
    assert r"\label{tab:oslbench-feasibility}" in tex and r"\label{tab:oslbench-timing}" in tex
    # 15 designs with long ids: split into tables of consecutive designs, each within the text width
    designs = [f"lqr+design_number_{i:02d}" for i in range(15)]
    wide = pd.DataFrame({"plant": ["p_1"] * 15, "design": designs, "status": ["feasible"] * 15})
    tables = tabulars(tables_tex(wide, text_width_pt=460))
    headers = [rows[0][1:] for spec, rows in tables if rows[0][0] == "plant"]
    assert len(headers) > 1
    assert [h for head in headers for h in head] == [escape_tex(d) for d in designs]  # all, in order
    for head in headers:  # 5.6 pt a character and 12 pt a column are generous for a 10 pt font
        assert sum(len(h.replace("\\", "")) * 5.6 + 12 for head2 in [head] for h in head2) < 460
    assert tables_tex(wide).count(r"\label{tab:oslbench-feasibility}") == 1


def test_bad_frames():
    with pytest.raises(TypeError, match="frame"):
        tables_tex([{"plant": "a", "design": "b"}])
    with pytest.raises(ValueError, match="design"):
        tables_tex(pd.DataFrame({"plant": ["a"], "status": ["feasible"]}))
    with pytest.raises(ValueError, match=r"\('a', 'b'\)"):
        tables_tex(pd.DataFrame({"plant": ["a", "a"], "design": ["b", "b"], "status": ["feasible", "infeasible"]}))
    assert tables_tex(pd.DataFrame({"plant": [], "design": []})).startswith("%")


def test_cells():
    assert escape_tex(r"a_b&c%d$e#f{g}h~i^j\k") == (r"a\_b\&c\%d\$e\#f\{g\}h\textasciitilde{}i"
                                                    r"\textasciicircum{}j\textbackslash{}k")
    assert escape_tex("x+y") == "x+y"
    assert [format_cell(v) for v in (None, NAN, pd.NA, np.float64("nan"))] == [""] * 4
    assert [format_cell(v) for v in (True, False, np.bool_(False))] == ["yes", "no", "no"]
    assert format_cell(123456789) == "123456789" and format_cell(np.int64(7)) == "7"
    assert format_cell(3.14159) == "3.14" and format_cell(2.5e-11) == "2.5e-11"


def test_minimal_document(frame):
    doc = minimal_document(tables_tex(frame))
    assert doc.startswith(r"\documentclass{article}")
    assert r"\usepackage{booktabs}" in doc and "graphicx" not in doc
    assert doc.index(r"\begin{document}") < doc.index(r"\begin{table}") < doc.index(r"\end{document}")
    assert "landscape" in minimal_document("x", landscape=True)
    with pytest.raises(TypeError, match="body"):
        minimal_document(None)


def _overfull(log: str) -> list[float]:
    """The sizes (pt) of the overfull boxes pdflatex reports."""
    return [float(x) for x in re.findall(r"Overfull \\[hv]box \(([\d.]+)pt too", log)]


def _big_frame() -> pd.DataFrame:
    """The shape of the default run: 9 plants with long ids x 15 designs, every kind of cell."""
    plants = ["flexible_link", "flexible_link_printed", "random_lipschitz_v1", "moving_object_v1", "pendulum_v1",
              "chain_v1", "chua_v1", "flexible_joint_v1", "random_osl_v1"]
    designs = ["thm1", "thm1_printed", "cor1", "cor1_printed", "paper_gains", "thm1_sep", "cor1_sep", "structured",
               "thm1_scaled", "cor1_scaled", "lqr+ekf", "lqr+lqe", "lqr+rajamani", "lqr+rh_riccati", "lqr+zhang_osl"]
    statuses = ["feasible", "infeasible", "computed", "inapplicable", "marginal", "given", "undecided", "timeout"]
    levels = ["certified", "not certified", "marginal", "inapplicable", "undecided"]
    rows = []
    for i, p in enumerate(plants):
        for j, d in enumerate(designs):
            k = i * len(designs) + j
            rows.append({"plant": p, "design": d, "status": statuses[k % len(statuses)],
                         "decay_paper": 0.0155 * (k % 3), "decay_full": 1.234e-5 * k, "decay_structured": 12.3456,
                         "cert_paper": levels[k % 5], "cert_full": levels[(k + 1) % 5], "cert_structured": levels[k % 2],
                         "cert_level": "structured", "cert_scope": ["global", "from x0", "local"][k % 3],
                         "converged": k % 2 == 0, "settling_x_s": 123.456, "settling_e_s": 0.000123,
                         "peak_u": 1.5e6, "horizon_s": 200.0, "design_s": 12.3456, "cert_s": 0.0001234,
                         "sim_s": 1234.5})
    return pd.DataFrame(rows)


@pytest.mark.skipif(shutil.which("pdflatex") is None,
                    reason="pdflatex is not on PATH (Debian: apt-get install texlive-latex-base "
                           "texlive-latex-recommended); the tables were not compiled")
@pytest.mark.parametrize("which", ["fixture", "default run"])
def test_tables_standalone_compiles_without_overfull_boxes(frame, tmp_path, which):
    df = frame if which == "fixture" else _big_frame()
    (tmp_path / "tables.tex").write_text(tables_tex(df))
    (tmp_path / "tables_standalone.tex").write_text(minimal_document(r"\input{tables.tex}"))
    proc = subprocess.run(["pdflatex", "-interaction=nonstopmode", "-halt-on-error", "tables_standalone.tex"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    log = (tmp_path / "tables_standalone.log").read_text(errors="replace")
    assert proc.returncode == 0, log[-3000:]
    assert (tmp_path / "tables_standalone.pdf").stat().st_size > 0
    assert [pt for pt in _overfull(log) if pt > 10] == [], [line for line in log.splitlines() if "Overfull" in line]


def test_overfull_parser_reads_pdflatex_lines():
    log = "Overfull \\hbox (82.7pt too wide) in paragraph at lines 3--9\nOverfull \\vbox (1.5pt too high) has"
    assert _overfull(log) == [82.7, 1.5]


def test_long_frames_are_split(frame):
    tex = tables_tex(frame, max_rows=4)
    # feasibility once; decay, convergence and timing each as 2 tables: (heading + 2 rows + heading), then the rest
    assert tex.count(r"\begin{tabular}{") == 1 + 3 * 2
    assert tex.count("(continued)") >= 3
    assert tex.count(r"\label{tab:oslbench-timing}") == 1
    last = tabulars(tex)[-1][1]
    assert last[1][0].startswith(r"# random\_osl\_v1")  # a continued table starts with its plant's heading
    for _, rows in tabulars(tex):
        assert not rows[-1][0].startswith("#")  # a heading never ends a table
    with pytest.raises(ValueError, match="max_rows"):
        tables_tex(frame, max_rows=1)
