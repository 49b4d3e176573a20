"""The largest value that passes a monotone test, searched on a fixed geometric grid.

Every search of the suite for "the largest value that still passes" (a certified decay rate, a
design's decay target, a study's admissible scale) probes only points of one grid,
``g_k = (1 + rtol)^k`` for integer k, brackets the threshold by moves of a fixed factor and then
bisects the grid indices until the passing and failing points are neighbours. The answer is the
largest grid point that passed, within a factor ``1 + rtol`` below the threshold.

The points probed depend only on the outcomes, never on arithmetic between them, so two machines
whose floating point differs in the last bits probe the same points and report the same value
unless a probe itself flips; a probe near the threshold that flips moves the answer by one grid
step, within ``rtol``. A caller counts a probe as passing only when its evidence is clear (a
certificate verified with a margin beyond its tolerance); a probe within the tolerance is not a
pass.
"""

from __future__ import annotations

import math
from typing import Callable

__all__ = ["RATE_RTOL", "largest_passing"]

#: The suite's rate tolerance: a reported rate is within this factor (relative) below the largest
#: one its test admits.
RATE_RTOL = 0.01

# the grid's log step is a hair below log(1 + rtol), so that neighbours are within 1 + rtol in floats
_SHRINK = 1 - 1e-12


def _step(rtol: float) -> float:
    if not (math.isfinite(rtol) and rtol > 0):
        raise ValueError(f"rtol: must be finite and > 0, got {rtol!r}")
    return math.log1p(rtol) * _SHRINK


def _point(k: int, rtol: float) -> float:
    return math.exp(k * _step(rtol))


def _index(x: float, rtol: float, up: bool) -> int:
    """The grid index at or below (``up=False``) or at or above (``up=True``) ``x > 0``."""
    v = math.log(x) / _step(rtol)
    k = round(v)
    if abs(v - k) < 1e-9:  # x is a grid point (to rounding)
        return int(k)
    return math.ceil(v) if up else math.floor(v)


def grid_floor(x: float, rtol: float = RATE_RTOL) -> float:
    """The largest point ``(1 + rtol)^k`` of the grid at or below ``x > 0``."""
    return _point(_index(x, rtol, up=False), rtol)


