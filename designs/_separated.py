"""The corrected Theorem 1 and Corollary 1 in one layout: the joint LMI, its two sides, their verdicts.

Without the Young coupling the joint LMI splits into an x-side in (Q, Fh, kappa) and an e-side in
(R, Kh, multipliers), each 2n x 2n, and the joint LMI is feasible iff both are (``docs/paper.md``): for
strictly feasible sides with margins ``X < 0`` and ``E < 0``, Schur complements on the Young blocks
``-Q/phi`` and ``-phi Q`` make the joint matrix negative definite at
``phi = 0.5 |lmax(X)| / lmax(B Fh' Q^{-1} Fh B')`` with the (homogeneous) e-side scaled by
``s = 2 / (phi lmin(Q) |lmax(E)|)``. The rebuilt joint matrix is verified after Jacobi equilibration
``D M D``, ``D = diag(|M_ii|^{-1/2})`` (Sylvester's law of inertia: ``D M D < 0`` iff ``M < 0``).

Each side is homogeneous, so under ``slack I << Q << cap I`` an infeasible side has best slack 0, like
one on the boundary. Such a side is decided again under the scale-free ``I << Q << cap I`` (R for the
e-side), where a clearly negative margin proves it infeasible; both sides are principal submatrices of
the joint matrix, so that proves the joint LMI infeasible (:func:`settle_joint`). The gains always come
from the capped solve.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from bench import lmi
from designs._core import DesignResult

#: The decision matrix that sets each side's scale.
SIDE_MATRIX = {"x-side": "Q", "e-side": "R"}


def state_feedback_block(d: dict):
    """``AQ + QA' + B Fh' + Fh B'``: the x-side's Lyapunov block (values dict, cvxpy or numpy)."""
    A, B, Q, Fh = d["A"], d["B"], d["Q"], d["Fh"]
    return A @ Q + Q @ A.T + B @ Fh.T + Fh @ B.T


def append_schur_column(rows: list, Q, corner) -> list:
    """Border the block rows with the Schur column ``[Q; 0; ...; 0]`` and the corner block ``corner``."""
    Z = np.zeros(Q.shape)
    for i, row in enumerate(rows):
        row.append(Q if i == 0 else Z)
    rows.append([Q, *[Z] * (len(rows) - 1), corner])
    return rows


def young_layout(n: int, eside: Callable[[dict], list], schur_weight: Callable[[dict], object] | None):
    """Block functions ``(joint, xside, eside)`` of a corrected Theorem 1 / Corollary 1 LMI::

        [ s11    0     0     B Fh'    0        Q    ]
        [ 0      E11   E12   0        I        0    ]
        [ 0      E12'  E22   0        0        0    ]
        [ Fh B'  0     0     -Q/phi   0        0    ]
        [ 0      I     0     0        -phi Q   0    ]
        [ Q      0     0     0        0        -w I ]

    with ``s11 = AQ + QA' + B Fh' + Fh B' + kappa I``; the last row and column only with ``schur_weight``
    (``w = kappa / beta_eff`` or ``kappa / alpha^2``). The functions read ``A``, ``B``, ``Q``, ``Fh``,
    ``kappa``, ``phi``, ``iphi`` from a values dict, so they build cvxpy and numpy matrices alike.

    Parameters
    ----------
    n : int
    eside : callable
        ``eside(values)``: the e-side blocks ``[[E11, E12], [E21, E22]]``.
    schur_weight : callable or None
        ``schur_weight(values)``: ``w``, or None without the Schur column.

    Returns
    -------
    joint, xside, eside : callable
    """
    I, Z = np.eye(n), np.zeros((n, n))

    def s11(d):
        return state_feedback_block(d) + d["kappa"] * I

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
        return rows if schur_weight is None else append_schur_column(rows, Q, -schur_weight(d) * I)

    def xside(d):
        rows = [[s11(d)]]
        return rows if schur_weight is None else append_schur_column(rows, d["Q"], -schur_weight(d) * I)

    return joint, xside, eside


@dataclass(frozen=True)
class YoungForm:
    """One corrected LMI in the Young layout and its programs: ``what`` names it in reasons, ``key`` (with the
    shape and the cap) keys its compiled programs, ``blocks`` are :func:`young_layout`'s ``(joint, xside, eside)``,
    ``e_scalars`` the e-side's nonnegative scalars (the x-side has ``kappa``), ``constants`` the scalar Parameters.
    """

    what: str
    key: tuple
    blocks: tuple
    e_scalars: tuple[str, ...]
    constants: dict

    def joint_program(self, plant, *, cap: float, phi_name: str) -> lmi.Program:
        """The joint program (compiled once per shape), plant and constants set; ``phi`` left to the caller."""
        scalars = ("kappa", *self.e_scalars)
        return joint_program(plant, (*self.key, "joint"), self.blocks[0], scalars,
                             {"phi": phi_name, "iphi": f"inv_{phi_name}"}, self.constants,
                             lambda d: [d[k] >= 0 for k in scalars], cap=cap)

    def side_program(self, plant, side: str, *, cap: float, scale_free: bool = False) -> lmi.Program:
        """The x-side or e-side program, compiled once per shape; ``scale_free`` adds ``I << Q`` (``I << R``)."""
        n, m, p = plant.n, plant.m, plant.p
        X = SIDE_MATRIX[side]
        scalars, blocks = (("kappa",), self.blocks[1]) if side == "x-side" else (self.e_scalars, self.blocks[2])
        return side_program((*self.key, side, n, m, p, tuple(self.constants)), blocks,
                            lambda: synthesis_variables(n, m, p, scalars, (X, "Fh" if side == "x-side" else "Kh")),
                            lmi.plant_matrices(plant), self.constants, scalars, X, cap=cap, scale_free=scale_free)

    def decide_side(self, plant, side: str, *, cap: float, solver: str) -> dict:
        """Decide a side that is not strictly feasible under the capped normalisation by its scale-free solve:
        :func:`bench.lmi.conclude`'s dict plus ``normalisation``, ``cap`` and ``cost``.
        """
        prog = self.side_program(plant, side, cap=cap, scale_free=True)
        lmi.solve_side(prog, "CLARABEL" if solver == "auto" else solver)  # a verdict of infeasibility not left to SCS
        norm = f"I << {SIDE_MATRIX[side]} << {cap:g} I"
        out = lmi.conclude(prog, what=f"{self.what} {side}", normalisation=norm, searched="(scale-free)")
        out.update(normalisation=norm, cap=cap, cost=(prog.compile_s, prog.solve_s, prog.n_solves))
        return out


def _scale_free_clause(decided: dict[str, dict]) -> str:
    norms = " and ".join(d["normalisation"] for d in decided.values())
    ts = ", ".join(f"{d.get('slack', float('nan')):.3g}" for d in decided.values())
    mats = ", ".join(f"cond({SIDE_MATRIX[side]})" for side in decided)
    cap = max(d["cap"] for d in decided.values())
    return (f"not strictly feasible under the normalisation {norms} (best slack = {ts} there; "
            f"{'the side is' if len(decided) == 1 else 'each side is'} homogeneous in its variables, so this loses "
            f"only points with {mats} > {cap:g})")


def recombine(
    B: np.ndarray,
    xprog: lmi.Program,
    eprog: lmi.Program,
    form: YoungForm,
    decide: Callable[[str], dict] | None,
    joint_verdict: Callable[..., dict] | None = None,
) -> dict:
    """Rebuild and verify ``form``'s joint certificate from its solved x-side and e-side programs (module docstring).

    R, Kh and the e-side scalars are scaled by s; ``decide(side)`` (:meth:`YoungForm.decide_side`) labels a side
    that is not strictly feasible (None: undecided). Returns ``status``, ``reason``, ``margin`` (equilibrated joint
    matrix), ``raw_margin``, ``lmi_size``, ``min_eig``, ``phi``, ``scale``, ``x_margin``, ``e_margin``, ``values``,
    ``cost`` (and ``certificate`` when ``joint_verdict`` gives one). ``joint_verdict(B, xv, ev, form, lx, le)``
    replaces the continuous joint rebuild (the discrete forms: :mod:`designs._discrete`).
    """
    out: dict = {"margin": float("nan"), "lmi_size": 0, "min_eig": {}, "phi": float("nan"),
                 "scale": float("nan"), "x_margin": float("nan"), "e_margin": float("nan"), "values": None,
                 "cost": (0.0, 0.0, 0)}
    for side, prog in (("x-side", xprog), ("e-side", eprog)):
        if prog.last_status not in ("optimal", "optimal_inaccurate"):
            out.update(status="undecided", reason=f"{side} solver status {prog.last_status!r} {prog.last_error}".strip())
            return out
    X, E = xprog.numeric_matrix(), eprog.numeric_matrix()
    xv, ev = xprog.values(), eprog.values()
    lx, le = lmi.max_eig(X), lmi.max_eig(E)
    out.update(x_margin=lx, e_margin=le)
    failed = _failed_sides(xprog, eprog, X, E, lx, le, decide)
    out.update(failed if failed is not None else (joint_verdict or _joint_verdict)(B, xv, ev, form, lx, le))
    return out


def _failed_sides(xprog: lmi.Program, eprog: lmi.Program, X: np.ndarray, E: np.ndarray, lx: float, le: float,
                  decide: Callable[[str], dict] | None) -> dict | None:
    """Status and reason when a side does not verify (a solver's unverified positive margin: undecided); None if both do."""
    sides = {"x-side": (lmi.classify(lx, X), xprog), "e-side": (lmi.classify(le, E), eprog)}
    if not lmi.is_positive_definite(xprog.values()["Q"]):
        sides["x-side"] = ("violated", xprog)
    bad = [name for name, (verdict, _) in sides.items() if verdict != "verified"]
    if not bad:
        return None
    claimed = [name for name in bad if float(sides[name][1].values()["slack"]) > lmi.verify_tol(X if name == "x-side" else E)]
    margins = f"max eig x-side {lx:.3g}, e-side {le:.3g}"
    if claimed:
        return dict(status="undecided", reason=(
            f"the solver reported a positive margin on the {' and '.join(claimed)} but the recomputed matrix "
            f"does not verify ({margins})"))
    if decide is None:
        return dict(status="undecided", reason=(
            f"the {' and '.join(bad)} {'is' if len(bad) == 1 else 'are'} not strictly feasible under the "
            f"normalisation ({margins}), not decided further"))
    return _side_verdict({name: decide(name) for name in bad}, margins)


def _joint_verdict(B: np.ndarray, xv: dict, ev: dict, form: YoungForm, lx: float, le: float) -> dict:
    """The joint matrix rebuilt at the module docstring's ``phi`` and ``s``, its equilibrated margin and verdict."""
    qmin = lmi.min_eig(xv["Q"])
    Q, Fh = xv["Q"], xv["Fh"]
    BF = B @ np.linalg.solve(Q, Fh).T  # B Fh' Q^{-1}
    gmax = lmi.max_eig(BF @ Q @ BF.T)  # lmax(B Fh' Q^{-1} Fh B')
    phi = 0.5 * abs(lx) / gmax if gmax > 0 else 1.0
    s = 2.0 / (phi * qmin * abs(le))
    vals = {**xv, **ev, **{k: ev[k] * s for k in ("R", "Kh", *form.e_scalars)}, "phi": phi, "iphi": 1.0 / phi}
    M = lmi.assemble(form.blocks[0], vals, numeric=True)
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
    out = dict(margin=margin, raw_margin=raw, lmi_size=int(M.shape[0]), min_eig=min_eig, phi=phi, scale=s,
               values=vals)
    if lmi.classify(margin, Meq) == "verified" and lmi.is_positive_definite(vals["R"]):
        out.update(status="feasible", reason="")
    else:
        out.update(status="undecided", reason=(
            f"both sides are strictly feasible (max eig {lx:.3g}, {le:.3g}) but the rebuilt joint matrix has max eig "
            f"{raw:.3g} (equilibrated {margin:.3g}; phi1 = {phi:.3g}, e-scale {s:.3g}): numerical range exceeded"))
    return out


def _side_verdict(decided: dict[str, dict], margins: str) -> dict:
    """Status and reason from the scale-free solves of the sides that are not strictly feasible."""
    cost = tuple(sum(c) for c in zip(*(d["cost"] for d in decided.values())))
    proven = {k: d for k, d in decided.items() if d["status"] == "infeasible"}
    marginal = [k for k, d in decided.items() if d["status"] == "marginal"]
    clauses = []
    if proven:
        clauses.append(f"the {' and '.join(proven)} {'is' if len(proven) == 1 else 'are'} {_scale_free_clause(proven)}")
    if marginal:
        clauses.append(f"the {' and '.join(marginal)} {'is' if len(marginal) == 1 else 'are'} within the verification "
                       "tolerance of zero (neither strictly feasible nor proven infeasible)")
    if proven or len(marginal) == len(decided):
        status = "infeasible" if proven else "marginal"
        return {"status": status, "cost": cost, "reason": (
            f"{' and '.join(clauses)} ({margins}); the joint LMI is feasible iff both sides are")}
    other = next(k for k, d in decided.items() if d["status"] not in ("infeasible", "marginal"))
    return {"status": "undecided", "cost": cost, "reason": (
        f"the {other} is not strictly feasible under the normalisation {SIDE_MATRIX[other]} << cap I ({margins}), "
        f"but its scale-free solve is {decided[other]['status']}: {decided[other]['reason']}")}


def separated_design(plant, form: YoungForm, *, solver: str, cap: float, phi_name: str, extra_params,
                     decide: bool = True, joint_verdict: Callable[..., dict] | None = None,
                     form_name: str = "separated (x-side and e-side apart, joint certificate rebuilt)") -> DesignResult:
    """Solve ``form``'s x-side and e-side apart and rebuild the joint certificate (:func:`recombine`) as a
    :class:`DesignResult`; ``phi_name`` names the Young weight, ``extra_params(values)`` adds the design's scalars,
    ``decide=False`` leaves a side that is not strictly feasible undecided; ``joint_verdict`` as in
    :func:`recombine` (its ``certificate`` becomes the result's), ``form_name`` is ``params["form"]``.
    """
    xprog, eprog = (form.side_program(plant, side, cap=cap) for side in SIDE_MATRIX)
    xlog, elog = (lmi.solve_side(prog, solver, plant.n) for prog in (xprog, eprog))
    rc = recombine(B=plant.B, xprog=xprog, eprog=eprog, form=form,
                   decide=(lambda side: form.decide_side(plant, side, cap=cap, solver=solver)) if decide else None,
                   joint_verdict=joint_verdict)
    K = F = None
    vals = rc["values"] or {}
    if rc["status"] == "feasible":
        K, F = paper_gains_from(vals)
    used = "+".join(dict.fromkeys((xprog.solver, eprog.solver)))
    return DesignResult(
        status=rc["status"], reason=rc["reason"] and f"{form.what} (separated): {rc['reason']}", route="sdp",
        K=K, F=F, solver=used, solver_status=f"x {xlog}; e {elog}", margin=rc["margin"], lmi_size=rc["lmi_size"],
        min_eig=rc["min_eig"], **{k: getattr(xprog, k) + getattr(eprog, k) + c
                                  for k, c in zip(("compile_s", "solve_s", "n_solves"), rc["cost"])},
        certificate=rc.get("certificate") if rc["status"] == "feasible" else None,
        params={"form": form_name, phi_name: rc["phi"],
                "e_scale": rc["scale"], "x_margin": rc["x_margin"], "e_margin": rc["e_margin"],
                "raw_joint_margin": rc.get("raw_margin", float("nan")), "cap": cap, **extra_params(vals)})


def settle_joint(plant, form: YoungForm, concl: dict, *, cap: float, solver: str, searched: str,
                 normalisation: str) -> tuple[dict, tuple]:
    """Re-decide a marginal joint solve side by side: a side proven infeasible by its scale-free solve makes the
    joint LMI infeasible (a principal submatrix); else ``concl`` unchanged. Returns ``(concl, cost)``.
    """
    if concl["status"] != "marginal":
        return concl, (0.0, 0.0, 0)
    decided = {side: form.decide_side(plant, side, cap=cap, solver=solver) for side in SIDE_MATRIX}
    cost = tuple(sum(c) for c in zip(*(d["cost"] for d in decided.values())))
    proven = {k: d for k, d in decided.items() if d["status"] == "infeasible"}
    if not proven:
        return concl, cost
    block = "block is a principal submatrix" if len(proven) == 1 else "blocks are principal submatrices"
    reason = (f"{form.what}: infeasible: its {' and '.join(proven)} {block} of the joint LMI and "
              f"{'is' if len(proven) == 1 else 'are'} {_scale_free_clause(proven)}; the joint LMI's own best margin "
              f"is within the verification tolerance of zero (max eig {concl['margin']:.3g}) {searched}, under "
              f"{normalisation}")
    return {**concl, "status": "infeasible", "reason": reason}, cost


# -- helpers shared by the corrected Theorem 1, Corollary 1 and the LMI observers ----------------
def synthesis_variables(n: int, m: int, p: int, scalars: tuple[str, ...],
                        matrices: tuple[str, ...] = ("Q", "R", "Fh", "Kh")) -> dict:
    """cvxpy variables ``matrices`` among Q, R, P (symmetric), Fh (n x m), Kh (p x n), W (n x p), the margin
    ``slack`` and ``scalars``."""
    import cvxpy as cp

    shapes = {"Q": (n, n), "R": (n, n), "P": (n, n), "Fh": (n, m), "Kh": (p, n), "W": (n, p)}
    v = {k: cp.Variable(shapes[k], symmetric=k in ("Q", "R", "P"), name=k) for k in matrices}
    v.update({s: cp.Variable(name=s) for s in ("slack", *scalars)})
    return v


def joint_program(plant, key: tuple, blocks, scalars: tuple[str, ...], nonneg: dict[str, str], constants: dict,
                  extra, *, cap: float, signed: tuple[str, ...] = ()) -> lmi.Program:
    """A program over :func:`synthesis_variables` with ``scalars``, ``Q`` and ``R`` positive (compiled once per
    ``key`` and shape), the plant and ``constants`` set; the Parameters ``nonneg`` (key -> cvxpy name,
    nonnegative) and ``signed`` are left to the caller."""
    import cvxpy as cp

    n, m, p = plant.n, plant.m, plant.p
    mats = lmi.plant_matrices(plant)

    def build():
        prm = {k: cp.Parameter(nonneg=True, name=name) for k, name in nonneg.items()}
        prm.update({**mats.parameters(), **lmi.scalar_parameters(*signed, *constants)})
        return lmi.margin_program(blocks, synthesis_variables(n, m, p, scalars), prm, ("Q", "R"), extra, cap=cap)

    prog = lmi.cached_program((*key, n, m, p, float(cap), mats.key), build)
    prog.set(**mats.settable(), **constants)
    return prog


def side_program(key: tuple, blocks, variables, mats: lmi.Matrices, constants: dict, nonneg: tuple[str, ...],
                 X: str, *, cap: float, scale_free: bool) -> lmi.Program:
    """The program ``max slack`` over ``variables()`` with ``nonneg`` >= 0 and ``X << cap I`` (and ``I << X`` when
    ``scale_free``), compiled once per ``key``, ``mats`` and ``constants`` set."""
    def build():
        def extra(d):
            return [d[k] >= 0 for k in nonneg] + ([d[X] >> np.eye(d[X].shape[0])] if scale_free else [])

        prm = {**mats.parameters(), **lmi.scalar_parameters(*constants)}
        return lmi.margin_program(blocks, variables(), prm, (X,), extra, cap=cap)

    prog = lmi.cached_program((*key, "scale-free" if scale_free else "capped", float(cap), mats.key), build)
    prog.set(**mats.settable(), **constants)
    return prog


def paper_gains_from(vals: dict) -> tuple[np.ndarray, np.ndarray]:
    """K = R^{-1} Khat', F = Fhat' Q^{-1} (the paper's recovery, correct as printed)."""
    K = np.linalg.solve(vals["R"], vals["Kh"].T)
    F = np.linalg.solve(vals["Q"], vals["Fh"]).T  # Q symmetric: Fh' Q^-1 = (Q^-1 Fh)'
    return K, F


def scalar(vals: dict, k: str) -> float:
    v = vals.get(k)
    return float(v) if v is not None else float("nan")


def joint_result(prog: lmi.Program, concl: dict, params: dict, cost: tuple = (0.0, 0.0, 0), *,
                 gains: tuple | None = None, log: str = "") -> DesignResult:
    """The :class:`DesignResult` of a concluded program, with ``cost`` of other solves added; when feasible, the
    gains ``(K, F)`` (default: :func:`paper_gains_from`); ``log``: the solvers tried (:func:`bench.lmi.solve_side`)."""
    K = F = None
    if concl["status"] == "feasible":
        K, F = gains or paper_gains_from(prog.values())
    return DesignResult(
        status=concl["status"], reason=concl["reason"], route="sdp", K=K, F=F, solver=prog.solver,
        solver_status=log or concl["solver_status"], compile_s=prog.compile_s + cost[0], solve_s=prog.solve_s + cost[1],
        n_solves=prog.n_solves + cost[2], margin=concl["margin"], lmi_size=concl["lmi_size"], min_eig=concl["min_eig"],
        params={**params, "slack": concl.get("slack", float("nan"))},
    )


def concluded(prog: lmi.Program, params: Callable[[dict], dict], *, what: str, cap: float, searched: str,
              settle: Callable[..., tuple[dict, tuple]] | None = None) -> DesignResult:
    """:func:`joint_result` of ``prog``'s best solve concluded (:func:`bench.lmi.conclude`) under the normalisation
    ``Q, R << cap I``, with the scalars ``params(values)``; ``settle(concl, searched=..., normalisation=...)``
    (:func:`settle_joint`) may re-decide the verdict, the cost of its solves added."""
    prog.restore_best()
    norm = f"the normalisation Q, R << {cap:g} I, slack <= 1"
    concl = lmi.conclude(prog, what=what, normalisation=norm, searched=searched)
    concl, cost = settle(concl, searched=searched, normalisation=norm) if settle else (concl, (0.0, 0.0, 0))
    return joint_result(prog, concl, params(prog.values()), cost)
