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
constants are lower bounds and never certify. Decay rates are searched on the grid of
:mod:`bench.search` (a marginal probe fails), from the rate of the level below up to the rate of
the loop linearised at the origin, which no certificate can beat.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np
from scipy.linalg import block_diag

from bench import checks, lmi, witness
from bench.constants import Knowledge
from bench.search import RATE_RTOL, grid_floor, largest_passing
from plants import Plant

__all__ = ["Certificate", "certify", "certify_from_x0", "explain", "level_set"]

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

    @property
    def certified(self) -> bool:
        """True when this level certified the pair."""
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
@dataclass(frozen=True)
class _Spec:
    """The structure of a level's LMI (it keys the compiled program)."""

    level: str
    n: int
    nw: int
    full_p: bool
    scalars: tuple[str, ...]  # subset of ("osl", "qib", "lip")
    channels: bool


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


def _build(spec: _Spec, mats: lmi.Matrices, blocks, rows: np.ndarray | None = None) -> lmi.Program:
    """A level's margin program: ``trace(P) = 1``, or with ``rows`` z0's level set held in the region (Schur)."""
    import cvxpy as cp

    n, nw = spec.n, spec.nw
    pos, size = (("P",), 2 * n) if spec.full_p else (("P1", "P2"), n)
    v = {"slack": cp.Variable(name="slack")}
    v.update({k: cp.Variable((size, size), symmetric=True, name=k) for k in pos})
    for side in ("x", "e"):
        for k in spec.scalars:
            v[f"{k}_{side}"] = cp.Variable(name=f"tau_{k}_{side}")
        if spec.channels:
            v[f"ch_{side}"] = cp.Variable(nw, name=f"tau_channels_{side}")
    prm = {"lam": cp.Parameter(nonneg=True, name="lam"), **mats.parameters(),
           **lmi.scalar_parameters("rho", "beta", "gamma", "a2")}
    if spec.channels:
        prm["lohi"] = cp.Parameter(nw, name="lo_times_hi")
        prm["losum"] = cp.Parameter(nw, name="lo_plus_hi")
    t_build = time.perf_counter()
    M = lmi.sym(lmi.assemble(blocks, {**v, **prm}, numeric=False))
    slack = v["slack"]
    cons = [M << -slack * np.eye(M.shape[0])]
    cons += [v[k] >> slack * np.eye(v[k].shape[0]) for k in pos]
    if rows is None:
        cons.append(sum(cp.trace(v[k]) for k in pos) == 1)
    else:
        prm["Z0"] = cp.Parameter((2 * n, 2 * n), PSD=True, name="Z0")
        prm["r2"] = cp.Parameter(nonneg=True, name="r2")
        P, r2 = v["P"], cp.reshape(prm["r2"], (1, 1), order="F")
        cons += [cp.trace(prm["Z0"] @ P) <= 1, slack <= 1]
        cons += [lmi.sym(cp.bmat([[P, a[:, None]], [a[None, :], r2]])) >> 0 for a in rows]
    cons += [v[k] >= 0 for k in v if k not in pos and k != "slack"]
    prob = cp.Problem(cp.Maximize(slack), cons)
    return lmi.Program(prob, v, prm, blocks, pos, build_s=time.perf_counter() - t_build)


