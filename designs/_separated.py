"""Separated solves: the x-side and e-side LMIs alone, then a joint certificate rebuilt from them.

Without the Young coupling the corrected Theorem 1 (and Corollary 1) LMI splits into an x-side
LMI in (Q, Fh, kappa) and an e-side LMI in (R, Kh, multipliers), each 2n x 2n. The joint LMI
is feasible iff both are (MATH.md): given strictly feasible sides with margins ``X < 0`` and
``E < 0``, Schur complements on the Young blocks ``-Q/phi`` and ``-phi Q`` show that the joint
matrix is negative definite iff

- x-side: ``X + diag(phi B Fh' Q^{-1} Fh B', 0) < 0``, true for
  ``phi = 0.5 |lmax(X)| / lmax(B Fh' Q^{-1} Fh B')``, and
- e-side: ``s E + diag(Q^{-1} / phi, 0) < 0`` with the e-variables scaled by s > 0 (the e-side
  is homogeneous in them, and K = R^{-1} Kh' does not change), true for
  ``s = 2 / (phi lmin(Q) |lmax(E)|)``.

The joint matrix is then rebuilt with numpy at (Q, Fh, kappa, sR, sKh, s eps..., phi). Its
entries span many orders of magnitude (phi can be tiny and s large), so it is verified after
the congruence ``D M D`` with ``D = diag(|M_ii|^{-1/2})`` (Jacobi equilibration): by Sylvester's
law of inertia ``D M D < 0`` iff ``M < 0``, and the equilibrated matrix has a unit diagonal
scale, so its largest eigenvalue (the reported margin) is a well-conditioned test. The raw
largest eigenvalue is reported too. An interior-point
solver's cost grows roughly with the cube of the PSD cone's size, so two 2n cones are much
cheaper than one 6n cone.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from bench import lmi
from designs._core import DesignResult

__all__ = ["coordinate_hint", "joint_result", "paper_gains_from", "recombine", "scalar", "separated_design", "synthesis_variables",
           "young_layout"]


def young_layout(n: int, s11: Callable[[dict], object], eside: Callable[[dict], list],
                 schur_weight: Callable[[dict], object] | None):
    """Block functions ``(joint, xside, eside)`` of a corrected Theorem 1 / Corollary 1 LMI.

    Both LMIs share one layout (MATH.md): the x-side block ``s11`` (``AQ + QA' + B Fh' +
    Fh B' + kappa I``), an e-side 2 x 2 block matrix ``[[E11, E12], [E12', E22]]``, the Young
    coupling of ``-B F e`` through ``-Q/phi`` and ``-phi Q``, and, when ``schur_weight`` is
    given, the Schur column ``Q`` with ``-w I`` (``w = kappa / beta_eff`` or ``kappa / alpha^2``)::

        [ s11    0     0     B Fh'    0        Q    ]
        [ 0      E11   E12   0        I        0    ]
        [ 0      E12'  E22   0        0        0    ]
        [ Fh B'  0     0     -Q/phi   0        0    ]
        [ 0      I     0     0        -phi Q   0    ]
        [ Q      0     0     0        0        -w I ]

    The functions read ``B``, ``Q``, ``Fh``, ``phi`` and ``iphi`` (= 1/phi) from the values dict,
    so they build the cvxpy matrix (Parameters) and the numeric one (arrays) alike.

    Parameters
    ----------
    n : int
    s11 : callable
        ``s11(values)``: the x-side (1, 1) block.
    eside : callable
        ``eside(values)``: the e-side blocks ``[[E11, E12], [E21, E22]]``.
    schur_weight : callable or None
        ``schur_weight(values)``: the scalar ``w`` of the Schur block, or None without the column.

    Returns
    -------
    joint, xside, eside : callable
    """
    I, Z = np.eye(n), np.zeros((n, n))

    def joint(d):
        (E11, E12), (E21, E22) = eside(d)
        B, Q, Fh = d["B"], d["Q"], d["Fh"]
        rows = [
            [s11(d), Z, Z, B @ Fh.T, Z],
            [Z, E11, E12, Z, I],
            [Z, E21, E22, Z, Z],
            [Fh @ B.T, Z, Z, -d["iphi"] * Q, Z],
            [Z, I, Z, Z, -d["phi"] * Q],
        ]
        if schur_weight is not None:
            for row, blk in zip(rows, (Q, Z, Z, Z, Z)):
                row.append(blk)
            rows.append([Q, Z, Z, Z, Z, -schur_weight(d) * I])
        return rows

    def xside(d):
        if schur_weight is None:
            return [[s11(d)]]
        return [[s11(d), d["Q"]], [d["Q"], -schur_weight(d) * I]]

    return joint, xside, eside


def recombine(
    B: np.ndarray,
    xprog: lmi.Program,
    eprog: lmi.Program,
    e_keys: tuple[str, ...],
    joint_blocks: Callable[[dict], list],
) -> dict:
    """Rebuild and verify the joint certificate from solved x-side and e-side programs.

    Parameters
    ----------
    B : ndarray
    xprog, eprog : Program
        Solved (restored to their best point) x-side and e-side programs; the x-side holds
        ``Q`` and ``Fh``.
    e_keys : tuple of str
        The e-side variables, all scaled by s.
    joint_blocks : callable
        Blocks of the joint LMI, taking the values of both sides plus ``phi`` and ``iphi``.

    Returns
    -------
    dict
        ``status`` (feasible / infeasible / undecided), ``reason``, ``margin`` (largest eigenvalue of
        the equilibrated joint matrix, verified), ``raw_margin`` (of the joint matrix itself),
        ``lmi_size``, ``min_eig``, ``phi``, ``scale``, ``x_margin``, ``e_margin``, ``values``.
    """
    out: dict = {"margin": float("nan"), "lmi_size": 0, "min_eig": {}, "phi": float("nan"),
                 "scale": float("nan"), "x_margin": float("nan"), "e_margin": float("nan"), "values": None}
    for side, prog in (("x-side", xprog), ("e-side", eprog)):
        if prog.last_status not in ("optimal", "optimal_inaccurate"):
            out.update(status="undecided", reason=f"{side} solver status {prog.last_status!r} {prog.last_error}".strip())
            return out
    X, E = xprog.numeric_matrix(), eprog.numeric_matrix()
    xv, ev = xprog.values(), eprog.values()
    lx, le = lmi.max_eig(X), lmi.max_eig(E)
    out.update(x_margin=lx, e_margin=le)
    qmin = lmi.min_eig(xv["Q"])
    sides = {"x-side": (lmi.classify(lx, X), xprog), "e-side": (lmi.classify(le, E), eprog)}
    if not lmi.is_positive_definite(xv["Q"]):
        sides["x-side"] = ("violated", xprog)
    bad = [name for name, (verdict, _) in sides.items() if verdict != "verified"]
    # a solver that claimed a positive margin its point does not have: undecided, not infeasible
    claimed = [name for name in bad if float(sides[name][1].values()["t"]) > lmi.verify_tol(X if name == "x-side" else E)]
    margins = f"max eig x-side {lx:.3g}, e-side {le:.3g}"
    if claimed:
        out.update(status="undecided", reason=(
            f"the solver reported a positive margin on the {' and '.join(claimed)} but the recomputed matrix "
            f"does not verify ({margins})"))
        return out
    if bad:
        marginal = all(sides[name][0] == "marginal" for name in bad)
        status = "marginal" if marginal else "infeasible"
        what = ("within the verification tolerance of zero (neither strictly feasible nor proven infeasible)"
                if marginal else "not strictly feasible under the normalisation")
        out.update(status=status, reason=(
            f"the {' and '.join(bad)} {'is' if len(bad) == 1 else 'are'} {what} ({margins}); the joint LMI is "
            "feasible iff both sides are"))
        return out
    Q, Fh = xv["Q"], xv["Fh"]
    BF = B @ np.linalg.solve(Q, Fh).T  # B Fh' Q^{-1}
    G = BF @ Q @ BF.T  # = B Fh' Q^{-1} Fh B'
    gmax = lmi.max_eig(G)
    phi = 0.5 * abs(lx) / gmax if gmax > 0 else 1.0
    s = 2.0 / (phi * qmin * abs(le))
    vals = {**xv, **ev}
    for k in e_keys:
        vals[k] = ev[k] * s
    vals.update(phi=phi, iphi=1.0 / phi)
    M = lmi.assemble(joint_blocks, vals, numeric=True)
    M = (M + M.T) / 2
    diag = np.diag(M)
    raw = lmi.max_eig(M)
    if np.all(diag < 0):
        d = 1.0 / np.sqrt(-diag)
        Meq = M * d[:, None] * d[None, :]
        margin = lmi.max_eig(Meq)
    else:
        Meq, margin = M, float("inf")  # a nonnegative diagonal entry: not negative definite
    min_eig = {"Q": qmin, "R": lmi.min_eig(vals["R"])}
    out.update(margin=margin, raw_margin=raw, lmi_size=int(M.shape[0]), min_eig=min_eig, phi=phi, scale=s,
               values=vals)
    if lmi.classify(margin, Meq) == "verified" and lmi.is_positive_definite(vals["R"]):
        out.update(status="feasible", reason="")
    else:
        out.update(status="undecided", reason=(
            f"both sides are strictly feasible (max eig {lx:.3g}, {le:.3g}) but the rebuilt joint matrix has max eig "
            f"{raw:.3g} (equilibrated {margin:.3g}; phi1 = {phi:.3g}, e-scale {s:.3g}): numerical range exceeded"))
    return out


def separated_design(plant, blocks, e_scalars: tuple[str, ...], *, solver: str, cap: float, what: str,
                     phi_name: str, extra_params, key: tuple, constants: dict):
    """Solve the x-side (Q, Fh, kappa) and e-side (R, Kh, ``e_scalars``) apart and rebuild the joint.

    Parameters
    ----------
    plant : Plant
    blocks : tuple
        ``(joint, xside, eside)`` block functions of the design.
    e_scalars : tuple of str
        Nonnegative scalar variables of the e-side (scaled with R and Kh).
    solver : str
        ``"auto"``, ``"CLARABEL"`` or ``"SCS"`` (see :func:`bench.lmi.solve_side`).
    cap : float
        Normalisation cap.
    what : str
        Name of the design for reasons.
    phi_name : str
        Name under which the recombination's Young weight is reported.
    extra_params : callable
        ``extra_params(values) -> dict`` of design-specific scalars to report.
    key : tuple
        Identifies the design's structure (e.g. ``("thm1.sep", schur)``); with the shape and
        the cap it keys the compiled side programs (:func:`designs.lmi.cached_program`).
    constants : dict
        The design's scalar constants (each becomes a cvxpy Parameter of both sides); the
        plant's ``A``, ``B``, ``C`` enter as :func:`designs.lmi.plant_matrices`.

    Returns
    -------
    DesignResult
    """
    import cvxpy as cp

    n, m, p = plant.n, plant.m, plant.p
    joint, xside, eside = blocks
    scalars = tuple(constants)
    mats = lmi.plant_matrices(plant)

    def params() -> dict:
        return {**mats.parameters(), **lmi.scalar_parameters(*scalars)}

    def build_x():
        xv = {"Q": cp.Variable((n, n), symmetric=True), "Fh": cp.Variable((n, m)), "kappa": cp.Variable(),
              "t": cp.Variable()}
        return lmi.margin_program(xside, xv, params(), ("Q",), lambda d: [d["kappa"] >= 0], cap=cap)

    def build_e():
        ev = {"R": cp.Variable((n, n), symmetric=True), "Kh": cp.Variable((p, n)), "t": cp.Variable()}
        ev.update({k: cp.Variable() for k in e_scalars})
        return lmi.margin_program(eside, ev, params(), ("R",), lambda d: [d[k] >= 0 for k in e_scalars], cap=cap)

    shape = (n, m, p, scalars, float(cap), mats.key)
    xprog = lmi.cached_program((*key, "x-side", *shape), build_x)
    eprog = lmi.cached_program((*key, "e-side", *shape), build_e)
    xprog.set(**mats.settable(), **constants)
    eprog.set(**mats.settable(), **constants)
    xlog = lmi.solve_side(xprog, solver, n)
    elog = lmi.solve_side(eprog, solver, n)
    rc = recombine(B=plant.B, xprog=xprog, eprog=eprog, e_keys=("R", "Kh", *e_scalars), joint_blocks=joint)
    K = F = None
    vals = rc["values"] or {}
    if rc["status"] == "feasible":
        K, F = paper_gains_from(vals)
    used = "+".join(dict.fromkeys((xprog.solver, eprog.solver)))
    return DesignResult(
        status=rc["status"], reason=rc["reason"] and f"{what} (separated): {rc['reason']}", route="sdp",
        K=K, F=F, solver=used, solver_status=f"x {xlog}; e {elog}",
        compile_s=xprog.compile_s + eprog.compile_s, solve_s=xprog.solve_s + eprog.solve_s,
        n_solves=xprog.n_solves + eprog.n_solves, margin=rc["margin"], lmi_size=rc["lmi_size"],
        min_eig=rc["min_eig"],
        params={"form": "separated (x-side and e-side apart, joint certificate rebuilt)", phi_name: rc["phi"],
                "e_scale": rc["scale"], "x_margin": rc["x_margin"], "e_margin": rc["e_margin"],
                "raw_joint_margin": rc.get("raw_margin", float("nan")), "cap": cap, **extra_params(vals)})


# -- helpers shared by the corrected Theorem 1 and Corollary 1 ---------------------------------
def synthesis_variables(n: int, m: int, p: int, scalars: tuple[str, ...]) -> dict:
    """cvxpy variables Q, R (n x n symmetric), Fh (n x m), Kh (p x n), the margin t and ``scalars``."""
    import cvxpy as cp

    v = {
        "Q": cp.Variable((n, n), symmetric=True, name="Q"),
        "R": cp.Variable((n, n), symmetric=True, name="R"),
        "Fh": cp.Variable((n, m), name="Fhat"),
        "Kh": cp.Variable((p, n), name="Khat"),
        "t": cp.Variable(name="t"),
    }
    for s in scalars:
        v[s] = cp.Variable(name=s)
    return v


def paper_gains_from(vals: dict) -> tuple[np.ndarray, np.ndarray]:
    """K = R^{-1} Khat', F = Fhat' Q^{-1} (the paper's recovery, correct as printed)."""
    K = np.linalg.solve(vals["R"], vals["Kh"].T)
    F = np.linalg.solve(vals["Q"], vals["Fh"]).T  # Q symmetric: Fh' Q^-1 = (Q^-1 Fh)'
    return K, F


def scalar(vals: dict, k: str) -> float:
    """``vals[k]`` as a float (NaN when unsolved)."""
    v = vals.get(k)
    return float(v) if v is not None else float("nan")


def joint_result(prog: lmi.Program, concl: dict, params: dict) -> DesignResult:
    """The :class:`DesignResult` of a joint LMI program concluded by :func:`bench.lmi.conclude`."""
    K = F = None
    if concl["status"] == "feasible":
        K, F = paper_gains_from(prog.values())
    return DesignResult(
        status=concl["status"], reason=concl["reason"], route="sdp", K=K, F=F, solver=prog.solver,
        solver_status=concl["solver_status"], compile_s=prog.compile_s, solve_s=prog.solve_s,
        n_solves=prog.n_solves, margin=concl["margin"], lmi_size=concl["lmi_size"], min_eig=concl["min_eig"],
        params={**params, "margin_t": concl.get("t", float("nan"))},
    )


def coordinate_hint(plant, res: DesignResult, variant: str) -> DesignResult:
    """Append to an infeasible or marginal result that the scalar constants depend on the coordinates.

    The constants of f change with a state scaling ``x = D x~``; for a plant with channels the
    ``variant`` design (e.g. ``thm1_scaled``) searches one (:mod:`designs.scaled`).
    """
    scaled_already = plant.id.endswith(".scaled")
    if res.status in ("infeasible", "marginal") and plant.channels is not None and not scaled_already:
        res.reason += (f"; the scalar constants depend on the state's coordinates: {variant} searches a diagonal "
                       "scaling, and the structured design uses the channels themselves")
    return res
