"""What ``python -m bench run`` and ``python -m bench study`` check before any computing."""

from __future__ import annotations

import sys

from bench.registry import DESIGNS, PLANTS, UnknownIdError

__all__ = ["check_selection"]


def check_selection(prog: str, plant_globs, design_globs, out, *, all_by_default: bool = True,
                    keep_order: bool = False):
    """What ``run`` and ``study`` check before any computing: the ids the globs select, and ``out`` usable.

    Parameters
    ----------
    prog : str
        The command, at the start of the error line (``python -m bench run``).
    plant_globs, design_globs : list of str or None
        ``--plant`` and ``--design``.
    out : str
        ``--out`` (created if missing).
    all_by_default : bool
        Without globs: every registered id (True), or None for the caller's own default.
    keep_order : bool
        The ids in the order of the globs (True) or of the registry (:meth:`bench.registry.Registry.select`).

    Returns
    -------
    (list of str or None, list of str or None) or None
        The plant and design ids; None after printing the one-line error (exit code 2): an
        unknown id (with "did you mean") or an unusable output folder.
    """
    from bench.outdir import OutDirError, check_out_dir

    try:
        plant_ids = PLANTS.select(plant_globs, keep_order=keep_order) if plant_globs or all_by_default else None
        design_ids = DESIGNS.select(design_globs, keep_order=keep_order) if design_globs or all_by_default else None
        check_out_dir(out)  # an unusable --out is found now, not after the run
    except (UnknownIdError, OutDirError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return None
    return plant_ids, design_ids
