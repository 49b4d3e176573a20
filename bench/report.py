"""Reports: the run's records and findings rendered as markdown, CSV, JSON, LaTeX and figures.

The report computes no verdict: every judgement comes from the records (:mod:`bench.pipeline`) and the
findings (:mod:`bench.findings`). ``write_report`` renders everything into a staging folder and
publishes it whole or not at all (:mod:`bench.outdir`). It saves what the figures plot in
:data:`FIGURE_DATA`, so that :func:`redraw` renders REPORT.md, report.html (:mod:`bench.html`), the LaTeX
tables and the figures again from a report folder's files, without computing anything.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import platform
import re
import sys
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import numpy as np

from bench.findings import constants_rows, findings
from bench.harness import RunResult
from bench.latex import level_cell, minimal_document, plain_cell, tables_tex
from designs import GAIN_STATUSES

__all__ = ["FIGURE_DATA", "draw_figures", "redraw", "results_table", "write_report"]

#: Plants that get per-design figures of states, estimates and errors (like the paper's Figures
#: 2-5); every plant gets the norm comparison figure.
FIGURE_PLANTS = ("flexible_link",)

_PACKAGES = ("numpy", "scipy", "cvxpy", "clarabel", "scs", "control", "filterpy", "pandas", "matplotlib", "tabulate")


def package_versions() -> dict[str, str]:
    """Versions of Python and of the packages a run depends on."""
    out = {"python": platform.python_version()}
    for name in _PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def git_revision() -> dict[str, object]:
    """``{"commit": sha or None, "dirty": bool or None}`` of the checkout holding this package (None outside
    git); ``dirty``: tracked files outside ``reports/`` differ from the commit.
    """
    import subprocess

    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "GIT_OPTIONAL_LOCKS": "0"}

    def git(*args: str) -> str | None:
        try:
            done = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, timeout=10,
                                  env=env, check=False)
        except (OSError, subprocess.SubprocessError):
            return None
        return done.stdout.strip() if done.returncode == 0 else None

    top = git("rev-parse", "--show-toplevel")
    if top is None or Path(top).resolve() != root:
        return {"commit": None, "dirty": None}
    status = git("status", "--porcelain", "--untracked-files=no", "--", ".", ":(exclude)reports")
    return {"commit": git("rev-parse", "HEAD"), "dirty": None if status is None else bool(status)}


def format_cell(v, spec: str = ".3g") -> str:
    """A markdown cell: :func:`bench.latex.plain_cell` on one line, with ``|`` escaped."""
    return plain_cell(v, spec).replace("|", "\\|").replace("\n", " ")


#: The longest ``reason`` cell of :func:`results_table` (the full text is in ``details``).
REASON_CHARS = 120


def short_reason(text, limit: int = REASON_CHARS) -> str:
    """The gist of a record's ``reason`` (None or NaN: ``""``) in at most ``limit`` (>= 20) characters: a longer
    text is cut to its first clause (up to ``"; "`` outside parentheses), without parenthesised asides of 30
    characters or more, then at a word boundary with ``"..."``.
    """
    import re

    if text is None or (isinstance(text, float) and math.isnan(text)):
        return ""
    text = str(text)
    if len(text) <= limit:
        return text
    depths = itertools.accumulate((ch == "(") - (ch == ")") for ch in text)
    head = next((text[:i] for i, depth in enumerate(depths) if depth <= 0 and text.startswith("; ", i)), text)
    removed = 1
    while removed:  # innermost asides first, so nested parentheses go too
        head, removed = re.subn(r" ?\([^()]{30,}\)", "", head)
    if len(head) <= limit:
        return head
    cut = head[: limit - 3]
    if " " in cut[limit // 2:]:
        cut = cut[: cut.rindex(" ")]
    return cut.rstrip(" ,;:") + "..."


def clip_words(text, limit: int) -> str:
    """``text`` in at most ``limit`` characters: cut at the last word boundary before it, with ``"..."``."""
    text = str(text)
    if len(text) <= limit:
        return text
    cut = text[: max(limit - 3, 1)]
    if " " in cut[limit // 2:]:
        cut = cut[: cut.rindex(" ")]
    return cut.rstrip(" ,;:(") + "..."


def cell_fits(blank, value) -> bool:
    """True when ``value`` is of the kind of a record column whose blank value is ``blank``
    (:func:`bench.pipeline.blank_record`): text, a flag (True, False or None) or a number (or None)."""
    if isinstance(blank, str):
        return isinstance(value, str)
    if blank is None or isinstance(blank, bool):
        return value is None or isinstance(value, (bool, np.bool_))
    return value is None or (isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool))


def check_cells(outcomes) -> None:
    """Make every cell of the outcomes' records of the kind of its column (:func:`cell_fits`), in place: a cell holding
    anything else (an object a plugin handed over, which results.csv and gains.json cannot hold) becomes its blank
    value, and the pair's reason says which column and what it held."""
    from bench.pipeline import blank_record

    blank = blank_record("", "")
    for o in outcomes:
        rec = o.record
        bad = [c for c, b in blank.items() if c in rec and not cell_fits(b, rec[c])]
        notes = []
        for c in bad:
            notes.append(f"{c} held a {type(rec[c]).__name__}, which results.csv and gains.json cannot hold (blanked)")
            rec[c] = blank[c]
        if notes:
            rec["reason"] = "; ".join(([rec["reason"]] if rec["reason"] else []) + notes)


def results_table(df):
    """The results table as results.csv and :attr:`bench.api.Results.table` show it: the records of
    :meth:`bench.harness.RunResult.frame` (a DataFrame) with ``reason`` shortened by :func:`short_reason` and the
    full text in a last column ``details``; returns a new frame.
    """
    out = df.copy()
    out["details"] = df["reason"].fillna("")
    out["reason"] = out["details"].map(short_reason)
    return out


def md_table(rows, columns: list, headers: list[str] | None = None) -> str:
    """A markdown table of ``rows`` (dicts) restricted to ``columns``, each cell by :func:`format_cell`."""
    headers = [str(h).replace("|", "\\|") for h in (headers or columns)]
    out = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    out += ["| " + " | ".join(format_cell(r.get(c)) for c in columns) + " |" for r in rows]
    return "\n".join(out)


