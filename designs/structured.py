"""A design that uses the nonlinearity's channel structure: separated sides, a searched decay target.

For a plant that declares ``f(x) = G phi(H x)`` with channel slopes in ``[lo, hi]``
(:class:`plants.Channels`), in the loop-transformed data of :mod:`bench.joint` (``A0``,
``Dr = diag(r)``), each side is an S-procedure LMI with one multiplier per channel
(``docs/structured.md``) at a decay target ``lam``:

- x-side, in ``Q > 0``, ``Y`` (m x n), ``S = diag(s) >= 0``; ``F = Y Q^-1`` ::

      [ A0 Q + Q A0' + B Y + Y' B' + G S G' + 2 lam Q    Q H' Dr ]
      [ Dr H Q                                          -S      ]  < 0

- e-side, in ``R > 0``, ``Kh`` (n x p), ``T = diag(t) >= 0``; ``K = R^-1 Kh`` ::

      [ A0' R + R A0 - Kh C - C' Kh' + H' Dr T Dr H + 2 lam R    R G ]
      [ G' R                                                    -T  ]  < 0

Both sides are homogeneous, so ``Q >= I`` and ``R >= I`` fix their scale, and each side
minimises a bound on its gain (``||Y|| <= kF`` gives ``||F|| <= kF``; likewise ``||K|| <= kK``).

**Discrete time** (``plant.dt > 0``, ``x_{k+1} = A x_k + B u_k + G phi(H x_k)``, the observer the one-step
predictor). With ``V(x_{k+1}) <= r^2 V(x_k)`` in place of ``V' <= -2 lam V`` and the same multipliers, the
S-procedure on ``[A0 + B F, G]' P [A0 + B F, G] - diag(r^2 P, 0) + [[H'Dr L Dr H, 0], [0, -L]] < 0``
(``L = S^-1``), the congruence ``diag(Q, S)`` and Schur complements on ``P = Q^-1``, ``S`` and the channel row
give, exactly, the x-side ::

      [ -r^2 Q         Q A0' + Y' B'     Q H' Dr ]
      [ A0 Q + B Y     -Q + G S G'       0       ]  < 0
      [ Dr H Q         0                 -S      ]

and the e-side (``K = R^-1 Kh``) ::

      [ -r^2 R + H' Dr T Dr H    0       A0' R - C' Kh' ]
      [ 0                        -T      G' R           ]  < 0
      [ R A0 - Kh C              R G     -R             ]

The decay target is searched as a rate per second ``lam`` with the contraction factor ``r = exp(-lam dt)``,
under the same gain bound, where the observer gain counts as ``||K|| / dt`` (its Euler-equivalent
continuous gain, so the bound means the same at every sample time). The joint certificate is the discrete one
of :func:`designs._discrete.joint_certificate` (``V = x'Q^-1 x + s e'Re``, the sides' multipliers), its
contraction factor found by bisection and reported as ``decay_rate = -ln(r) / dt``. The SDP margin is
``1e-3 (dt + ||A0 - I||)``, ``dt`` times the continuous one's for an Euler-like ``A0 = I + dt A0c``. The
Riccati route has no discrete form here (it would need discrete algebraic Riccati equations with an
indefinite weight): a discrete plant takes the SDP route, and ``route="riccati"`` is inapplicable.

Two routes solve the sides (``route``): ``"sdp"`` (the LMIs above, Clarabel or SCS) and
``"riccati"`` (one scalar multiplier per side, each side an algebraic Riccati equation:
:mod:`designs._riccati_route`; O(n^3), sufficient, not necessary). ``"auto"`` takes the Riccati
route from :data:`RICCATI_FROM_N` states on. Either way the gains are certified by the joint
certificate of :mod:`bench.joint`, whose ``decay_rate`` is the rate it proves, not the target.

References
----------
Discrete time: the same S-procedure with the discrete Lyapunov difference (Boyd et al., *Linear Matrix
Inequalities in System and Control Theory*, SIAM 1994, sections 5.1 and 8.2); the discrete forms and their
derivation here are ours.
T. Acikmese and M. Corless, "Observers for systems with nonlinearities satisfying incremental
quadratic constraints", Automatica 47(7), 2011. A. Zemouche and M. Boutayeb, Automatica 49(2),
2013 (LMI observers with channel structure).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial

import numpy as np

from bench import joint, lmi
from bench.search import largest_passing, secant_estimate
from bench.registry import register_design
from designs import _discrete
from designs._core import Design, DesignResult, check_choice, check_positive
from plants import Constants, Plant

__all__ = ["Structured"]

RICCATI_FROM_N = 64


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
        SDP solver of the sides (:func:`bench.lmi.solve_side`).
    route : {"auto", "sdp", "riccati"}
        How the sides are solved (see the module docstring).
    """

    decay: float | None = None
    max_gain: float = 20.0
    max_decay: float = 10.0
    rtol: float = 0.05
    solver: str = "CLARABEL"
    route: str = "auto"

    time_domains = ("continuous", "discrete")

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
        """The x-side and e-side programs on the loop data ``A0, B, C, G, H, Dr`` (all channels, as the multipliers are
        per channel)."""
        ch = plant.channels
        d = {"A0": plant.A + ch.G @ np.diag(ch.center) @ ch.H, "B": plant.B, "C": plant.C, "G": ch.G, "H": ch.H,
             "Dr": np.diag(ch.spread)}
        if plant.discrete:
            d["dt"] = plant.dt
        n, m, p, q = plant.n, plant.m, plant.p, ch.q
        # the side programs bake the loop data in (A0, G, H, Dr): the key must hold their values
        key = ("structured", n, m, p, q, plant.dt, tuple((k, lmi.digest(v)) for k, v in d.items()))
        build = _side_program_discrete if plant.discrete else _side_program
        return (lmi.cached_program((*key, "x"), lambda: build("x", d, n, m, q)),
                lmi.cached_program((*key, "e"), lambda: build("e", d, n, p, q)))

    def _side(self, prog: lmi.Program, lam: float) -> dict | None:
        """One side at ``lam``: its values when its solution verifies, else None."""
        dt = float(prog.constants.get("dt", 0.0))
        prog.set(**({"c": -math.expm1(-2 * lam * dt) / dt} if dt else {"lam": lam}))
        pos = "Q" if "Q" in prog.variables else "R"
        lmi.solve_side(prog, self.solver, prog.variables[pos].shape[0])
        return prog.values() if prog.verified() else None

    @staticmethod
    def _gain(name: str, v: dict, dt: float) -> np.ndarray:
        """The side's gain: ``F = Y Q^-1`` (x-side) or ``K = R^-1 Kh`` (times ``dt`` in discrete time: Kh = R K / dt)."""
        if name == "x":
            return np.linalg.solve(v["Q"], v["Y"].T).T
        return np.linalg.solve(v["R"], v["Kh"]) * (dt or 1.0)

    def _candidate(self, lam: float, x: dict, e: dict, dt: float) -> dict:
        F, K = self._gain("x", x, dt), self._gain("e", e, dt)
        return {"lam": lam, "F": F, "K": K, "P": np.linalg.inv(x["Q"]), "Q": x["Q"], "R": e["R"], "s": x["s"],
                "t": e["t"], "gain": max(np.linalg.norm(F, 2), np.linalg.norm(K, 2) / (dt or 1.0))}

    def _try(self, progs, lam: float) -> dict | None:
        """Both sides at ``lam``: the gains and multipliers, or None when a side fails."""
        xprog, eprog = progs
        x = self._side(xprog, lam)
        e = None if x is None else self._side(eprog, lam)
        if e is None:
            return None
        return self._candidate(lam, x, e, float(eprog.constants.get("dt", 0.0)))

    def _search(self, progs) -> tuple[dict | None, int]:
        """The largest decay target within the gain bound (:func:`bench.search.largest_passing`), or the fixed one.

        Both sides pass below their own thresholds (each is monotone in the target: a larger one shrinks its
        feasible set and raises its least gain), so the largest grid point where both pass is the smaller of the
        two sides' own: the x-side is searched alone, then the e-side is probed there first (one solve when it
        passes) and searched below only when it fails. The grid and range are those of a joint search, so the
        answer is the same grid point, in about half the solves. ``lam = 0`` is solved only when a side fails
        below its first probe (no target passes where it fails at 0: the search stops) or none passes; then the
        design at ``lam = 0`` is returned, its gains within the bound or not.
        """
        if self.decay is not None:
            return self._try(progs, float(self.decay)), 1
        dt = float(progs[1].constants.get("dt", 0.0))
        seen: dict[str, dict[float, dict | None]] = {"x": {}, "e": {}}

        def side(name: str, lam: float) -> dict | None:
            if lam not in seen[name]:
                seen[name][lam] = self._side(progs[0 if name == "x" else 1], lam)
            return seen[name][lam]

        # the least gain grows with the target: a secant of the verified points' gains against the bound aims the
        # searches (it only chooses the probes)
        gains: dict[str, dict[float, tuple]] = {"x": {}, "e": {}}

        def passes(name: str):
            def test(lam: float) -> bool:
                v = side(name, lam)
                if v is None:
                    return False
                g = np.linalg.norm(self._gain(name, v, dt), 2) / (1.0 if name == "x" else (dt or 1.0))
                gains[name][lam] = (g <= self.max_gain, g - self.max_gain, 0.0)
                return g <= self.max_gain
            return test

        def at_zero() -> dict | None:  # the design at lam = 0, its gains within the bound or not
            x0 = side("x", 0.0)
            e0 = None if x0 is None else side("e", 0.0)
            return None if e0 is None else self._candidate(0.0, x0, e0, dt)

        kw = dict(rtol=self.rtol, down_until=1e-6)
        # lam = 0 is solved only when the x-side fails below the first probe (no target passes if it fails there)
        lam = largest_passing(passes("x"), start=min(0.5, self.max_decay / 2), hi=self.max_decay,
                              aim=lambda: secant_estimate(gains["x"]), stop=lambda: not passes("x")(0.0), **kw)["lo"]
        if math.isfinite(lam) and not passes("e")(lam):
            lam = largest_passing(passes("e"), hi=lam, aim=lambda: secant_estimate(gains["e"]),
                                  stop=lambda: not passes("e")(0.0), **kw)["lo"]
        x, e = (side("x", lam), side("e", lam)) if math.isfinite(lam) else (None, None)
        if x is None or e is None:  # none passed (or a side flipped below its own threshold, numerically)
            first = at_zero()
            return first, len(set(seen["x"]) | set(seen["e"]))
        return self._candidate(lam, x, e, dt), len(set(seen["x"]) | set(seen["e"]))

    def design(self, plant: Plant, constants: Constants) -> DesignResult:
        """Search the decay target, then verify the joint certificate of the gains."""
        route = self.route if self.route != "auto" else (
            "riccati" if plant.n >= RICCATI_FROM_N and not plant.discrete else "sdp")
        if route == "riccati" and plant.discrete:
            return DesignResult(status="inapplicable", route="riccati", reason=(
                "structured design: the Riccati route has no discrete-time form (it would need discrete algebraic "
                "Riccati equations with an indefinite weight); use route='sdp' for a discrete plant"))
        if route == "riccati":
            return self._design_riccati(plant)
        progs = self._programs(plant)
        best, tries = self._search(progs)
        base = dict(route="sdp", solver="+".join(dict.fromkeys(p.solver for p in progs)),
                    **{k: sum(getattr(p, k) for p in progs) for k in ("compile_s", "solve_s", "n_solves")})
        if best is None:
            return DesignResult(status="infeasible", reason=(
                "structured design: a side is not strictly feasible at decay 0 (Q, R >= I normalisation)"), **base)
        P, R, F, K = best["P"], best["R"], best["F"], best["K"]
        s, t = np.maximum(best["s"], 1e-12), np.maximum(best["t"], 1e-12)
        ch = plant.channels
        if plant.discrete:  # delta form: S = S_delta / dt, T = T_delta * dt (module docstring)
            s, t = s / plant.dt, t * plant.dt
            return self._discrete_result(plant, best, s, t, tries, base)
        cert = joint.certify(joint.loop(plant.A, plant.B, plant.C, ch.G, ch.H, ch.lo, ch.hi), F, K, P, R, s, t)
        n, q = plant.n, ch.q
        params = {"decay_target": best["lam"], "rate_bound": cert.bound, "gain_norm": best["gain"],
                  "max_gain": self.max_gain, "mu": cert.mu, "x_rate": cert.side_rates[0], "e_rate": cert.side_rates[1],
                  "decay_searches": tries}
        if cert.verified:
            note = "" if best["gain"] <= self.max_gain else (
                f"the gains exceed max_gain = {self.max_gain:g} already at decay 0 (||F||, ||K|| up to "
                f"{best['gain']:.3g}): the smallest gains found are returned")
            out = {"level": "structured", "P": cert.P, "decay_rate": cert.rate, "margin": cert.margin,
                   "radius": ch.radius, "joint": {"P": P, "R": R, "mu": cert.mu, "s": s, "t": t},
                   "how": "the design's own joint certificate (V = x'Q^-1 x + mu e'Re), its rate by a generalised "
                          "eigenvalue"}
            return DesignResult(status="feasible", reason=note, K=K, F=F, margin=cert.margin, lmi_size=2 * n + 2 * q,
                                min_eig={"Q^-1": lmi.min_eig(P), "R": lmi.min_eig(R)}, params=params, certificate=out,
                                **base)
        return DesignResult(status="undecided", reason=(
            f"structured design: both sides verified at decay {best['lam']:.3g}, but the joint certificate with "
            f"mu = {cert.mu:.3g} is {cert.status} (equilibrated max eig {cert.margin:.3g})"), margin=cert.margin,
            params=params, **base)

    def _discrete_result(self, plant: Plant, best: dict, s: np.ndarray, t: np.ndarray, tries: int,
                         base: dict) -> DesignResult:
        """The joint discrete certificate of the sides' solution (:func:`designs._discrete.joint_certificate`)."""
        ch = plant.channels
        lp = joint.loop(plant.A, plant.B, plant.C, ch.G, ch.H, ch.lo, ch.hi)
        P, R, F, K = best["P"], best["R"], best["F"], best["K"]
        lam_x, lam_t = 1.0 / s[lp.keep], t[lp.keep]
        DH = lp.DH
        Pix = np.block([[(DH.T * lam_x) @ DH, np.zeros((plant.n, DH.shape[0]))],
                        [np.zeros((DH.shape[0], plant.n)), -np.diag(lam_x)]])
        Pie = np.block([[(DH.T * lam_t) @ DH, np.zeros((plant.n, DH.shape[0]))],
                        [np.zeros((DH.shape[0], plant.n)), -np.diag(lam_t)]])
        jc = _discrete.joint_certificate(lp.A0 + plant.B @ F, plant.B @ F, lp.A0 - K @ plant.C, lp.G, lp.G,
                                         (P + P.T) / 2, R, Pix, Pie, dt=plant.dt, Sx=best["Q"])
        params = {"decay_target": best["lam"], "contraction_target": math.exp(-best["lam"] * plant.dt),
                  "gain_norm": best["gain"], "max_gain": self.max_gain, "mu": jc["scale"],
                  "contraction": jc["contraction"], "decay_rate": jc["decay_rate"], "decay_searches": tries,
                  "dt": plant.dt, "form": "discrete (contraction factor r = exp(-lam dt))"}
        if jc["status"] != "feasible":
            return DesignResult(status="undecided", reason=f"structured design (discrete): {jc['reason']}",
                                margin=jc["margin"], params=params, **base)
        note = "" if best["gain"] <= self.max_gain else (
            f"the gains exceed max_gain = {self.max_gain:g} already at decay 0 (||F||, ||K||/dt up to "
            f"{best['gain']:.3g}): the smallest gains found are returned")
        cert = {"level": "structured", "P": jc["P"], "decay_rate": jc["decay_rate"], "margin": jc["margin"],
                "radius": ch.radius, "contraction": jc["contraction"], "dt": plant.dt,
                "how": "the design's own joint discrete certificate (V = x'Q^-1 x + s e'Re), its contraction factor "
                       "by bisection"}
        return DesignResult(status="feasible", reason=note, K=K, F=F, margin=jc["margin"], lmi_size=jc["lmi_size"],
                            min_eig={"Q^-1": lmi.min_eig(P), "R": lmi.min_eig(R)}, params=params, certificate=cert,
                            **base)

    def _design_riccati(self, plant: Plant) -> DesignResult:
        """The Riccati route: the decay target searched side by side (or the fixed ``decay``)."""
        import time

        from designs._riccati_route import structured_riccati

        ch = plant.channels
        t0 = time.perf_counter()
        rr = structured_riccati(plant.A, plant.B, plant.C, ch.G, ch.H, ch.lo, ch.hi, lam=self.decay,
                                max_gain=self.max_gain, max_decay=self.max_decay, rtol=self.rtol)
        wall = time.perf_counter() - t0
        params = {"decay_target": rr.lam, "rate_bound": rr.rate_bound, "mu": rr.mu, "tau": rr.tau,
                  "tau_e": rr.tau_e, "residual_x": rr.residual_x, "residual_e": rr.residual_e,
                  "ares": len(rr.tries), "max_gain": self.max_gain, "search_s": rr.timings.get("search", math.nan),
                  "certificate_s": rr.timings.get("certificate", math.nan)}
        if rr.F is not None:
            params["gain_norm"] = max(np.linalg.norm(rr.F, 2), np.linalg.norm(rr.K, 2))
        base = dict(route="riccati", solver=f"{'/'.join(dict.fromkeys(rr.methods)) or 'sign'} (ARE)",
                    solver_status=rr.status, solve_s=wall, n_solves=len(rr.tries), margin=rr.margin,
                    lmi_size=2 * plant.n, params=params)
        if not rr.ok:
            return DesignResult(status=rr.status, reason=f"structured design (Riccati route): {rr.reason}", **base)
        n = plant.n
        P = np.block([[rr.P, np.zeros((n, n))], [np.zeros((n, n)), rr.mu * rr.R]])
        cert = {"level": "structured", "P": P, "decay_rate": rr.rate, "margin": rr.margin, "radius": ch.radius,
                "joint": {"P": rr.P, "R": rr.R, "mu": rr.mu, "s": rr.s, "t": rr.t},
                "how": "the design's own joint certificate (Riccati route), its rate by a generalised eigenvalue"}
        return DesignResult(status="feasible", K=rr.K, F=rr.F, certificate=cert, **base)


