"""Scalar-constant designs in better coordinates: a diagonal state scaling searched, then undone.

With ``x = D x~`` (D diagonal, positive) the plant becomes ``x~' = D^-1 A D x~ + D^-1 B u + D^-1 f(D x~)``,
``y = C D x~``, and the constants of its nonlinearity follow from the channels ``f = G phi(H x)`` (slopes
in [lo, hi]): with ``G~ = D^-1 G``, ``H~ = H D`` and ``delta = max(|lo|, |hi|)``,

- Lipschitz ``alpha~ = delta ||G~|| ||H~||``;
- OSL ``rho~`` = the largest ``lmax(sym(G~ Delta H~))`` over the vertices Delta of the slope box (lmax is
  convex in Delta; ``alpha~`` for more than 10 channels);
- QIB ``(beta~, gamma~) = (alpha~^2, 0)``.

The search is a coordinate descent over the states the channels touch, each on a log grid in [0.1, 10]:
a scaling whose separated design verifies beats every other, and among those the smaller gains win;
among unverified ones, the better worst-side margin. The gains are mapped back: ``F = F~ D^-1``, ``K = D K~``.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace

import numpy as np

from bench import lmi
from bench.registry import DESIGNS, register_design
from designs._core import Design, DesignResult, check_choice, check_int
from plants import Channels, Constants, Plant

__all__ = ["Scaled", "scaled_plant"]


def scaled_plant(plant: Plant, d: np.ndarray) -> tuple[Plant, Constants]:
    """The plant (with channels) in coordinates ``x = diag(d) x~``, ``d > 0``, and the constants of its nonlinearity."""
    ch = plant.channels
    D, Di = np.diag(d), np.diag(1 / d)
    G, H = Di @ ch.G, ch.H @ D
    delta = float(np.max(np.maximum(np.abs(ch.lo), np.abs(ch.hi))))
    alpha = delta * np.linalg.norm(G, 2) * np.linalg.norm(H, 2)
    if ch.q <= 10:
        rho = max(float(np.linalg.eigvalsh(lmi.sym(G @ np.diag(v) @ H))[-1])
                  for v in itertools.product(*zip(ch.lo, ch.hi)))
    else:
        rho = alpha
    f = plant.f
    consts = Constants(alpha=alpha, rho=rho, beta=alpha**2, gamma=0.0, radius=None)
    new = replace(plant, id=f"{plant.id}.scaled", A=Di @ plant.A @ D, B=Di @ plant.B, C=plant.C @ D,
                  f=lambda x: Di @ np.asarray(f(D @ np.asarray(x, dtype=float)), dtype=float),
                  jacobian=None, x0=plant.x0 / d, x_hat0=plant.x_hat0 / d, bounds=consts, claimed=Constants(),
                  channels=Channels(G=G, H=H, phi=ch.phi, lo=ch.lo, hi=ch.hi, radius=None))
    return new, consts


@register_design("cor1_scaled", "Corrected Corollary 1 (separated) after a searched diagonal state scaling x = D x~ "
                 "(needs channels).", order=19, inner="cor1_sep")
@register_design("thm1_scaled", "Corrected Theorem 1 (separated) after a searched diagonal state scaling x = D x~ "
                 "(needs channels).", order=18, inner="thm1_sep")
@dataclass(frozen=True, kw_only=True)
class Scaled(Design):
    """Corrected Theorem 1 / Corollary 1 after a searched diagonal state scaling (needs channels).

    Parameters
    ----------
    inner : {"thm1_sep", "cor1_sep", "thm1", "cor1"}
        The design run on the scaled plant.
    grid : int
        Log-spaced scales per coordinate, in ``[0.1, 10]``.
    sweeps : int
        Coordinate-descent sweeps.
    """

    inner: str = "thm1_sep"
    grid: int = 5
    sweeps: int = 1

    def __post_init__(self) -> None:
        check_choice("inner", self.inner, ("thm1_sep", "cor1_sep", "thm1", "cor1"))
        check_int("grid", self.grid, minimum=2)
        check_int("sweeps", self.sweeps, minimum=1)

    def applicable(self, plant: Plant, constants: Constants) -> str | None:
        if plant.channels is None:
            return "needs the channel structure f = G phi(Hx) to compute the scaled plant's constants"
        if plant.channels.radius is not None:
            return "the channels' slopes hold on a region; the scaled region would not be a ball"
        return None

    def _score(self, plant: Plant, d: np.ndarray, beat: float = -math.inf) -> float:
        """The scaling's score (module docstring); a score that cannot exceed ``beat`` may come back as a bound.

        The x-side is solved first: when it does not verify, the design there is not feasible and its score
        ``-max(x_margin, e_margin)`` is at most ``-x_margin``; when that cannot exceed ``beat``, the e-side is not
        solved (the bound is returned). When it verifies and ``beat`` is a verified design's score, the x-side's F
        alone bounds the score (``1 + 1 / (1 + ||F D^-1||)``); when that cannot exceed ``beat`` either, the e-side is
        not solved. Otherwise the separated design is made (its x-side from the program's memo).
        """
        sp, consts = scaled_plant(plant, d)
        inner = DESIGNS.create(self.inner if self.inner.endswith("_sep") else f"{self.inner}_sep")
        xprog = inner.form(sp, consts).side_program(sp, "x-side", cap=inner.cap)
        lmi.solve_side(xprog, inner.solver, sp.n)  # as separated_design solves it (the memo answers it there)
        if xprog.last_status not in ("optimal", "optimal_inaccurate"):
            return -math.inf  # the design is undecided there: no margins, no score
        X = xprog.numeric_matrix()
        xm = lmi.max_eig(X)
        x_ok = lmi.classify(xm, X) == "verified" and lmi.is_positive_definite(xprog.values()["Q"])
        if not x_ok and (not math.isfinite(xm) or -xm <= beat):
            return -xm if math.isfinite(xm) else -math.inf
        if x_ok and beat > 1.0:  # only a verified design with smaller gains beats it; F is the x-side's alone
            xv = xprog.values()
            F = np.linalg.solve(xv["Q"], xv["Fh"]).T  # as the separated design recovers it (F = Fh' Q^-1)
            bound = 1.0 + 1.0 / (1.0 + np.linalg.norm(F @ np.diag(1 / d), 2))  # ||D K|| >= 0 only lowers it
            if bound <= beat:
                return bound
        res = inner.separated(sp, consts, decide=False)  # the margins score it; no label needed
        if res.status == "feasible":  # any verified design beats every unverified one; then the smaller gains
            gain = np.linalg.norm(res.F @ np.diag(1 / d), 2) + np.linalg.norm(np.diag(d) @ res.K, 2)
            return 1.0 + 1.0 / (1.0 + gain)
        xm, em = res.params.get("x_margin", math.nan), res.params.get("e_margin", math.nan)
        return -max(xm, em) if math.isfinite(xm) and math.isfinite(em) else -math.inf

    def design(self, plant: Plant, constants: Constants) -> DesignResult:
        """Search the scaling, design on the scaled plant, map the gains back."""
        ch = plant.channels
        coords = sorted(set(np.nonzero(np.any(ch.G != 0, axis=1))[0]) | set(np.nonzero(np.any(ch.H != 0, axis=0))[0]))
        d = np.ones(plant.n)
        best, tried = self._score(plant, d), 1
        for _, i, v in itertools.product(range(self.sweeps), coords, np.logspace(-1, 1, self.grid)):
            cand = d.copy()
            cand[i] = v
            score = self._score(plant, cand, best)
            tried += 1
            if score > best:
                best, d = score, cand
        sp, consts = scaled_plant(plant, d)
        res = DESIGNS.create(self.inner).design(sp, consts)
        params = {**res.params, "scaling": "[" + ", ".join(f"{v:.3g}" for v in d) + "]", "scalings_tried": tried,
                  "alpha_scaled": consts.alpha, "rho_scaled": consts.rho}
        K = F = None
        if res.K is not None and res.F is not None:
            K, F = np.diag(d) @ res.K, res.F @ np.diag(1 / d)
        why = res.reason and f"in the coordinates x = diag({params['scaling']}) x~: {res.reason}"
        return replace(res, K=K, F=F, reason=why, params=params)