def pyplot():
    """matplotlib.pyplot with the Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


#: Words of the feasibility matrix that differ from the status.
_SHORT = {"inapplicable": "n/a", "error": "ERROR"}


def _cell(rec) -> str:
    s = _SHORT.get(rec["status"], rec["status"])
    if rec["status"] not in GAIN_STATUSES:
        return s
    cert = f"cert {rec['cert_level']}" if rec["certified"] else "no cert"
    if rec["certified"] and rec["cert_scope"] in ("local", "from x0"):
        cert += f" ({rec['cert_scope']})"
    conv = "conv" if rec["converged"] else "no conv"
    return f"{s}: {cert}, {conv}"


def _matrix(df) -> str:
    rows: dict[str, dict] = {}
    for r in df.to_dict("records"):
        rows.setdefault(r["plant"], {"plant": r["plant"]})[r["design"]] = _cell(r)
    return md_table(list(rows.values()), ["plant", *dict.fromkeys(df["design"])])


def _ladder(df) -> str:
    """Certified decay rate per plant x design x level (blank: not certified at that level)."""
    from bench.certify import LEVELS

    sub = df[df[[f"cert_{lv}" for lv in LEVELS]].ne("").any(axis=1)]
    if not len(sub):
        return "No pair has fixed gains to certify."
    rows = [{"plant": r["plant"], "design": r["design"], **{lv: level_cell(r, f"decay_{lv}") for lv in LEVELS},
             "head": f"{format_cell(r['decay_rate'])} ({r['cert_level']})" if r["certified"] else "not certified",
             "scope": r["cert_scope"]} for r in sub.to_dict("records")]
    return md_table(rows, ["plant", "design", *LEVELS, "head", "scope"],
                    ["plant", "design", *LEVELS, "headline (strongest level)", "scope"])


#: The columns of the attenuation table (:func:`_attenuation_table`).
ATTENUATION_COLUMNS = ["plant", "design", "cert_level", "l2_gain_e", "l2_gain_x", "l2_measured_e", "l2_measured_x",
                       "l2_radius", "l2_max_norm"]

#: The columns of the discrete-time table (:func:`_discrete_table`).
DISCRETE_COLUMNS = ["plant", "design", "dt", "stabilizing", "certified", "cert_level", "contraction", "decay_rate",
                    "rate_ceiling", "cert_scope", "max_re_eig_x", "max_re_eig_e", "converged", "horizon_s",
                    "settling_x_s", "settling_e_s"]


def _attenuation_rows(df):
    """The rows of plants with disturbance inputs (a certified gain or a measured ratio on some pair of the plant)
    that have gains."""
    cols = ["l2_gain_e", "l2_gain_x", "l2_measured_e", "l2_measured_x"]
    have = df[cols].astype(float).notna().any(axis=1)
    plants = set(df.loc[have, "plant"])
    return df[df["plant"].isin(plants) & df["max_re_eig_x"].notna()]


def _attenuation_table(df) -> str:
    """Certified L2 gains beside the measured ratios, per pair of a plant with disturbance inputs."""
    sub = _attenuation_rows(df)
    if not len(sub):
        return ("No pair has a certified L2 gain or a measured ratio (no plant with disturbance inputs Bw, Dw, or "
                "none of its pairs certified, and `--disturbance` off).")
    return md_table(sub.to_dict("records"), ATTENUATION_COLUMNS)


def _discrete_table(df) -> str:
    """The discrete-time plants' pairs with gains: contraction factor per step, rate per second."""
    sub = df[(df["dt"].astype(float) > 0) & df["max_re_eig_x"].notna()]
    rows = [{**r, "contraction": format_cell(r["contraction"], ".6g")} for r in sub.to_dict("records")]
    return md_table(rows, DISCRETE_COLUMNS)


def _constants_table(result: RunResult) -> str:
    rows = constants_rows(result.constants, result.constants_errors)
    keys = ["plant", "constant", "claimed", "analytic", "sampled", "used", "source", "region", "flag"]
    return md_table(rows, keys, [*keys[:4], "sampled (lower bound)", *keys[5:]])


@dataclass(frozen=True)
class _FigureJob:
    """One figure to draw: its file stem, caption and the data it plots (picklable)."""

    kind: str  # "norms" (one plant, every converging design) or "states" (one pair)
    stem: str
    caption: str
    title: str
    data: tuple


def _figure_jobs(result: RunResult) -> list[_FigureJob]:
    """The figures of a run in report order: per plant the norms, and the states for :data:`FIGURE_PLANTS`."""
    by_plant: dict[str, list] = {}
    for o in result.outcomes:
        if o.trajectory is not None and o.record["converged"] and o.plant is not None:
            by_plant.setdefault(o.plant.id, []).append(o)
    jobs = []
    for pid, outs in by_plant.items():
        norms = tuple((o.record["design"], np.asarray(o.trajectory.t, dtype=float),
                       *(np.linalg.norm(v, axis=0).astype(NORM_DTYPE) for v in (o.trajectory.x, o.trajectory.e)))
                      for o in outs)
        jobs.append(_FigureJob("norms", f"{pid}__norms", f"{pid}: state and error norms of every converging design "
                               f"(log scale; a norm below {NORM_FLOOR:.0e} is drawn on that floor)", pid, norms))
        if pid not in FIGURE_PLANTS:
            continue
        for o in outs:
            tr, did = o.trajectory, o.record["design"]
            settle = [s for s in (o.record["settling_x_s"], o.record["settling_e_s"])
                      if isinstance(s, float) and math.isfinite(s)]
            t_show = min(float(tr.t[-1]), max(1.0, 2.0 * max(settle))) if settle else float(tr.t[-1])
            title = f"{pid} with {did} (cf. the paper's Figures 2-5; first {t_show:.3g} s of {tr.t[-1]:.3g} s)"
            keep = tr.t <= t_show
            names = o.plant.state_names or tuple(f"x{i + 1}" for i in range(o.plant.n))
            jobs.append(_FigureJob("states", f"{pid}__{did}", f"{pid} with {did}: states, estimates (dashed) and "
                                   "estimation errors", title,
                                   (tr.t[keep], tr.x[:, keep], tr.x_hat[:, keep], t_show, names)))
    return jobs


