"""Certificates for any gain pair (K, F), however it was designed: a ladder of three levels.

With K and F fixed, the closed loop (9) in ``z = (x, e)`` is ::

    z' = Acl z + Gb w,   Acl = [[A + B F, -B F], [0, A - K C]],   Gb = diag(Gw, Gw),

where ``w = (w_x, w_e)`` carries the nonlinearity: ``f(x) = Gw w_x`` and
``f(x) - f(x_hat) = Gw w_e``. A quadratic certificate is ``V = z' P z`` with ``P > 0`` and
S-procedure multipliers ``tau_k >= 0`` such that ::

    [ Acl' P + P Acl + 2 lam P    P Gb ]
    [ Gb' P                       0    ]  +  sum_k tau_k Pi_k  <  0

for the quadratic constraints ``xi' Pi_k xi >= 0`` that f is known to satisfy along the pairs
``(x, 0)`` and ``(x, x_hat)``. Then ``V' <= -2 lam V``: the loop is exponentially stable with
rate ``lam`` (globally, or on the region where the constraints hold). Every level maximises a
margin under ``trace(P) = 1`` (the LMI is homogeneous in (P, tau), so this loses nothing) and
is verified by recomputing the matrix with numpy (:func:`bench.lmi.classify`, one tolerance).

The ladder (each level's feasible set contains the one below, so a pair certified at a lower
level is certified above it, with a rate no smaller):

- ``paper``: the paper's (20): block-diagonal ``P = diag(P1, P2)``, ``w = (f, f - f_hat)`` (so
  ``Gw = I``), the OSL and QIB constraints (16)-(19) with one multiplier each;
- ``full``: full ``2n x 2n`` P, every scalar constant known about f (Lipschitz
  ``alpha^2 |dx|^2 - |df|^2 >= 0``, OSL ``rho |dx|^2 - <dx, df> >= 0``, QIB
  ``beta |dx|^2 + gamma <dx, df> - |df|^2 >= 0``), one multiplier per constraint and pair;
- ``structured``: full P with every constraint the plant declares: its channels
  ``f = G phi(H x)`` (``Gw = G``, ``w`` the channel outputs) with one multiplier per channel and
  pair on the slope (sector) constraint ``(w_i - lo_i z_i)(hi_i z_i - w_i) >= 0``,
  ``z = H dx`` (Acikmese & Corless, Automatica 2011; ``docs/structured.md``), plus the scalar constants
  written in channel coordinates.

Only *trusted* knowledge enters (:meth:`bench.constants.ConstantsReport.knowledge`); sampled
constants are lower bounds and never certify. Each level's LMI is written, solved (in balanced coordinates,
with a second solver) and its rate searched by :mod:`bench.lyapunov`; decay rates are searched on the grid of
:mod:`bench.search` (a marginal probe fails), from the rate of the level below up to the smaller of the rate
of the loop linearised at the origin and the class's rate ceiling, which no certificate can beat. A level left
within the tolerance or unsolved is solved again normalised as the verification judges, then offered a cascade
certificate; constraints that hold on a region choose P with the level set through x0 inside it.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.linalg as sla

from bench import checks, joint, lmi, lyapunov, witness
from bench.constants import Knowledge
from bench.search import RATE_RTOL, largest_passing
from plants import Plant

__all__ = ["Certificate", "adopt", "certify", "certify_from_x0", "explain", "level_set", "verify_certificate"]

#: The ladder, weakest first.
LEVELS = ("paper", "full", "structured")

#: Beyond this many states the ladder's SDPs are not attempted; a design's own certificate,
#: verified by eigenvalues, is kept (:func:`adopt`).
LADDER_MAX_N = 16

#: :func:`adopt` replaces a certified level only when its rate is below this fraction of the design's own.
ADOPT_RATIO = 0.9

#: How the reason of a level ruled out by a linear member of its class begins.
RULED_OUT = "no certificate over this level's class exists"

#: Statuses of one level.
LEVEL_STATUSES = ("certified", "not certified", "marginal", "inapplicable", "undecided")


@dataclass
class LevelResult:
    """One level of the ladder for one gain pair.

    Attributes
    ----------
    level : str
        One of :data:`LEVELS`.
    status : str
        One of :data:`LEVEL_STATUSES`.
    decay_rate : float
        Largest verified ``lam`` (0 if only ``lam = 0`` verifies); NaN unless certified.
    margin : float
        Largest eigenvalue of the verified matrix at ``lam = 0`` (negative = certified).
    reason : str
        Why not certified (empty when certified).
    P : ndarray or None
        ``2n x 2n`` Lyapunov matrix at the reported rate (``V = z' P z``, ``z = (x, e)``).
    radius : float or None
        The constraints hold on ``||x|| <= radius`` (None: globally): the certificate is local.
    region_H : ndarray or None
        When set, the region is ``|(H x)_i|, |(H x_hat)_i| <= radius`` for these rows H instead (a
        certificate from x0 on narrowed channel slopes, :func:`certify_from_x0`).
    solve_s : float
        Compile and solve seconds of this level.
    n_solves : int
    slopes : tuple of ndarray or None
        ``(lo, hi)``, each channel's slope bounds narrowed on the region, when the certificate used them (a
        certificate from x0), else None (the declared ones, or none).
    from_x0 : bool
        The certificate was searched with its level set through ``z0`` inside the region (constraints that
        hold on a region), so it proves convergence from the initial condition.
    dt : float
        The plant's sample time (0: continuous): the certificate proves ``V(z_{k+1}) <= r^2 V(z_k)`` with the
        contraction factor ``r = exp(-decay_rate dt)`` per step (:attr:`contraction`).
    l2 : dict
        The level's L2 gains by output (``"e"``, ``"x"``): :class:`Gain` (empty when not computed).
    """

    level: str
    status: str
    decay_rate: float = float("nan")
    margin: float = float("nan")
    reason: str = ""
    P: np.ndarray | None = None
    radius: float | None = None
    solve_s: float = 0.0
    n_solves: int = 0
    region_H: np.ndarray | None = None
    slopes: tuple | None = None
    from_x0: bool = False
    dt: float = 0.0
    l2: dict = field(default_factory=dict)

    @property
    def certified(self) -> bool:
        """True when this level certified the pair."""
        return self.status == "certified"

    @property
    def contraction(self) -> float:
        """The contraction factor per step ``r = exp(-decay_rate dt)`` of a discrete certificate (NaN in continuous
        time or when not certified)."""
        if not (self.dt > 0 and self.certified):
            return float("nan")
        return math.exp(-self.decay_rate * self.dt)


#: Outputs of the L2 gains: the estimation error e (``Cz = [0 I]``) and the state x (``Cz = [I 0]``).
ZETAS = ("e", "x")


@dataclass
class Gain:
    """A level's certified L2 gain from the disturbance w to one output (bounded real lemma with the level's
    S-procedure terms, :mod:`bench.lyapunov`).

    Attributes
    ----------
    zeta : str
        ``"e"`` or ``"x"``.
    status : str
        One of :data:`LEVEL_STATUSES`.
    gain : float
        ``g = sqrt(g2)`` of the verified point (NaN unless certified): ``||zeta||_L2 <= g ||w||_L2`` from
        ``z(0) = 0`` (discrete time: the l2 norms of the sequences).
    P : ndarray or None
        ``V = z' P z`` with ``V' + |zeta|^2 - g^2 |w|^2 <= 0`` over the class (discrete time:
        ``V(z_{k+1}) - V(z_k) + |zeta_k|^2 - g^2 |w_k|^2 <= 0``).
    margin : float
        Largest eigenvalue of the verified matrix.
    reason : str
    radius : float or None
        The class's constraints hold on ``||x|| <= radius`` only (None: globally): the gain then holds while x
        and x_hat stay there.
    level : str
        The level whose LMI proved it (a level below's when inherited).
    solve_s : float
    n_solves : int
    """

    zeta: str
    status: str
    gain: float = float("nan")
    P: np.ndarray | None = None
    margin: float = float("nan")
    reason: str = ""
    radius: float | None = None
    level: str = ""
    solve_s: float = 0.0
    n_solves: int = 0

    @property
    def certified(self) -> bool:
        """True when the gain is certified."""
        return self.status == "certified"


@dataclass
class Certificate:
    """The ladder's outcome for one gain pair.

    Attributes
    ----------
    levels : dict
        :class:`LevelResult` by level name, weakest first (only the levels asked for).
    local : LevelResult or None
        A certificate from x0 on a region where the channel slopes narrow
        (:func:`certify_from_x0`), searched when no level certified.
    local_note : str
        Why no certificate from x0 was found (when it was searched).
    witnesses : list of bench.witness.Witness
        Members of the class that rule out a global certificate (:mod:`bench.witness`).
    equilibria_searched : bool
        The true loop was searched for an equilibrium besides the origin (or the channel class
        proved there is none, :func:`bench.witness.no_equilibrium`).
    """

    levels: dict[str, LevelResult]
    local: LevelResult | None = None
    local_note: str = ""
    witnesses: list = field(default_factory=list)
    equilibria_searched: bool = False

    @property
    def best(self) -> LevelResult | None:
        """The strongest level that certified, else the certificate from x0, or None."""
        cert = [r for r in self.levels.values() if r.certified]
        return cert[-1] if cert else self.local

    @property
    def certified(self) -> bool:
        """True when some level certified."""
        return self.best is not None

    @property
    def decay_rate(self) -> float:
        """The strongest certified level's rate (NaN if none)."""
        b = self.best
        return b.decay_rate if b is not None else float("nan")

    def gain(self, zeta: str) -> Gain | None:
        """The L2 gain to ``zeta`` of the strongest certified level of the ladder (it inherits a better one from
        below, :func:`_inherit_gains`), or None (no level certified, or the gains were not computed). A certificate
        from x0 (:attr:`local`) bounds no gain."""
        cert = [r for r in self.levels.values() if r.certified]
        return cert[-1].l2.get(zeta) if cert else None

    def reason(self, witnessed: bool = False) -> str:
        """One line on the levels that did not certify (``witnessed``: the levels a witness rules out
        are only named, the witness being stated elsewhere)."""
        out, ruled = [], {}
        for r in self.levels.values():
            if r.certified or not r.reason:
                continue
            by = next((k for k in ("linear member", "equilibrium") if r.reason.startswith(f"{RULED_OUT} ({k})")), None)
            if witnessed and by:
                ruled.setdefault(by, []).append(r.level)
            else:
                out.append(f"{r.level}: {r.reason}")
        head = [f"{', '.join(lvs)}: ruled out without a solve by the {k}" for k, lvs in ruled.items()]
        return "; ".join(head + out)


# -- the constraints of a level ---------------------------------------------------------------
_Spec = lyapunov.Spec


def _spec(level: str, n: int, know: Knowledge) -> tuple[_Spec | None, str]:
    """The level's structure, or None and the reason it does not apply."""
    c = know.constants
    have = {"osl": c.rho is not None, "qib": c.beta is not None and c.gamma is not None, "lip": c.alpha is not None}
    notes = f" ({'; '.join(know.notes)})" if know.notes else ""
    if level == "paper":
        if not (have["osl"] and have["qib"]):
            return None, f"needs trusted rho, beta, gamma (the OSL and QIB constants of (20)){notes}"
        return _Spec(level, n, n, False, ("osl", "qib"), False), ""
    scalars = tuple(k for k in ("osl", "qib", "lip") if have[k])
    if level == "full":
        if not scalars:
            return None, f"no trusted scalar constant (alpha, rho, beta/gamma){notes}"
        return _Spec(level, n, n, True, scalars, False), ""
    if know.channels is None:
        if "channels" in know.untrusted:
            return None, f"not used: {know.untrusted['channels']}"
        return None, f"the plant declares no channel structure f = G phi(Hx){notes}"
    return _Spec(level, n, know.channels.q, True, scalars, True), ""


def linearised_rate(plant: Plant, K: np.ndarray, F: np.ndarray) -> float:
    """Decay rate of the loop (6) linearised at the origin, ``-max Re eig`` of ``A + Df(0) + B F`` and
    ``A + Df(0) - K C``: no certificate can beat it (negative when the linearisation is unstable)."""
    return checks.closed_loop(plant, K, F).linearised_rate


def _radius(spec: _Spec, know: Knowledge) -> float | None:
    """The radius on which a level's constraints hold (None: globally)."""
    if not spec.channels:
        return know.constants.radius
    held = (know.constants.radius if spec.scalars else None, know.channels.radius)
    return min((r for r in held if r is not None), default=None)


#: The containment of a level set in its region uses the radius shrunk by this fraction (the solver's rounding).
REGION_SHRINK = 1e-4


def _level(spec: _Spec, plant: Plant, K, F, know: Knowledge, rtol: float, *, box: tuple | None = None,
           rows: tuple = (), r: float | None = None) -> lyapunov.Level:
    """A level's program bound to the gains (:class:`bench.lyapunov.Level`); with ``rows``, the level set through
    ``z0 = (x0, x0 - x_hat0)`` must lie in ``|R z| <= r`` for each block R of ``rows``."""
    z0 = np.concatenate([plant.x0, plant.x0 - plant.x_hat0]) if rows else None
    if rows:
        spec = replace(spec, region=tuple(np.atleast_2d(R).shape[0] for R in rows))
        r = r * (1 - REGION_SHRINK)
    spec = replace(spec, discrete=plant.discrete)
    data = lyapunov.level_data(spec, plant.A, plant.B, plant.C, K, F, know, box=box, rows=rows, r=r, z0=z0,
                               dt=plant.dt)
    return lyapunov.Level(spec, data, rtol=rtol)


def _ball_rows(n: int) -> tuple:
    """The region ``||x||, ||x_hat|| <= r`` as blocks on ``z = (x, e)``: ``x = [I 0] z``, ``x_hat = [I -I] z``."""
    I, Z = np.eye(n), np.zeros((n, n))
    return (np.hstack([I, Z]), np.hstack([I, -I]))


def _solve_level(spec: _Spec, plant: Plant, K, F, know: Knowledge, *, start: float, hi: float, rates: bool,
                 rtol: float, prev: LevelResult | None = None, top_first: bool = False) -> LevelResult:
    """One level's certificate: for constraints that hold on a region, first with the level set through z0
    inside it (:func:`_solve_in`; scope from x0), else as the global problem."""
    radius = _radius(spec, know)
    kw = {"hi": hi, "rates": rates, "top_first": top_first}
    if radius is None:
        return _attempt(spec, plant, K, F, know, rtol, radius, start=start, **kw)
    held = prev is not None and prev.certified and prev.from_x0
    res = _attempt(spec, plant, K, F, know, rtol, radius, region=True, start=start if held else 0.0, **kw)
    if res.certified or held:  # held: the level below's certificate from x0 holds here (it inherits it)
        res.from_x0 = res.certified
        return res
    plain = _attempt(spec, plant, K, F, know, rtol, radius, start=0.0 if held else start, **kw)
    plain.solve_s += res.solve_s
    plain.n_solves += res.n_solves
    return plain


def _attempt(spec: _Spec, plant: Plant, K, F, know: Knowledge, rtol: float, radius: float | None, *,
             region: bool = False, **kw) -> LevelResult:
    """:func:`_solve_in` of the level (with ``region``, the level set through z0 in the ball of ``radius``); when
    the solvers failed on a level with channels and scalar constants, again with the channels alone (a
    certificate of that class is one of the level's, with the scalars' multipliers 0)."""
    rows = {"rows": _ball_rows(plant.n), "r": radius} if region else {}
    lv = _level(spec, plant, K, F, know, rtol, **rows)
    res = _solve_in(lv, radius, **kw)
    if not region and res.status in ("marginal", "undecided"):  # normalised as the verification judges
        rel = _solve_in(_level(replace(spec, norm="relative"), plant, K, F, know, rtol), radius, **kw)
        rel.solve_s += res.solve_s
        rel.n_solves += res.n_solves
        if rel.certified or rel.status == "marginal":
            rel.reason = rel.reason or f"normalised by |M_ij|, |P_ij| <= 1 (by trace(P) = 1: {res.reason})"
            res = rel
        else:
            res.solve_s, res.n_solves = rel.solve_s, rel.n_solves
    elif not region and kw.get("rates") and _stopped_marginal(lv, _reached(res, kw["start"])):
        res = _continue_relative(spec, plant, K, F, know, rtol, radius, res, kw["hi"], _reached(res, kw["start"]))
    if not region and (res.status == "undecided" or (res.status == "marginal" and lv.solver_errors)):
        res = _cascade(lv, res, radius, kw["hi"] if kw.get("rates") else 0.0)
    if res.certified or not (spec.channels and spec.scalars) or not (res.status == "undecided" or lv.solver_errors):
        return res
    alt = _solve_in(_level(replace(spec, scalars=()), plant, K, F, know, rtol, **rows), radius, **kw)
    alt.solve_s += res.solve_s
    alt.n_solves += res.n_solves
    if not alt.certified:
        alt.reason = f"with the scalar constants: {res.reason}; with the channels alone: {alt.reason}"
    else:
        alt.reason = f"with the channels alone (with the scalar constants: {res.reason or res.status})"
    return alt


def _stopped_marginal(lv: lyapunov.Level, lam: float) -> bool:
    """Whether the rate search of ``lv`` (normalised by ``trace(P) = 1``) stopped at ``lam`` because the grid rate
    above it was *marginal* (a point within the tolerance: not a refutation)."""
    from bench.search import _index, _point

    if lv.spec.norm != "trace" or not lam > 0:  # NaN too
        return False
    return lv.verdicts.get(_point(_index(lam, lv.rtol, up=False) + 1, lv.rtol)) == "marginal"


def _reached(res: LevelResult, start: float) -> float:
    """The rate a level's search reached: its own certified rate, or the level below's it started from when it
    certified no grid rate above it (NaN otherwise)."""
    if res.certified:
        return res.decay_rate
    return start if res.reason.startswith("certifies no grid rate above") else math.nan


def _continue_relative(spec: _Spec, plant: Plant, K, F, know: Knowledge, rtol: float, radius: float | None,
                       res: LevelResult, hi: float, lo: float) -> LevelResult:
    """A rate search that stopped at ``lo`` on a marginal probe, continued above it normalised by ``|M_ij|,
    |P_ij| <= 1`` (the margin the verification judges: large multipliers, as a class of constants near 0 needs, or
    high gains leave the ``trace(P) = 1`` point within the tolerance though a certificate exists)."""
    rel = _level(replace(spec, norm="relative"), plant, K, F, know, rtol)
    lam = rel.search(lo, hi)
    out = replace(res, solve_s=res.solve_s + rel.solve_s, n_solves=res.n_solves + rel.n_solves)
    if lam > lo:
        out.status, out.decay_rate, out.P = "certified", lam, rel.found[lam]
        if math.isnan(out.margin):
            out.margin = rel.lam0_margin
        out.reason = f"the rate searched on above {lo:.4g} normalised by |M_ij|, |P_ij| <= 1" + (
            f" ({res.reason})" if res.reason else "")
    return out


def _solve_in(lv: lyapunov.Level, radius: float | None, *, start: float, hi: float, rates: bool,
              top_first: bool = False) -> LevelResult:
    """The level of ``lv``: above ``start`` (a rate the level below certified, which holds here too: no solve
    there), else from a solve at ``lam = 0``; then its rate, up to ``hi``, which no certificate reaches."""
    spec = lv.spec
    out = LevelResult(spec.level, "not certified", radius=radius)
    if rates and 0 < start < hi:
        lam = lv.search(start, hi, top_first=top_first)
        if lam > start:
            out.status, out.decay_rate, out.P = "certified", lam, lv.found[lam]
            out.margin = lv.lam0_margin
        else:
            out.reason = f"certifies no grid rate above the level below's {start:.4g}"
        out.solve_s, out.n_solves = lv.solve_s, lv.n_solves
        return out
    if rates and top_first and hi > 0:  # a tight ceiling: just below it first; a pass there certifies the level
        below = _below_ceiling(lv, hi)
        if below is not None:
            out.status, out.decay_rate, out.P, out.margin = "certified", below, lv.found[below], lv.lam0_margin
            out.solve_s, out.n_solves = lv.solve_s, lv.n_solves
            return out
    verdict, margin = lv.solve(0.0)
    out.margin = margin
    if verdict == "verified":
        out.status, out.P, out.decay_rate = "certified", lv.found[0.0], 0.0
        if rates and hi > 0:
            lam = _rate_from_zero(lv, hi, top_first=top_first)
            out.decay_rate, out.P = lam, lv.found.get(lam, out.P)
    elif verdict == "marginal":
        out.status, out.reason = "marginal", (
            f"best max eig {margin:.3g} is within the verification tolerance of zero ({_normalisation(spec)}; "
            f"{lv.prog.tried})")
    elif verdict == "violated" and lv.prog.last_status == "optimal":
        out.reason = (f"no P > 0 and multipliers make the LMI negative definite: best max eig {margin:.3g} "
                      f"({_normalisation(spec)}; {lv.prog.tried})")
    elif verdict == "violated":  # an inaccurate point proves nothing either way
        out.status, out.reason = "undecided", (f"the solvers' best point is inaccurate and does not verify (max eig "
                                               f"{margin:.3g}; {_normalisation(spec)}; {lv.prog.tried})")
    else:
        out.status, out.reason = "undecided", f"solver status {verdict!r} {lv.prog.last_error} ({lv.prog.tried})"
    out.solve_s, out.n_solves = lv.solve_s, lv.n_solves
    return out


def _cascade(lv: lyapunov.Level, res: LevelResult, radius: float | None, hi: float) -> LevelResult:
    """The level's cascade certificate (:func:`bench.lyapunov.cascade`) where its joint LMI was left within the
    tolerance or unsolved, verified by the level's own matrix; ``res`` when there is none."""
    got = lyapunov.cascade(lv.spec, lv.data, hi, lv.rtol)
    if got["P"] is None:
        res.reason += "; no cascade certificate (a side is not certified, or no weight mu verifies)"
        res.solve_s += got["solve_s"]
        res.n_solves += got["n_solves"]
        return res
    rx, re_ = got["side_rates"]["x"], got["side_rates"]["e"]
    return LevelResult(lv.spec.level, "certified", decay_rate=got["rate"], margin=got["margin"], P=got["P"],
                       radius=radius, solve_s=res.solve_s + got["solve_s"], n_solves=res.n_solves + got["n_solves"],
                       reason=(f"cascade certificate V = x'Px x + mu e'Pe e, mu = {got['mu']:.3g} (the x side "
                               f"certified at {rx:.4g} with B F e as an input, the e side at {re_:.4g}; the joint "
                               f"LMI: {res.status}: {res.reason})"))


#: A level searched from nothing under a tight ceiling first probes these many grid steps below it.
CEILING_STEPS = (1, 3)


def _below_ceiling(lv: lyapunov.Level, hi: float) -> float | None:
    """The level's rate when a grid rate :data:`CEILING_STEPS` steps below its tight ceiling ``hi`` verifies
    (then searched up to ``hi``), else None (the probes' failures stay known to the level's later search)."""
    from bench.search import _index, _point

    kh = _index(hi, lv.rtol, up=True)
    for step in CEILING_STEPS:
        lam = _point(kh - step, lv.rtol)
        if lv.solve(lam)[0] == "verified":
            return lv.search(lam, _point(kh - step + 1, lv.rtol) if step > 1 else hi)
        lv.failed_at = min(lam, lv.failed_at)
    return None


def _rate_from_zero(lv: lyapunov.Level, hi: float, *, top_first: bool = False) -> float:
    """The level's rate after a verified solve at ``lam = 0``: from the grid rate that point reaches
    (:meth:`bench.lyapunov.Level.reach_grid`), or down from ``hi`` by factors of 4 when it reaches none."""
    hi = min(hi, lv.failed_at)  # below the ceiling's failed probes the search goes on down (top_first)
    up = lv.reach_grid(0.0, hi)
    if up is not None:
        return lv.search(up, hi, top_first=top_first, seen=(0.0, lv.margin(0.0)), above_lo=False)

    def passes(x: float):
        return lv.solve(x, probe=True)[0] == "verified" and (True, lv.reach_grid(x, hi))

    res = largest_passing(passes, rtol=lv.rtol, hi=hi, factor=4.0, down_until=1e-6 * max(1.0, hi), aim=lv.secant,
                          aim_next=True)
    return res["lo"] if math.isfinite(res["lo"]) else 0.0


def _normalisation(spec: _Spec) -> str:
    if spec.region:
        return "V(z0) <= 1, the level set through z0 in the region"
    return "|M_ij|, |P_ij| <= 1" if spec.norm == "relative" else "trace(P) = 1"


def _inherit(out: LevelResult, prev: LevelResult | None) -> LevelResult:
    """The better of a level's own result and the certificate of the level below (which holds here too): the
    higher rate, but a certificate whose level set holds z0 (``from_x0``) before one whose does not."""
    if prev is None or not prev.certified:
        return out
    if out.certified and (out.from_x0 > prev.from_x0 or (out.from_x0 == prev.from_x0
                                                          and out.decay_rate >= prev.decay_rate)):
        return out
    own = f"its own LMI: {out.status}" + (f", rate {out.decay_rate:.3g}" if out.certified else "")
    if out.reason.startswith("certifies no grid rate above"):
        own = f"its own LMI {out.reason}"
    return replace(prev, level=out.level, reason=f"inherits the {prev.level} level's certificate ({own})",
                   solve_s=out.solve_s, n_solves=out.n_solves, l2=out.l2)


def certify(
    plant: Plant,
    K: np.ndarray,
    F: np.ndarray,
    knowledge: Knowledge,
    *,
    levels: tuple[str, ...] = LEVELS,
    rates: bool = True,
    rate_rtol: float = RATE_RTOL,
    inherit: bool = True,
    loop: checks.ClosedLoop | None = None,
    gains: bool | None = None,
) -> Certificate:
    """Certify the observer-based closed loop with gains K, F at each level of the ladder.

    A discrete plant (``plant.dt > 0``) is certified in discrete time (:mod:`bench.lyapunov`'s delta form): each
    level proves ``V(z_{k+1}) <= r^2 V(z_k)``, reported as the rate ``-ln(r) / dt`` per second
    (:attr:`LevelResult.contraction` gives r). Beside each rate, each certified level bounds the L2 gains from the
    disturbance to e and to x (:attr:`LevelResult.l2`, :func:`_level_gains`).

    Parameters
    ----------
    plant : Plant
    K, F : ndarray
        Observer gain (n x p) and feedback gain (m x n), ``u = F x_hat``.
    knowledge : Knowledge
        What is trusted about f (constants and channels).
    levels : tuple of str
        Levels to compute (a subset of :data:`LEVELS`, in ladder order).
    rates : bool
        Also find each certified level's decay rate (otherwise ``lam = 0`` only).
    rate_rtol : float
        Relative tolerance of the rate bisection.
    inherit : bool
        A level whose own LMI certifies less than the level below keeps the lower certificate
        (:func:`_inherit`); False reports each level's own LMI only.
    loop : ClosedLoop, optional
        The checked gains K, F and their spectra (:func:`bench.checks.closed_loop`), when the
        caller has them; the rate search stops at its linearised rate.
    gains : bool, optional
        Compute the L2 gains of each certified level (default: with ``rates``; a plant without disturbance
        inputs gets an ``inapplicable`` gain that says so).

    Returns
    -------
    Certificate

    Raises
    ------
    ValueError
        An unknown level, or K, F of the wrong shape.
    """
    for lv in levels:
        if lv not in LEVELS:
            raise ValueError(f"levels: unknown certificate level {lv!r} (known: {', '.join(LEVELS)})")
    loop = loop if loop is not None else checks.closed_loop(plant, K, F)
    gains = rates if gains is None else gains
    cert = Certificate({})
    prev: LevelResult | None = None
    bound = _Bound(plant, loop, knowledge, levels)
    for lv in (lv for lv in LEVELS if lv in levels):
        res = _ladder_level(lv, plant, loop, knowledge, prev, cert, rates=rates, rtol=rate_rtol,
                            inherit=inherit, bound=bound)
        if gains:
            res.l2 = _level_gains(res, plant, loop, knowledge, prev if inherit else None)
        cert.levels[lv] = res
        if res.status != "inapplicable":
            prev = res
    return _stamp(cert, plant)


def _stamp(cert: Certificate, plant: Plant) -> Certificate:
    """Every level's and the local certificate's sample time (their contraction factors), ``cert`` returned."""
    for r in [*cert.levels.values(), cert.local]:
        if r is not None:
            r.dt = float(plant.dt)
    return cert


#: The L2 program's margins: first ``M << -L2_EPS I`` in the original coordinates; a point that does not verify is
#: solved again with the margin ``L2_EPS diag(|M_ii|)`` of its own matrix's diagonal (multipliers that must grow
#: without bound, as for a class of constants 0, keep it in the Jacobi-equilibrated matrix), then with
#: ``M << -eps I`` at :data:`L2_EPS_FACTOR` and ``L2_EPS_FACTOR^2`` times the first point's verification
#: tolerance (entries of M large beside 1): at most four solves.
L2_EPS = 1e-6
L2_EPS_FACTOR = 10.0


def _level_gains(res: LevelResult, plant: Plant, loop: checks.ClosedLoop, know: Knowledge,
                 prev: LevelResult | None) -> dict:
    """The L2 gains of one level of the ladder (``{}`` for an inapplicable level): solved where the level certifies
    (a level that proves no stability proves no finite gain), then the better of its own and the level below's
    (:func:`_inherit_gains`)."""
    if res.status == "inapplicable":
        return {}
    if plant.q == 0:
        return {z: Gain(z, "inapplicable", reason="no disturbance input (the plant has no Bw, Dw)") for z in ZETAS}
    if not res.certified:
        return {z: Gain(z, "not certified", reason=(
            f"the {res.level} level certifies no stability (rate 0): it proves no finite L2 gain")) for z in ZETAS}
    if plant.n > LADDER_MAX_N:
        return {z: Gain(z, "inapplicable", reason=(
            f"n = {plant.n} is beyond the SDP certificate's reach (LADDER_MAX_N = {LADDER_MAX_N})")) for z in ZETAS}
    spec, _ = _spec(res.level, plant.n, know)
    own = {z: l2_gain(spec, plant, loop, know, z) for z in ZETAS}
    below = prev.l2 if prev is not None and prev.certified else {}
    return {z: _inherit_gains(own[z], below.get(z)) for z in ZETAS}


def _inherit_gains(own: Gain, prev: Gain | None) -> Gain:
    """The better of a level's own gain and the level below's (which holds here too: the class is smaller): the
    smaller gain, but a global one before one that holds on a region only."""
    if prev is None or not prev.certified:
        return own
    if own.certified and ((own.radius is None) > (prev.radius is None) or (
            (own.radius is None) == (prev.radius is None) and own.gain <= prev.gain)):
        return own
    mine = f"its own LMI: {own.status}" + (f", gain {own.gain:.4g}" if own.certified else "")
    return replace(prev, reason=f"inherits the {prev.level} level's gain ({mine})", solve_s=own.solve_s,
                   n_solves=own.n_solves)


def l2_gain(spec: _Spec, plant: Plant, loop: checks.ClosedLoop, know: Knowledge, zeta: str) -> Gain:
    """The least L2 gain from the disturbance to ``zeta`` that a level's class proves for the gains of ``loop``.

    The bounded real lemma with the level's P structure and S-procedure terms (:mod:`bench.lyapunov`, measure
    ``"l2"``; a discrete plant's in the delta form), ``g2`` minimised with the margin ``M << -eps I``; the point is
    verified like every level's (the matrix rebuilt with numpy in the original coordinates,
    :func:`bench.lmi.classify`, or its Jacobi-equilibrated form by :func:`bench.joint.verdict`, a congruence), the
    margin changed on the schedule of :data:`L2_EPS` until it verifies; the gain is ``sqrt(g2)`` of the verified
    point.

    Parameters
    ----------
    spec : bench.lyapunov.Spec
        The level's decay structure (:func:`_spec`).
    plant : Plant
        With disturbance inputs (``Bw``, ``Dw``).
    loop : ClosedLoop
    know : Knowledge
    zeta : {"e", "x"}

    Returns
    -------
    Gain
    """
    if plant.q == 0:
        return Gain(zeta, "inapplicable", reason="no disturbance input (the plant has no Bw, Dw)")
    spec = replace(spec, measure="l2", nd=plant.q, region=(), norm="trace", discrete=plant.discrete)
    data = lyapunov.level_data(spec, plant.A, plant.B, plant.C, loop.K, loop.F, know, dt=plant.dt, Bw=plant.Bw,
                               Dw=plant.Dw, zeta=zeta)
    lv = lyapunov.Level(spec, data)
    radius = _radius(spec, know)
    tries, verdict, margin, eps, weights = [(L2_EPS, None)], "", math.nan, L2_EPS, None
    while tries:
        eps, weights = tries.pop(0)
        verdict, margin = lv.minimise(eps, weights)
        M = lv.prog.numeric_matrix() if lv.prog.last_status in ("optimal", "optimal_inaccurate") else None
        if M is None or verdict == "verified":
            break
        P = _p_of(lv)
        if P is not None and lmi.is_positive_definite(P) and joint.verdict(lmi.sym(M)) == "verified":
            verdict = "verified"  # a congruence (Jacobi equilibration) of the same matrix: the same inertia
            break
        if weights is None and eps == L2_EPS:  # the first point: the schedule of L2_EPS
            tol = max(lmi.verify_tol(M), lmi.verify_tol(P) if P is not None else 0.0)
            diag = np.maximum(np.abs(np.diag(M)), lmi.VERIFY_TOL * max(1.0, float(np.abs(M).max())))
            tries = [(L2_EPS, diag)] + [(f * tol, None) for f in (L2_EPS_FACTOR, L2_EPS_FACTOR**2)
                                         if f * tol > L2_EPS]
    out = Gain(zeta, "not certified", margin=margin, radius=radius, level=spec.level, solve_s=lv.solve_s,
               n_solves=lv.n_solves)
    what = f"(bounded real lemma, margin {eps:.3g}{' diag(|M_ii|)' if weights is not None else ''}; {lv.prog.tried})"
    if verdict == "verified":
        g2, P, _ = lv.gain_point()
        out.status, out.gain, out.P = "certified", math.sqrt(max(g2, 0.0)), P
        if radius is not None:
            out.reason = f"holds while x and x_hat stay in ||x|| <= {radius:g}, where the constants hold"
    elif verdict == "marginal":
        out.status, out.reason = "marginal", f"best max eig {margin:.3g} is within the verification tolerance {what}"
    elif verdict == "violated":
        out.status, out.reason = "undecided", (f"the solvers' point does not verify (max eig {margin:.3g}) {what}")
    elif verdict in ("infeasible", "infeasible_inaccurate"):
        out.reason = f"no P > 0, multipliers and g2 make the bounded real LMI negative definite {what}"
    else:
        out.status, out.reason = "undecided", f"solver status {verdict!r} {lv.prog.last_error} {what}"
    return out


def _p_of(lv: lyapunov.Level) -> np.ndarray | None:
    """The last point's full P in the original coordinates (None without one)."""
    vals = lv.prog.checked_values()
    if any(vals.get(k) is None for k in lv.spec.decision):
        return None
    return lyapunov._p(lv.spec, vals)


def _search_equilibria(cert: Certificate, plant: Plant, K: np.ndarray, F: np.ndarray, know: Knowledge):
    """The equilibrium witness of the true loop (searched once per certificate, unless none can exist), or None."""
    if not cert.equilibria_searched:
        cert.equilibria_searched = True
        eq = None if witness.no_equilibrium(plant, K, F, know) else witness.equilibrium_witness(plant, K, F, know)
        if eq is not None:
            cert.witnesses = [eq, *[w for w in cert.witnesses if w.kind != eq.kind]]
    return next((w for w in cert.witnesses if w.kind == "equilibrium"), None)


#: A discrete level's rate search stops at this contraction factor per step (a deadbeat loop's rate is infinite).
DISCRETE_R_MIN = 1e-6


class _Bound:
    """The upper end of the ladder's rate searches: the loop's linearised rate and, once a search needs it, the
    rate ceiling of the highest applicable level's class (:func:`bench.witness.rate_ceiling`). That class is the
    smallest, its members belong to every class below, so its ceiling bounds every level's rate."""

    def __init__(self, plant: Plant, loop: checks.ClosedLoop, know: Knowledge, levels: tuple[str, ...]) -> None:
        self.plant, self.loop, self.know = plant, loop, know
        specs = [(lv, _spec(lv, plant.n, know)[0]) for lv in LEVELS if lv in levels]
        top = [(lv, s) for lv, s in specs if s is not None and plant.n <= LADDER_MAX_N]
        self.top, self._spec = top[-1] if top else (None, None)
        self._ceiling: float | None = None

    @property
    def ceiling(self) -> float:
        """The top level's class ceiling (NaN without a linear member)."""
        if self._ceiling is None:
            s = self._spec
            self._ceiling = math.nan if s is None else witness.rate_ceiling(
                self.plant, self.loop.K, self.loop.F, self.know, channels=s.channels, scalars=s.scalars)[0]
        return self._ceiling

    def hi(self, level: str) -> tuple[float, bool]:
        """The bound for ``level``'s search, and whether it is that level's own class ceiling (then tight enough
        that the search probes just below it first)."""
        lin = self.loop.linearised_rate
        if self.plant.discrete:  # a deadbeat loop's rate is infinite: the search stops at r = DISCRETE_R_MIN
            lin = min(lin, -math.log(DISCRETE_R_MIN) / self.plant.dt)
        c = self.ceiling if lin > 0 else math.nan
        if math.isfinite(c) and c <= lin:
            return c, level == self.top
        return lin, False


def _ladder_level(lv: str, plant: Plant, loop: checks.ClosedLoop, knowledge: Knowledge, prev: LevelResult | None,
                  cert: Certificate, *, rates: bool, rtol: float, inherit: bool,
                  bound: _Bound | None = None) -> LevelResult:
    """One level of :func:`certify` above ``prev``: inapplicable, ruled out by a witness, or solved."""
    spec, why = _spec(lv, plant.n, knowledge)
    if spec is not None and plant.n > LADDER_MAX_N:
        spec, why = None, f"n = {plant.n} is beyond the SDP certificate's reach (LADDER_MAX_N = {LADDER_MAX_N})"
    if spec is None:
        return LevelResult(lv, "inapplicable", reason=why)
    K, F = loop.K, loop.F
    # a level below certified: every linear member of its class, which holds this level's, is stable (no witness)
    below = prev is not None and prev.certified
    unstable = None if below else witness.linear_witness(plant, K, F, knowledge, channels=spec.channels,
                                                         scalars=spec.scalars)
    if unstable is not None:  # the strongest level's witness (its class is the smallest)
        cert.witnesses = [*[w for w in cert.witnesses if w.kind != unstable.kind], unstable]
        return LevelResult(lv, "not certified", reason=(
            f"{RULED_OUT} (linear member): {unstable.text}, and that linear f meets every constraint of the level"))
    if _radius(spec, knowledge) is None and not (below and prev.radius is None):
        eq = _search_equilibria(cert, plant, K, F, knowledge)
        if eq is not None:
            return LevelResult(lv, "not certified", reason=f"{RULED_OUT} (equilibrium): {eq.text}")
    start = prev.decay_rate if inherit and prev is not None and prev.certified else 0.0
    hi, top = bound.hi(lv) if bound is not None and rates else (loop.linearised_rate, False)
    kw = {"start": start, "hi": hi, "top_first": top, "rates": rates, "rtol": rtol, "prev": prev}
    res = _solve_level(spec, plant, K, F, knowledge, **kw)
    return _inherit(res, prev) if inherit else res


def explain(cert: Certificate, plant: Plant, K: np.ndarray, F: np.ndarray, knowledge: Knowledge, *,
            loop: checks.ClosedLoop | None = None) -> Certificate:
    """Complete a ladder's outcome with why it is what it is: witnesses, and a certificate from x0.

    Where a level certified globally, a linear member that ruled out a lower level is dropped from the
    witnesses (it concerns that level's larger class only; that level's reason gives it). Where no
    level certified globally and a linear member already rules the ladder out, or no level
    certified at all, the true closed loop is searched for an equilibrium besides the origin
    (:func:`bench.witness.equilibrium_witness`; it rules out every global certificate), unless
    :func:`certify` already searched it before a global level's LMI. Where no
    level certified, a certificate from x0 is searched on regions where the channel slopes narrow
    (:func:`certify_from_x0`), on regions smaller than the equilibrium found.

    Parameters
    ----------
    cert : Certificate
        From :func:`certify` (updated in place: ``witnesses``, ``local``, ``local_note``).
    plant, K, F, knowledge, loop
        As for :func:`certify`.

    Returns
    -------
    Certificate
    """
    loop = loop if loop is not None else checks.closed_loop(plant, K, F)
    K, F = loop.K, loop.F
    ladder = [r for r in cert.levels.values() if r.certified]
    if any(r.radius is None and r.region_H is None for r in ladder):  # a lower level's linear member rules out
        cert.witnesses = [w for w in cert.witnesses if w.kind != "linear member"]  # its class only (its reason)
        return cert
    eq = _search_equilibria(cert, plant, K, F, knowledge) if cert.witnesses or not ladder else None
    if not ladder:
        r_eq = None
        if eq is not None and knowledge.channels is not None:
            r_eq = float(np.abs(_region_rows(knowledge.channels.H) @ eq.z).max())
        cert.local, cert.local_note = certify_from_x0(plant, K, F, knowledge, r_max=r_eq, loop=loop)
        if r_eq is not None and cert.local is None:
            cert.local_note += f" (regions stop below r = {r_eq:.4g}, where the loop has an equilibrium)"
    return _stamp(cert, plant)


def ceiling(cert: Certificate, plant: Plant, K: np.ndarray, F: np.ndarray, knowledge: Knowledge) -> tuple[float, str]:
    """The rate ceiling of the certified class of ``cert`` (:func:`bench.witness.rate_ceiling`):
    the best level's class, or the narrowed slope box of a certificate from x0.

    Returns
    -------
    float, str
        NaN and "" when nothing is certified.
    """
    best = cert.best
    if best is None:
        return float("nan"), ""
    if best.region_H is not None:
        box = knowledge.channels.slopes_on(best.radius)
        return witness.rate_ceiling(plant, K, F, knowledge, channels=True, scalars=(), box=box)
    spec, _ = _spec(best.level, plant.n, knowledge)
    if spec is None:
        return float("nan"), ""
    return witness.rate_ceiling(plant, K, F, knowledge, channels=spec.channels, scalars=spec.scalars)


def level_set(P: np.ndarray, radius: float, H: np.ndarray | None = None) -> float:
    """The largest ``v`` with ``{z' P z <= v}`` inside ``||x|| <= radius`` and ``||x_hat|| <= radius``
    (with ``H``: inside ``|(H x)_i| <= radius`` and ``|(H x_hat)_i| <= radius``).

    With ``z = (x, e)``, ``x = [I 0] z`` and ``x_hat = [I -I] z``; the largest ``||T z||`` on the
    ellipsoid ``z' P z <= v`` is ``sqrt(v lmax(T P^-1 T'))``, and the largest ``|a' z|`` is
    ``sqrt(v a' P^-1 a)``.

    Parameters
    ----------
    P : ndarray (2n, 2n)
        Positive definite.
    radius : float
    H : ndarray (q, n), optional

    Returns
    -------
    float
    """
    Pinv = np.linalg.inv((P + P.T) / 2)
    if H is not None:
        rows = _region_rows(H)
        return radius**2 / float(np.max(np.einsum("ij,jk,ik->i", rows, Pinv, rows)))
    Tx, Th = np.split(_region_rows(np.eye(P.shape[0] // 2)), 2)  # x = Tx z, x_hat = Th z
    worst = max(float(np.linalg.eigvalsh(T @ Pinv @ T.T)[-1]) for T in (Tx, Th))
    return radius**2 / worst


def _region_rows(H: np.ndarray) -> np.ndarray:
    """The rows ``a`` on ``z = (x, e)`` with ``a' z = (H x)_i`` and ``(H x_hat)_i`` (``x_hat = x - e``)."""
    H = np.asarray(H, dtype=float)
    return np.vstack([np.hstack([H, np.zeros_like(H)]), np.hstack([H, -H])])


#: Regions of the from-x0 search: r grows by ``FROM_X0_GROWTH`` from ``max |H x0|, |H x_hat0|``, at
#: most ``FROM_X0_STEPS`` times (the containment uses r shrunk by :data:`REGION_SHRINK`); after the first
#: region with a certificate, ``FROM_X0_MORE`` larger ones are tried.
FROM_X0_GROWTH = 1.25
FROM_X0_STEPS = 12
FROM_X0_MORE = 2


def certify_from_x0(plant: Plant, K: np.ndarray, F: np.ndarray, knowledge: Knowledge, *,
                    r_max: float | None = None,
                    loop: checks.ClosedLoop | None = None) -> tuple[LevelResult | None, str]:
    """A certificate from the initial condition where the channel slopes narrow on a region.

    On ``|(H x)_i|, |(H x_hat)_i| <= r`` the channels' slopes lie in the declared narrowing
    ``[lo(r), hi(r)]`` (:meth:`plants.Channels.slopes_on`; analytic, never sampled). The
    structured level's LMI with those slopes, plus the containment of the level set through
    ``z0 = (x0, x0 - x_hat0)`` in the region (Schur complements, :mod:`bench.lyapunov`), proves
    ``V' <= -2 lam V`` on ``{V <= V(z0)}``, which the trajectory from z0 never leaves: the loop
    converges from x0 at rate lam. The regions are those of :data:`FROM_X0_GROWTH`; the best rate is kept.

    Parameters
    ----------
    plant, K, F, knowledge, loop
        As for :func:`certify`; the knowledge's channels must declare a narrowing (``Channels.narrow``).
    r_max : float, optional
        Regions are kept below this r (e.g. the size of an equilibrium of the loop, which no
        region with a certificate can hold).

    Returns
    -------
    LevelResult or None, str
        The certificate (level ``"structured"``, ``radius = r``, ``region_H = H``) or None, and
        a sentence on the search (why none was found, up to which r).
    """
    ch = knowledge.channels
    if ch is None or ch.narrow is None:
        return None, "no certificate from x0 searched: the channels declare no narrowing of their slopes on a region"
    if plant.n > LADDER_MAX_N:
        return None, f"no certificate from x0 searched: n = {plant.n} is beyond LADDER_MAX_N = {LADDER_MAX_N}"
    loop = loop if loop is not None else checks.closed_loop(plant, K, F)
    z0 = np.concatenate([plant.x0, plant.x0 - plant.x_hat0])
    rows = _region_rows(ch.H)
    r0 = max(float(np.abs(rows @ z0).max()), 1e-3)
    spec = _Spec("structured", plant.n, ch.q, True, (), True)  # the channels' narrowed slopes only
    best: LevelResult | None = None
    tried, more, cost = [], FROM_X0_MORE, [0.0, 0]
    for r, lo, hi in _regions(ch, r0, r_max):
        tried.append(r)
        lv = _level(spec, plant, loop.K, loop.F, knowledge, RATE_RTOL, box=(lo, hi), rows=tuple(rows), r=r)
        # after a certificate: this region matters only when it certifies that rate too (a failure there ends the
        # search as a lower rate would), so it is probed there first, not at 0
        start = best.decay_rate if best is not None and best.decay_rate > 0 else 0.0
        verdict, margin = lv.solve(start)
        found = None
        if verdict == "verified" and _contains(lv.found[start], z0, ch.H, r):
            found = _rate_in_region(lv, plant, loop, knowledge, z0, r, (lo, hi), margin, start)
        cost[0] += lv.solve_s
        cost[1] += lv.n_solves
        if found is not None:
            if best is None or found.decay_rate > best.decay_rate:
                best = found
            more -= 1
            if more < 0 or found.decay_rate < best.decay_rate:
                break
        elif best is not None:
            break
    if best is not None:
        best.solve_s, best.n_solves = cost
        return best, ""
    return None, _none_from_x0(tried)


def _none_from_x0(tried: list) -> str:
    """The sentence for a from-x0 search that found nothing, naming the regions it tried."""
    if not tried:
        return "no local quadratic certificate from x0 searched: no region holds z0 short of the equilibrium"
    span = f"r = {tried[0]:.4g}" if len(tried) == 1 else f"r from {tried[0]:.4g} up to r = {tried[-1]:.4g}"
    return f"no local quadratic certificate containing z0 was found on |Hx|, |Hx_hat| <= r for {span}"


def _regions(ch, r0: float, r_max: float | None):
    """The regions ``r`` (growing from ``r0``, below ``r_max``) the from-x0 search tries, with their slopes."""
    last, r = None, r0
    for _ in range(FROM_X0_STEPS):
        r *= FROM_X0_GROWTH
        lo, hi = ch.slopes_on(r)
        wide = bool(np.all(lo <= ch.lo) and np.all(hi >= ch.hi))
        if wide:  # no narrowing left: the largest region worth trying is where it ends
            r = max(r / FROM_X0_GROWTH, r0)
        if r_max is not None and r >= r_max:
            if last is not None or math.sqrt(r / FROM_X0_GROWTH * r_max) >= r_max:
                return
            r = math.sqrt(r / FROM_X0_GROWTH * r_max)  # one region between z0 and the equilibrium
        if last is not None and r <= last:
            return
        last = r
        yield r, lo, hi
        if wide:
            return


def _rate_in_region(lv: lyapunov.Level, plant: Plant, loop: checks.ClosedLoop, knowledge: Knowledge,
                    z0: np.ndarray, r: float, box: tuple, margin: float, start: float = 0.0) -> LevelResult:
    """The certificate from x0 on a region where the rate ``start`` (a grid rate, or 0) verified, with the best rate
    whose set holds z0; ``margin``: the verified matrix's largest eigenvalue at ``lam = 0``'s solve (above 0: that of
    the point at ``start``, taken at ``lam = 0``)."""
    lo, hi = box
    ceiling, _ = witness.rate_ceiling(plant, loop.K, loop.F, knowledge, channels=True, scalars=(), box=(lo, hi))
    top = min(loop.linearised_rate, ceiling)
    if start > 0:
        margin = lv.lam0_margin
        lam = lv.search(start, top, seen=(start, lv.margin(start))) if top > start else start
    else:
        lam = _rate_from_zero(lv, top) if top > 0 else 0.0
    P = lv.found.get(lam, lv.found[start])
    if not _contains(P, z0, knowledge.channels.H, r):
        lam, P = start, lv.found[start]
    return LevelResult("structured", "certified", decay_rate=lam, margin=margin, P=P, radius=r,
                       region_H=knowledge.channels.H, slopes=(np.array(lo, dtype=float), np.array(hi, dtype=float)),
                       from_x0=True, reason=(
                           f"certified from x0 on |Hx|, |Hx_hat| <= {r:.4g}, where the slopes narrow to "
                           f"[{_vec(lo)}, {_vec(hi)}]: the level set through z0 stays in that region"))


def _contains(P: np.ndarray, z0: np.ndarray, H: np.ndarray, r: float) -> bool:
    """True when P is positive definite and ``{V <= V(z0)}`` lies in ``|Hx|, |Hx_hat| <= r`` (:func:`level_set`)."""
    return lmi.is_positive_definite(P) and float(z0 @ P @ z0) <= level_set(P, r, H)


def _vec(v) -> str:
    return ", ".join(f"{x:.4g}" for x in np.atleast_1d(v))


#: The declarations a design's own certificate at each level rests on (unless it names its own in
#: ``uses``): :func:`adopt` refuses a certificate that uses one a sample disproved.
LEVEL_USES = {"paper": ("rho", "beta", "gamma"), "full": ("alpha", "rho", "beta", "gamma"),
              "structured": ("channels",)}

#: How a refused design certificate's sentence begins (:func:`adopt`).
REFUSED = "the design's certificate is refused"


def adopt(cert: Certificate, candidate: dict | None, plant: Plant, loop: checks.ClosedLoop,
          knowledge: Knowledge) -> str:
    """Keep a design's own certificate where the ladder's LMI certifies less, once the suite has verified it.

    A design may hand over a certificate of its own (``DesignResult.certificate``: ``level``, ``P``,
    ``decay_rate``, ``how``, optionally ``uses``, ``multipliers`` or ``joint``). Where the ladder's own
    LMI certified clearly less (below :data:`ADOPT_RATIO` of its rate: numerical trouble, or ``n`` beyond
    :data:`LADDER_MAX_N`), the certificate is checked by :func:`verify_certificate`; verified, the level
    takes it (with the suite's margin and the level's own radius) and the levels above inherit it.
    Refused, the level keeps the ladder's own result. A certificate that rests on a declaration
    ``knowledge`` does not trust (``uses``, default :data:`LEVEL_USES` of its level; e.g. channels whose
    slopes a sample disproved) is refused too: the level is then "not certified" unless the ladder
    certified it, and its reason names the declaration.

    Parameters
    ----------
    cert : Certificate
        The ladder's outcome (updated in place).
    candidate : dict or None
    plant : Plant
    loop : ClosedLoop
        The checked gains and their linearised rate (:func:`bench.checks.closed_loop`).
    knowledge : Knowledge

    Returns
    -------
    str
        Why the design's certificate was refused (starting with :data:`REFUSED`), else "".
    """
    if not candidate:
        return ""
    lv = candidate.get("level") if isinstance(candidate, dict) else None
    if lv not in LEVELS:
        return f"{REFUSED}: it names no level of the ladder ({checks.brief(lv)}; known: {', '.join(LEVELS)})"
    if lv not in cert.levels:
        return ""
    cur = cert.levels[lv]
    uses = candidate.get("uses", LEVEL_USES[lv])
    bad = [knowledge.untrusted[k] for k in uses if k in knowledge.untrusted]
    how = str(candidate.get("how", "the design's own certificate"))
    if bad:
        if not cur.certified:
            cert.levels[lv] = replace(cur, status="not certified", reason=(
                f"{how} is refused: it rests on {'; '.join(bad)}"
                + (f" (the ladder's own LMI: {cur.status}: {cur.reason})" if cur.reason else "")))
        return ""
    rate = candidate.get("decay_rate")
    if cur.certified and isinstance(rate, (int, float, np.floating)) and cur.decay_rate >= ADOPT_RATIO * rate:
        return ""  # the ladder's own P (normalised, usually better conditioned) is kept
    own, why = verify_certificate(candidate, plant, loop, knowledge)
    if own is None:
        return f"{REFUSED}: {why}"
    ladder = f"the ladder's own LMI: {cur.status}" + (f", rate {cur.decay_rate:.3g}" if cur.certified else "")
    cert.levels[lv] = replace(own, reason=f"{how}, verified by the suite ({ladder})", solve_s=cur.solve_s,
                              n_solves=cur.n_solves, l2=cur.l2)
    if cur.l2 and not cur.certified:  # the level now certifies stability: its gains are solved
        below = [cert.levels[b] for b in LEVELS[:LEVELS.index(lv)] if b in cert.levels
                 and cert.levels[b].status != "inapplicable"]
        cert.levels[lv].l2 = _level_gains(cert.levels[lv], plant, loop, knowledge, below[-1] if below else None)
    for up in LEVELS[LEVELS.index(lv) + 1:]:
        if up in cert.levels:
            cert.levels[up] = _inherit(cert.levels[up], cert.levels[lv])
            if cert.levels[up].l2:
                cert.levels[up].l2 = {z: _inherit_gains(g, cert.levels[lv].l2.get(z))
                                      for z, g in cert.levels[up].l2.items()}
    return ""


def verify_certificate(candidate: dict, plant: Plant, loop: checks.ClosedLoop,
                       knowledge: Knowledge) -> tuple[LevelResult | None, str]:
    """Check a certificate a design supplies with the suite's own numerics at its level.

    The checks, in order: the level applies to the trusted ``knowledge`` (:func:`_spec`); the rate
    ``lam = decay_rate`` is a finite number ``>= 0``, at most the linearised loop's rate and (up to
    :data:`LADDER_MAX_N` states) at most the ceiling of the level's class (:func:`bench.witness.rate_ceiling`);
    ``P`` (``2n x 2n``, ``V = z' P z``) is symmetric and positive definite
    (:func:`bench.lmi.is_positive_definite`); and the level's matrix inequality holds at ``P`` and
    ``lam`` with multipliers ``>= 0``: those the certificate names (``multipliers``, in the level's
    variable names ``osl_x``, ``qib_e``, ``lip_x``, ``ch_x``, ``ch_e``, ...; a multiplier not named is 0),
    else the best ones found with P and lam fixed (a small SDP, up to :data:`LADDER_MAX_N` states). A
    certificate of the channel-structured joint form (``joint``: ``P``, ``R``, ``mu``, ``s``, ``t``, as
    :mod:`bench.joint`; its ``V = x'P x + mu e'R e``) is checked by :mod:`bench.joint`'s Cholesky test at any size.

    Parameters
    ----------
    candidate : dict
        ``DesignResult.certificate``.
    plant : Plant
    loop : ClosedLoop
    knowledge : Knowledge

    Returns
    -------
    LevelResult or None, str
        The verified certificate (status "certified", the suite's margin at rate 0, the level's radius),
        or None and why it is refused.
    """
    lv, n = candidate.get("level"), plant.n
    spec, why = _spec(lv, n, knowledge)
    if spec is None:
        return None, f"its level {lv!r} does not apply: {why}"
    spec = replace(spec, full_p=True, discrete=plant.discrete)  # a full P of the level's constraints: the same class
    try:
        lam = float(candidate.get("decay_rate"))
        P = _own_matrix(candidate, n)
    except (KeyError, TypeError, ValueError) as exc:
        return None, f"{type(exc).__name__}: {exc}" if isinstance(exc, KeyError) else str(exc)
    if not (math.isfinite(lam) and lam >= 0):
        return None, f"its decay rate {lam!r} is not a finite number >= 0"
    if plant.discrete and candidate.get("contraction") is not None:
        why = _contraction_mismatch(candidate.get("contraction"), lam, plant.dt)
        if why:
            return None, why
    if lam > loop.linearised_rate:
        return None, (f"its rate {lam:.4g} exceeds the rate {loop.linearised_rate:.4g} of the loop linearised at "
                      "the origin, which no certificate can beat")
    if n <= LADDER_MAX_N:
        top, how = witness.rate_ceiling(plant, loop.K, loop.F, knowledge, channels=spec.channels,
                                        scalars=spec.scalars)
        if lam > top:
            return None, f"its rate {lam:.4g} exceeds the rate ceiling {top:.4g} of the level's class ({how})"
    why = _not_positive_definite(P)
    if why:
        return None, why
    if "joint" in candidate:
        if not spec.channels:
            return None, f"a joint certificate needs the channels, which the {lv} level does not use"
        spec = replace(spec, scalars=())
        margin, why = _joint_margin(candidate["joint"], plant, loop, knowledge, lam)
    else:
        margin, why = _level_margin(candidate.get("multipliers"), spec, plant, loop, knowledge, P, lam)
    if why:
        return None, why
    return LevelResult(lv, "certified", decay_rate=lam, margin=margin, P=P, radius=_radius(spec, knowledge),
                       dt=float(plant.dt)), ""


def _contraction_mismatch(r, lam: float, dt: float) -> str:
    """Why a discrete certificate's contraction factor ``r`` is not its rate's ``exp(-lam dt)`` ("" when it is)."""
    try:
        r = float(r)
    except (TypeError, ValueError):
        return f"its contraction factor {checks.brief(r)} is not a number"
    if not (math.isfinite(r) and 0 <= r <= 1):
        return f"its contraction factor {r!r} is not a number in [0, 1]"
    if abs(r - math.exp(-lam * dt)) > 1e-9 * max(1.0, r):
        return (f"its contraction factor r = {r:.9g} is not exp(-decay_rate dt) = {math.exp(-lam * dt):.9g} "
                f"(decay_rate {lam:.6g} /s, dt = {dt:g} s)")
    return ""


def _own_matrix(candidate: dict, n: int) -> np.ndarray:
    """The ``2n x 2n`` P of a design's certificate (``blkdiag(P, mu R)`` of a joint one), symmetrised;
    ValueError when it is missing, of the wrong shape, not finite or not symmetric."""
    if "joint" in candidate:
        j = candidate["joint"]
        P = sla.block_diag(np.asarray(j["P"], dtype=float), float(j["mu"]) * np.asarray(j["R"], dtype=float))
    else:
        P = np.asarray(candidate.get("P"), dtype=float)
    if P.shape != (2 * n, 2 * n) or not np.all(np.isfinite(P)):
        raise ValueError(f"P must be a finite {2 * n} x {2 * n} matrix (z = (x, e)), got shape {P.shape}")
    if np.abs(P - P.T).max() > 1e-9 * max(1.0, float(np.abs(P).max())):
        raise ValueError(f"P is not symmetric (max |P - P'| = {np.abs(P - P.T).max():.3g})")
    return (P + P.T) / 2


def _not_positive_definite(P: np.ndarray) -> str:
    """Why P is not verified positive definite ("" when it is): :func:`bench.lmi.is_positive_definite` of
    ``E = D P D``, ``D = diag(P_ii)^-1/2`` (a congruence: same inertia, whatever the coordinates' scales); from
    :data:`bench.joint.LANCZOS_FROM` rows, the same test (``E > VERIFY_TOL I``) by a Cholesky factorisation."""
    d = np.diag(P)
    if not np.all(d > 0):
        return f"P is not positive definite (a diagonal entry is {d.min():.3g})"
    s = 1.0 / np.sqrt(d)
    E = P * s[:, None] * s[None, :]
    if E.shape[0] >= joint.LANCZOS_FROM:
        return "" if joint.verdict(-E) == "verified" else "P is not positive definite (its Cholesky test fails)"
    return "" if lmi.is_positive_definite(E) else f"P is not positive definite (min eig {lmi.min_eig(P):.3g})"


def _verified_margin(M: np.ndarray, W: np.ndarray, lam: float) -> tuple[float, str]:
    """A certificate's matrix ``M`` at rate ``lam`` judged by :func:`bench.joint.verdict` (Cholesky tests of the
    equilibrated matrix), and its equilibrated margin at rate 0 (``M - 2 lam W``, W the rate's weight on the
    leading block); the verdict when it is not "verified"."""
    verdict = joint.verdict(M)
    if verdict != "verified":
        return math.nan, verdict
    M0 = M.copy()
    k = W.shape[0]
    M0[:k, :k] -= 2 * lam * W
    if k < joint.LANCZOS_FROM:
        return joint.equilibrated_max_eig(M0), ""
    try:  # as bench.joint.certify: Lanczos on a Cholesky factor of -D M0 D
        L = sla.cholesky(-M0, lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        return joint.equilibrated_max_eig(M0), ""
    margin = -joint._lanczos_min(L / np.sqrt(np.abs(np.diag(M0)))[:, None])
    return (margin if math.isfinite(margin) else joint.equilibrated_max_eig(M0)), ""


def _level_values(spec: _Spec, plant: Plant, loop: checks.ClosedLoop, know: Knowledge, P: np.ndarray,
                  lam: float) -> dict:
    """The numbers of a level's LMI at a given P and rate (:func:`bench.lyapunov.matrix`, a discrete plant's in the
    delta form, ``lam`` converted by :func:`bench.lyapunov.measure`; the multipliers ``tau`` are added by the
    caller)."""
    spec = replace(spec, discrete=plant.discrete)
    d = lyapunov.level_data(spec, plant.A, plant.B, plant.C, loop.K, loop.F, know, dt=plant.dt)
    return {**lyapunov.values(spec, d), "lam": lyapunov.measure(lam, plant.dt), "P": P}


def _multiplier_names(spec: _Spec) -> dict[str, int | None]:
    """The level's multipliers: name -> length (None for a scalar)."""
    out: dict[str, int | None] = {}
    for side in ("x", "e"):
        out.update({f"{k}_{side}": None for k in spec.scalars})
        if spec.channels:
            out[f"ch_{side}"] = spec.nw
    return out


def _tau(spec: _Spec, named: dict):
    """The multipliers by name (:func:`_multiplier_names`) as the vector ``tau`` of :attr:`bench.lyapunov.Spec.
    multipliers` (numpy or cvxpy values)."""
    parts = []
    for side in ("x", "e"):
        parts += [named[f"{k}_{side}"] for k in spec.scalars]
        if spec.channels:
            parts.append(named[f"ch_{side}"])
    if all(isinstance(v, (float, int, np.floating, np.ndarray)) for v in parts):
        return np.concatenate([np.atleast_1d(np.asarray(v, dtype=float)) for v in parts])
    import cvxpy as cp

    return cp.hstack([cp.reshape(v, (1,), order="F") if v.ndim == 0 else v for v in parts])


def _level_margin(named, spec: _Spec, plant: Plant, loop: checks.ClosedLoop, know: Knowledge, P: np.ndarray,
                  lam: float) -> tuple[float, str]:
    """The verified margin at rate 0 of the level's LMI at ``P`` and ``lam`` (``named`` multipliers, else found),
    or NaN and why it does not hold."""
    names, found = _multiplier_names(spec), named is None
    if found:
        if plant.n > LADDER_MAX_N:
            return math.nan, (f"unverifiable: it names no multipliers and n = {plant.n} is beyond LADDER_MAX_N = "
                              f"{LADDER_MAX_N}, where the suite does not search them")
        named = _find_multipliers(spec, plant, loop, know, P, lam)
        if named is None:
            return math.nan, f"no multipliers >= 0 make the {spec.level} level's LMI hold at its P and rate {lam:.4g}"
    elif not isinstance(named, dict) or set(named) - set(names):
        return math.nan, (f"its multipliers must be a dict of the level's names ({', '.join(names)}), got "
                          f"{checks.brief(named if not isinstance(named, dict) else sorted(named))}")
    values = _level_values(spec, plant, loop, know, P, lam)
    taus = {}
    for k, size in names.items():
        v = np.asarray(named.get(k, np.zeros(size) if size else 0.0), dtype=float)
        if v.shape != (() if size is None else (size,)) or not np.all(np.isfinite(v)) or np.any(v < 0):
            return math.nan, f"its multiplier {k} must be finite and >= 0 of shape {size or 'scalar'}, got {v!r}"
        taus[k] = float(v) if size is None else v
    M = lyapunov.matrix(spec, {**values, "tau": _tau(spec, taus)})[0][0]
    margin, verdict = _verified_margin((M + M.T) / 2, P, lyapunov.measure(lam, plant.dt))
    if verdict:
        return math.nan, (f"the {spec.level} level's LMI at its P and rate {lam:.4g} is {verdict} (bench.joint's "
                          f"Cholesky test, with the multipliers {'the suite found' if found else 'it names'})")
    return margin, ""


def _find_multipliers(spec: _Spec, plant: Plant, loop: checks.ClosedLoop, know: Knowledge, P: np.ndarray,
                      lam: float) -> dict | None:
    """The multipliers ``>= 0`` that make the level's LMI at ``P`` and ``lam`` most negative (None: the solve
    failed): maximise ``t`` with ``M << -t I``, ``t <= 1``, P scaled to a unit largest entry."""
    import cvxpy as cp

    scale = float(np.abs(P).max())
    tau = {k: cp.Variable(nonneg=True, name=k) if size is None else cp.Variable(size, nonneg=True, name=k)
           for k, size in _multiplier_names(spec).items()}
    values = {**_level_values(spec, plant, loop, know, P / scale, lam), "tau": _tau(spec, tau)}
    M = lmi.sym(lyapunov.matrix(spec, values)[0][0])
    t = cp.Variable(name="t")
    prob = cp.Problem(cp.Maximize(t), [M << -t * np.eye(M.shape[0]), t <= 1])
    if not lmi.solve_timed(prob).solved:
        return None
    return {k: scale * np.maximum(np.asarray(v.value, dtype=float), 0.0) for k, v in tau.items()}


def _joint_margin(j: dict, plant: Plant, loop: checks.ClosedLoop, know: Knowledge, lam: float) -> tuple[float, str]:
    """The equilibrated margin at rate 0 of a joint certificate (:mod:`bench.joint`) verified at ``lam`` with the
    trusted channels, or NaN and why it does not hold."""
    ch = know.channels
    lp = joint.loop(plant.A, plant.B, plant.C, ch.G, ch.H, ch.lo, ch.hi)
    try:
        Pj, Rj = (np.asarray(j[k], dtype=float) for k in ("P", "R"))
        mu, s, t = float(j["mu"]), j["s"], j["t"]
        if not (mu > 0 and np.all(np.asarray(s, float) > 0) and np.all(np.asarray(t, float) > 0)):
            return math.nan, "its joint multipliers mu, s, t must be > 0"
        Mx, Me = joint.side_matrices(lp, loop.F, loop.K, Pj, Rj, s, t, lam)
    except (KeyError, TypeError, ValueError) as exc:
        return math.nan, f"its joint multipliers cannot be used: {type(exc).__name__}: {exc}"
    PBF = Pj @ plant.B @ loop.F
    margin, verdict = _verified_margin(np.block([[Mx, -PBF], [-PBF.T, mu * Me]]), sla.block_diag(Pj, mu * Rj), lam)
    if verdict:
        return math.nan, f"its joint matrix at rate {lam:.4g} is {verdict} (bench.joint's Cholesky test)"
    return margin, ""
