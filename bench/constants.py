"""Constants of a plant's nonlinearity: analytic where known, sampled lower bounds always.

For difference pairs ``dx = x1 - x2``, ``df = f(x1) - f(x2)`` the sampled quantities are

- Lipschitz: ``alpha >= ||df|| / ||dx||``;
- one-sided Lipschitz: ``rho >= <df, dx> / ||dx||^2``;
- quadratic inner-boundedness for a given gamma: ``beta >= (||df||^2 - gamma <dx, df>) / ||dx||^2``.

Each supremum is estimated from seeded random pairs (points at several scales, differences
from 1e-4 to 10 times the point scale; inside the ball ``||x|| <= radius`` when the constants
are local) followed by a local optimisation (L-BFGS-B) from the best pairs. A sampled value is
a *lower bound* on the true constant: it can prove a claimed constant wrong, never right.
Claimed constants are checked on the region they are claimed for (``claimed.radius``; None =
everywhere), with pairs of their own when that region differs from the analytic one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from plants._core import Constants, Plant

__all__ = ["ConstantsReport", "Violation", "compute_constants", "resolve_constants"]

_REL_TOL = 1e-7  # a claimed constant is flagged when a sample exceeds it by more than this


@dataclass(frozen=True)
class Violation:
    """A claimed constant and the sampled pair that violates it."""

    name: str
    claimed: float
    sampled: float
    x1: tuple[float, ...]
    x2: tuple[float, ...]

    def describe(self) -> str:
        """One line for the report."""
        fmt = lambda v: "(" + ", ".join(f"{a:.4g}" for a in v) + ")"  # noqa: E731
        return (
            f"claimed {self.name} = {self.claimed:.4g} is violated: the pair x1 = {fmt(self.x1)}, "
            f"x2 = {fmt(self.x2)} gives {self.sampled:.4g}"
        )


@dataclass(frozen=True)
class ConstantsReport:
    """Claimed, analytic and sampled constants of one plant, and which ones to use.

    Attributes
    ----------
    claimed : Constants
        As the source claims them.
    analytic : Constants or None
        Valid bounds supplied by the plant.
    sampled : Constants
        Sampled lower bounds (beta at ``gamma = valid.gamma``).
    valid : Constants
        What designs use by default: analytic where available, else the sampled value.
    source : dict
        For each of alpha, rho, beta: ``"analytic"`` or ``"sampled"`` (or ``"none"``).
    violations : list of Violation
        Claimed constants a sample violates.
    seed, n_samples : int
        Sampler settings, for reproducibility.
    """

    claimed: Constants
    analytic: Constants | None
    sampled: Constants
    valid: Constants
    source: dict[str, str]
    violations: list[Violation] = field(default_factory=list)
    seed: int = 0
    n_samples: int = 0

    def violated(self, name: str) -> Violation | None:
        """The violation of claimed constant ``name``, if any."""
        return next((v for v in self.violations if v.name == name), None)


def _ratios(f: Callable, x1: np.ndarray, x2: np.ndarray, gamma: float):
    """alpha, rho and beta(gamma) ratios for batches of pairs, shape (n, N) each."""
    dx = x1 - x2
    with np.errstate(over="ignore", invalid="ignore"):  # a superlinear f sampled globally overflows: inf
        df = np.asarray(f(x1), dtype=float) - np.asarray(f(x2), dtype=float)
        nx2 = np.sum(dx * dx, axis=0)
        nx2 = np.where(nx2 > 0, nx2, np.nan)
        inner = np.sum(dx * df, axis=0)
        nf2 = np.sum(df * df, axis=0)
        return np.sqrt(nf2 / nx2), inner / nx2, (nf2 - gamma * inner) / nx2


def _project(x: np.ndarray, radius: float | None) -> np.ndarray:
    if radius is None:
        return x
    norms = np.linalg.norm(x, axis=0)
    scale = np.where(norms > radius, radius / np.maximum(norms, 1e-300), 1.0)
    return x * scale


def _random_pairs(rng: np.random.Generator, n: int, N: int, radius: float | None):
    if radius is None:
        scale = 10.0 ** rng.uniform(-2, 1.5, size=N)  # point scales 0.01 .. 30
    else:
        scale = radius * rng.uniform(0, 1, size=N) ** (1.0 / n)
    dirs = rng.standard_normal((n, N))
    dirs /= np.linalg.norm(dirs, axis=0)
    x1 = dirs * scale
    step = scale * 10.0 ** rng.uniform(-4, 1, size=N)
    d = rng.standard_normal((n, N))
    d /= np.linalg.norm(d, axis=0)
    x2 = _project(x1 + d * step, radius)
    return x1, x2


def _local_max(f, which: int, gamma: float, x1, x2, radius, n):
    """Maximise one ratio from a starting pair with L-BFGS-B (finite differences)."""
    from scipy.optimize import minimize

    def unpack(z):
        a = _project(z[:n, None], radius)
        b = _project((z[:n] + z[n:])[:, None], radius)
        return a, b

    def neg(z):
        a, b = unpack(z)
        if np.linalg.norm(a - b) < 1e-12:
            return 0.0
        val = _ratios(f, a, b, gamma)[which][0]
        return -val if np.isfinite(val) else 0.0

    z0 = np.concatenate([x1, x2 - x1])
    # globally, keep the search in a (generous) box: an unbounded ratio (e.g. the Lipschitz
    # ratio of a cubic f) would otherwise run to overflow; the claim is violated long before
    box = None if radius is not None else [(-b, b) for b in [1e3 * max(1.0, float(np.abs(z0).max()))] * (2 * n)]
    try:
        res = minimize(neg, z0, method="L-BFGS-B", bounds=box, options={"maxiter": 200})
        z = res.x
    except Exception:  # a user f that fails away from the samples: keep the sample
        z = z0
    a, b = unpack(z)
    return a[:, 0], b[:, 0], -neg(z)


def _best_pairs(f, x1, x2, gamma, radius, n, n_refine) -> dict[str, tuple[float, np.ndarray, np.ndarray]]:
    """For alpha, rho and beta(gamma): the largest ratio over the pairs, refined locally."""
    ratios = _ratios(f, x1, x2, gamma)
    best: dict[str, tuple[float, np.ndarray, np.ndarray]] = {}
    for which, name in enumerate(("alpha", "rho", "beta")):
        r = np.where(np.isfinite(ratios[which]), ratios[which], -np.inf)
        order = np.argsort(r)[::-1][:n_refine]
        top = (float(r[order[0]]), x1[:, order[0]], x2[:, order[0]])
        for k in order:
            a, b, val = _local_max(f, which, gamma, x1[:, k], x2[:, k], radius, n)
            if val > top[0]:
                top = (float(val), a, b)
        best[name] = top
    return best


def compute_constants(
    plant: Plant,
    *,
    seed: int = 0,
    n_samples: int = 20000,
    n_refine: int = 5,
) -> ConstantsReport:
    """Compute the constants of ``plant.f``: analytic, sampled, and flags on the claimed ones.

    Parameters
    ----------
    plant : Plant
        The plant; ``plant.bounds`` supplies analytic constants if known, and
        ``plant.bounds.radius`` (or, without it, ``plant.claimed.radius``) the region where the
        sampled and valid constants hold. Claimed constants are checked on the claimed region
        ``plant.claimed.radius`` (None = everywhere), sampled separately when it differs.
    seed : int
        Seed of the sampler (results are reproducible for a given seed).
    n_samples : int
        Number of random pairs.
    n_refine : int
        Number of best pairs refined by local optimisation, per constant.

    Returns
    -------
    ConstantsReport
    """
    if n_samples < 1:
        raise ValueError(f"n_samples: must be >= 1, got {n_samples}")
    rng = np.random.default_rng(seed)
    n = plant.n
    analytic = plant.bounds
    radius = (analytic.radius if analytic is not None else None) or plant.claimed.radius
    if analytic is not None and analytic.gamma is not None:
        gamma = analytic.gamma
    elif plant.claimed.gamma is not None:
        gamma = plant.claimed.gamma
    else:
        gamma = 0.0

    x1, x2 = _random_pairs(rng, n, n_samples, radius)
    best = _best_pairs(plant.f, x1, x2, gamma, radius, n, n_refine)
    sampled = Constants(
        alpha=max(best["alpha"][0], 0.0), rho=best["rho"][0], beta=best["beta"][0], gamma=gamma, radius=radius
    )

    # claimed constants: flag any a sample violates, with the violating pair. They are checked
    # on the region the source claims them for (which may differ from the analytic region).
    violations: list[Violation] = []
    claimed = plant.claimed
    c_radius = claimed.radius
    if c_radius != radius and any(getattr(claimed, k) is not None for k in ("alpha", "rho", "beta")):
        crng = np.random.default_rng([seed, 1])
        x1, x2 = _random_pairs(crng, n, n_samples, c_radius)
        best = _best_pairs(plant.f, x1, x2, gamma, c_radius, n, n_refine)
    for name in ("alpha", "rho"):
        cval = getattr(claimed, name)
        if cval is not None:
            val, a, b = best[name]
            if val > cval + _REL_TOL * max(1.0, abs(cval)):
                violations.append(Violation(name, cval, val, tuple(a), tuple(b)))
    if claimed.beta is not None:
        # the claimed pair is checked at the claimed gamma
        if claimed.gamma == gamma:
            val, a, b = best["beta"]
        else:
            r = _ratios(plant.f, x1, x2, claimed.gamma)[2]
            r = np.where(np.isfinite(r), r, -np.inf)
            k = int(np.argmax(r))
            a, b, val = _local_max(plant.f, 2, claimed.gamma, x1[:, k], x2[:, k], c_radius, n)
        if val > claimed.beta + _REL_TOL * max(1.0, abs(claimed.beta)):
            violations.append(Violation("beta", claimed.beta, val, tuple(a), tuple(b)))

    valid_kw, source = {}, {}
    for name in ("alpha", "rho", "beta"):
        av = getattr(analytic, name) if analytic is not None else None
        if av is not None:
            valid_kw[name], source[name] = av, "analytic"
        else:
            valid_kw[name], source[name] = getattr(sampled, name), "sampled"
    valid = Constants(**valid_kw, gamma=gamma, radius=radius)
    return ConstantsReport(
        claimed=claimed,
        analytic=analytic,
        sampled=sampled,
        valid=valid,
        source=source,
        violations=violations,
        seed=seed,
        n_samples=n_samples,
    )


def resolve_constants(report: ConstantsReport, *, use_claimed: bool = False) -> Constants:
    """The constants a design should use: ``report.valid``, or the claimed ones on request.

    With ``use_claimed=True`` a claimed constant replaces the valid one where the source gives
    it (missing claimed constants fall back to the valid ones).
    """
    if not use_claimed:
        return report.valid
    c, v = report.claimed, report.valid
    pick = lambda a, b: a if a is not None else b  # noqa: E731
    if c.beta is not None:
        beta, gamma = c.beta, c.gamma
    else:
        beta, gamma = v.beta, v.gamma
    return Constants(
        alpha=pick(c.alpha, v.alpha),
        rho=pick(c.rho, v.rho),
        beta=beta,
        gamma=gamma,
        radius=pick(c.radius, v.radius),
    )