#: Colours of the designs in every figure of the suite (the report's and the studies'): matplotlib's ten, then
#: eight more, each far from every other in CIELAB and of another hue (no light/dark pairs of one hue, as tab20
#: has) (:func:`design_styles`).
DESIGN_COLOURS = ("C0", "C1", "C2", "C3", "C4", "C5", "C6", "C7", "C8", "C9", "black", "#b8860b", "#000080",
                  "#ff00ff", "#556b2f", "#00ff7f", "#4169e1", "#ba55d3")
#: Line styles and markers cycled beside the colours: two designs never share all three.
DESIGN_LINESTYLES = ("-", "--", "-.", ":")
DESIGN_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*", "<", ">", "h")
#: The norms figure's colours and line styles (the design palette).
NORM_COLOURS, NORM_STYLES = DESIGN_COLOURS, DESIGN_LINESTYLES


def design_styles(design_ids) -> dict[str, dict]:
    """The colour, line style and marker of each design, the same in every figure of the suite.

    A registered design keeps the slot of its place in the registry (so ``thm1`` has one colour in the report
    and in every study); another label (``lqr+ekf (r = sigma^2)``) takes the next free slot, in the order given,
    whose colour none of ``design_ids`` has (when one is left).
    Slot ``k`` has colour ``k mod 18``, line style ``k mod 4`` and marker ``k mod 11`` (beyond 18 designs a
    colour comes back, with another line style or marker).

    Parameters
    ----------
    design_ids : iterable of str

    Returns
    -------
    dict
        Design id -> ``{"color", "linestyle", "marker"}`` (matplotlib keywords).
    """
    from bench.registry import DESIGNS

    registered = DESIGNS.ids()
    slot = {d: k for k, d in enumerate(registered)}
    ids = list(dict.fromkeys(design_ids))
    taken = {slot[d] % len(DESIGN_COLOURS) for d in ids if d in slot}  # the colours of this figure's designs
    out = {}
    extra = len(registered)
    for did in ids:
        k = slot.get(did)
        if k is None:  # the next slot whose colour no design of this figure has (if any is left)
            free = next((j for j in range(extra, extra + len(DESIGN_COLOURS))
                         if j % len(DESIGN_COLOURS) not in taken), extra)
            k, extra = free, free + 1
            taken.add(k % len(DESIGN_COLOURS))
        out[did] = {"color": DESIGN_COLOURS[k % len(DESIGN_COLOURS)],
                    "linestyle": DESIGN_LINESTYLES[k % len(DESIGN_LINESTYLES)],
                    "marker": DESIGN_MARKERS[k % len(DESIGN_MARKERS)]}
    return out
#: Norms below this are drawn on it (a log axis has no 0); the figure draws and names the floor.
NORM_FLOOR = 1e-16


#: The norms of the norms figures are drawn and kept (:data:`FIGURE_DATA`) in single precision: a log axis of
#: some twenty decades over a few hundred pixels shows no digit beyond the fourth.
NORM_DTYPE = np.float32


def _reset(ax) -> None:
    """Empty an axes of a reused figure for the next job: no lines, no legend, data limits and colour cycle anew."""
    for line in list(ax.lines):
        line.remove()
    if ax.get_legend() is not None:
        ax.get_legend().remove()
    ax.relim()
    ax.set_prop_cycle(None)


def _norms_figure(job: _FigureJob, fig=None):
    """||x(t)|| and ||e(t)|| of every converging design of a plant on log axes; returns (figure, dpi).

    ``fig``: a figure this function returned before, drawn again with ``job`` (the same picture as a new one)."""
    if fig is None:
        fig = pyplot().figure(figsize=(12, 4.2))
        grid = fig.add_gridspec(1, 3, width_ratios=(1, 1, 0.36), left=0.06, right=0.995, bottom=0.12, top=0.86,
                                wspace=0.22)
        axes = [fig.add_subplot(grid[0, 0]), fig.add_subplot(grid[0, 1])]
        axes[1].sharex(axes[0])
        key = fig.add_subplot(grid[0, 2])
        key.axis("off")
    else:
        *axes, key = fig.axes
        for ax in (*axes, key):
            _reset(ax)
    clipped = False
    styles = design_styles(did for did, *_ in job.data)
    for did, t, nx, ne in job.data:
        style = dict(color=styles[did]["color"], linestyle=styles[did]["linestyle"], linewidth=1.3)
        for ax, v in zip(axes, (nx, ne)):
            clipped |= bool(np.any(v < NORM_FLOOR))
            ax.semilogy(t, np.maximum(v, NORM_FLOOR), label=did, **style)
    if clipped:
        for ax in axes:
            ax.axhline(NORM_FLOOR, color="0.35", linewidth=0.9, linestyle=(0, (1, 2)),
                       label=f"floor {NORM_FLOOR:.0e}\n(smaller norms\ndrawn on it)")
    axes[0].set(title="state", xlabel="t [s]", ylabel="||x(t)||")
    axes[1].set(title="estimation error", xlabel="t [s]", ylabel="||e(t)|| = ||x(t) - x_hat(t)||")
    for ax in axes:
        ax.grid(True, which="major", alpha=0.3)
    fig.suptitle(f"{job.title}: norms of every converging design (log scale)")
    handles, labels = axes[1].get_legend_handles_labels()  # the error panel holds the floor if any
    key.legend(handles, labels, loc="center left", bbox_to_anchor=(-0.12, 0.5), fontsize=8, frameon=False,
               title="design", title_fontsize=9, handlelength=3.2)
    return fig, 110


