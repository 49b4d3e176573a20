"""A design that uses the nonlinearity's channel structure: separated sides, a searched decay target.

For a plant that declares ``f(x) = G phi(H x)`` with channel slopes in ``[lo, hi]``
(:class:`plants.Channels`), the loop transformation ``c0 = (lo + hi) / 2``, ``r = (hi - lo) / 2``,
``A0 = A + G diag(c0) H``, ``psi(z) = phi(z) - c0 z`` gives ``|delta psi_i| <= r_i |delta z_i|``
and the closed loop (6) with ``u = F x_hat``, ``e = x - x_hat`` ::

    x' = (A0 + B F) x - B F e + G psi(H x)
    e' = (A0 - K C) e + G (psi(H x) - psi(H x_hat))

Each side is an S-procedure LMI with one multiplier per channel (``../shared/design/STRUCTURE.md``);
with ``Dr = diag(r)`` and a decay target ``lam``:

- x-side, in ``Q > 0``, ``Y`` (m x n), ``S = diag(s) >= 0``; ``F = Y Q^-1`` ::

      [ A0 Q + Q A0' + B Y + Y' B' + G S G' + 2 lam Q    Q H' Dr ]
      [ Dr H Q                                          -S      ]  < 0

- e-side, in ``R > 0``, ``Kh`` (n x p), ``T = diag(t) >= 0``; ``K = R^-1 Kh`` ::

      [ A0' R + R A0 - Kh C - C' Kh' + H' Dr T Dr H + 2 lam R    R G ]
      [ G' R                                                    -T  ]  < 0

Both sides are homogeneous, so ``Q >= I`` and ``R >= I`` fix their scale, and each side
minimises a bound on its gain: ``||Y|| <= kF`` gives ``||F|| <= ||Y|| ||Q^-1|| <= kF`` (and
``||K|| <= kK`` likewise). The decay target ``lam`` is searched (bisection, relative tolerance
``rtol``) for the largest value at which both gains stay within ``max_gain``: a faster
certified rate bought with a huge gain is no win, so the bound is part of the design.

Two routes solve the sides (``route``): ``"sdp"`` (the LMIs above, Clarabel or SCS) and
``"riccati"`` (one scalar multiplier per side and ``F = -tau B' P``, ``K = tau' X C'``: each side is
an algebraic Riccati equation, :func:`designs._riccati_route.structured_riccati`; O(n^3), for
large n; sufficient, not necessary, and with the decay target fixed at ``decay`` (default 0)
since each try costs two AREs). ``"auto"`` takes the Riccati route from
:data:`RICCATI_FROM_N` states on.

The joint certificate is then verified: ``V = x' Q^-1 x + mu e' R e`` with multipliers
``S^-1`` (x-side) and ``mu T`` (e-side) makes the joint matrix in ``(x, e, psi, delta psi)``
negative definite for ``mu`` large enough to absorb the cross term ``-P B F`` (a cascade);
``mu = 2 ||P B F||^2 / (a_x a_e)`` with ``a_x``, ``a_e`` the sides' margins, and the matrix is
checked by its eigenvalues (after a Jacobi equilibration, which keeps the inertia).

References
----------
T. Acikmese and M. Corless, "Observers for systems with nonlinearities satisfying incremental
quadratic constraints", Automatica 47(7), 2011. A. Zemouche and M. Boutayeb, Automatica 49(2),
2013 (LMI observers with channel structure).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial

import numpy as np

from bench import lmi
from bench.registry import register_design
from designs._core import Design, DesignResult, check_choice, check_positive
from plants import Constants, Plant

__all__ = ["RICCATI_FROM_N", "Structured", "joint_matrix"]

#: ``route="auto"`` solves the sides by Riccati equations from this n on (the SDP sides'
#: interior-point cost grows like n^4 - n^6; measured by ``python -m bench perf``).
RICCATI_FROM_N = 64


def _loop(plant: Plant) -> dict:
    """The loop-transformed data of a plant with channels."""
    ch = plant.channels
    return {"A0": plant.A + ch.G @ np.diag(ch.center) @ ch.H, "B": plant.B, "C": plant.C, "G": ch.G, "H": ch.H,
            "Dr": np.diag(ch.spread)}


def joint_matrix(d: dict, K: np.ndarray, F: np.ndarray, P: np.ndarray, R: np.ndarray, s: np.ndarray, t: np.ndarray,
                 mu: float, lam: float = 0.0) -> np.ndarray:
    """The joint analysis matrix in ``(x, e, psi(Hx), delta psi)`` of the structured design.

    Parameters
    ----------
    d : dict
        Loop data ``A0, B, C, G, H, Dr``.
    K, F : ndarray
        Gains.
    P, R : ndarray
        ``V = x' P x + mu e' R e``.
    s, t : ndarray (q,)
        x-side multipliers are ``1 / s``, e-side ``mu t``.
    mu : float
    lam : float
        Decay rate tested (``V' <= -2 lam V``).

    Returns
    -------
    ndarray
        Symmetric ``(2n + 2q)`` matrix; negative definite certifies the loop.
    """
    A0, B, C, G, H, Dr = d["A0"], d["B"], d["C"], d["G"], d["H"], d["Dr"]
    n, q = A0.shape[0], G.shape[1]
    Ax, Ae = A0 + B @ F, A0 - K @ C
    Xb = Ax.T @ P + P @ Ax + 2 * lam * P + H.T @ Dr @ np.diag(1 / s) @ Dr @ H
    Eb = Ae.T @ R + R @ Ae + 2 * lam * R + H.T @ Dr @ np.diag(t) @ Dr @ H
    Z = np.zeros
    M = np.block([
        [Xb, -P @ B @ F, P @ G, Z((n, q))],
        [(-P @ B @ F).T, mu * Eb, Z((n, q)), mu * R @ G],
        [(P @ G).T, Z((q, n)), -np.diag(1 / s), Z((q, q))],
        [Z((q, n)), mu * (R @ G).T, Z((q, q)), -mu * np.diag(t)],
    ])
    return (M + M.T) / 2


def _equilibrated_margin(M: np.ndarray) -> tuple[float, np.ndarray]:
    """Largest eigenvalue of ``D M D``, ``D = diag(|M_ii|^-1/2)`` (same inertia), and that matrix."""
    diag = np.diag(M)
    if not np.all(diag < 0):
        return math.inf, M
    dd = 1.0 / np.sqrt(-diag)
    Me = M * dd[:, None] * dd[None, :]
    return lmi.max_eig(Me), Me


@register_design("structured", order=17)
@dataclass(frozen=True, kw_only=True)
class Structured(Design):
    """Channel-structured design: separated x/e LMIs with one multiplier per channel, decay target searched.

    Parameters
    ----------
    decay : float, optional
        A fixed decay target ``lam`` (>= 0); None (default) searches the largest one in
        ``[0, max_decay]`` whose gains stay within ``max_gain``.
    max_gain : float
        Bound on ``||F||`` and ``||K||`` (2-norms) for the search.
    max_decay : float
        Upper end of the search.
    rtol : float
        Relative tolerance of the decay search.
    solver : {"auto", "CLARABEL", "SCS"}
        SDP solver of the sides (:func:`bench.lmi.solve_side`). Default Clarabel: on these
        min-gain programs SCS was much slower (chain, n = 16: 51.5 s with SCS or "auto", 2.3 s
        with Clarabel, same decay target and gains within tolerance).
    route : {"auto", "sdp", "riccati"}
        How the sides are solved (see the module docstring).
    """

    decay: float | None = None
    max_gain: float = 20.0
    max_decay: float = 10.0
    rtol: float = 0.05
    solver: str = "CLARABEL"
    route: str = "auto"

    def __post_init__(self) -> None:
        if self.decay is not None:
            check_positive("decay", self.decay, allow_zero=True)
        check_positive("max_gain", self.max_gain)
        check_positive("max_decay", self.max_decay)
        check_positive("rtol", self.rtol)
        check_choice("solver", self.solver, ("auto", "CLARABEL", "SCS"))
        check_choice("route", self.route, ("auto", "sdp", "riccati"))

    def applicable(self, plant: Plant, constants: Constants) -> str | None:
        if plant.channels is None:
            return "the plant declares no channel structure f = G phi(Hx) (Plant.channels)"
        return None

    # -- the sides -------------------------------------------------------------------------------
    def _programs(self, plant: Plant) -> tuple[lmi.Program, lmi.Program]:
        d = _loop(plant)
        n, m, p, q = plant.n, plant.m, plant.p, plant.channels.q
        # the side programs bake the loop data in (A0, G, H, Dr): the key must hold their values
        key = ("structured", n, m, p, q, tuple((k, lmi.digest(v)) for k, v in d.items()))
        return (lmi.cached_program((*key, "x"), lambda: _side_program("x", d, n, m, q)),
                lmi.cached_program((*key, "e"), lambda: _side_program("e", d, n, p, q)))

    def _try(self, progs, lam: float) -> dict | None:
        """Both sides at ``lam``: the gains and multipliers, or None when a side fails."""
        xprog, eprog = progs
        out = {}
        for name, prog in (("x", xprog), ("e", eprog)):
            prog.set(lam=lam)
            lmi.solve_side(prog, self.solver, prog.variables["Q" if name == "x" else "R"].shape[0])
            if not prog.verified():
                return None
            out[name] = prog.values()
        x, e = out["x"], out["e"]
        F = np.linalg.solve(x["Q"], x["Y"].T).T
        K = np.linalg.solve(e["R"], e["Kh"])
        return {"lam": lam, "F": F, "K": K, "P": np.linalg.inv(x["Q"]), "R": e["R"], "s": x["s"], "t": e["t"],
                "gain": max(np.linalg.norm(F, 2), np.linalg.norm(K, 2))}

    def _search(self, progs) -> tuple[dict | None, int]:
        """The largest decay target within the gain bound (or the fixed one)."""
        if self.decay is not None:
            return self._try(progs, float(self.decay)), 1
        tries = 0
        lo = self._try(progs, 0.0)
        tries += 1
        if lo is None:
            return None, tries
        top = self.max_decay
        lam = min(0.5, top / 2)
        while lo["gain"] <= self.max_gain and top / max(lo["lam"], 1e-12) - 1 > self.rtol:
            cand = self._try(progs, lam)
            tries += 1
            if cand is not None and cand["gain"] <= self.max_gain:
                lo = cand
                lam = min(2 * lam, math.sqrt(lam * top)) if top < self.max_decay else 2 * lam
                lam = min(lam, top)
            else:
                top = lam
                lam = math.sqrt(lo["lam"] * top) if lo["lam"] > 0 else top / 4
            if lam <= 1e-6:
                break
        return lo, tries

    def design(self, plant: Plant, constants: Constants) -> DesignResult:
        """Search the decay target, then verify the joint certificate of the gains."""
        route = self.route if self.route != "auto" else ("riccati" if plant.n >= RICCATI_FROM_N else "sdp")
        if route == "riccati":
            return self._design_riccati(plant)
        progs = self._programs(plant)
        best, tries = self._search(progs)
        compile_s = sum(p.compile_s for p in progs)
        solve_s = sum(p.solve_s for p in progs)
        n_solves = sum(p.n_solves for p in progs)
        base = dict(route="sdp", solver="+".join(dict.fromkeys(p.solver for p in progs)), compile_s=compile_s,
                    solve_s=solve_s, n_solves=n_solves)
        if best is None:
            return DesignResult(status="infeasible", reason=(
                "structured design: a side is not strictly feasible at decay 0 (Q, R >= I normalisation)"), **base)
        return _conclude(plant, best, tries, self, base)

    def _design_riccati(self, plant: Plant) -> DesignResult:
        """The Riccati route at the fixed decay target ``decay`` (default 0)."""
        import time

        from designs._riccati_route import structured_riccati

        ch = plant.channels
        lam = float(self.decay or 0.0)
        t0 = time.perf_counter()
        rr = structured_riccati(plant.A, plant.B, plant.C, ch.G, ch.H, ch.lo, ch.hi, lam=lam)
        wall = time.perf_counter() - t0
        params = {"decay_target": lam, "mu": rr.mu, "tau": rr.tau, "tau_e": rr.tau_e, "x_margin": rr.margin_x,
                  "e_margin": rr.margin_e, "residual_x": rr.residual_x, "residual_e": rr.residual_e}
        base = dict(route="riccati", solver="scipy.linalg.schur (ARE)", solver_status=rr.status, solve_s=wall,
                    n_solves=2, margin=rr.margin, lmi_size=2 * plant.n, params=params)
        if not rr.ok:
            return DesignResult(status=rr.status, reason=f"structured design (Riccati route): {rr.reason}", **base)
        n = plant.n
        P = np.block([[rr.P, np.zeros((n, n))], [np.zeros((n, n)), rr.mu * rr.R]])
        cert = {"level": "structured", "P": P, "decay_rate": lam, "margin": rr.margin, "radius": ch.radius,
                "how": "the design's own joint certificate (Riccati route), verified by an eigenvalue test"}
        return DesignResult(status="feasible", K=rr.K, F=rr.F, certificate=cert, **base)


def _diag(v):
    """``diag(v)`` of a cvxpy vector or of a numpy array (the blocks build both)."""
    import cvxpy as cp

    return np.diag(v) if isinstance(v, np.ndarray) else cp.diag(v)


def _x_blocks(d: dict, x: dict) -> list:
    """x-side: ``[[A0 Q + Q A0' + B Y + Y' B' + G S G' + 2 lam Q, Q H' Dr], [Dr H Q, -S]]``."""
    A0, B, G, H, Dr = d["A0"], d["B"], d["G"], d["H"], d["Dr"]
    Q, Y, S = x["Q"], x["Y"], _diag(x["s"])
    return [[A0 @ Q + Q @ A0.T + B @ Y + Y.T @ B.T + G @ S @ G.T + 2 * x["lam"] * Q, Q @ H.T @ Dr],
            [Dr @ H @ Q, -S]]


def _e_blocks(d: dict, x: dict) -> list:
    """e-side: ``[[A0' R + R A0 - Kh C - C' Kh' + H' Dr T Dr H + 2 lam R, R G], [G' R, -T]]``."""
    A0, C, G, H, Dr = d["A0"], d["C"], d["G"], d["H"], d["Dr"]
    R, Kh, T = x["R"], x["Kh"], _diag(x["t"])
    return [[A0.T @ R + R @ A0 - Kh @ C - C.T @ Kh.T + H.T @ Dr @ T @ Dr @ H + 2 * x["lam"] * R, R @ G],
            [G.T @ R, -T]]


#: Each side's blocks, decision matrix, gain variable and channel multipliers.
_SIDES = {"x": (_x_blocks, "Q", "Y", "s"), "e": (_e_blocks, "R", "Kh", "t")}


def _side_program(side: str, d: dict, n: int, k: int, q: int) -> lmi.Program:
    """The min-gain program of one side; the gain is ``Y`` (k = m inputs, m x n) or ``Kh`` (k = p outputs, n x p)."""
    import cvxpy as cp

    blocks, pos, gain, mult = _SIDES[side]
    v = {pos: cp.Variable((n, n), symmetric=True), gain: cp.Variable((k, n) if side == "x" else (n, k)),
         mult: cp.Variable(q), "k": cp.Variable()}
    prm = {"lam": cp.Parameter(nonneg=True, name="lam")}
    return _min_gain_program(partial(blocks, d), v, prm, pos, gain, mult, n + q,
                             scale=1.0 + np.linalg.norm(d["A0"], 2))


def _min_gain_program(blocks, v: dict, prm: dict, pos: str, gain: str, mult: str, size: int, *,
                      scale: float) -> lmi.Program:
    """``min k`` s.t. ``M << -eps I``, ``pos >= I``, ``||gain|| <= k``, multipliers >= 0."""
    import cvxpy as cp

    M = lmi.sym(lmi.assemble(blocks, {**v, **prm}, numeric=False))
    g = v[gain]
    r, c = g.shape
    eps = 1e-3 * scale
    cons = [M << -eps * np.eye(size), v[pos] >> np.eye(v[pos].shape[0]), v[mult] >= 0,
            cp.bmat([[v["k"] * np.eye(r), g], [g.T, v["k"] * np.eye(c)]]) >> 0]
    prob = cp.Problem(cp.Minimize(v["k"]), cons)
    return lmi.Program(prob, v, prm, blocks, (pos,))


def _conclude(plant: Plant, best: dict, tries: int, design: Structured, base: dict) -> DesignResult:
    """Verify the joint certificate of the chosen gains and build the result."""
    d = _loop(plant)
    P, R, F, K = best["P"], best["R"], best["F"], best["K"]
    s, t = np.maximum(best["s"], 1e-12), np.maximum(best["t"], 1e-12)
    lam = best["lam"]
    Mx = joint_matrix(d, K, F, P, R, s, t, mu=0.0, lam=lam)
    n, q = plant.n, plant.channels.q
    ix = np.r_[0:n, 2 * n:2 * n + q]
    ie = np.r_[n:2 * n, 2 * n + q:2 * n + 2 * q]
    ax = -lmi.max_eig(Mx[np.ix_(ix, ix)])
    Me = joint_matrix(d, K, F, P, R, s, t, mu=1.0, lam=lam)[np.ix_(ie, ie)]
    ae = -lmi.max_eig(Me)
    cross = float(np.linalg.norm(P @ plant.B @ F, 2))
    mu = 2 * cross**2 / (ax * ae) if ax > 0 and ae > 0 else math.nan
    margin, Meq = _equilibrated_margin(joint_matrix(d, K, F, P, R, s, t, mu=mu, lam=lam)) if math.isfinite(mu) \
        else (math.inf, None)
    params = {"decay_target": best["lam"], "gain_norm": best["gain"], "max_gain": design.max_gain, "mu": mu,
              "x_margin": ax, "e_margin": ae, "decay_searches": tries}
    if Meq is not None and lmi.classify(margin, Meq) == "verified":
        note = "" if best["gain"] <= design.max_gain else (
            f"the gains exceed max_gain = {design.max_gain:g} already at decay 0 (||F||, ||K|| up to "
            f"{best['gain']:.3g}): the smallest gains found are returned")
        Pj = np.block([[P, np.zeros((n, n))], [np.zeros((n, n)), mu * R]])
        cert = {"level": "structured", "P": Pj, "decay_rate": lam, "margin": margin, "radius": plant.channels.radius,
                "how": "the design's own joint certificate (V = x'Q^-1 x + mu e'Re), verified by eigenvalues"}
        return DesignResult(status="feasible", reason=note, K=K, F=F, margin=margin, lmi_size=2 * n + 2 * q,
                            min_eig={"Q^-1": lmi.min_eig(P), "R": lmi.min_eig(R)}, params=params, certificate=cert,
                            **base)
    return DesignResult(status="undecided", reason=(
        f"structured design: both sides verified at decay {best['lam']:.3g}, but the joint certificate with "
        f"mu = {mu:.3g} has max eig {margin:.3g} (equilibrated)"), margin=margin, params=params, **base)