def _blocks(spec: _Spec, Gw: np.ndarray, Hc: np.ndarray | None, d: dict) -> list[list]:
    """The 4 x 4 block matrix in (x, e, w_x, w_e), numeric or cvxpy (``d``: values)."""
    n, nw = spec.n, spec.nw
    I, Zn, Zw, Znw = np.eye(n), np.zeros((n, n)), np.zeros((nw, nw)), np.zeros((n, nw))
    GtG = Gw.T @ Gw
    if spec.full_p:
        P = d["P"]
        P11, P12, P22 = P[:n, :n], P[:n, n:], P[n:, n:]
    else:
        P11, P12, P22 = d["P1"], Zn, d["P2"]
    Ax, Ae, BF, lam = d["Ax"], d["Ae"], d["BF"], d["lam"]
    # V' terms: Acl' P + P Acl + 2 lam P, Acl = [[Ax, -BF], [0, Ae]]
    xx = Ax.T @ P11 + P11 @ Ax + 2 * lam * P11
    xe = -P11 @ BF + Ax.T @ P12 + P12 @ Ae + 2 * lam * P12
    ee = -BF.T @ P12 - P12.T @ BF + Ae.T @ P22 + P22 @ Ae + 2 * lam * P22
    xwx, xwe = P11 @ Gw, P12 @ Gw
    ewx, ewe = P12.T @ Gw, P22 @ Gw
    ww = {"x": Zw, "e": Zw}
    diag = {"x": 0 * I, "e": 0 * I}
    cross = {"x": Znw, "e": Znw}
    for side in ("x", "e"):
        for k in spec.scalars:
            tau = d[f"{k}_{side}"]
            diag[side] = diag[side] + tau * d[{"osl": "rho", "qib": "beta", "lip": "a2"}[k]] * I
            if k == "osl":
                cross[side] = cross[side] - (0.5 * tau) * Gw
            elif k == "qib":
                cross[side] = cross[side] + (0.5 * tau * d["gamma"]) * Gw
            if k != "osl":  # QIB and Lipschitz: - |df|^2
                ww[side] = ww[side] - tau * GtG
        if spec.channels:
            tau = d[f"ch_{side}"]
            diag[side] = diag[side] + Hc.T @ lmi.diag(-(lmi.diag(d["lohi"]) @ tau)) @ Hc
            cross[side] = cross[side] + Hc.T @ lmi.diag(0.5 * (lmi.diag(d["losum"]) @ tau))
            ww[side] = ww[side] - lmi.diag(tau)
    return [
        [xx + diag["x"], xe, xwx + cross["x"], xwe],
        [xe.T, ee + diag["e"], ewx, ewe + cross["e"]],
        [(xwx + cross["x"]).T, ewx.T, ww["x"], Zw],
        [xwe.T, (ewe + cross["e"]).T, Zw, ww["e"]],
    ]


def _full_p(prog: lmi.Program, spec: _Spec) -> np.ndarray:
    vals = prog.values()
    return np.array(vals["P"]) if spec.full_p else block_diag(vals["P1"], vals["P2"])


def _rate(prog: lmi.Program, spec: _Spec, lam0: float, hi: float, rtol: float,
          local: bool = False) -> tuple[float, np.ndarray]:
    """Largest verified grid rate in ``[lam0, hi)`` from a verified solve at ``lam0`` (``local``: a step lower)."""
    found = {lam0: _full_p(prog, spec)}

    def passes(lam: float) -> bool:
        prog.solve(lam=lam)
        ok = prog.verified()
        if ok:
            found[lam] = _full_p(prog, spec)
        return ok

    if lam0 > 0:
        out = largest_passing(passes, rtol=rtol, lo=lam0, hi=hi)
    else:  # a first positive rate: down from hi by factors of 4
        out = largest_passing(passes, rtol=rtol, hi=hi, factor=4.0, down_until=1e-6 * max(1.0, hi))
    lam = out["lo"] if math.isfinite(out["lo"]) else 0.0
    if local and lam > lam0:
        below = grid_floor(lam / (1 + rtol) * (1 + 1e-9), rtol)
        lam = below if below > lam0 and (below in found or passes(below)) else lam0
    return lam, found.get(lam, found[lam0])


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


def _set_program(spec: _Spec, plant: Plant, K, F, know: Knowledge, rows: np.ndarray | None = None) -> lmi.Program:
    """The level's analysis program, compiled once per structure (with ``rows``: of a certificate from x0), set
    for the gains K, F and the trusted scalar constants."""
    mats = lmi.matrices(all_parameters=True, Ax=plant.A + plant.B @ F, Ae=plant.A - K @ plant.C, BF=plant.B @ F)
    ch = know.channels if spec.channels else None
    Gw = ch.G if ch is not None else np.eye(spec.n)
    Hc = ch.H if ch is not None else None
    blocks = partial(_blocks, spec, Gw, Hc)
    key = ("certify" if rows is None else "certify-from-x0", spec, mats.key, lmi.digest(Gw), lmi.digest(Hc))
    prog = lmi.cached_program(key, lambda: _build(spec, mats, blocks, rows=rows))
    c = know.constants
    prog.set(**mats.settable(), rho=c.rho or 0.0, beta=c.beta or 0.0, gamma=c.gamma or 0.0, a2=(c.alpha or 0.0) ** 2)
    return prog


