"""LaTeX (booktabs) tables of a results frame (one row per (plant, design), as ``reports/results.csv``):
:func:`tables_tex` writes the fragment, :func:`minimal_document` a document ``pdflatex`` compiles as it is.
"""

from __future__ import annotations

import numbers

import numpy as np

__all__ = ["minimal_document", "tables_tex"]

#: Short cells of the feasibility matrix (a status not listed is written as it is).
STATUS_SHORT: dict[str, str] = {
    "feasible": "yes",
    "computed": "comp",
    "unverified": "unver",
    "infeasible": "no",
    "marginal": "marg",
    "inapplicable": "n/a",
    "undecided": "undec",
    "error": "err",
    "failed": "fail",
    "timeout": "t/o",
    "diverged": "div",
}

#: Cells of a certificate level that did not certify (a certified level shows its decay rate, a status not
#: listed is written as it is).
CERT_SHORT: dict[str, str] = {
    "not certified": "no",
    "inapplicable": "n/a",
}

#: Number formats of the row tables' columns other than ``.3g``: a contraction factor per step is close to 1.
CELL_SPECS: dict[str, str] = {"contraction": ".6g"}

#: The LaTeX packages the fragment needs.
PACKAGES = ("booktabs",)

#: The text width (points) the tables are laid out for: A4 or US letter with 2 cm margins
#: (:func:`minimal_document`) give 483 and 500 pt.
TEXT_WIDTH_PT = 460.0

_ESCAPES = str.maketrans({
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
    "<": r"\textless{}",
    ">": r"\textgreater{}",
    "|": r"\textbar{}",
})

# (column, header) of the three row tables, in display order; a "\n" in a header breaks its line
_DECAY_COLUMNS = (("decay_paper", "paper"), ("decay_full", "full"), ("decay_structured", "structured"),
                  ("cert_level", "level"), ("cert_scope", "scope"), ("rate_ceiling", "ceiling"),
                  ("rate_ratio", "rate /\nceiling"))
_CONVERGENCE_COLUMNS = (("converged", "converged"), ("settling_x_s", "settling\nx [s]"),
                        ("settling_e_s", "settling\ne [s]"), ("peak_u", "peak\n|u|"),
                        ("horizon_s", "horizon\n[s]"))
_TIMING_COLUMNS = (("design_s", "design\n[s]"), ("cert_s", "certificate\n[s]"), ("sim_s", "simulation\n[s]"))
_ATTENUATION_COLUMNS = (("cert_level", "level"), ("l2_gain_e", "certified\nw to e"), ("l2_gain_x", "certified\nw to x"),
                        ("l2_measured_e", "measured\nw to e"), ("l2_measured_x", "measured\nw to x"),
                        ("l2_radius", "region\nr"))
_DISCRETE_COLUMNS = (("dt", "dt [s]"), ("cert_level", "level"), ("contraction", "r per\nstep"),
                     ("decay_rate", "rate\n[1/s]"), ("rate_ceiling", "ceiling\n[1/s]"), ("cert_scope", "scope"))

#: Width estimates (points) of the default 10 pt font: per character of a cell, and per column
#: (``2 \tabcolsep``); generous, so that an estimate that fits does fit.
_CHAR_PT = 5.6
_COLSEP_PT = 12.0


def escape_tex(text) -> str:
    """Escape LaTeX's special characters (``\\ & % $ # _ { } ~ ^ < > |``) in ``str(text)``, in one pass."""
    return str(text).translate(_ESCAPES)


def _is_missing(value) -> bool:
    """None, NaN, ``pd.NA`` or ``pd.NaT``."""
    import pandas as pd

    return pd.api.types.is_scalar(value) and bool(pd.isna(value))


def plain_cell(value, spec: str = ".3g") -> str:
    """One table cell as plain text: blank for None/NaN/``pd.NA``, yes/no for a bool, an integer in full,
    another real formatted with ``spec``, anything else with ``str``.
    """
    if _is_missing(value):
        return ""
    if isinstance(value, (bool, np.bool_)):
        return "yes" if value else "no"
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        return format(float(value), spec)
    return str(value)


def format_cell(value) -> str:
    """One table cell as escaped LaTeX text (:func:`plain_cell`)."""
    return escape_tex(plain_cell(value))