def largest_passing(passes: Callable[[float], object], *, rtol: float = RATE_RTOL, start: float | None = None,
                    lo: float | None = None, hi: float | None = None, factor: float = 2.0, max_moves: int = 12,
                    down_until: float = 0.0, stop: Callable[[], bool] | None = None,
                    first_above: bool = False, aim: Callable[[], float | None] | None = None,
                    aim_next: bool = False) -> dict:
    """The largest grid point at which ``passes`` holds, for a test that holds below a threshold.

    Parameters
    ----------
    passes : callable
        ``passes(x) -> bool`` for ``x > 0``; assumed monotone (passing below a threshold). It may return
        ``(True, y)`` instead of True: ``y`` (None, or a grid point above x) passes too, on the same evidence (the
        passing point of x shown to hold up to y); the search moves its passing end there.
    rtol : float
        The grid ``(1 + rtol)^k``: the answer is within ``1 + rtol`` of the threshold.
    start : float, optional
        The first probe when ``lo`` is not given (and ``start`` is below ``hi``).
    lo : float, optional
        A value known to pass (not probed).
    hi : float, optional
        A value known to fail, or an upper bound of the threshold (not probed).
    factor : float
        Bracketing moves up from a passing point (or down from a failing one) by this factor.
    max_moves : int
        Bracketing gives up after this many moves (``"above_range"`` or ``"below_range"``).
    down_until : float
        Bracketing down stops below this value (``"below_range"``).
    stop : callable, optional
        ``stop() -> bool``, asked after each failing probe while bracketing down; True ends the
        search (``"below_range"``, the last probe lay outside the test's valid range: ``hi`` stays
        the failing value before it).
    first_above : bool
        With ``lo`` and ``hi`` given, probe the grid point just above ``lo`` first (the threshold is often
        there: one probe then ends the search), then bisect.
    aim : callable, optional
        ``aim() -> float or None``, asked before each probe after the first: an estimate of the threshold from the
        probes so far (e.g. a secant through their margins). A grid point below the estimate inside the bracket is
        probed instead of the next bracketing move or the midpoint (the midpoint after two failures in a row). The
        answer does not depend on it, only which grid points are probed.
    aim_next : bool
        When the estimate lies within a grid step of the passing end, probe the grid point just above it (a
        failure there ends the search), once per search. For estimates that mark the threshold itself (a
        margin's secant); not for ones that trail it.

    Returns
    -------
    dict
        ``lo`` (the largest passing value, NaN if none), ``hi`` (the smallest failing value or the
        bound, NaN if none) and ``kind``: ``"bracketed"`` (``hi / lo <= 1 + rtol``),
        ``"above_range"`` or ``"below_range"``.
    """
    if start is None and lo is None and hi is None:
        raise ValueError("largest_passing: give start, lo or hi")
    moves = max(1, round(math.log(factor) / _step(rtol)))
    kl = None if lo is None else _index(lo, rtol, up=False)  # grid indices known to pass / fail
    kh = None if hi is None else _index(hi, rtol, up=True)

    next_once = aim_next  # one probe of the passing end's next grid point where the aim points (below)

    def aimed(default: int) -> int:
        nonlocal next_once
        est = aim() if aim is not None else None
        if est is None or not est > 0 or not math.isfinite(est):
            return default
        k = _index(est, rtol, up=False)
        if kl is not None and kh is not None and k <= kl + 1 < kh and next_once:
            # the threshold within a grid step of the passing end: its next grid point ends the search when it
            # fails; once only (an aim that keeps pointing there, bent away from the threshold, would creep up)
            next_once = False
            return kl + 1
        return k if (kl is None or k > kl + 1) and (kh is None or k < kh) else default

    def probe(k: int) -> bool:
        nonlocal kl, kh
        ok = passes(_point(k, rtol))
        up = None
        if isinstance(ok, tuple):
            ok, up = bool(ok[0]), ok[1]
        if ok:
            kl = k if up is None else max(k, _index(up, rtol, up=False))
            if kh is not None:
                kl = min(kl, kh - 1)
        else:
            kh = k
        return ok

    if kl is None and start is not None and (kh is None or _index(start, rtol, up=False) < kh):
        probe(_index(start, rtol, up=False))
    for _ in range(max_moves if kh is None else 0):
        if not probe(kl + moves):
            break
    for _ in range(max_moves if kl is None else 0):
        last = kh
        k = aimed(kh - moves)
        if _point(k, rtol) < down_until:  # an aim below the range is not a reason to stop
            k = kh - moves
        if _point(k, rtol) < down_until or probe(k):
            break
        if stop is not None and stop():
            kh = last
            break
    if first_above and kl is not None and kh is not None and kh - kl > 1:
        probe(kl + 1)
    fails = 0
    while kl is not None and kh is not None and kh - kl > 1:
        mid = (kl + kh) // 2
        fails = 0 if probe(mid if fails >= 2 else aimed(mid)) else fails + 1
    kind = "above_range" if kh is None else "below_range" if kl is None else "bracketed"
    return {"lo": _value(kl, lo, rtol, up=False), "hi": _value(kh, hi, rtol, up=True), "kind": kind}


def _value(k: int | None, given: float | None, rtol: float, up: bool) -> float:
    """The value of grid index k, or the given bound it was taken from (NaN without k)."""
    return math.nan if k is None else given if given is not None and k == _index(given, rtol, up) else _point(k, rtol)


#: Where a secant of the re-optimised points' margins aims (:func:`secant_estimate`): this many tolerances below zero.
SECANT_AIM = 1.05


def secant_estimate(curve: dict) -> float | None:
    """Where a program's optimal margin reaches :data:`SECANT_AIM` tolerances below zero, from its probes ``curve``
    (``lam -> (passed, max eig, tolerance)``, e.g. :attr:`bench.lyapunov.Level.curve`; only probes that passed or
    failed by their margin): the secant through the highest passing probe and the lowest failing one, else through
    the two lowest failing ones, else through the two highest passing ones; None without two such probes.

    A re-optimised point's margin is nearly linear in the rate near its threshold (a fixed point's bends), so a
    failed probe's margin says how far below it the threshold lies. An estimate only chooses where to probe.
    """
    failed = sorted((lam, m, tol) for lam, (ok, m, tol) in curve.items() if not ok)
    if not failed:  # the two highest verified points, extrapolated up
        good = sorted((lam, m, tol) for lam, (ok, m, tol) in curve.items() if ok)
        if len(good) >= 2 and good[-2][1] < good[-1][1]:
            (a, ma, _), (b, mb, tol) = good[-2:]
            return b + (-SECANT_AIM * tol - mb) * (b - a) / (mb - ma)
        return None
    b = failed[0]
    good = [(lam, m, tol) for lam, (ok, m, tol) in curve.items() if ok and lam < b[0]]
    if good:
        a = max(good)
        if a[1] < b[1]:
            return a[0] + (-SECANT_AIM * a[2] - a[1]) * (b[0] - a[0]) / (b[1] - a[1])
    if len(failed) >= 2 and failed[1][1] > b[1]:
        c = failed[1]
        est = b[0] - (b[1] + SECANT_AIM * b[2]) * (c[0] - b[0]) / (c[1] - b[1])
        return est if est > 0 else None
    return None
