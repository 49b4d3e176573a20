"""bench.latex: booktabs tables of a results frame (structure, escaping, and a pdflatex build when available)."""

from __future__ import annotations

import math
import re
import shutil
import subprocess

import numpy as np
import pandas as pd
import pytest

from bench.latex import escape_tex, format_cell, minimal_document, tables_tex

NAN = math.nan


@pytest.fixture
def frame() -> pd.DataFrame:
    """Two plants with underscores, a design with '+', a status with specials, NaNs and bools."""
    rows = [
        # plant, design, status, decay_paper, decay_full, decay_structured, cert_level, converged,
        # settling_x_s, settling_e_s, peak_u, horizon_s, design_s, cert_s, sim_s
        ("flexible_link", "thm1", "feasible", 0.0151694, 0.02, NAN, "full", True, 2.75, 1.18, 81.0286, 20.0,
         0.2359, 0.2195, 0.197),
        ("flexible_link", "lqr+rh_riccati", "infeasible", NAN, NAN, NAN, NAN, False, NAN, NAN, 1.5e6, 20.0,
         1.0, NAN, 3.0),
        ("random_osl_v1", "thm1", "timeout", NAN, NAN, 0.5, "structured", np.bool_(True), 12.0, 3.0, 2.0, 20,
         100.0, 2.0, 1e-4),
        ("random_osl_v1", "weird_{#1}", "odd 50%_&$~^\\", NAN, 1.0, NAN, "a_b", True, 1.0, 1.0, 1.0, 20.0,
         1.0, 1.0, 1.0),
    ]
    cols = ["plant", "design", "status", "decay_paper", "decay_full", "decay_structured", "cert_level",
            "converged", "settling_x_s", "settling_e_s", "peak_u", "horizon_s", "design_s", "cert_s", "sim_s"]
    return pd.DataFrame(rows, columns=cols)


def tabulars(tex: str) -> list[tuple[str, list[list[str]]]]:
    """(column spec, rows split at unescaped '&') of every tabular; asserts begin/end pair up."""
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
            assert len(row) == len(spec), (spec, row)
    # environments nest: no table ends before its tabular
    for b, e in zip(re.finditer(r"\\begin\{table\}", tex), re.finditer(r"\\end\{table\}", tex)):
        chunk = tex[b.start():e.start()]
        assert chunk.count(r"\begin{tabular}") == chunk.count(r"\end{tabular}") == 1


def test_feasibility_matrix(frame):
    spec, rows = tabulars(tables_tex(frame))[0]
    assert spec == "l" + "c" * 3  # three distinct designs
    header, body = rows[0], rows[1:]
    assert header == ["plant", "thm1", r"lqr+rh\_riccati", r"weird\_\{\#1\}"]
    assert body[0] == [r"flexible\_link", "yes", "no", ""]  # a pair not run is blank
    assert body[1][:2] == [r"random\_osl\_v1", "t/o"]
    assert body[1][2] == ""
    assert body[1][3] == r"odd 50\%\_\&\$\textasciitilde{}\textasciicircum{}\textbackslash{}"


def test_row_tables_format_and_escape(frame):
    tex = tables_tex(frame)
    (_, decay), (_, conv), (_, timing) = [t for t in tabulars(tex)[1:]]
    assert decay[0] == ["plant", "design", "paper", "full", "structured", "level"]
    assert decay[1] == [r"flexible\_link", "thm1", "0.0152", "0.02", "", "full"]  # NaN blank, .3g
    assert decay[2] == ["", r"lqr+rh\_riccati", "", "", "", ""]  # plant shown once per group
    assert decay[4][1] == r"weird\_\{\#1\}" and decay[4][-1] == r"a\_b"
    assert [r[2] for r in conv[1:]] == ["yes", "no", "yes", "yes"]  # bools (also numpy bools)
    assert conv[2][5] == "1.5e+06"
    assert conv[3][6] == "20"  # an integer column value stays an integer
    assert timing[0] == ["plant", "design", "design [s]", "certificate [s]", "simulation [s]"]
    assert timing[3][4] == "0.0001"
    # no raw special character left in any cell
    for _, rows in tabulars(tex):
        for row in rows:
            for cell in row:
                stripped = re.sub(r"\\(textbackslash|textasciitilde|textasciicircum|textless|textgreater|textbar)\{\}"
                                  r"|\\[&%$#_{}]", "", cell)
                assert not re.search(r"[&%$#_{}~^\\]", stripped), cell