def _states_figure(job: _FigureJob, fig=None):
    """One pair's states, estimates (dashed) and errors (the paper's Figures 2-5), each state named with its unit
    (:attr:`plants.Plant.state_names`); returns (figure, dpi). ``fig``: a figure this function returned before for
    as many states, drawn again with ``job`` (the same picture as a new one)."""
    t, x, x_hat, t_show, names = job.data
    n = x.shape[0]
    if fig is None:
        fig, axes = pyplot().subplots(2, n, figsize=(3.2 * n, 5.2), squeeze=False)
        fig.subplots_adjust(left=0.06, right=0.99, bottom=0.09, top=0.88, wspace=0.35, hspace=0.4)
    else:
        axes = np.array(fig.axes, dtype=object).reshape(2, n)
        for ax in axes.flat:
            _reset(ax)
            ax.set_autoscalex_on(True)
    for i in range(n):
        unit = re.search(r"\[[^\]]*\]\s*$", names[i])
        unit = f" {unit.group(0).strip()}" if unit else ""
        what = f"x{i + 1} and its estimate" if names[i] == f"x{i + 1}" else f"x{i + 1}: {names[i]}"
        ax = axes[0, i]
        ax.plot(t, x[i], label=f"x{i + 1}")
        ax.plot(t, x_hat[i], "--", label=f"x_hat{i + 1}")
        ax.set(title=what, xlabel="t [s]", ylabel=f"x{i + 1}, x_hat{i + 1}{unit}")
        ax.legend(fontsize=8, loc="upper right")
        ax = axes[1, i]
        ax.plot(t, x[i] - x_hat[i], color="C3")
        ax.set(title=f"estimation error e{i + 1}", xlabel="t [s]",
               ylabel=f"e{i + 1} = x{i + 1} - x_hat{i + 1}{unit}")
    for ax in axes.flat:
        ax.set(xlim=(0, t_show))
        ax.grid(True, alpha=0.3)
    fig.suptitle(job.title)
    return fig, 100


#: PNG figures are written with at most this many colours (an adaptive palette: line plots on white use far fewer
#: distinct colours than that, antialiased edges included), a third of the size of a full-colour PNG, which
#: report.html embeds.
PNG_COLOURS = 256


def _save_png(fig, path: Path, dpi: int) -> None:
    """Render ``fig`` at ``dpi`` and write it as a palette PNG (:data:`PNG_COLOURS`), without metadata."""
    import io

    from PIL import Image

    w, h = (int(v) for v in fig.get_size_inches() * dpi)  # Agg's own size: the figure's bounding box, truncated
    with io.BytesIO() as buf:
        fig.savefig(buf, format="rgba", dpi=dpi)
        raw = buf.getvalue()
    if len(raw) != 4 * w * h:  # not the size expected: Pillow reads matplotlib's own PNG instead
        with io.BytesIO() as buf:
            fig.savefig(buf, format="png", dpi=dpi)
            image = Image.open(io.BytesIO(buf.getvalue())).convert("RGB")
    else:
        image = Image.frombuffer("RGBA", (w, h), raw, "raw", "RGBA", 0, 1).convert("RGB")
    image.quantize(PNG_COLOURS, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).save(path, format="png")


def _draw(job: _FigureJob, figdir: Path, fmts: tuple[str, ...], figures: dict | None = None) -> str:
    """Draw one figure into ``figdir`` in every format; return the first file's name. ``figures``: figures drawn
    before, by kind and shape, to draw this one on (updated; the caller closes them), else a new one, closed."""
    key = (job.kind, job.data[1].shape[0] if job.kind == "states" else 0)
    reuse = None if figures is None else figures.get(key)
    fig, dpi = (_norms_figure if job.kind == "norms" else _states_figure)(job, reuse)
    for fmt in fmts:
        if fmt == "png":
            _save_png(fig, figdir / f"{job.stem}.png", dpi)
        else:
            fig.savefig(figdir / f"{job.stem}.{fmt}", dpi=dpi)
    if figures is None:
        pyplot().close(fig)
    else:
        figures[key] = fig
    return f"{job.stem}.{fmts[0]}"


def _draw_chunk(todo: list[_FigureJob], figdir: Path, fmts: tuple[str, ...]) -> list[str]:
    """Draw figure jobs in turn on one figure per kind and shape (a figure reused draws the same picture as a new
    one, in a fraction of the time: its axes, ticks and text are laid out once)."""
    figures: dict = {}
    try:
        return [_draw(job, figdir, fmts, figures) for job in todo]
    finally:
        for fig in figures.values():
            pyplot().close(fig)


def draw_figures(result: RunResult, figdir: Path, fmts: tuple[str, ...] = ("png",), jobs: int | None = None
             ) -> list[tuple[str, str]]:
    """Draw the report's figures of a run into ``figdir``, each in every format of ``fmts`` (``"png"``, ``"pdf"``),
    ``jobs`` at a time (default: all cores); returns (caption, path of the first format relative to the report)
    pairs in report order.
    """
    return _draw_jobs(_figure_jobs(result), figdir, fmts, jobs)


#: Figures drawn in one process before a second is worth its start (a reused figure draws in about 0.1 s).
FIGURES_PER_WORKER = 40