def _head(text: str) -> str:
    """A header cell: escaped, with a line break at each ``"\n"`` (a one-column tabular: no package)."""
    lines = [escape_tex(t) for t in text.split("\n")]
    if len(lines) == 1:
        return lines[0]
    return r"\begin{tabular}[b]{@{}c@{}}" + r"\\{}".join(lines) + r"\end{tabular}"  # {}: "[s]" is no \\[length]


def _width(cells) -> float:
    """Estimated width in points of a column holding ``cells`` (plain texts, before escaping)."""
    longest = max((max(len(line) for line in str(c).split("\n")) for c in cells), default=0)
    return longest * _CHAR_PT + _COLSEP_PT


def _tabular(spec: str, header: list[str], rows: list) -> str:
    """A booktabs ``tabular``; a row None is an ``\\addlinespace``, a row str a full-width group heading."""
    ncol = len(spec)
    lines = [rf"\begin{{tabular}}{{{spec}}}", r"\toprule", " & ".join(header) + r" \\", r"\midrule"]
    for row in rows:
        if row is None:
            lines.append(r"\addlinespace")
        elif isinstance(row, str):
            lines.append(rf"\multicolumn{{{ncol}}}{{@{{}}l}}{{\emph{{{row}}}}} \\")
        else:
            lines.append(" & ".join(row) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    return "\n".join(lines)


def _table(tabular: str, caption: str, label: str | None) -> str:
    """A ``table`` float around a tabular, at the text's own size (never scaled)."""
    lines = [r"\begin{table}[htbp]", r"\centering", tabular, rf"\caption{{{caption}}}"]
    if label:
        lines.append(rf"\label{{{label}}}")
    return "\n".join(lines + [r"\end{table}"])


def level_cell(rec: dict, col: str) -> str:
    """A row table's cell as plain text (:func:`plain_cell`); a ``decay_<level>`` cell whose level did not
    certify shows the level's status in short instead (:data:`CERT_SHORT`)."""
    status = rec.get(f"cert_{col.removeprefix('decay_')}") if col.startswith("decay_") else None
    if _is_missing(status) or status in ("", "certified"):
        return plain_cell(rec[col], CELL_SPECS.get(col, ".3g"))
    return CERT_SHORT.get(str(status), str(status))


def _row_table(frame, columns, caption: str, label: str, *, max_rows: int) -> str | None:
    """Tables of one row per pair under a heading per plant, split every ``max_rows`` lines ("(continued)")."""
    present = [(col, head) for col, head in columns if col in frame.columns]
    if not present:
        return None
    spec = "l" + "".join("l" if col in ("cert_level", "cert_scope") else "r" for col, _ in present)
    header = ["design"] + [_head(head) for _, head in present]
    tables: list[list] = []  # the rows of each table; a plant's heading counts as a line, a continued one not
    used, previous = 0, None
    for rec in frame.to_dict("records"):
        plant = format_cell(rec["plant"])
        heading = plant != previous
        previous = plant
        if not tables or used + heading + 1 > max_rows:  # a heading never ends a table
            tables.append([] if heading else [plant + " (continued)"])
            used = 0
        if heading:
            tables[-1] += [None, plant] if tables[-1] else [plant]
        tables[-1].append([format_cell(rec["design"])] + [escape_tex(level_cell(rec, col)) for col, _ in present])
        used += heading + 1
    return "\n\n".join(_table(_tabular(spec, header, rows), caption + (" (continued)" if k else ""),
                               None if k else label) for k, rows in enumerate(tables))


def tables_tex(frame, *, caption_prefix: str = "", label_prefix: str = "tab:oslbench-", max_rows: int = 40,
               text_width_pt: float = TEXT_WIDTH_PT) -> str:
    r"""Booktabs tables of a results frame, as a LaTeX fragment that needs only ``booktabs``.

    The tables, each left out when the frame has none of its columns: feasibility (plant x design
    matrix of ``status``, :data:`STATUS_SHORT`, split by designs when wider than ``text_width_pt``);
    certified decay by level (``decay_paper``, ``decay_full``, ``decay_structured``, else ``decay_rate``;
    a level that did not certify shows its status, :data:`CERT_SHORT`) with ``cert_level`` and
    ``cert_scope``; convergence; timing; the L2 gains (certified ``l2_gain_e``, ``l2_gain_x`` beside the measured
    ``l2_measured_e``, ``l2_measured_x``, rows with one of them); the certified discrete-time pairs (``contraction``
    per step and ``decay_rate`` per second). The tables are set at the text's own size: too wide or too long ones
    are split, never scaled.

    Parameters
    ----------
    frame : pandas.DataFrame
        One row per (plant, design) pair with at least the columns ``plant`` and ``design``.
    caption_prefix : str
        Put before every caption, verbatim (LaTeX).
    label_prefix : str
        Prefix of each table's ``\label`` (``feasibility``, ``decay``, ``convergence``, ``timing``, ``attenuation``,
        ``discrete`` follow).
    max_rows : int
        Lines per row table (a plant's heading counts); longer frames are split.
    text_width_pt : float
        The text width the feasibility matrix must fit.

    Returns
    -------
    str
        The fragment (a LaTeX comment only, when the frame has no rows).

    Raises
    ------
    TypeError
        If ``frame`` is not a DataFrame.
    ValueError
        A missing ``plant`` or ``design`` column, two rows for one pair, or ``max_rows < 2``.
    """
    _check_frame(frame, max_rows)
    if frame.empty:
        return "% tables_tex: the results frame has no rows\n"
    frame = frame.reset_index(drop=True)
    parts = [_preamble_comment(text_width_pt)]
    if "status" in frame.columns:
        parts.append(_feasibility_tables(frame, caption_prefix, f"{label_prefix}feasibility", text_width_pt))
    decay = _DECAY_COLUMNS
    if not any(c in frame.columns for c, _ in _DECAY_COLUMNS[:3]):
        decay = (("decay_rate", "decay rate"),) + _DECAY_COLUMNS[3:] if "decay_rate" in frame.columns else ()
    for columns, caption, key in (
        (decay, r"Certified decay rate $\lambda$ ($\dot V \le -2\lambda V$) by certificate level; no: not certified, "
                "marginal: margin within the verification tolerance of zero, n/a: the level does not apply; scope: "
                "global, from x0 (the certified level set holds the initial condition) or local.", "decay"),
        (_CONVERGENCE_COLUMNS, "Convergence of the closed loop (settling times of the state x and of the "
                               "estimation error e).", "convergence"),
        (_TIMING_COLUMNS, "Wall-clock time of the design, the certificate and the simulation.", "timing"),
    ):
        parts.append(_row_table(frame, columns, caption_prefix + caption, f"{label_prefix}{key}",
                                max_rows=int(max_rows)))
    for sub, columns, caption, key in (
        (_with_any(frame, ("l2_gain_e", "l2_gain_x", "l2_measured_e", "l2_measured_x")), _ATTENUATION_COLUMNS,
         "L2 gains from the disturbance w: certified by the strongest certified level (bounded real lemma over its "
         "class) and measured from $z(0) = 0$ ($\\|\\zeta\\|_{L_2} / \\|w\\|_{L_2}$); region r: the gains hold "
         "while $\\|x\\|, \\|\\hat x\\| \\le r$ (blank: globally).", "attenuation"),
        (_with_any(frame, ("contraction",)), _DISCRETE_COLUMNS,
         "Certified discrete-time pairs: $V(z_{k+1}) \\le r^2 V(z_k)$ with the contraction factor r per step and the "
         "rate $-\\ln(r) / dt$ per second.", "discrete"),
    ):
        if sub is not None and len(sub):
            parts.append(_row_table(sub, columns, caption_prefix + caption, f"{label_prefix}{key}",
                                    max_rows=int(max_rows)))
    return "\n\n".join(p for p in parts if p) + "\n"


def _with_any(frame, columns):
    """The rows of ``frame`` with a number in one of ``columns`` (None when it has none of them)."""
    import pandas as pd

    present = [c for c in columns if c in frame.columns]
    if not present:
        return None
    return frame[frame[present].apply(pd.to_numeric, errors="coerce").notna().any(axis=1)]


def _preamble_comment(text_width_pt: float) -> str:
    needs = ", ".join(r"\usepackage{" + p + "}" for p in PACKAGES)
    return "\n".join([
        "% oslbench tables (bench.latex.tables_tex).",
        f"% Needs: {needs}.",
        f"% Laid out for a text width of at least {text_width_pt:g} pt (A4 or letter paper with 2 cm margins), "
        "at the text's own size.",
        "% tables_standalone.tex beside this file compiles it as it is: pdflatex tables_standalone.tex",
    ])


def _check_frame(frame, max_rows) -> None:
    """TypeError or ValueError unless ``frame`` is a DataFrame with one row per pair and ``max_rows >= 2``."""
    import pandas as pd

    if not isinstance(frame, pd.DataFrame):
        raise TypeError(f"frame: expected a pandas DataFrame, got {type(frame).__name__}")
    missing = [c for c in ("plant", "design") if c not in frame.columns]
    if missing:
        raise ValueError(f"frame: missing column(s) {missing}; need one row per (plant, design) pair, "
                         f"got columns {list(frame.columns)}")
    dup = frame.duplicated(["plant", "design"])
    if dup.any():
        first = frame.loc[dup, ["plant", "design"]].iloc[0].tolist()
        raise ValueError(f"frame: more than one row for the pair (plant, design) = {tuple(first)}; "
                         "tables_tex needs one row per pair")
    if isinstance(max_rows, bool) or not isinstance(max_rows, numbers.Integral) or max_rows < 2:
        raise ValueError(f"max_rows: expected an integer >= 2 (a plant's heading and a row), got {max_rows!r}")


def _feasibility_tables(frame, caption_prefix: str, label: str, text_width_pt: float) -> str:
    """The plant x design matrix of ``status`` with a legend, split by designs to fit ``text_width_pt``."""
    import pandas as pd

    plants = list(pd.unique(frame["plant"]))
    designs = list(pd.unique(frame["design"]))
    cells = {(r["plant"], r["design"]): r["status"] for r in frame.to_dict("records")}
    shown = {d: [cells.get((p, d)) for p in plants] for d in designs}  # None: not run
    used = {str(st) for col in shown.values() for st in col if not _is_missing(st)}
    short = {d: ["" if _is_missing(st) else STATUS_SHORT.get(str(st), str(st)) for st in col]
             for d, col in shown.items()}
    legend = ", ".join(f"{escape_tex(STATUS_SHORT[s])} = {escape_tex(s)}"
                       for s in STATUS_SHORT if s in used and STATUS_SHORT[s] != s)
    room = text_width_pt - _width(["plant", *plants])
    widths = {d: _width([d] + short[d]) for d in designs}
    groups: list[list] = [[]]
    for d in designs:
        if groups[-1] and sum(widths[g] for g in groups[-1]) + widths[d] > room:
            groups.append([])
        groups[-1].append(d)
    parts = []
    for k, group in enumerate(groups):
        rows = [[format_cell(p)] + [escape_tex(short[d][i]) for d in group] for i, p in enumerate(plants)]
        part = f", designs {designs.index(group[0]) + 1}-{designs.index(group[-1]) + 1} of {len(designs)}"
        caption = (caption_prefix + "Feasibility of each design on each plant" + (part if len(groups) > 1 else "")
                   + (f" ({legend})." if legend else "."))
        tab = _tabular("l" + "c" * len(group), ["plant"] + [format_cell(d) for d in group], rows)
        parts.append(_table(tab, caption, label if k == 0 else None))
    return "\n\n".join(parts)


def minimal_document(body: str, *, landscape: bool = False) -> str:
    r"""Wrap a fragment in a minimal compilable document (article, :data:`PACKAGES`, 2 cm margins).

    Parameters
    ----------
    body : str
        LaTeX between ``\begin{document}`` and ``\end{document}`` (e.g. ``r"\input{tables.tex}"``).
    landscape : bool
        Landscape pages, for wide feasibility matrices.

    Returns
    -------
    str

    Raises
    ------
    TypeError
        If ``body`` is not a string.
    """
    if not isinstance(body, str):
        raise TypeError(f"body: expected a str of LaTeX, got {type(body).__name__}")
    geometry = "margin=2cm,landscape" if landscape else "margin=2cm"
    return "\n".join([
        r"\documentclass{article}",
        r"\usepackage{" + ",".join(PACKAGES) + "}",
        rf"\usepackage[{geometry}]{{geometry}}",
        r"\begin{document}",
        body.rstrip("\n"),
        r"\end{document}",
        "",
    ])
