"""LaTeX (booktabs) tables of a results frame, for papers.

:func:`tables_tex` turns the results table (one row per (plant, design) pair, as
``reports/results.csv``) into four ``table`` environments: feasibility (a plant x design matrix
of ``status``), certified decay by certificate level, convergence and timing. Columns that are
missing are skipped; a table with none of its value columns is left out. Every cell is escaped;
numbers are written like ``.3g``, booleans as yes/no, NaN as a blank cell.
:func:`minimal_document` wraps the fragment in a compilable document.
"""

from __future__ import annotations

import math
import numbers
import re

import numpy as np

__all__ = ["STATUS_SHORT", "escape_tex", "format_cell", "minimal_document", "tables_tex"]

#: Short cells of the feasibility matrix (a status not listed is written as it is).
STATUS_SHORT: dict[str, str] = {
    "feasible": "yes",
    "infeasible": "no",
    "inapplicable": "n/a",
    "error": "err",
    "failed": "fail",
    "timeout": "t/o",
    "diverged": "div",
}

_ESCAPES = {
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
}
_ESCAPE_RE = re.compile("|".join(re.escape(c) for c in _ESCAPES))

# (column, header) of the three row tables, in display order
_DECAY_COLUMNS = (("decay_paper", "paper"), ("decay_full", "full"), ("decay_structured", "structured"),
                  ("cert_level", "level"), ("rate_ceiling", "ceiling"), ("rate_ratio", "rate / ceiling"))
_CONVERGENCE_COLUMNS = (("converged", "converged"), ("settling_x_s", "settling x [s]"),
                        ("settling_e_s", "settling e [s]"), ("peak_u", "peak u"),
                        ("horizon_s", "horizon [s]"))
_TIMING_COLUMNS = (("design_s", "design [s]"), ("cert_s", "certificate [s]"), ("sim_s", "simulation [s]"))


def escape_tex(text) -> str:
    """Escape LaTeX's special characters in plain text.

    Parameters
    ----------
    text : object
        Converted with ``str``.

    Returns
    -------
    str
        ``\\ & % $ # _ { } ~ ^`` (and ``< > |``, which the default OT1 font encoding would
        misprint) replaced by their text-mode commands, in one pass so that a replacement is
        never escaped again.

    Examples
    --------
    >>> escape_tex("lqr+rh_riccati 5% & $x$")
    'lqr+rh\\\\_riccati 5\\\\% \\\\& \\\\$x\\\\$'
    """
    return _ESCAPE_RE.sub(lambda m: _ESCAPES[m.group(0)], str(text))


def _is_missing(value) -> bool:
    """None, NaN, ``pd.NA`` or ``pd.NaT``."""
    if value is None:
        return True
    try:
        import pandas as pd

        if value is pd.NA or value is pd.NaT:
            return True
    except ImportError:  # pragma: no cover - pandas is a dependency
        pass
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_)) and math.isnan(value)


def format_cell(value) -> str:
    """One table cell as escaped LaTeX text.

    Parameters
    ----------
    value : object
        None, NaN or ``pd.NA`` give a blank cell; a bool gives ``yes``/``no``; an integer is
        written in full; another real number like ``.3g``; anything else with ``str``.

    Returns
    -------
    str
        The escaped cell.

    Examples
    --------
    >>> [format_cell(v) for v in (float("nan"), True, 12, 0.0151694, "a_b")]
    ['', 'yes', '12', '0.0152', 'a\\\\_b']
    """
    if _is_missing(value):
        return ""
    if isinstance(value, (bool, np.bool_)):
        return "yes" if value else "no"
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        return escape_tex(f"{float(value):.3g}")
    return escape_tex(value)


def _tabular(spec: str, header: list[str], rows: list[list[str]]) -> str:
    """A booktabs ``tabular``; a row None is an ``\\addlinespace``."""
    lines = [rf"\begin{{tabular}}{{{spec}}}", r"\toprule", " & ".join(header) + r" \\", r"\midrule"]
    lines += [r"\addlinespace" if row is None else " & ".join(row) + r" \\" for row in rows]
    lines += [r"\bottomrule", r"\end{tabular}"]
    return "\n".join(lines)