def _solve_level(spec: _Spec, plant: Plant, K, F, know: Knowledge, *, start: float, hi: float, rates: bool,
                 rtol: float) -> LevelResult:
    """One level's program: certified at ``start`` (else at 0), then its rate."""
    prog = _set_program(spec, plant, K, F, know)
    if spec.channels:
        prog.set(lohi=know.channels.lo * know.channels.hi, losum=know.channels.lo + know.channels.hi)
    radius = _radius(spec, know)
    for lam0 in dict.fromkeys((start if 0 < start < hi else 0.0, 0.0)):
        prog.solve(lam=lam0)
        verdict, margin = prog.verdict()
        if verdict == "verified":
            break
    out = LevelResult(spec.level, "not certified", margin=margin, radius=radius)
    if verdict == "verified":
        out.status, out.P, out.decay_rate = "certified", _full_p(prog, spec), 0.0
        if lam0 > 0:  # the margin at lam = 0 of the same solution: M(0) = M(lam0) - 2 lam0 diag(P, 0)
            M = prog.numeric_matrix()
            M[: out.P.shape[0], : out.P.shape[0]] -= 2 * lam0 * out.P
            out.margin = lmi.max_eig(M)
        if rates and hi > 0:
            out.decay_rate, out.P = _rate(prog, spec, lam0, hi, rtol, local=radius is not None)
    elif verdict == "marginal":
        out.status, out.reason = "marginal", (
            f"best max eig {margin:.3g} is within the verification tolerance of zero (trace(P) = 1)")
    elif verdict == "violated":
        out.reason = f"no P > 0 and multipliers make the LMI negative definite: best max eig {margin:.3g} (trace(P) = 1)"
    else:
        out.status, out.reason = "undecided", f"solver status {verdict!r} {prog.last_error}".strip()
    out.solve_s, out.n_solves = prog.compile_s + prog.solve_s, prog.n_solves
    return out