def _x_blocks(d: dict, x: dict) -> list:
    """x-side: ``[[A0 Q + Q A0' + B Y + Y' B' + G S G' + 2 lam Q, Q H' Dr], [Dr H Q, -S]]``."""
    A0, B, G, H, Dr = d["A0"], d["B"], d["G"], d["H"], d["Dr"]
    Q, Y, S = x["Q"], x["Y"], lmi.diag(x["s"])
    return [[A0 @ Q + Q @ A0.T + B @ Y + Y.T @ B.T + G @ S @ G.T + 2 * x["lam"] * Q, Q @ H.T @ Dr],
            [Dr @ H @ Q, -S]]


def _e_blocks(d: dict, x: dict) -> list:
    """e-side: ``[[A0' R + R A0 - Kh C - C' Kh' + H' Dr T Dr H + 2 lam R, R G], [G' R, -T]]``."""
    A0, C, G, H, Dr = d["A0"], d["C"], d["G"], d["H"], d["Dr"]
    R, Kh, T = x["R"], x["Kh"], lmi.diag(x["t"])
    return [[A0.T @ R + R @ A0 - Kh @ C - C.T @ Kh.T + H.T @ Dr @ T @ Dr @ H + 2 * x["lam"] * R, R @ G],
            [G.T @ R, -T]]


