"""What a run found, in a few lines: computed from the records and the constants, rendered by the report.

:func:`findings` decides nothing new about a pair (the pipeline did): it only selects and counts what the
results table (:data:`bench.pipeline.COLUMNS`) and the plants' constants reports hold; run.json stores it.
"""

from __future__ import annotations

__all__ = ["findings"]


def _best(sub) -> dict | None:
    cert = sub[sub["certified"].astype(bool)]
    if not len(cert):
        return None
    r = cert.loc[cert["decay_rate"].astype(float).idxmax()]
    return {"design": r["design"], "level": r["cert_level"], "decay_rate": float(r["decay_rate"]),
            "scope": r["cert_scope"], "peak_u": float(r["peak_u"]), "converged": bool(r["converged"]),
            "rate_ratio": float(r.get("rate_ratio", float("nan")))}


def _best_gains(sub) -> dict:
    """Per ``zeta`` in (e, x): the design with the smallest certified L2 gain ``l2_gain_<zeta>`` and that gain
    (designs within a relative 1e-4 of it, ties, joined by ", "; empty where no pair has one: a plant without
    disturbance inputs, or nothing certified)."""
    out = {}
    for z in ("e", "x"):
        col = f"l2_gain_{z}"
        if col not in sub:
            continue
        g = sub[col].astype(float)
        if g.notna().any():
            best = float(g.min())
            tied = sub["design"][g <= best * (1 + 1e-4)]
            out[z] = {"design": ", ".join(map(str, tied)), "gain": best}
    return out


def findings(frame, constants: dict) -> dict:
    """The run's findings.

    Parameters
    ----------
    frame : pandas.DataFrame
        The results table.
    constants : dict
        Plant id -> :class:`bench.constants.ConstantsReport`.

    Returns
    -------
    dict
        ``plants`` (per plant: ``best`` certified design or None, ``best_gains`` (the smallest certified L2
        gain to e and to x with its design, :func:`_best_gains`), ``uncertified_converging`` split
        into ``no_certificate_can_exist`` (a witness rules a global certificate out) and
        ``no_certificate_found``, ``certified_pairs``, ``pairs``), ``violated_claims``, ``disproved``
        (by the samplers or along a pair's simulation), ``printed_infeasible``, ``inconsistent``
        (with the ``witness`` time and state) (lists of dicts, JSON-ready), and ``counts`` of the
        lists that must be empty in a sound run (``inconsistent_attenuation``: the INCONSISTENT rows whose
        certified L2 gain is below its measured ratio, :func:`bench.verdicts.attenuation_note`).
    """
    plants = {}
    for pid in dict.fromkeys(frame["plant"]):
        sub = frame[frame["plant"] == pid]
        conv_uncert = sub[sub["converged"].astype(bool) & ~sub["certified"].astype(bool)]
        witnessed = (conv_uncert["witness"].fillna("").astype(str).ne("") if "witness" in sub
                     else conv_uncert["design"].isna())  # no witness column: none witnessed
        plants[pid] = {"best": _best(sub), "best_gains": _best_gains(sub),
                       "uncertified_converging": list(conv_uncert["design"]),
                       "no_certificate_can_exist": list(conv_uncert["design"][witnessed]),
                       "no_certificate_found": list(conv_uncert["design"][~witnessed]),
                       "certified_pairs": int(sub["certified"].astype(bool).sum()), "pairs": int(len(sub))}
    violated, disproved = [], []
    for pid, rep in constants.items():
        violated += [{"plant": pid, "constant": v.name, "claimed": v.claimed, "sampled": v.sampled,
                      "text": v.describe("claimed")} for v in rep.violations]
        for found, what in ((rep.disproved, "analytic"), (rep.channel_violations, "declared")):
            disproved += [{"plant": pid, "constant": v.name, "stated": v.claimed, "sampled": v.sampled,
                           "text": v.describe(what)} for v in found]
    if "disproved" in frame:
        import json

        for r in frame[frame["disproved"].fillna("").astype(str) != ""].itertuples():
            for name, text in json.loads(r.disproved).items():
                disproved.append({"plant": r.plant, "constant": name, "stated": None, "sampled": None,
                                  "text": f"{text} (simulation of {r.design})"})
    printed = frame[frame["design"].astype(str).str.endswith("_printed") & (frame["status"] == "infeasible")]
    printed_rows = [{"plant": r.plant, "design": r.design, "reason": r.reason} for r in printed.itertuples()]
    bad = frame[frame["reason"].astype(str).str.contains("INCONSISTENT")]
    inconsistent = [{"plant": r.plant, "design": r.design, "reason": r.reason,
                     "witness": getattr(r, "sim_witness", "")} for r in bad.itertuples()]
    attenuation = bad[bad["reason"].astype(str).str.contains(ATTENUATION_MARK, regex=False)]
    return {"plants": plants, "violated_claims": violated, "disproved": disproved,
            "printed_infeasible": printed_rows, "inconsistent": inconsistent,
            "counts": {"inconsistent": len(inconsistent), "inconsistent_attenuation": len(attenuation),
                       "disproved": len(disproved), "violated_claims": len(violated)}}


#: How :func:`bench.verdicts.attenuation_note`'s INCONSISTENT sentence begins (counted apart in ``counts``).
ATTENUATION_MARK = "INCONSISTENT with the certificate: the measured L2 ratio"


def constants_rows(constants: dict, errors: dict) -> list[dict]:
    """One row per plant and constant (``constants``: plant id -> report; ``errors``: plant id -> why its
    constants failed): ``plant``, ``constant``, ``claimed``, ``analytic``, ``sampled``, ``used``,
    ``source``, ``region`` and the flags in ``flag``."""
    rows = []
    for pid, rep in constants.items():
        for name in ("alpha", "rho", "beta", "gamma"):
            flags = [f"{label}: {v.describe(what)}" for label, found, what in (
                ("CLAIM VIOLATED", rep.violations, "claimed"),
                ("ANALYTIC BOUND DISPROVED", rep.disproved, "analytic"),
            ) for v in found if v.name == name]
            if name in rep.unbounded:
                flags.append(rep.unbounded[name])
            rows.append(_row(
                pid, name, "; ".join(flags), claimed=getattr(rep.claimed, name),
                analytic=getattr(rep.analytic, name) if rep.analytic is not None else None,
                sampled=getattr(rep.sampled, name), used=getattr(rep.used, name),
                source=rep.source.get(name, "fixed" if name == "gamma" else ""),
                region=rep.region,
            ))
        for v in rep.channel_violations:
            rows.append(_row(pid, v.name, f"CHANNEL SLOPE DISPROVED: {v.describe('declared')}", analytic=v.claimed,
                             sampled=v.sampled, source="declared channels", region=rep.region))
        rows += [_row(pid, "(A, B, C)", msg) for msg in rep.prechecks]
    rows += [_row(pid, "(error)", err) for pid, err in errors.items()]
    return rows


def _row(pid: str, constant: str, flag: str, **values) -> dict:
    """A row of :func:`constants_rows`; the values not given are None (``source``, ``region``: empty)."""
    return {"plant": pid, "constant": constant, "claimed": None, "analytic": None, "sampled": None, "used": None,
            "source": "", "region": "", **values, "flag": flag}
