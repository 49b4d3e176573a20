"""report.html: a report folder's results as one self-contained page (inline CSS and JavaScript, figures as data
URIs: it works offline and from a copy of the one file).

The page is made of what the report already rendered, so that it follows the report without knowing its
sections or columns: REPORT.md's sections (headings, paragraphs, lists, tables and figures; the subset of
markdown :func:`bench.report.render_markdown` writes), opening with "What the suite found", and results.csv
as the table "Results by pair", one row per pair with every column, each row opening onto the pair's details
(the full ``details`` text, the gains K and F and each level of its certificate, from gains.json).

Every table can be sorted (click a header: ascending, again descending; a column whose cells are all numbers
or blank sorts as numbers, blanks last) and filtered (a text box per table: the rows holding every word typed).
The URL's fragment does the same on load and when it changes: ``#filter=thm1`` filters every table,
``sort=decay_rate`` (``order=desc``, or ``sort=-decay_rate``) sorts every table with that column, and
``table=results`` restricts both to one table (by id: ``results``, or the section's heading in lower case with
dashes, e.g. ``convergence``); e.g. ``report.html#table=results&filter=thm1&sort=decay_rate&order=desc``.
Every value is escaped: a plant id, a reason or a parameter holding ``< > & "`` is text, never markup.
"""

from __future__ import annotations

import base64
import html
import math
import re
from pathlib import Path

__all__ = ["parse_markdown", "render_html"]

#: The section that opens the page (REPORT.md's first screen).
FIRST_SECTION = "What the suite found"
#: The id of the results table.
RESULTS_ID = "results"
#: A matrix with more entries is not printed (gains.json holds it).
MATRIX_ENTRIES = 400


def _esc(text) -> str:
    return html.escape(str(text), quote=True)