#: Each side's blocks, decision matrix, gain variable and channel multipliers.
_SIDES = {"x": (_x_blocks, "Q", "Y", "s"), "e": (_e_blocks, "R", "Kh", "t")}


def _side_program(side: str, d: dict, n: int, k: int, q: int) -> lmi.Program:
    """The min-gain program of one side, ``min k`` s.t. ``M << -eps I``, ``pos >= I``, ``||gain|| <= k``, multipliers
    >= 0; the gain is ``Y`` (k = m inputs, m x n) or ``Kh`` (k = p outputs, n x p)."""
    import cvxpy as cp

    blocks, pos, gain, mult = _SIDES[side]
    blocks = partial(blocks, d)
    v = {pos: cp.Variable((n, n), symmetric=True), gain: cp.Variable((k, n) if side == "x" else (n, k)),
         mult: cp.Variable(q), "k": cp.Variable()}
    prm = {"lam": cp.Parameter(nonneg=True, name="lam")}
    M = lmi.sym(lmi.assemble(blocks, {**v, **prm}, numeric=False))
    g = v[gain]
    r, c = g.shape
    eps = 1e-3 * (1.0 + np.linalg.norm(d["A0"], 2))
    cons = [M << -eps * np.eye(n + q), v[pos] >> np.eye(n), v[mult] >= 0,
            cp.bmat([[v["k"] * np.eye(r), g], [g.T, v["k"] * np.eye(c)]]) >> 0]
    prob = cp.Problem(cp.Minimize(v["k"]), cons)
    return lmi.Program(prob, v, prm, blocks, (pos,))


