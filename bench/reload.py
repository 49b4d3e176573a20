"""A report folder read back: the run's results from its files, for :meth:`bench.api.Results.load` and
``python -m bench report`` (:func:`bench.report.redraw`), without computing anything.

results.csv gives the records: each cell is read back as the kind of its column (:func:`bench.pipeline.blank_record`:
text, a flag True/False/blank, or a number; a column the code does not know by its text), so that the table and
everything rendered from it are what the run rendered. run.json gives the settings, the findings and the plants'
constants (:meth:`bench.constants.ConstantsReport.from_dict`), gains.json the gains and certificates,
:data:`bench.report.FIGURE_DATA` what the figures plot.
"""

from __future__ import annotations

import csv
import json
import math
import os
import re
from dataclasses import dataclass, field, fields
from pathlib import Path

from bench.errors import OutDirError

__all__ = ["Loaded", "read_report"]

#: run.json's keys of the run options (:class:`bench.pipeline.RunOptions` field -> key).
_OPTION_KEYS = {"seed": "seed", "use_claimed": "use_claimed_constants", "n_samples": "n_samples_constants",
                "t_final": "t_final_override", "horizon_cap": "horizon_cap", "noise": "noise", "noise_dt": "noise_dt",
                "disturbance": "disturbance", "timeout": "timeout"}
#: run.json's keys that :func:`bench.report._run_json` writes (the others are the run's selection: ``Results.info``).
_SETTINGS = {"command", "findings", "seed", "use_claimed_constants", "n_samples_constants", "t_final_override",
             "horizon_cap", "noise", "noise_dt", "disturbance", "timeout", "sim", "constants", "constants_errors",
             "git_commit", "git_dirty", "cache", "sdp_solves", "versions", "platform", "executable", "wall_s"}
_INT = re.compile(r"[-+]?\d+")


@dataclass
class Loaded:
    """What a report folder holds.

    Attributes
    ----------
    folder : Path
    result : bench.harness.RunResult
        The records (``reason`` the full text), the constants, the options; no design results, certificates or
        trajectories (they are in ``gains`` and ``figure_jobs``).
    table : pandas.DataFrame
        results.csv, each cell of its column's kind.
    gains : list of dict
        gains.json.
    run_info : dict
        run.json.
    figure_jobs : list or None
        The figures' data (None: the folder has no :data:`bench.report.FIGURE_DATA`).
    figure_formats : tuple of str
    """

    folder: Path
    result: object
    table: object
    gains: list
    run_info: dict
    figure_jobs: list | None = None
    figure_formats: tuple = ("png",)
    info: dict = field(default_factory=dict)


def _kinds() -> dict:
    """Column -> its blank value (:func:`bench.pipeline.blank_record`), whose type says the column's kind."""
    from bench.pipeline import blank_record

    return blank_record("", "")


def _number(text: str):
    return int(text) if _INT.fullmatch(text) else float(text)


def cell(text: str, blank):
    """A results.csv cell as the kind of its column (``blank``: the column's blank value; ``...``: unknown column).

    Text stays text; a flag is True, False or None (blank); a number is an int when written as one, else a float
    (blank: NaN); in a column of unknown kind, True/False are flags, numbers numbers, the rest text.
    """
    if blank is ...:
        if text in ("True", "False"):
            return text == "True"
        try:
            return _number(text)
        except ValueError:
            return text
    if isinstance(blank, str):
        return text
    if blank is None or isinstance(blank, bool):
        if text == "":
            return blank
        if text in ("True", "False"):
            return text == "True"
        raise ValueError(f"expected True, False or blank, got {text!r}")
    if text == "":
        return math.nan
    return _number(text)


def read_table(path: Path):
    """results.csv as the DataFrame the run returned (:func:`cell`); ValueError naming the file, row and column."""
    import pandas as pd

    kinds = _kinds()
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if not header or "plant" not in header or "design" not in header:
            raise ValueError(f"{path}: not a results table (no plant and design columns)")
        rows = []
        for k, row in enumerate(reader, start=2):
            if len(row) != len(header):
                raise ValueError(f"{path}, line {k}: {len(row)} cells for {len(header)} columns")
            rec = {}
            for c, text in zip(header, row):
                try:
                    rec[c] = cell(text, "" if c == "details" else kinds.get(c, ...))
                except ValueError as exc:
                    raise ValueError(f"{path}, line {k}, column {c!r}: {exc}") from None
            rows.append(rec)
    return pd.DataFrame(rows, columns=header)


def _options(run: dict):
    """The :class:`bench.pipeline.RunOptions` run.json records (what it does not record: the defaults)."""
    from bench.pipeline import RunOptions
    from bench.simulate import SimOptions

    kw = {f: run[k] for f, k in _OPTION_KEYS.items() if k in run}
    sim = run.get("sim")
    if isinstance(sim, dict):
        known = {f.name for f in fields(SimOptions)}
        kw["sim"] = SimOptions(**{k: v for k, v in sim.items() if k in known})
    return RunOptions(**kw)


def read_report(folder: str | os.PathLike) -> Loaded:
    """Read a report folder (see the module docstring).

    Parameters
    ----------
    folder : path

    Returns
    -------
    Loaded

    Raises
    ------
    OutDirError
        ``folder`` is not a folder, or lacks results.csv, gains.json or run.json.
    ValueError
        A file that cannot be read as the report wrote it (the message names it).
    """
    from bench.constants import ConstantsReport
    from bench.harness import RunResult
    from bench.pipeline import PairOutcome
    from bench.report import FIGURE_DATA, RESULT_FILES, load_figure_data

    path = Path(os.fsdecode(folder))
    if not path.is_dir():
        raise OutDirError(f"{os.fsdecode(folder)!r}: not a folder")
    missing = [name for name in RESULT_FILES if not (path / name).is_file()]
    if missing:
        raise OutDirError(f"{path}: not a report folder (no {', '.join(missing)}); write one with python -m bench run "
                          "or Results.write")
    table = read_table(path / "results.csv")
    docs = {}
    for name in ("gains.json", "run.json"):
        try:
            docs[name] = json.loads((path / name).read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise ValueError(f"{path / name}: cannot be read ({type(exc).__name__}: {exc})") from None
    gains, run = docs["gains.json"], docs["run.json"]
    if not isinstance(gains, list) or not isinstance(run, dict):
        raise ValueError(f"{path}: gains.json must hold a list and run.json an object")
    try:
        constants = {pid: ConstantsReport.from_dict(doc) for pid, doc in (run.get("constants") or {}).items()}
        options = _options(run)
    except (TypeError, ValueError, KeyError) as exc:
        raise ValueError(f"{path / 'run.json'}: cannot be read as a run's settings and constants "
                         f"({type(exc).__name__}: {exc})") from None
    records = table.drop(columns=["details"]).to_dict("records") if "details" in table else table.to_dict("records")
    if "details" in table:
        for rec, text in zip(records, table["details"]):
            rec["reason"] = text
    result = RunResult([PairOutcome(rec) for rec in records], constants, dict(run.get("constants_errors") or {}),
                       options, float(run.get("wall_s") or 0.0), cache_dir=(run.get("cache") or {}).get("dir"),
                       cache_hits=int((run.get("cache") or {}).get("hits") or 0),
                       cache_misses=int((run.get("cache") or {}).get("misses") or 0))
    jobs, fmts = (None, ("png",))
    if (path / FIGURE_DATA).is_file():
        jobs, fmts = load_figure_data(path / FIGURE_DATA)
    info = {k: v for k, v in run.items() if k not in _SETTINGS}
    return Loaded(path, result, table, gains, run, jobs, fmts, info)