def _inherit(out: LevelResult, prev: LevelResult | None) -> LevelResult:
    """The better of a level's own result and the certificate of the level below (which holds here too)."""
    if prev is None or not prev.certified or (out.certified and out.decay_rate >= prev.decay_rate):
        return out
    own = f"its own LMI: {out.status}" + (f", rate {out.decay_rate:.3g}" if out.certified else "")
    return replace(prev, level=out.level, reason=f"inherits the {prev.level} level's certificate ({own})",
                   solve_s=out.solve_s, n_solves=out.n_solves)


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
) -> Certificate:
    """Certify the observer-based closed loop with gains K, F at each level of the ladder.

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
    cert = Certificate({})
    prev: LevelResult | None = None
    for lv in (lv for lv in LEVELS if lv in levels):
        cert.levels[lv] = _ladder_level(lv, plant, loop, knowledge, prev, cert, rates=rates, rtol=rate_rtol,
                                        inherit=inherit)
        if cert.levels[lv].status != "inapplicable":
            prev = cert.levels[lv]
    return cert


def _search_equilibria(cert: Certificate, plant: Plant, K: np.ndarray, F: np.ndarray, know: Knowledge):
    """The equilibrium witness of the true loop (searched once per certificate, unless none can exist), or None."""
    if not cert.equilibria_searched:
        cert.equilibria_searched = True
        eq = None if witness.no_equilibrium(plant, K, F, know) else witness.equilibrium_witness(plant, K, F, know)
        if eq is not None:
            cert.witnesses = [eq, *[w for w in cert.witnesses if w.kind != eq.kind]]
    return next((w for w in cert.witnesses if w.kind == "equilibrium"), None)


def _ladder_level(lv: str, plant: Plant, loop: checks.ClosedLoop, knowledge: Knowledge, prev: LevelResult | None,
                  cert: Certificate, *, rates: bool, rtol: float, inherit: bool) -> LevelResult:
    """One level of :func:`certify` above ``prev``: inapplicable, ruled out by a witness, or solved."""
    spec, why = _spec(lv, plant.n, knowledge)
    if spec is not None and plant.n > LADDER_MAX_N:
        spec, why = None, f"n = {plant.n} is beyond the SDP certificate's reach (LADDER_MAX_N = {LADDER_MAX_N})"
    if spec is None:
        return LevelResult(lv, "inapplicable", reason=why)
    K, F = loop.K, loop.F
    unstable = witness.linear_witness(plant, K, F, knowledge, channels=spec.channels, scalars=spec.scalars)
    if unstable is not None:  # the strongest level's witness (its class is the smallest)
        cert.witnesses = [*[w for w in cert.witnesses if w.kind != unstable.kind], unstable]
        return LevelResult(lv, "not certified", reason=(
            f"{RULED_OUT} (linear member): {unstable.text}, and that linear f meets every constraint of the level"))
    if _radius(spec, knowledge) is None:
        eq = _search_equilibria(cert, plant, K, F, knowledge)
        if eq is not None:
            return LevelResult(lv, "not certified", reason=f"{RULED_OUT} (equilibrium): {eq.text}")
    start = prev.decay_rate if prev is not None and prev.certified else 0.0
    kw = {"start": start, "hi": loop.linearised_rate, "rates": rates, "rtol": rtol}
    res = _solve_level(spec, plant, K, F, knowledge, **kw)
    if res.status == "undecided" and spec.channels and spec.scalars:  # the channels alone (still valid)
        alt = _solve_level(replace(spec, scalars=()), plant, K, F, knowledge, **kw)
        alt.solve_s += res.solve_s
        alt.n_solves += res.n_solves
        if not alt.certified:
            alt.reason = f"with the scalar constants: {res.reason}; with the channels alone: {alt.reason}"
        res = alt
    return _inherit(res, prev) if inherit else res


def explain(cert: Certificate, plant: Plant, K: np.ndarray, F: np.ndarray, knowledge: Knowledge, *,
            loop: checks.ClosedLoop | None = None) -> Certificate:
    """Complete a ladder's outcome with why it is what it is: witnesses, and a certificate from x0.

    Where no level certified globally and a linear member already rules the ladder out, or no level
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
    if any(r.radius is None and r.region_H is None for r in ladder):
        return cert
    eq = _search_equilibria(cert, plant, K, F, knowledge) if cert.witnesses or not ladder else None
    if not ladder:
        r_eq = None
        if eq is not None and knowledge.channels is not None:
            r_eq = float(np.abs(_region_rows(knowledge.channels.H) @ eq.z).max())
        cert.local, cert.local_note = certify_from_x0(plant, K, F, knowledge, r_max=r_eq, loop=loop)
        if r_eq is not None and cert.local is None:
            cert.local_note += f" (regions stop below r = {r_eq:.4g}, where the loop has an equilibrium)"
    return cert


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
#: most ``FROM_X0_STEPS`` times; the containment uses r shrunk by ``FROM_X0_SHRINK`` (relative, for the
#: solver's rounding); after the first region with a certificate, ``FROM_X0_MORE`` larger ones are tried.
FROM_X0_GROWTH = 1.25
FROM_X0_STEPS = 12
FROM_X0_SHRINK = 1e-4
FROM_X0_MORE = 2