def _table(tabular: str, caption: str, label: str | None, *, wide: bool) -> str:
    """A ``table`` float around a tabular: scaled to the text width when wide, else ``\\small``."""
    if wide:
        body = "\\resizebox{\\textwidth}{!}{%\n" + tabular + "%\n}"
    else:
        body = "\\small\n" + tabular
    lines = [r"\begin{table}[htbp]", r"\centering", body, rf"\caption{{{caption}}}"]
    if label:
        lines.append(rf"\label{{{label}}}")
    return "\n".join(lines + [r"\end{table}"])


def _row_table(frame, columns, caption: str, label: str, *, max_rows: int, wide_after: int = 7) -> str | None:
    """One table (several when longer than ``max_rows``: continued, the label on the first)."""
    present = [(col, head) for col, head in columns if col in frame.columns]
    if not present:
        return None
    spec = "ll" + "".join("l" if col in ("cert_level",) else "r" for col, _ in present)
    header = ["plant", "design"] + [escape_tex(head) for _, head in present]
    records = frame.to_dict("records")
    parts = []
    for start in range(0, len(records), max_rows):
        rows, previous = [], None
        for rec in records[start:start + max_rows]:
            plant = format_cell(rec["plant"])
            if previous is not None and plant != previous:
                rows.append(None)  # \addlinespace between plants
            rows.append([plant if plant != previous else "", format_cell(rec["design"])]
                        + [format_cell(rec[col]) for col, _ in present])
            previous = plant
        cap = caption if start == 0 else caption + " (continued)"
        parts.append(_table(_tabular(spec, header, rows), cap, label if start == 0 else None,
                            wide=len(spec) > wide_after))
    return "\n\n".join(parts)


def tables_tex(frame, *, caption_prefix: str = "", label_prefix: str = "tab:oslbench-", max_rows: int = 40) -> str:
    r"""Booktabs tables of a results frame, as a LaTeX fragment.

    Four ``table`` environments, each left out when the frame has none of its value columns:

    1. feasibility: plant x design matrix of ``status`` (short cells, see :data:`STATUS_SHORT`;
       a pair that was not run is blank);
    2. certified decay by certificate level: ``decay_paper``, ``decay_full``,
       ``decay_structured``, ``cert_level`` (or ``decay_rate`` when none of the first three is
       in the frame), ``rate_ceiling`` (the slowest linear member of the certified class: no
       certificate over it proves more) and ``rate_ratio`` (the certified rate over it);
    3. convergence: ``converged``, ``settling_x_s``, ``settling_e_s``, ``peak_u``, ``horizon_s``;
    4. timing: ``design_s``, ``cert_s``, ``sim_s``.

    Tables wider than a few columns are scaled to ``\textwidth`` with ``\resizebox`` (graphicx);
    the others are set ``\small``. The fragment needs ``booktabs`` and ``graphicx``.

    Parameters
    ----------
    frame : pandas.DataFrame
        One row per (plant, design) pair with at least the columns ``plant`` and ``design``
        (e.g. ``pd.read_csv("reports/results.csv")``).
    caption_prefix : str
        Put before every caption, verbatim (it is LaTeX: escape plain text with
        :func:`escape_tex`).
    label_prefix : str
        Prefix of the ``\label`` of each table (``feasibility``, ``decay``, ``convergence``,
        ``timing`` follow it).
    max_rows : int
        Rows per table of the decay, convergence and timing tables: a longer frame is split into
        several tables (captions "(continued)"), since a float cannot break across pages.

    Returns
    -------
    str
        The fragment (a LaTeX comment only, when the frame has no rows).

    Raises
    ------
    TypeError
        If ``frame`` is not a DataFrame.
    ValueError
        If ``frame`` lacks the column ``plant`` or ``design``, or has two rows for one pair, or
        ``max_rows < 1``.

    Examples
    --------
    >>> import pandas as pd
    >>> df = pd.DataFrame({"plant": ["flexible_link"], "design": ["thm1"], "status": ["feasible"],
    ...                    "design_s": [0.236]})
    >>> print(minimal_document(tables_tex(df)))  # doctest: +SKIP
    """
    _check_frame(frame, max_rows)
    if frame.empty:
        return "% tables_tex: the results frame has no rows\n"
    frame = frame.reset_index(drop=True)
    parts = []
    if "status" in frame.columns:
        parts.append(_feasibility_table(frame, caption_prefix, f"{label_prefix}feasibility"))
    decay = _DECAY_COLUMNS
    if not any(c in frame.columns for c, _ in _DECAY_COLUMNS[:3]):
        decay = (("decay_rate", "decay rate"),) + _DECAY_COLUMNS[3:]
    table = _row_table(frame, decay, caption_prefix + "Certified decay rate by certificate level "
                                                       "(blank: not certified at that level).",
                       f"{label_prefix}decay", max_rows=int(max_rows))
    if table and any(c in frame.columns for c, _ in decay if c != "cert_level"):
        parts.append(table)
    for columns, caption, key in (
        (_CONVERGENCE_COLUMNS, "Convergence of the closed loop (settling times of the state x and of the "
                               "estimation error e).", "convergence"),
        (_TIMING_COLUMNS, "Wall-clock time of the design, the certificate and the simulation.", "timing"),
    ):
        table = _row_table(frame, columns, caption_prefix + caption, f"{label_prefix}{key}", max_rows=int(max_rows))
        if table:
            parts.append(table)
    return "\n\n".join(parts) + "\n"