def _x_blocks_discrete(d: dict, x: dict) -> list:
    """Discrete x-side in delta form (module docstring): with ``tau = dt``, ``Ad = (A0 - I) / tau``,
    ``Bd = B / tau``, ``Gd = G / tau``, ``Xd = Ad Q + Bd Y``, ``c = (1 - r^2) / tau``, ``S`` the scaled multipliers ::

        [ Xd + Xd' + c Q + Gd S Gd'     sqrt(tau) (Xd' + Gd S Gd')    Q H' Dr ]
        [ *                             -Q + tau Gd S Gd'             0       ]
        [ Dr H Q                        0                             -S      ]
    """
    Ad, Bd, Gd, H, Dr, tau = d["Ad"], d["Bd"], d["Gd"], d["H"], d["Dr"], d["tau"]
    Q, Y, S = x["Q"], x["Y"], lmi.diag(x["s"])
    Xd = Ad @ Q + Bd @ Y
    GSG = Gd @ S @ Gd.T
    rt = math.sqrt(tau)
    Z = np.zeros((Q.shape[0], S.shape[0]))
    return [[Xd + Xd.T + x["c"] * Q + GSG, rt * (Xd.T + GSG), Q @ H.T @ Dr],
            [rt * (Xd + GSG), -Q + tau * GSG, Z],
            [Dr @ H @ Q, Z.T, -S]]