def certify_from_x0(plant: Plant, K: np.ndarray, F: np.ndarray, knowledge: Knowledge, *,
                    r_max: float | None = None,
                    loop: checks.ClosedLoop | None = None) -> tuple[LevelResult | None, str]:
    """A certificate from the initial condition where the channel slopes narrow on a region.

    On ``|(H x)_i|, |(H x_hat)_i| <= r`` the channels' slopes lie in the declared narrowing
    ``[lo(r), hi(r)]`` (:meth:`plants.Channels.slopes_on`; analytic, never sampled). The
    structured level's LMI with those slopes, plus the containment of the level set through
    ``z0 = (x0, x0 - x_hat0)`` in the region (Schur complements, :func:`_build`), proves
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
    prog = _set_program(spec, plant, loop.K, loop.F, knowledge, rows)
    prog.set(Z0=np.outer(z0, z0))
    best: LevelResult | None = None
    tried, more = [], FROM_X0_MORE
    for r, lo, hi in _regions(ch, r0, r_max):
        tried.append(r)
        prog.set(lohi=lo * hi, losum=lo + hi, r2=(r * (1 - FROM_X0_SHRINK)) ** 2)
        prog.solve(lam=0.0)
        verdict, margin = prog.verdict()
        if verdict == "verified" and _contains(_full_p(prog, spec), z0, ch.H, r):
            found = _rate_in_region(prog, spec, plant, loop, knowledge, z0, r, (lo, hi), margin)
            if best is None or found.decay_rate > best.decay_rate:
                best = found
            more -= 1
            if more < 0 or found.decay_rate < best.decay_rate:
                break
        elif best is not None:
            break
    if best is not None:
        best.solve_s, best.n_solves = prog.compile_s + prog.solve_s, prog.n_solves
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


def _rate_in_region(prog: lmi.Program, spec: _Spec, plant: Plant, loop: checks.ClosedLoop, knowledge: Knowledge,
                    z0: np.ndarray, r: float, box: tuple, margin: float) -> LevelResult:
    """The certificate from x0 on a region where ``lam = 0`` verified, with the best rate whose set holds z0."""
    lo, hi = box
    ceiling, _ = witness.rate_ceiling(plant, loop.K, loop.F, knowledge, channels=True, scalars=(), box=(lo, hi))
    top = min(loop.linearised_rate, ceiling)
    P0 = _full_p(prog, spec)
    lam, P = _rate(prog, spec, 0.0, top, RATE_RTOL) if top > 0 else (0.0, P0)
    if not _contains(P, z0, knowledge.channels.H, r):
        lam, P = 0.0, P0
    return LevelResult("structured", "certified", decay_rate=lam, margin=margin, P=P, radius=r,
                       region_H=knowledge.channels.H, slopes=(np.array(lo, dtype=float), np.array(hi, dtype=float)),
                       reason=(
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


def adopt(cert: Certificate, candidate: dict | None, knowledge: Knowledge) -> None:
    """Keep a design's own verified certificate where the ladder's LMI certifies less (``cert`` updated).

    A design may verify a joint certificate of its own (``DesignResult.certificate``: ``level``, ``P``,
    ``decay_rate``, ``margin``, ``radius``, ``how``, optionally ``uses``); it uses that level's knowledge,
    so it is a certificate at that level (and, by inclusion, at every level above). Where the ladder's own
    LMI certified clearly less (below :data:`ADOPT_RATIO` of its rate: numerical trouble, or ``n`` beyond
    :data:`LADDER_MAX_N`), the level takes it, and the levels above inherit it. A certificate that rests on
    a declaration ``knowledge`` does not trust (``uses``, default :data:`LEVEL_USES` of its level; e.g.
    channels whose slopes a sample disproved) is refused: the level is "not certified" and its reason
    names the declaration.
    """
    if not candidate or candidate.get("level") not in cert.levels:
        return
    lv = candidate["level"]
    cur = cert.levels[lv]
    bad = [knowledge.untrusted[k] for k in candidate.get("uses", LEVEL_USES[lv]) if k in knowledge.untrusted]
    if bad:
        if not cur.certified:
            cert.levels[lv] = replace(cur, status="not certified", reason=(
                f"{candidate['how']} is refused: it rests on {'; '.join(bad)}"
                + (f" (the ladder's own LMI: {cur.status}: {cur.reason})" if cur.reason else "")))
        return
    if cur.certified and cur.decay_rate >= ADOPT_RATIO * candidate["decay_rate"]:
        return  # the ladder's own P (normalised, usually better conditioned) is kept
    own = f"the ladder's own LMI: {cur.status}" + (f", rate {cur.decay_rate:.3g}" if cur.certified else "")
    cert.levels[lv] = replace(cur, status="certified", decay_rate=float(candidate["decay_rate"]),
                              margin=float(candidate["margin"]), reason=f"{candidate['how']} ({own})",
                              P=candidate["P"], radius=candidate.get("radius"))
    for up in LEVELS[LEVELS.index(lv) + 1:]:
        if up in cert.levels:
            cert.levels[up] = _inherit(cert.levels[up], cert.levels[lv])