# -- markdown (the subset REPORT.md uses) -------------------------------------------------------------
def _cells(line: str) -> list[str]:
    """The cells of a markdown table row (``\\|`` is a literal bar)."""
    body = line.strip()
    body = body[1:] if body.startswith("|") else body
    body = body[:-1] if body.endswith("|") and not body.endswith("\\|") else body
    return [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", body)]


def parse_markdown(text: str) -> list[tuple]:
    """REPORT.md as blocks: ``("h", level, text)``, ``("p", text)``, ``("list", [(depth, text), ...])``,
    ``("table", header, rows)`` and ``("img", caption, path)``, in order."""
    lines = text.splitlines()
    blocks: list[tuple] = []
    i = 0
    while i < len(lines):
        line = lines[i]
        if not line.strip():
            i += 1
            continue
        m = re.match(r"(#{1,6}) +(.*)$", line)
        if m:
            blocks.append(("h", len(m.group(1)), m.group(2).strip()))
            i += 1
            continue
        if line.lstrip().startswith("|"):
            rows = []
            while i < len(lines) and lines[i].lstrip().startswith("|"):
                rows.append(lines[i])
                i += 1
            cells = [_cells(r) for r in rows]
            sep = len(cells) > 1 and all(re.fullmatch(r":?-+:?", c) for c in cells[1])
            blocks.append(("table", cells[0], cells[2:] if sep else cells[1:]))
            continue
        m = re.match(r"!\[(.*)\]\((.*)\)\s*$", line.strip())
        if m:
            blocks.append(("img", m.group(1), m.group(2)))
            i += 1
            continue
        if re.match(r"\s*- ", line):
            items: list[list] = []
            while i < len(lines) and lines[i].strip() and not lines[i].lstrip().startswith(("|", "#")):
                m = re.match(r"(\s*)- (.*)$", lines[i])
                if m:
                    items.append([len(m.group(1)) // 2, m.group(2)])
                elif items:  # an indented continuation of the item above
                    items[-1][1] += "\n" + lines[i].strip()
                i += 1
            blocks.append(("list", [tuple(x) for x in items]))
            continue
        para = []
        while i < len(lines) and lines[i].strip() and not re.match(r"(#{1,6} |\s*\||\s*- |!\[)", lines[i]):
            para.append(lines[i].strip())
            i += 1
        blocks.append(("p", " ".join(para)))
    return blocks


def _inline(text: str) -> str:
    """Markdown inline text as HTML: escaped, with `code`, **bold** and *emphasis*."""
    parts = re.split(r"(`[^`]*`)", text.replace("\\|", "|"))
    out = []
    for part in parts:
        if len(part) >= 2 and part.startswith("`") and part.endswith("`"):
            out.append(f"<code>{_esc(part[1:-1])}</code>")
            continue
        s = _esc(part)
        s = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", s)
        s = re.sub(r"(?<![\w*])\*([^*\s](?:[^*]*?[^*\s])?)\*(?![\w*])", r"<em>\1</em>", s)
        out.append(s)
    return "".join(out).replace("\n", "<br>")


def _list_html(items: list[tuple[int, str]]) -> str:
    out, depth = ["<ul>"], 0
    for k, (d, text) in enumerate(items):
        d = min(d, depth + 1) if k else 0
        while depth < d:
            out.append("<ul>")
            depth += 1
        while depth > d:
            out.append("</li></ul>")
            depth -= 1
        if k and out[-1] != "<ul>":
            out.append("</li>")
        out.append(f"<li>{_inline(text)}")
    out.append("</li>")
    out += ["</ul></li>"] * depth
    out.append("</ul>")
    return "".join(out)


# -- tables ---------------------------------------------------------------------------------------------
def _slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-") or "section"


def _tools(table_id: str, n_rows: int) -> str:
    return (f'<div class="tools"><input type="search" class="filter" data-table="{_esc(table_id)}" '
            f'placeholder="filter rows (words, all must match)" aria-label="filter the rows of {_esc(table_id)}">'
            f' <span class="count" data-table="{_esc(table_id)}">{n_rows} rows</span></div>')


def _plain_table(table_id: str, header: list[str], rows: list[list[str]]) -> str:
    """A markdown table as a sortable, filterable table (cells as text)."""
    head = "".join(f'<th data-name="{_esc(h)}" title="sort by {_esc(h)}">{_esc(h)}</th>' for h in header)
    body = "".join("<tr>" + "".join(f"<td>{_esc(c)}</td>" for c in r) + "</tr>" for r in rows)
    return (_tools(table_id, len(rows)) + f'<div class="scroll"><table class="data" id="{_esc(table_id)}">'
            f"<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>")


def _cell_text(v) -> str:
    from bench.latex import plain_cell

    return plain_cell(v)


def _sort_value(v) -> str | None:
    """The exact value a cell sorts by (None: by its text)."""
    import numbers

    if isinstance(v, bool) or v is None:
        return None
    if isinstance(v, numbers.Integral):
        return str(int(v))
    if isinstance(v, numbers.Real):
        f = float(v)
        return None if math.isnan(f) else repr(f)
    return None


def _number(v) -> str:
    try:
        return format(float(v), ".4g")
    except (TypeError, ValueError):
        return _esc(v)


def _matrix(name: str, value) -> str:
    """A matrix (list of rows), a vector or a scalar of gains.json, printed when small."""
    if value is None:
        return f"<p><b>{_esc(name)}</b>: none</p>"
    if isinstance(value, list) and value and all(isinstance(r, list) for r in value):
        rows, cols = len(value), max(len(r) for r in value)
        if rows * cols > MATRIX_ENTRIES:
            return f"<p><b>{_esc(name)}</b>: {rows} x {cols} (in gains.json)</p>"
        body = "".join("<tr>" + "".join(f"<td>{_number(x)}</td>" for x in r) + "</tr>" for r in value)
        return (f'<div class="mat"><b>{_esc(name)}</b> ({rows} x {cols})<table class="matrix">{body}</table>'
                "</div>")
    if isinstance(value, list):
        shown = ", ".join(_number(x) for x in value[:MATRIX_ENTRIES])
        return f"<p><b>{_esc(name)}</b>: ({shown}{', ...' if len(value) > MATRIX_ENTRIES else ''})</p>"
    return f"<p><b>{_esc(name)}</b>: {_esc(value)}</p>"


def _scalar(v) -> bool:
    return v is None or isinstance(v, (str, int, float, bool))


def _value_html(v) -> str:
    if isinstance(v, float):
        return _esc(_cell_text(v))
    if _scalar(v):
        return "" if v is None else _esc(_cell_text(v))
    return _esc(str(v))


def _levels_html(entry: dict) -> str:
    """The certificate's levels of a gains.json entry: a row per level (its scalar fields), then its arrays."""
    levels = [(k, v) for k, v in (entry.get("certificate") or {}).items() if isinstance(v, dict)]
    if isinstance(entry.get("from_x0"), dict):
        levels.append(("from x0", entry["from_x0"]))
    if not levels:
        return "<p>No certificate.</p>"
    cols = list(dict.fromkeys(k for _, lv in levels for k, v in lv.items() if _scalar(v)))
    head = "".join(f"<th>{_esc(c)}</th>" for c in ["level", *[c for c in cols if c != "level"]])
    body = []
    arrays = []
    for name, lv in levels:
        body.append("<tr>" + f"<td>{_esc(name)}</td>" + "".join(
            f"<td>{_value_html(lv.get(c))}</td>" for c in cols if c != "level") + "</tr>")
        for k, v in lv.items():
            if not _scalar(v):
                if isinstance(v, dict):
                    inner = "".join(_matrix(f"{k}.{kk}", vv) for kk, vv in v.items())
                else:
                    inner = _matrix(k, v)
                arrays.append(f"<details><summary>{_esc(name)}: {_esc(k)}</summary>{inner}</details>")
    return (f'<table class="levels"><thead><tr>{head}</tr></thead><tbody>{"".join(body)}</tbody></table>'
            + "".join(arrays))


def _details_html(rec: dict, entry: dict | None) -> str:
    parts = []
    text = rec.get("details", rec.get("reason", ""))
    if isinstance(text, str) and text:
        parts.append(f'<h4>Details</h4><p class="long">{_esc(text)}</p>')
    if entry is None:
        parts.append("<p>No gains (gains.json has no entry for this pair).</p>")
    elif "error" in entry:
        parts.append(f"<p>{_esc(entry['error'])}</p>")
    else:
        parts.append("<h4>Gains</h4>" + _matrix("K", entry.get("K")) + _matrix("F", entry.get("F")))
        if entry.get("estimator"):
            parts.append(f"<p><b>estimator</b>: {_esc(entry['estimator'])}</p>")
        best = entry.get("best")
        parts.append(f"<h4>Certificate levels</h4><p>strongest: {_esc(best if best is not None else 'none')}</p>"
                     + _levels_html(entry))
    return "".join(parts)


def _results_table(table, gains: list[dict]) -> str:
    """results.csv as a table of pairs, each row opening onto its details (full reason, gains, certificate)."""
    by_pair = {(g.get("plant"), g.get("design")): g for g in gains if isinstance(g, dict)}
    cols = [c for c in table.columns if c != "details"]
    head = '<th class="nosort" aria-label="details"></th>' + "".join(
        f'<th data-name="{_esc(c)}" title="sort by {_esc(c)}">{_esc(c)}</th>' for c in cols)
    bodies = []
    for k, rec in enumerate(table.to_dict("records")):
        cells = []
        for c in cols:
            v = rec[c]
            sv = _sort_value(v)
            full = "" if v is None or (isinstance(v, float) and math.isnan(v)) else str(v)
            attrs = (f' data-v="{_esc(sv)}"' if sv is not None else "") + (f' title="{_esc(full)}"' if full else "")
            cells.append(f"<td{attrs}>{_esc(_cell_text(v))}</td>")
        detail = _details_html(rec, by_pair.get((rec.get("plant"), rec.get("design"))))
        bodies.append(
            f'<tbody class="pair"><tr class="main"><td><button type="button" class="more" aria-expanded="false" '
            f'aria-controls="pair-{k}" title="details">+</button></td>{"".join(cells)}</tr>'
            f'<tr class="detail" id="pair-{k}" hidden><td colspan="{len(cols) + 1}">{detail}</td></tr></tbody>')
    return (_tools(RESULTS_ID, len(bodies)) + f'<div class="scroll"><table class="data grouped" id="{RESULTS_ID}">'
            f"<thead><tr>{head}</tr></thead>{''.join(bodies)}</table></div>")


# -- figures --------------------------------------------------------------------------------------------
def _figure(caption: str, path: str, folder: Path) -> str:
    file = folder / path
    if path.endswith(".png") and ".." not in Path(path).parts and file.is_file():
        data = base64.b64encode(file.read_bytes()).decode("ascii")
        body = f'<img alt="{_esc(caption)}" src="data:image/png;base64,{data}">'
    else:  # a PDF (or a missing file): linked, not embedded
        body = f'<p><a href="{_esc(path)}">{_esc(path)}</a></p>'
    return f"<figure>{body}<figcaption>{_inline(caption)}</figcaption></figure>"


# -- the page -------------------------------------------------------------------------------------------
def _sections(blocks: list[tuple]) -> tuple[str, list[tuple], list[tuple[str, list[tuple]]]]:
    """(title, the blocks before the first section, [(section heading, its blocks)])."""
    title, pre, sections = "oslbench report", [], []
    for b in blocks:
        if b[0] == "h" and b[1] == 1 and not sections and not pre:
            title = b[2]
        elif b[0] == "h" and b[1] == 2:
            sections.append((b[2], []))
        elif sections:
            sections[-1][1].append(b)
        else:
            pre.append(b)
    return title, pre, sections


def _blocks_html(blocks: list[tuple], section_id: str, folder: Path, used: set[str]) -> str:
    out = []
    skip = None
    for b in blocks:
        kind = b[0]
        if kind == "p" and skip is not None and b[1] == f"*{skip}*":  # the caption REPORT.md repeats under a figure
            skip = None
            continue
        skip = None
        if kind == "h":
            level = min(max(b[1], 3), 6)  # inside a section: h3 and below
            out.append(f"<h{level}>{_inline(b[2])}</h{level}>")
        elif kind == "p":
            out.append(f"<p>{_inline(b[1])}</p>")
        elif kind == "list":
            out.append(_list_html(list(b[1])))
        elif kind == "table":
            tid = section_id
            k = 2
            while tid in used:
                tid, k = f"{section_id}-{k}", k + 1
            used.add(tid)
            out.append(_plain_table(tid, b[1], b[2]))
        elif kind == "img":
            out.append(_figure(b[1], b[2], folder))
            skip = b[1]
    return "".join(out)


def render_html(markdown: str, table, gains: list[dict], folder: str | Path) -> str:
    """The report page (module docstring).

    Parameters
    ----------
    markdown : str
        REPORT.md's text (:func:`bench.report.render_markdown`).
    table : pandas.DataFrame
        results.csv (:func:`bench.report.results_table`): every column is shown, ``details`` in each pair's details.
    gains : list of dict
        gains.json's entries.
    folder : path
        Where the figures REPORT.md links are (``figures/...``), embedded as data URIs.

    Returns
    -------
    str
        The HTML document.
    """
    folder = Path(folder)
    title, pre, sections = _sections(parse_markdown(markdown))
    first = [s for s in sections if s[0] == FIRST_SECTION] or sections[:1]
    rest = [s for s in sections if s not in first]
    used = {RESULTS_ID}
    parts, nav = [], []

    def section(heading: str, body: str) -> None:
        sid = base = _slug(heading)
        k = 2
        while sid in {n for n, _ in nav}:
            sid, k = f"{base}-{k}", k + 1
        nav.append((sid, heading))
        parts.append(f'<section id="sec-{_esc(sid)}"><h2>{_inline(heading)}</h2>{body}</section>')

    for heading, blocks in first:
        section(heading, _blocks_html(blocks, _slug(heading), folder, used))
    if pre:
        section("This run", _blocks_html(pre, "this-run", folder, used))
    section("Results by pair", "<p>One row per pair (results.csv); + opens its details: the full reason, the gains "
                               "and each level of its certificate (gains.json).</p>" + _results_table(table, gains))
    for heading, blocks in rest:
        section(heading, _blocks_html(blocks, _slug(heading), folder, used))
    links = " ".join(f'<a href="#sec-{_esc(sid)}">{_esc(h)}</a>' for sid, h in nav)
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>{_esc(title)}</title><style>{_CSS}</style></head>\n<body>"
            f"<header><h1>{_inline(title)}</h1><nav>{links}</nav></header><main>{''.join(parts)}</main>"
            f"<script>{_JS}</script></body></html>\n")


_CSS = """
body{font:14px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0;color:#1b1b1b;background:#fff}
header{padding:.6em 1.2em;border-bottom:1px solid #ddd;background:#f6f8fa;position:sticky;top:0;z-index:3}
header h1{font-size:1.3em;margin:.1em 0 .3em}
nav a{margin-right:1em;white-space:nowrap;color:#0550ae;text-decoration:none}
nav a:hover{text-decoration:underline}
main{padding:0 1.2em 3em}
section{margin-top:1.4em;scroll-margin-top:5.5em}
h2{font-size:1.15em;border-bottom:1px solid #e4e4e4;padding-bottom:.2em}
h3{font-size:1.02em}h4{margin:.6em 0 .2em}
code{background:#f0f0f0;padding:0 .25em;border-radius:3px;font-size:.93em}
.tools{margin:.4em 0}
.filter{width:24em;max-width:90%;padding:.25em .4em}
.count{color:#555;margin-left:.6em}
.scroll{overflow:auto;max-height:80vh;border:1px solid #ddd}
table.data{border-collapse:collapse;font-size:.92em}
table.data th{position:sticky;top:0;background:#eef1f4;cursor:pointer;white-space:nowrap;text-align:left;
padding:.3em .5em;border-bottom:1px solid #ccc;z-index:1;user-select:none}
table.data th.nosort{cursor:default}
table.data th[aria-sort=ascending]::after{content:" \\25B2"}
table.data th[aria-sort=descending]::after{content:" \\25BC"}
table.data td{padding:.2em .5em;border-bottom:1px solid #eee;white-space:nowrap;max-width:26em;overflow:hidden;
text-overflow:ellipsis;vertical-align:top}
table.data tr:hover td{background:#fafbfc}
tr.detail>td{white-space:normal;max-width:none;background:#fbfbfd;padding:.5em 1em}
p.long{white-space:pre-wrap;max-width:70em}
button.more{width:1.8em;cursor:pointer}
table.matrix,table.levels{border-collapse:collapse;margin:.2em 0 .6em;font-size:.9em}
table.matrix td{border:1px solid #e2e2e2;padding:.1em .4em;text-align:right;font-family:ui-monospace,monospace}
table.levels th,table.levels td{border:1px solid #e2e2e2;padding:.15em .4em;text-align:left;vertical-align:top}
figure{margin:1em 0}figure img{max-width:100%;height:auto;border:1px solid #eee}
figcaption{color:#444;font-size:.92em}
"""

_JS = r"""
(function () {
  "use strict";
  var NUM = /^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^[-+]?inf$/i;
  function tables() { return Array.prototype.slice.call(document.querySelectorAll("table.data")); }
  function items(t) {
    if (t.classList.contains("grouped")) { return Array.prototype.slice.call(t.tBodies); }
    return t.tBodies.length ? Array.prototype.slice.call(t.tBodies[0].rows) : [];
  }
  function mainRow(item) { return item.tagName === "TBODY" ? item.rows[0] : item; }
  function raw(item, col) {
    var c = mainRow(item).cells[col];
    if (!c) { return ""; }
    var v = c.getAttribute("data-v");
    return v !== null ? v : c.textContent.trim();
  }
  function num(s) {
    s = s.toLowerCase();
    return s === "inf" || s === "+inf" ? Infinity : s === "-inf" ? -Infinity : parseFloat(s);
  }
  function sortBy(t, col, desc) {
    var list = items(t);
    var vals = list.map(function (it) { return raw(it, col); });
    var numeric = vals.every(function (v) { return v === "" || v.toLowerCase() === "nan" || NUM.test(v); });
    var keyed = list.map(function (it, i) { return {it: it, v: vals[i], i: i}; });
    keyed.sort(function (a, b) {
      var ab = a.v === "" || a.v.toLowerCase() === "nan", bb = b.v === "" || b.v.toLowerCase() === "nan";
      if (ab || bb) { return ab === bb ? a.i - b.i : ab ? 1 : -1; }
      var r = numeric ? num(a.v) - num(b.v) : a.v.localeCompare(b.v, undefined, {numeric: true});
      if (r === 0 || isNaN(r)) { return a.i - b.i; }
      return desc ? -r : r;
    });
    var parent = t.classList.contains("grouped") ? t : t.tBodies[0];
    keyed.forEach(function (k) { parent.appendChild(k.it); });
    Array.prototype.forEach.call(t.tHead.rows[0].cells, function (th, i) {
      if (i === col) { th.setAttribute("aria-sort", desc ? "descending" : "ascending"); }
      else { th.removeAttribute("aria-sort"); }
    });
  }
  function box(t) { return document.querySelector('input.filter[data-table="' + t.id + '"]'); }
  function filter(t) {
    var b = box(t);
    var terms = (b ? b.value : "").toLowerCase().split(/\s+/).filter(Boolean);
    var list = items(t), shown = 0;
    list.forEach(function (it) {
      var text = mainRow(it).textContent.toLowerCase();
      var ok = terms.every(function (w) { return text.indexOf(w) >= 0; });
      it.hidden = !ok;
      if (ok) { shown += 1; }
    });
    var c = document.querySelector('span.count[data-table="' + t.id + '"]');
    if (c) { c.textContent = (terms.length ? shown + " of " : "") + list.length + " rows"; }
  }
  function column(t, name) {
    var cells = t.tHead.rows[0].cells;
    for (var i = 0; i < cells.length; i++) {
      var n = cells[i].getAttribute("data-name");
      if (n !== null && n.toLowerCase() === name.toLowerCase()) { return i; }
    }
    return -1;
  }
  function applyHash() {
    var h = location.hash.replace(/^#/, "");
    if (h.indexOf("=") < 0) { return; }
    var p = new URLSearchParams(h);
    var only = p.get("table");
    tables().forEach(function (t) {
      if (only && t.id !== only) { return; }
      if (p.has("filter")) { var b = box(t); if (b) { b.value = p.get("filter"); } filter(t); }
      var s = p.get("sort");
      if (s) {
        var desc = p.get("order") === "desc" || s.charAt(0) === "-";
        var col = column(t, s.replace(/^-/, ""));
        if (col >= 0) { sortBy(t, col, desc); }
      }
    });
  }
  function setup() {
    tables().forEach(function (t) {
      Array.prototype.forEach.call(t.tHead.rows[0].cells, function (th, i) {
        if (th.classList.contains("nosort")) { return; }
        th.addEventListener("click", function () {
          sortBy(t, i, th.getAttribute("aria-sort") === "ascending");
        });
      });
      var b = box(t);
      if (b) { b.addEventListener("input", function () { filter(t); }); }
    });
    Array.prototype.forEach.call(document.querySelectorAll("button.more"), function (btn) {
      btn.addEventListener("click", function () {
        var row = document.getElementById(btn.getAttribute("aria-controls"));
        var open = btn.getAttribute("aria-expanded") !== "true";
        row.hidden = !open;
        btn.setAttribute("aria-expanded", open ? "true" : "false");
        btn.textContent = open ? "\u2212" : "+";
      });
    });
    applyHash();
    window.addEventListener("hashchange", applyHash);
    document.body.setAttribute("data-ready", "1");
  }
  if (document.readyState === "loading") { document.addEventListener("DOMContentLoaded", setup); } else { setup(); }
})();
"""