def _e_blocks_discrete(d: dict, x: dict) -> list:
    """Discrete e-side in delta form (module docstring): ``Wd = R Ad - Kh C`` (``Kh = R K / tau``), ``T`` the scaled
    multipliers ::

        [ Wd + Wd' + c R + H' Dr T Dr H    R Gd                 sqrt(tau) Wd'   ]
        [ Gd' R                            -T                   sqrt(tau) Gd' R ]
        [ sqrt(tau) Wd                     sqrt(tau) R Gd       -R              ]
    """
    Ad, C, Gd, H, Dr, tau = d["Ad"], d["C"], d["Gd"], d["H"], d["Dr"], d["tau"]
    R, Kh, T = x["R"], x["Kh"], lmi.diag(x["t"])
    Wd = R @ Ad - Kh @ C
    rt = math.sqrt(tau)
    return [[Wd + Wd.T + x["c"] * R + H.T @ Dr @ T @ Dr @ H, R @ Gd, rt * Wd.T],
            [Gd.T @ R, -T, rt * (Gd.T @ R)],
            [rt * Wd, rt * (R @ Gd), -R]]


_SIDES_DISCRETE = {"x": (_x_blocks_discrete, "Q", "Y", "s"), "e": (_e_blocks_discrete, "R", "Kh", "t")}


