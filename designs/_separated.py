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

from designs import _lmi

__all__ = ["SCS_OPTS", "recombine", "solve_side"]

#: SCS settings for the separated sides (measured: n = 32 sides in ~0.15 s each vs ~3 s with
#: Clarabel; every point is verified with numpy, and a point that fails falls back to Clarabel).
SCS_OPTS = {"eps_abs": 1e-6, "eps_rel": 1e-6, "max_iters": 100_000}

#: From this n on, "auto" tries SCS first. Measured (thm1_sep, both sides, best of 3, 2 cores):
#: n = 4: Clarabel 0.024 s, SCS 0.026 s; n = 8: 0.062 vs 0.049; n = 12: 0.115 vs 0.042;
#: n = 16: 0.317 vs 0.059; n = 24: 1.57 vs 0.107; flexible link (n = 4): 0.025 vs 0.067.
SCS_FROM_N = 8


def solve_side(prog: _lmi.Program, solver: str = "auto", n: int | None = None) -> str:
    """Solve one side and return a log of the solvers tried.

    ``"auto"``: Clarabel when ``n < SCS_FROM_N``; otherwise SCS first, its point verified with
    numpy, and Clarabel when it does not verify.
    """
    if solver == "auto" and n is not None and n < SCS_FROM_N:
        solver = "CLARABEL"
    if solver == "auto":
        prog.solve(solver="SCS", solver_opts=SCS_OPTS)
        if prog.verified():
            return f"SCS:{prog.last_status}"
        first = f"SCS:{prog.last_status} (not verified)"
        prog.solve(solver="CLARABEL")
        return f"{first} -> CLARABEL:{prog.last_status}"
    prog.solve(solver=solver, solver_opts=SCS_OPTS if solver == "SCS" else None)
    return f"{solver}:{prog.last_status}"


def recombine(
    B: np.ndarray,
    xprog: _lmi.Program,
    eprog: _lmi.Program,
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
    lx, le = _lmi.max_eig(X), _lmi.max_eig(E)
    out.update(x_margin=lx, e_margin=le)
    qmin = _lmi.min_eig(xv["Q"])
    bad = [name for name, val, M in (("x-side", lx, X), ("e-side", le, E)) if not val < _lmi.verify_tol(M)]
    if qmin <= 0:
        bad.append("x-side (Q not positive definite)")
    # a solver that claimed a positive margin its point does not have: undecided, not infeasible
    claimed = [name for name, prog in (("x-side", xprog), ("e-side", eprog))
               if name in " ".join(bad) and float(prog.values()["t"]) > 0]
    if claimed:
        out.update(status="undecided", reason=(
            f"the solver reported a positive margin on the {' and '.join(claimed)} but the recomputed matrix "
            f"does not verify (max eig x-side {lx:.3g}, e-side {le:.3g})"))
        return out
    if bad:
        out.update(status="infeasible", reason=(
            f"no strictly feasible point on the {' and '.join(bad)} (max eig x-side {lx:.3g}, e-side {le:.3g}); "
            "the joint LMI is feasible iff both sides are"))
        return out
    Q, Fh = xv["Q"], xv["Fh"]
    BF = B @ np.linalg.solve(Q, Fh).T  # B Fh' Q^{-1}
    G = BF @ Q @ BF.T  # = B Fh' Q^{-1} Fh B'
    gmax = _lmi.max_eig(G)
    phi = 0.5 * abs(lx) / gmax if gmax > 0 else 1.0
    s = 2.0 / (phi * qmin * abs(le))
    vals = {**xv, **ev}
    for k in e_keys:
        vals[k] = ev[k] * s
    vals.update(phi=phi, iphi=1.0 / phi)
    M = _lmi.assemble(joint_blocks, vals, numeric=True)
    M = (M + M.T) / 2
    diag = np.diag(M)
    raw = _lmi.max_eig(M)
    if np.all(diag < 0):
        d = 1.0 / np.sqrt(-diag)
        margin = _lmi.max_eig(M * d[:, None] * d[None, :])
    else:
        margin = float("inf")  # a nonnegative diagonal entry: not negative definite
    min_eig = {"Q": qmin, "R": _lmi.min_eig(vals["R"])}
    out.update(margin=margin, raw_margin=raw, lmi_size=int(M.shape[0]), min_eig=min_eig, phi=phi, scale=s,
               values=vals)
    if margin < -_lmi.MARGIN_TOL * 1e3 and min(min_eig.values()) > 0:
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
        ``"auto"``, ``"CLARABEL"`` or ``"SCS"`` (see :func:`solve_side`).
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
        the cap it keys the compiled side programs (:func:`designs._lmi.cached_program`).
    constants : dict
        The design's scalar constants (each becomes a cvxpy Parameter of both sides); the
        plant's ``A``, ``B``, ``C`` enter as :func:`designs._lmi.plant_matrices`.

    Returns
    -------
    DesignResult
    """
    import cvxpy as cp

    from designs._core import DesignResult

    n, m, p = plant.n, plant.m, plant.p
    joint, xside, eside = blocks
    scalars = tuple(constants)
    mats = _lmi.plant_matrices(plant)

    def params() -> dict:
        return {**mats.parameters(), **_lmi.scalar_parameters(*scalars)}

    def build_x():
        xv = {"Q": cp.Variable((n, n), symmetric=True), "Fh": cp.Variable((n, m)), "kappa": cp.Variable(),
              "t": cp.Variable()}
        return _lmi.margin_program(xside, xv, params(), ("Q",), lambda d: [d["kappa"] >= 0], cap=cap)

    def build_e():
        ev = {"R": cp.Variable((n, n), symmetric=True), "Kh": cp.Variable((p, n)), "t": cp.Variable()}
        ev.update({k: cp.Variable() for k in e_scalars})
        return _lmi.margin_program(eside, ev, params(), ("R",), lambda d: [d[k] >= 0 for k in e_scalars], cap=cap)

    shape = (n, m, p, scalars, float(cap), mats.key)
    xprog = _lmi.cached_program((*key, "x-side", *shape), build_x)
    eprog = _lmi.cached_program((*key, "e-side", *shape), build_e)
    xprog.set(**mats.settable(), **constants)
    eprog.set(**mats.settable(), **constants)
    xlog = solve_side(xprog, solver, n)
    elog = solve_side(eprog, solver, n)
    rc = recombine(B=plant.B, xprog=xprog, eprog=eprog, e_keys=("R", "Kh", *e_scalars), joint_blocks=joint)
    K = F = None
    vals = rc["values"] or {}
    if rc["status"] == "feasible":
        K = np.linalg.solve(vals["R"], vals["Kh"].T)  # K = R^{-1} Kh'
        F = np.linalg.solve(vals["Q"], vals["Fh"]).T  # F = Fh' Q^{-1}
    return DesignResult(
        status=rc["status"], reason=rc["reason"] and f"{what} (separated): {rc['reason']}",
        K=K, F=F, solver=solver, solver_status=f"x {xlog}; e {elog}",
        compile_s=xprog.compile_s + eprog.compile_s, solve_s=xprog.solve_s + eprog.solve_s,
        n_solves=xprog.n_solves + eprog.n_solves, margin=rc["margin"], lmi_size=rc["lmi_size"],
        min_eig=rc["min_eig"],
        params={"form": "separated (x-side and e-side apart, joint certificate rebuilt)", phi_name: rc["phi"],
                "e_scale": rc["scale"], "x_margin": rc["x_margin"], "e_margin": rc["e_margin"],
                "raw_joint_margin": rc.get("raw_margin", float("nan")), "cap": cap, **extra_params(vals)})
