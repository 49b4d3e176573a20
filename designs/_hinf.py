"""Shared pieces of the H-infinity designs: the bounded-real sides and the two-stage minimisation of a level.

Setting (continuous time): ``x' = A x + B u + f(x) + Bw w``, ``y = C x + Dw w``, observer
``x_hat' = A x_hat + B u + f(x_hat) + K (y - C x_hat)``, ``u = F x_hat``, ``e = x - x_hat``::

    e' = (A - K C) e + df + (Bw - K Dw) w,          df = f(x) - f(x_hat)
    x' = (A + B F) x + f(x) + Bw w - B v,           v = F e

**e-side** (``V_e = e' R e``, ``Kh = K' R``): ``V_e' + |e|^2 - g |w|^2 <= 0`` for every ``df`` of the class is, by the
S-procedure with the class's multipliers (as in the decay designs, ``docs/paper.md``), the LMI ::

    [ A'R + RA - C'Kh - Kh'C + I + Pi_11   R + Pi_12   R Bw - Kh' Dw ]
    [ *                                    Pi_22       0             ]  <= 0
    [ *                                    *           -g I          ]

with ``Pi = [[2(eps3 rho + eps4 beta) I, (eps4 gamma - eps3) I], [*, -2 eps4 I]]`` (OSL / QIB) or
``[[mu alpha^2 I, 0], [0, -mu I]]`` (Lipschitz). It is linear in ``(R, Kh, multipliers, g)``: minimising ``g``
is one SDP, and ``sqrt(g)`` bounds the L2 gain from ``w`` to ``e`` over the whole class (zero initial error).

**Two stages.** The infimum of ``g`` may sit on the boundary (a singular H-infinity problem, gains growing
without bound), and a minimiser is never strictly feasible. Stage 1 minimises ``g`` with the non-strict LMI;
stage 2 fixes ``g = (1 + backoff)^2 g*`` and maximises the margin ``slack`` (``M << -slack I``,
``X >> slack I``, ``X << cap I`` for the decision matrices ``X`` and multipliers ``<= cap``,
``cap = max(1e3, 10 lmax(X*))``). Stage 2's
point is verified by :func:`bench.lmi.conclude` (the rebuilt numeric matrix's eigenvalues): only then is the
level reported, and it is the level of stage 2, ``(1 + backoff) sqrt(g*)``.

References
----------
S. Boyd, L. El Ghaoui, E. Feron and V. Balakrishnan, *Linear Matrix Inequalities in System and Control
Theory*, SIAM 1994, section 6.3.2 (the bounded real lemma with an S-procedure).
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from bench import lmi

__all__ = ["eside_blocks", "min_level"]


def eside_blocks(kind: str, n: int, q: int) -> Callable[[dict], list]:
    """The e-side bounded-real blocks (module docstring) as a function of a values dict with ``A``, ``C``,
    ``Bw``, ``Dw``, ``R``, ``Kh``, ``g`` and the multipliers: ``kind`` ``"osl_qib"`` (``eps3``, ``eps4``, ``rho``,
    ``beta``, ``gamma``) or ``"lipschitz"`` (``mu``, ``a2``). An optional ``W`` (n x n) in the values replaces
    the output weight ``I`` (``V_e' + e' W e - g |w|^2``)."""
    I = np.eye(n)

    def blocks(d):
        A, C, R, Kh = d["A"], d["C"], d["R"], d["Kh"]
        S = A.T @ R + R @ A - C.T @ Kh - Kh.T @ C + d.get("W", I)
        if kind == "osl_qib":
            S = S + 2 * (d["eps3"] * d["rho"] + d["eps4"] * d["beta"]) * I
            X, Y = R + (d["eps4"] * d["gamma"] - d["eps3"]) * I, -2 * d["eps4"] * I
        else:
            S = S + d["mu"] * d["a2"] * I
            X, Y = R, -d["mu"] * I
        Wb = R @ d["Bw"] - Kh.T @ d["Dw"]
        return [[S, X, Wb], [X.T, Y, np.zeros((n, q))], [Wb.T, np.zeros((q, n)), -d["g"] * np.eye(q)]]

    return blocks


def min_level(blocks: Callable[[dict], list], make_variables: Callable[[], dict], constants: dict,
              positive: tuple[str, ...], nonneg: tuple[str, ...], level: tuple[str, ...], *,
              objective: Callable[[dict], object] | None = None, extra: Callable[[dict], list] | None = None,
              backoff: float, solver: str, what: str) -> dict:
    """Minimise the level variables ``level`` (their sum, or ``objective(vars)``) of the LMI ``blocks <= 0`` and
    verify a strictly feasible point at ``(1 + backoff)^2`` times the optimum (module docstring).

    Parameters
    ----------
    blocks : callable
        ``blocks(values) -> list of lists`` (cvxpy or numpy).
    make_variables : callable
        A fresh dict of the decision variables (``level`` among them; no ``slack``).
    constants : dict
        Numeric values by name (arrays and scalars), baked into the programs.
    positive, nonneg : tuple of str
        Decision matrices (``> 0``) and scalars (``>= 0``).
    level : tuple of str
        The scalar level variables (fixed in stage 2).
    objective, extra : callable, optional
        Stage 1's objective (default: the sum of ``level``) and extra constraints of both stages.
    backoff : float
    solver : str
    what : str
        The LMI's name in reasons.

    Returns
    -------
    dict
        :func:`bench.lmi.conclude`'s keys (``status``, ``reason``, ``margin``, ...) plus ``levels`` (the
        verified stage-2 values of ``level``), ``optimum`` (stage 1's), ``values`` (stage 2's point) and
        ``compile_s``, ``solve_s``, ``n_solves``.
    """
    import cvxpy as cp

    v = make_variables()
    allv = {**constants, **v}
    M = lmi.sym(lmi.assemble(blocks, allv, numeric=False))
    cons = [M << 0] + [v[k] >> 0 for k in positive] + [v[k] >= 0 for k in nonneg] + (extra(allv) if extra else [])
    obj = objective(v) if objective else sum(v[k] for k in level)
    prob = cp.Problem(cp.Minimize(obj), cons)
    first = lmi.solve_timed(prob, solver)
    cost = [first.compile_s, first.solve_s, 1]
    out = {"levels": {k: math.nan for k in level}, "optimum": {k: math.nan for k in level}, "values": None,
           "margin": math.nan, "min_eig": {}, "lmi_size": int(M.shape[0]), "solver_status": first.status}
    if not first.solved:
        out.update(status="undecided" if first.status != "infeasible" else "infeasible",
                   reason=f"{what}: minimising the level: solver status {first.status!r} {first.error}".strip(),
                   compile_s=cost[0], solve_s=cost[1], n_solves=cost[2])
        return out
    opt = {k: max(float(v[k].value), 0.0) for k in level}
    cap = max(1e3, 10 * max(lmi.max_eig(v[k].value) for k in positive))
    fixed = {k: (1 + backoff) ** 2 * opt[k] + 1e-12 for k in level}

    w = make_variables()
    for k in level:
        w.pop(k)
    w["slack"] = cp.Variable(name="slack")
    consts = {k: np.asarray(val, dtype=float) for k, val in {**constants, **fixed}.items()}  # baked in
    prog = lmi.margin_program(blocks, w, consts, positive,
                              lambda d: [c for k in nonneg for c in (d[k] >= 0, d[k] <= cap)]
                              + (extra(d) if extra else []), cap=cap)
    prog.solve(solver=solver)
    concl = lmi.conclude(prog, what=what, normalisation=f"{', '.join(positive)} << {cap:.3g} I, slack <= 1",
                         searched=f"at the level {', '.join(f'{k} = {fixed[k]:.4g}' for k in level)} "
                                  f"({1 + backoff:g} times the optimum's square root)")
    out.update(concl)
    out.update(levels=fixed, optimum=opt, values=prog.values(), compile_s=cost[0] + prog.compile_s,
               solve_s=cost[1] + prog.solve_s, n_solves=cost[2] + prog.n_solves, cap=cap)
    return out