def test_missing_columns_are_skipped(frame):
    tex = tables_tex(frame[["plant", "design", "status", "sim_s", "converged"]])
    assert tex.count(r"\begin{tabular}") == 3  # feasibility, convergence (1 column), timing
    assert "settling x [s]" not in tex and "Certified decay" not in tex
    conv = tabulars(tex)[1][1]
    assert conv[0] == ["plant", "design", "converged"]
    only_ids = tables_tex(frame[["plant", "design"]])
    assert r"\begin{tabular}" not in only_ids
    # the current results.csv has decay_rate but no per-level columns: fall back to it
    legacy = frame[["plant", "design", "cert_level"]].assign(decay_rate=[0.015, NAN, 0.5, 1.0])
    spec, rows = tabulars(tables_tex(legacy))[0]
    assert rows[0] == ["plant", "design", "decay rate", "level"] and rows[1][2] == "0.015"


def test_caption_prefix_label_and_wide_matrix(frame):
    tex = tables_tex(frame, caption_prefix=r"\textbf{A}: ")
    assert tex.count(r"\caption{\textbf{A}: ") == 4
    assert r"\label{tab:oslbench-feasibility}" in tex and r"\label{tab:oslbench-timing}" in tex
    assert r"\resizebox" not in tex.split(r"\end{table}")[0]  # 3 designs: not scaled
    wide = pd.DataFrame({"plant": ["p_1"] * 8, "design": [f"d{i}" for i in range(8)], "status": ["feasible"] * 8})
    assert r"\resizebox{\textwidth}{!}{" in tables_tex(wide)


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
    assert r"\usepackage{booktabs,graphicx}" in doc
    assert doc.index(r"\begin{document}") < doc.index(r"\begin{table}") < doc.index(r"\end{document}")
    assert "landscape" in minimal_document("x", landscape=True)
    with pytest.raises(TypeError, match="body"):
        minimal_document(None)


@pytest.mark.skipif(shutil.which("pdflatex") is None, reason="pdflatex is not on PATH")
@pytest.mark.parametrize("landscape", [False, True])
def test_pdflatex_compiles(frame, tmp_path, landscape):
    wide = pd.concat([frame, pd.DataFrame({"plant": ["p_3"] * 9, "design": [f"lqr+d_{i}" for i in range(9)],
                                           "status": ["error"] * 9})], ignore_index=True)
    (tmp_path / "tables.tex").write_text(minimal_document(tables_tex(wide), landscape=landscape))
    proc = subprocess.run(["pdflatex", "-interaction=nonstopmode", "-halt-on-error", "tables.tex"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout[-3000:]
    assert (tmp_path / "tables.pdf").stat().st_size > 0


def test_long_frames_are_split(frame):
    tex = tables_tex(frame, max_rows=3)
    # feasibility once; decay, convergence and timing each as 3 + 1 rows
    assert tex.count(r"\begin{tabular}") == 1 + 3 * 2
    assert tex.count("(continued)") == 3
    assert tex.count(r"\label{tab:oslbench-timing}") == 1
    last = tabulars(tex)[-1][1]
    assert last[1][0] == r"random\_osl\_v1"  # the plant is repeated at the top of a continued table
    with pytest.raises(ValueError, match="max_rows"):
        tables_tex(frame, max_rows=0)