def _draw_jobs(todo: list[_FigureJob], figdir: Path, fmts: tuple[str, ...], jobs: int | None = None
               ) -> list[tuple[str, str]]:
    """Draw figure jobs (:func:`draw_figures`): in contiguous chunks of :data:`FIGURES_PER_WORKER` or more, one
    worker process per chunk (this process alone for one chunk)."""
    from bench.executors import default_jobs, executor

    jobs = max(1, min(default_jobs() if jobs is None else jobs, -(-len(todo) // FIGURES_PER_WORKER)))
    bounds = np.linspace(0, len(todo), jobs + 1).round().astype(int)
    chunks = [todo[a:b] for a, b in zip(bounds[:-1], bounds[1:])]
    with executor(jobs) as ex:
        names = [name for chunk in ex.map(_draw_chunk, chunks, [figdir] * jobs, [fmts] * jobs) for name in chunk]
    return [(job.caption, f"figures/{name}") for job, name in zip(todo, names)]


#: What the figures of a report plot, beside gains.json: :func:`redraw` draws them again from it.
FIGURE_DATA = "figure_data.npz"
_FIGURE_DATA_FORMAT = 2  # 2: an output grid of times kept as [t0, t1, n] (key "...tgrid"); 1 is read too


def save_figure_data(jobs: list[_FigureJob], fmts: tuple[str, ...], path: Path) -> None:
    """Write the figure jobs (their arrays as they are plotted, the rest as JSON) and the figure formats into the
    compressed ``path`` (:data:`FIGURE_DATA`), readable without pickles (:func:`load_figure_data`)."""
    arrays: dict[str, np.ndarray] = {}
    meta = []
    for k, job in enumerate(jobs):
        doc = {"kind": job.kind, "stem": job.stem, "caption": job.caption, "title": job.title}
        if job.kind == "norms":
            doc["designs"] = [did for did, *_ in job.data]
            for j, (_, t, *curves) in enumerate(job.data):
                t = np.asarray(t)
                if t.size > 2 and np.array_equal(t, np.linspace(t[0], t[-1], t.size)):  # the output grid: 3 numbers
                    arrays[f"j{k}_{j}_tgrid"] = np.array([t[0], t[-1], t.size], dtype=float)
                else:
                    arrays[f"j{k}_{j}_t"] = t
                for name, a in zip(("nx", "ne"), curves):
                    arrays[f"j{k}_{j}_{name}"] = np.asarray(a)
        else:
            t, x, x_hat, t_show, names = job.data
            doc.update(t_show=float(t_show), names=list(names))
            for name, a in (("t", t), ("x", x), ("x_hat", x_hat)):
                arrays[f"j{k}_{name}"] = np.asarray(a)
        meta.append(doc)
    arrays["meta"] = np.array(json.dumps({"format": _FIGURE_DATA_FORMAT, "formats": list(fmts), "jobs": meta}))
    with open(path, "wb") as fh:
        np.savez_compressed(fh, **arrays)


def _grid_or(arrays: dict, key: str) -> np.ndarray:
    """The array ``key``, or the grid ``np.linspace(t0, t1, n)`` that ``key + "grid"`` holds as ``[t0, t1, n]``."""
    if key in arrays:
        return arrays[key]
    t0, t1, n = arrays[key + "grid"]
    return np.linspace(t0, t1, int(n))


def load_figure_data(path: Path) -> tuple[list[_FigureJob], tuple[str, ...]]:
    """The figure jobs and formats :func:`save_figure_data` wrote; ValueError naming the file when it cannot be read."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        doc = json.loads(str(arrays.pop("meta")))
        if doc.get("format") not in (1, _FIGURE_DATA_FORMAT):
            raise ValueError(f"unknown format {doc.get('format')!r}")
        jobs = []
        for k, j in enumerate(doc["jobs"]):
            if j["kind"] == "norms":
                data = tuple((did, _grid_or(arrays, f"j{k}_{i}_t"), *(arrays[f"j{k}_{i}_{name}"] for name in ("nx", "ne")))
                             for i, did in enumerate(j["designs"]))
            else:
                data = (arrays[f"j{k}_t"], arrays[f"j{k}_x"], arrays[f"j{k}_x_hat"], j["t_show"], tuple(j["names"]))
            jobs.append(_FigureJob(j["kind"], j["stem"], j["caption"], j["title"], data))
        return jobs, tuple(doc["formats"])
    except (OSError, ValueError, KeyError, TypeError, IndexError) as exc:
        raise ValueError(f"{path}: cannot read the figure data ({type(exc).__name__}: {exc})") from None


def _summary(found: dict) -> str:
    """The report's first screen: what the run found (from :func:`bench.findings.findings`)."""
    lines = [f"- **INCONSISTENT** on {r['plant']} x {r['design']}: {format_cell(r['reason'])}"
             for r in found["inconsistent"]]
    for pid, f in found["plants"].items():
        b = f["best"]
        if b is None:
            best = "no design certified"
        else:
            best = (f"best certified: **{b['design']}**, decay {format_cell(b['decay_rate'])} at the {b['level']} level"
                    + (f" ({b['scope']})" if b["scope"] in ("local", "from x0") else "")
                    + (f", {format_cell(b['rate_ratio'])} of the class's rate ceiling"
                       if math.isfinite(b["rate_ratio"]) else "")
                    + f", peak |u| {format_cell(b['peak_u'])}")
        split = [f"{what}: {', '.join(f[key])}" for what, key in (
            ("no certificate can exist (witness)", "no_certificate_can_exist"),
            ("no certificate found", "no_certificate_found"),
        ) if f[key]]
        tail = f"; converge without a certificate ({'; '.join(split)})" if split else ""
        gains = f.get("best_gains") or {}
        l2 = "; smallest certified L2 gain " + ", ".join(
            f"w to {z}: {format_cell(gains[z]['gain'])} ({gains[z]['design']})" for z in ("e", "x") if z in gains
        ) if gains else ""
        lines.append(f"- **{pid}**: {best}; {f['certified_pairs']} of {f['pairs']} pairs certified{l2}{tail}.")
    for v in found["violated_claims"]:
        lines.append(f"- Claimed constant violated on {v['plant']}: {v['text']}.")
    for v in found["disproved"]:
        lines.append(f"- Declared bound disproved on {v['plant']} (not used by certificates): {v['text']}.")
    by_design: dict[str, list[dict]] = {}
    for r in found["printed_infeasible"]:
        by_design.setdefault(r["design"], []).append(r)
    for did, rows in by_design.items():
        plants = ", ".join(x["plant"] for x in rows)
        alike = len({x["reason"] for x in rows}) == 1
        why = (f": {clip_words(format_cell(rows[0]['reason']), 300)}" if alike else
               f"; on {rows[0]['plant']}: {clip_words(format_cell(rows[0]['reason']), 240)} (each plant's reason: "
               "\"Reasons, per plant\" below)")
        lines.append(f"- {did} (as printed) is infeasible on {plants}{why}")
    return "\n".join(lines)


_LEGEND = "\n".join([
    "**How to read a row**",
    "",
    "- *Status* with gains: `feasible` (an LMI or Riccati condition solved and verified), `computed` (LQR/Kalman "
    "gains), `given` (printed gains), `unverified` (a plugin's \"feasible\" the suite could not check).",
    "- *Status* without gains: `infeasible` (under the stated normalisation), `marginal` (best margin within the "
    "verification tolerance of zero), `inapplicable`, `undecided` (solver trouble), `error`, `timeout`.",
    "- *Stabilizing*: A+BF and A-KC Hurwitz (Schur, spectral radius < 1, for a discrete-time plant).",
    "- *Discrete time* (dt > 0): the plant is stepped, x_{k+1} = A x_k + B u_k + f(x_k); its rates are per "
    "second, -ln(max |eig|) / dt, and `max_re_eig_*` is the continuous equivalent ln(max |eig|) / dt.",
    "- **The certificate ladder** checks the gains (K, F) with quadratic Lyapunov functions V = z'Pz of z = (x, e) "
    "at three levels of what is known about f, each containing the one below:",
    "  *paper* is the paper's (20) (block-diagonal P, the OSL and QIB constants); *full* couples x and e in P and "
    "adds every scalar constant; *structured* adds the plant's declared channels f = G phi(Hx) with their slope "
    "bounds.",
    "- *Certified* is the strongest level that certifies and *decay rate* its rate lam (V' <= -2 lam V). Only "
    "analytic constants and channels no sample disproved are used (sampled constants are lower bounds and never "
    "certify).",
    "- *Scope*: with constants that hold on ||x|| <= r, `from x0` when the level set of V through the initial "
    "condition stays in the region, else `local`.",
    "- *Witness*: where no global certificate is found, a proof that none can exist: a linear phi(s) = c s in the "
    "declared slope box whose loop is unstable, or an equilibrium besides the origin; a certificate `from x0` is "
    "then searched on a region |Hx|, |Hx_hat| <= r where the slopes narrow.",
    "- *rate_ceiling*: the slowest linear member of the certified class (no certificate over it can prove more); "
    "*rate_ratio*: the certified rate over it.",
    "- *Discrete time*: the ladder proves V(z_{k+1}) <= r^2 V(z_k) over the class; *contraction* is r per step and "
    "*decay_rate* = -ln(r) / dt per second, so discrete and continuous rows compare.",
    "- *L2 gains* (plants with disturbance inputs Bw, Dw): each certified level also bounds the L2 gain from the "
    "disturbance w to e (*l2_gain_e*) and to x (*l2_gain_x*) over its class (bounded real lemma); the columns give "
    "the strongest level's; a class that holds on ||x|| <= *l2_radius* bounds runs that stay there (*l2_max_norm*).",
    "- *Measured L2 ratios* (`--disturbance`, peak 0.1 by default, 0: off): *l2_measured_e*, *l2_measured_x* are "
    "||zeta|| / ||w|| of a second run from z(0) = 0; a certified gain below its measured ratio is INCONSISTENT.",
    "- *Converged*: at the end of the horizon ||x|| and ||e|| are below 1e-3 of the peak of ||z|| (with noise: "
    "settled); blank for a pair without gains.",
    "- *Horizon*: long enough for the certified rate (uncertified: twice the linearisation's) to decay by 1e-3, "
    "from the plant's own to 10 times it (*horizon_rule*); a certified pair that does not converge says why in its "
    "reason.",
])


def render_markdown(result: RunResult, figures: list[tuple[str, str]], run_info: dict) -> str:
    """The REPORT.md text, rendered from the records and ``run_info["findings"]``."""
    df = result.frame()
    o = result.options
    found = run_info["findings"]
    conv_cols = ["plant", "design", "stabilizing", "certified", "cert_level", "decay_rate", "cert_scope",
                 "witness", "rate_ceiling", "rate_ratio", "converged", "horizon_s", "horizon_rule", "sim_status", "settling_x_s", "settling_e_s", "final_x",
                 "final_e", "tail_rate", "iae_e", "rms_e", "peak_u", "in_region"]
    time_cols = ["plant", "design", "route", "solver", "n_solves", "lmi_size", "lmi_margin", "compile_s", "solve_s",
                 "design_s", "cert_s", "sim_s"]
    with_gains = df[df["max_re_eig_x"].notna()]
    parts = [
        "# oslbench report",
        "",
        f"Command: `{run_info['command']}`. Seed {o.seed}; measurement noise sigma = {o.noise:g}; "
        + (f"disturbance peak {o.disturbance:g} (measured L2 ratios from z(0) = 0 in `l2_measured_e`, `l2_measured_x`); "
           if o.disturbance > 0 else "")
        + f"designs use the "
        f"{'constants claimed by the sources' if o.use_claimed else 'valid constants (analytic, else sampled)'}; "
        f"{len(df)} pairs. One row per pair in `results.csv` (every verdict below is a column there), gains and "
        "certificates in `gains.json`, settings, versions and these findings in `run.json`, LaTeX tables in "
        "`tables.tex` (`pdflatex tables_standalone.tex` compiles them), this report as one page with sortable and "
        "filterable tables in `report.html`.",
        "",
        "## What the suite found",
        "",
        _summary(found),
        "",
        _LEGEND,
        "",
        "## Feasibility and verdicts",
        "",
        _matrix(df),
        "",
        "## Certified decay rate by level",
        "",
        _ladder(df),
        "",
        "## Attenuation (L2 gains)",
        "",
        _attenuation_note(o.disturbance),
        "",
        _attenuation_table(df),
        "",
        *(["## Discrete-time plants", "",
           "Sampled plants (dt > 0 s), stepped; the certificate's contraction factor r per step and its rate "
           "-ln(r) / dt per second (the ceiling and the loop's rates, `max_re_eig_*` = ln(max |eig|) / dt, per "
           "second too).", "", _discrete_table(df), ""]
          if (df["dt"].astype(float) > 0).any() else []),
        "## Convergence",
        "",
        md_table(with_gains.to_dict("records"), conv_cols) if len(with_gains) else "No design produced gains.",
        "",
        "## Timing (seconds)",
        "",
        md_table(df.to_dict("records"), time_cols),
        "",
        "## Constants",
        "",
        "Sampled values are lower bounds from seeded random pairs refined by local optimisation. A claimed constant "
        "a sample exceeds is flagged with the violating pair; an analytic bound a sample exceeds is disproved and "
        "never used by certificates. Beta is sampled at the gamma in use.",
        "",
        _constants_table(result),
        "",
        "## Reasons, per plant",
        "",
        *_reasons(df),
        "## Figures",
        "",
        *_figure_lines(figures),
    ]
    return "\n".join(parts).rstrip() + "\n"


def _attenuation_note(amplitude: float) -> str:
    """The sentence above the attenuation table: what its columns are, and the run's disturbance."""
    head = ("Certified L2 gains (the strongest certified level's, `gains.json` has each level's with its P) from the "
            "disturbance w to e and to x, beside the ratios ||zeta||_L2 / ||w||_L2 measured from z(0) = 0")
    if amplitude > 0:
        return head + f" with the seeded disturbance of peak {amplitude:g} (`bench.disturbance`)."
    return head + ": this run had no disturbance (`--disturbance 0`), so no ratio was measured."


def _reasons(df) -> list[str]:
    reasons = df[(df["reason"] != "") & df["reason"].notna()]
    parts = []
    for pid in dict.fromkeys(reasons["plant"]):
        parts += [f"### {pid}", ""]
        parts += [f"- **{r.design}** ({r.status}): {format_cell(r.reason)}" for r in reasons[reasons["plant"] == pid].itertuples()]
        parts.append("")
    return parts


def _figure_lines(figures: list[tuple[str, str]]) -> list[str]:
    if not figures:
        return ["No converging pair to plot."]
    parts = []
    for caption, path in figures:
        parts += [f"![{caption}]({path})", "", f"*{caption}*", ""]
    return parts


def _num(v) -> float | None:
    """A finite float, else None (JSON null)."""
    v = float(v)
    return v if math.isfinite(v) else None


def _arr(M) -> list | None:
    return None if M is None else np.asarray(M).tolist()


def _region(lr) -> str:
    """Where a certificate's constraints hold, in words."""
    if lr.radius is None:
        return "everywhere"
    return f"{'|Hx|, |Hx_hat|' if lr.region_H is not None else '||x||, ||x_hat||'} <= {lr.radius:.17g}"


def _level_json(lr, plant) -> dict:
    """One certificate of gains.json: what an outside script needs to check it (docs/results.md)."""
    from bench.verdicts import certificate_scope

    scope = certificate_scope(lr.P if lr.certified else None, lr.radius, plant.x0, plant.x_hat0, H=lr.region_H)
    return {"level": lr.level, "status": lr.status, "decay_rate": _num(lr.decay_rate), "margin": _num(lr.margin),
            "reason": lr.reason, "P": _arr(lr.P), "scope": scope["cert_scope"],
            "radius": None if lr.radius is None else float(lr.radius), "region": _region(lr),
            "region_H": _arr(lr.region_H), "level_set": _num(scope["level_set"]), "level_x0": _num(scope["level_x0"]),
            "slopes": None if lr.slopes is None else {"lo": _arr(lr.slopes[0]), "hi": _arr(lr.slopes[1])},
            "dt": float(lr.dt), "contraction": _num(lr.contraction),
            "l2": {z: _gain_json(g) for z, g in lr.l2.items()}}


def _gain_json(g) -> dict:
    """One L2 gain of gains.json (:class:`bench.certify.Gain`): its claim and the P an outside script checks it
    with (``V' + |zeta|^2 - gain^2 |w|^2 <= 0``; discrete time ``V(z_{k+1}) - V(z_k) + ...``, docs/results.md)."""
    return {"zeta": g.zeta, "status": g.status, "gain": _num(g.gain), "level": g.level, "reason": g.reason,
            "P": _arr(g.P), "margin": _num(g.margin), "radius": None if g.radius is None else float(g.radius)}


def _pair_json(o) -> dict:
    """gains.json's entry of one pair: its checked gains, verdicts and every certificate (none for an error or a
    timeout row)."""
    r, rec, cert, loop = o.result, o.record, o.certificate, o.loop
    if rec["status"] in ("error", "timeout"):
        cert = None
    best = cert.best if cert is not None else None
    return {**{k: rec[k] for k in ("plant", "design", "status", "reason", "route")},
            "K": _arr(loop.K) if loop is not None else None, "F": _arr(loop.F) if loop is not None else None,
            "estimator": None if r.estimator is None else repr(r.estimator),
            "certified": bool(rec["certified"]), "cert_level": rec["cert_level"], "cert_scope": rec["cert_scope"],
            "decay_rate": _num(rec["decay_rate"]), "contraction": _num(rec["contraction"]),
            "l2_gain_e": _num(rec["l2_gain_e"]), "l2_gain_x": _num(rec["l2_gain_x"]),
            "best": None if best is None else "from_x0" if best is cert.local else best.level,
            "certificate": {} if cert is None else {lv: _level_json(lr, o.plant) for lv, lr in cert.levels.items()},
            "from_x0": None if cert is None or cert.local is None else _level_json(cert.local, o.plant)}


def _gains(result: RunResult) -> list[dict]:
    """gains.json: per pair with a controller, :func:`_pair_json`; a pair whose entry cannot be written (a value JSON
    cannot hold) is a note for that pair, never the loss of the file."""
    out = []
    for o in result.outcomes:
        if o.result is None or not o.result.has_controller:
            continue
        try:
            entry = _pair_json(o)
            json.dumps(entry)
        except Exception as exc:  # noqa: BLE001 - a plugin's value: this pair's note, not the report's failure
            rec = o.record
            entry = {"plant": rec["plant"], "design": rec["design"], "status": rec["status"],
                     "error": f"this pair's gains and certificates cannot be written to JSON: {type(exc).__name__}: "
                              f"{exc}"}
        out.append(entry)
    return out


def _sdp_solves(result: RunResult) -> dict:
    """The SDP solves the pairs took (their records' ``sdp_solves``: a pair from the cache counts those it took
    when it was computed): the total, the pairs and the mean per pair."""
    n = [o.record.get("sdp_solves") for o in result.outcomes]
    n = [int(v) for v in n if v is not None and math.isfinite(float(v))]
    return {"total": sum(n), "pairs": len(n), "per_pair": round(sum(n) / len(n), 2) if n else None}


def _run_json(result: RunResult, run_info: dict) -> dict:
    o = result.options
    return {
        **run_info,
        "seed": o.seed,
        "use_claimed_constants": o.use_claimed,
        "n_samples_constants": o.n_samples,
        "t_final_override": o.t_final,
        "horizon_cap": o.horizon_cap,
        "noise": o.noise,
        "noise_dt": o.noise_dt,
        "disturbance": o.disturbance,
        "timeout": o.timeout,
        "sim": {k: getattr(o.sim, k) for k in ("method", "rtol", "atol", "n_points", "blowup", "max_nfev")},
        "constants": {pid: rep.to_dict() for pid, rep in result.constants.items()},
        "constants_errors": result.constants_errors,
        **{f"git_{k}": v for k, v in git_revision().items()},
        "cache": {"dir": result.cache_dir, "hits": result.cache_hits, "misses": result.cache_misses},
        "sdp_solves": _sdp_solves(result),
        "versions": package_versions(),
        "platform": platform.platform(),
        "executable": sys.executable,
        "wall_s": round(result.wall_s, 3),
    }


def _render(result: RunResult, tmp: Path, run_info: dict, figures: bool, fmts: tuple[str, ...]) -> list[str]:
    (tmp / "figures").mkdir()
    check_cells(result.outcomes)
    df = result.frame()
    info = {**run_info, "findings": run_info.get("findings") or findings(df, result.constants)}
    jobs = _figure_jobs(result)
    save_figure_data(jobs, fmts, tmp / FIGURE_DATA)
    figs = _draw_jobs(jobs, tmp / "figures", fmts) if figures else []
    table = results_table(df)
    table.to_csv(tmp / "results.csv", index=False)
    gains = _gains(result)
    (tmp / "gains.json").write_text(json.dumps(gains, indent=1) + "\n", encoding="utf-8")
    (tmp / "run.json").write_text(json.dumps(_run_json(result, info), indent=1, default=str) + "\n",
                                  encoding="utf-8")
    pages = _pages(result, table, gains, tmp, info, figs)
    files = [f"figures/{p.name}" for p in sorted((tmp / "figures").iterdir())]
    return files + ["results.csv", "gains.json", "run.json", FIGURE_DATA, *pages]


def _pages(result: RunResult, table, gains: list[dict], tmp: Path, info: dict, figs: list[tuple[str, str]]
           ) -> list[str]:
    """Render the pages made from the results (REPORT.md last, for :func:`bench.outdir.publish`): the LaTeX tables,
    report.html (:func:`bench.html.render_html`, with the figures drawn into ``tmp``) and REPORT.md."""
    from bench.html import render_html

    df = result.frame()
    markdown = render_markdown(result, figs, info)
    (tmp / "tables.tex").write_text(tables_tex(df), encoding="utf-8")
    (tmp / "tables_standalone.tex").write_text(minimal_document(r"\input{tables.tex}"), encoding="utf-8")
    (tmp / "report.html").write_text(render_html(markdown, table, gains, tmp), encoding="utf-8")
    (tmp / "REPORT.md").write_text(markdown, encoding="utf-8")
    return ["tables.tex", "tables_standalone.tex", "report.html", "REPORT.md"]


def write_report(result: RunResult, out_dir: str | os.PathLike, run_info: dict, *, figures: bool = True,
                 figure_format="png") -> Path:
    """Write REPORT.md, report.html, results.csv, gains.json, run.json, figure_data.npz, tables.tex,
    tables_standalone.tex and figures/ into ``out_dir``, whole or not at all.

    Parameters
    ----------
    result : RunResult
    out_dir : path
    run_info : dict
        Must hold ``command``; extended with settings, versions, findings and constants into run.json.
    figures : bool
        Draw the figures.
    figure_format : str or iterable of str
        ``"png"``, ``"pdf"`` or both.

    Returns
    -------
    Path
        The REPORT.md path.

    Raises
    ------
    ValueError
        An unknown figure format.
    """
    from bench.outdir import publish, staged

    fmts = (figure_format,) if isinstance(figure_format, str) else tuple(figure_format)
    if not fmts or any(f not in ("png", "pdf") for f in fmts):
        raise ValueError(f"figure_format: each format must be 'png' or 'pdf', got {figure_format!r}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with staged(out, "report") as tmp:
        files = _render(result, tmp, run_info, figures, fmts)
        publish(out, tmp, files, writer="report")
    return out / "REPORT.md"


#: The files :func:`redraw` reads and keeps as they are.
RESULT_FILES = ("results.csv", "gains.json", "run.json")


def redraw(folder: str | os.PathLike, out_dir: str | os.PathLike | None = None, *, figures: bool = True,
           figure_format=None) -> Path:
    """Render REPORT.md, report.html, tables.tex, tables_standalone.tex and the figures of a report folder again from
    its files (results.csv, gains.json, run.json, figure_data.npz), computing nothing; whole or not at all.

    Parameters
    ----------
    folder : path
        A report folder (:func:`write_report`).
    out_dir : path, optional
        Where to write (default: ``folder`` itself); the result files are copied there unchanged.
    figures : bool
        Draw the figures (from :data:`FIGURE_DATA`).
    figure_format : str or iterable of str, optional
        ``"png"``, ``"pdf"`` or both (default: the formats the run drew).

    Returns
    -------
    Path
        The REPORT.md path.

    Raises
    ------
    bench.errors.OutDirError
        ``folder`` is not a report folder, or ``out_dir`` cannot be written.
    ValueError
        A file of the folder that cannot be read (the message names it), an unknown figure format.
    """
    import shutil

    from bench.outdir import check_out_dir, publish, staged
    from bench.reload import read_report

    loaded = read_report(folder)
    fmts = loaded.figure_formats if figure_format is None else (
        (figure_format,) if isinstance(figure_format, str) else tuple(figure_format))
    if not fmts or any(f not in ("png", "pdf") for f in fmts):
        raise ValueError(f"figure_format: each format must be 'png' or 'pdf', got {figure_format!r}")
    if figures and loaded.figure_jobs is None:
        raise ValueError(f"{loaded.folder}: no {FIGURE_DATA} (written by an older oslbench): the figures cannot be "
                         "redrawn; redraw without them (--no-figures), or run again")
    out = check_out_dir(loaded.folder if out_dir is None else out_dir)
    with staged(out, "report") as tmp:
        (tmp / "figures").mkdir()
        kept = [*RESULT_FILES, *([FIGURE_DATA] if loaded.figure_jobs is not None else [])]
        for name in kept:
            shutil.copyfile(loaded.folder / name, tmp / name)
        figs = _draw_jobs(loaded.figure_jobs, tmp / "figures", fmts) if figures else []
        pages = _pages(loaded.result, loaded.table, loaded.gains, tmp, loaded.run_info, figs)
        files = [f"figures/{p.name}" for p in sorted((tmp / "figures").iterdir())]
        publish(out, tmp, files + kept + pages, writer="report")
    return out / "REPORT.md"