def _side_program_discrete(side: str, d: dict, n: int, k: int, q: int) -> lmi.Program:
    """The discrete min-gain program of one side in delta form (module docstring): ``min k`` s.t. ``M << -eps I``,
    ``pos >= I``, ``||gain|| <= k`` (``Y``, or ``Kh = R K / dt``), multipliers >= 0, the Parameter ``c``
    (= ``(1 - r^2) / dt``); the sample time is the constant ``dt``."""
    import cvxpy as cp

    make, pos, gain, mult = _SIDES_DISCRETE[side]
    tau = float(d["dt"])
    dd = {**d, "tau": tau, "Ad": (d["A0"] - np.eye(n)) / tau, "Bd": d["B"] / tau, "Gd": d["G"] / tau}
    blocks = partial(make, dd)
    v = {pos: cp.Variable((n, n), symmetric=True), gain: cp.Variable((k, n) if side == "x" else (n, k)),
         mult: cp.Variable(q), "k": cp.Variable()}
    prm = {"c": cp.Parameter(nonneg=True, name="c"), "dt": np.array(tau)}
    M = lmi.sym(lmi.assemble(blocks, {**v, **prm}, numeric=False))
    g = v[gain]
    rows, cols = g.shape
    eps = 1e-3 * (1.0 + np.linalg.norm(dd["Ad"], 2))
    cons = [M << -eps * np.eye(M.shape[0]), v[pos] >> np.eye(n), v[mult] >= 0,
            cp.bmat([[v["k"] * np.eye(rows), g], [g.T, v["k"] * np.eye(cols)]]) >> 0]
    prob = cp.Problem(cp.Minimize(v["k"]), cons)
    return lmi.Program(prob, v, prm, blocks, (pos,))