def _check_frame(frame, max_rows) -> None:
    """TypeError or ValueError unless ``frame`` is a DataFrame with one row per (plant, design) and
    ``max_rows`` an integer >= 1 (the messages of :func:`tables_tex`)."""
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
    if isinstance(max_rows, bool) or not isinstance(max_rows, numbers.Integral) or max_rows < 1:
        raise ValueError(f"max_rows: expected an integer >= 1, got {max_rows!r}")


def _short_status(status) -> str:
    """A feasibility cell: the short form of ``status`` (:data:`STATUS_SHORT`), escaped; blank when missing."""
    if _is_missing(status):
        return ""
    return escape_tex(STATUS_SHORT.get(str(status), str(status)))


def _feasibility_table(frame, caption_prefix: str, label: str) -> str:
    """The plant x design matrix of ``status``, with a legend of the short cells it uses."""
    import pandas as pd

    plants = list(pd.unique(frame["plant"]))
    designs = list(pd.unique(frame["design"]))
    cells = {(r["plant"], r["design"]): r["status"] for r in frame.to_dict("records")}
    shown = [[cells[(p, d)] if (p, d) in cells else None for d in designs] for p in plants]  # None: not run
    rows = [[format_cell(p)] + [_short_status(status) for status in row] for p, row in zip(plants, shown)]
    used = {str(status) for row in shown for status in row if not _is_missing(status)}
    legend = ", ".join(f"{escape_tex(STATUS_SHORT[s])} = {escape_tex(s)}"
                       for s in STATUS_SHORT if s in used and STATUS_SHORT[s] != s)
    caption = caption_prefix + "Feasibility of each design on each plant" + (f" ({legend})." if legend else ".")
    tab = _tabular("l" + "c" * len(designs), ["plant"] + [format_cell(d) for d in designs], rows)
    return _table(tab, caption, label, wide=len(designs) > 5)


def minimal_document(body: str, *, landscape: bool = False) -> str:
    r"""Wrap a fragment (e.g. from :func:`tables_tex`) in a minimal compilable LaTeX document.

    Parameters
    ----------
    body : str
        LaTeX to put between ``\begin{document}`` and ``\end{document}``.
    landscape : bool
        Landscape pages (geometry's ``landscape`` option), for wide feasibility matrices.

    Returns
    -------
    str
        ``\documentclass{article}`` with booktabs, graphicx and geometry (2 cm margins).

    Raises
    ------
    TypeError
        If ``body`` is not a string.

    Examples
    --------
    >>> print(minimal_document("Hello").splitlines()[0])
    \documentclass{article}
    """
    if not isinstance(body, str):
        raise TypeError(f"body: expected a str of LaTeX, got {type(body).__name__}")
    geometry = "margin=2cm,landscape" if landscape else "margin=2cm"
    return "\n".join([
        r"\documentclass{article}",
        r"\usepackage{booktabs,graphicx}",
        rf"\usepackage[{geometry}]{{geometry}}",
        r"\begin{document}",
        body.rstrip("\n"),
        r"\end{document}",
        "",
    ])
