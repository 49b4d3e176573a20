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

from plants import Channels, Constants, Plant, PlantError

__all__ = ["ConstantsReport", "Knowledge", "Violation", "compute_constants", "linear_prechecks",
           "resolve_constants"]

_REL_TOL = 1e-7  # a constant is flagged when a sample exceeds it by more than this (relative)

#: Globally sampled constants with no analytic value: an estimate at ``||x|| ~ 30`` more than this
#: many times the estimate at ``||x|| <= 1`` is taken as growing without bound (f is not globally
#: Lipschitz / OSL / QIB with any constant): the constant is not provided.
GROWTH_FACTOR = 4.0


@dataclass(frozen=True)
class Violation:
    """A stated constant (claimed, analytic, or a channel's slope bound) and the sampled pair that violates it."""

    name: str
    claimed: float
    sampled: float
    x1: tuple[float, ...]
    x2: tuple[float, ...]

    def describe(self, what: str = "claimed") -> str:
        """One line for reports, e.g. ``"claimed rho = 0.1109 is violated: the pair ... gives 0.1665"``."""
        fmt = lambda v: "(" + ", ".join(f"{a:.4g}" for a in v) + ")"  # noqa: E731
        return (
            f"{what} {self.name} = {self.claimed:.4g} is violated: the pair x1 = {fmt(self.x1)}, "
            f"x2 = {fmt(self.x2)} gives {self.sampled:.4g}"
        )


@dataclass(frozen=True)
class Knowledge:
    """What is trusted about f: the constants and channels a certificate may use.

    Attributes
    ----------
    constants : Constants
        Trusted scalar constants (analytic, not disproved); unknown or untrusted ones are None.
    channels : Channels or None
        Trusted channel structure, or None.
    notes : tuple of str
        Why something known was not trusted (for the certificate levels' reasons).
    """

    constants: Constants = field(default_factory=Constants)
    channels: Channels | None = None
    notes: tuple[str, ...] = ()

    @staticmethod
    def trusting(plant: Plant) -> "Knowledge":
        """The plant's own declarations, trusted as they are (tests and scripts; the pipeline uses
        :attr:`ConstantsReport.knowledge`, which checks them by sampling first)."""
        return Knowledge(plant.bounds or Constants(), plant.channels)


@dataclass(frozen=True)
class ConstantsReport:
    """Claimed, analytic and sampled constants of one plant, which ones to use, and what is trusted.

    Attributes
    ----------
    claimed : Constants
        As the source claims them.
    analytic : Constants or None
        Valid bounds supplied by the plant.
    sampled : Constants
        Sampled lower bounds (beta at ``gamma = valid.gamma``).
    valid : Constants
        What designs use by default: analytic where available and not disproved, else the
        sampled value (a lower bound: designs using it carry no guarantee); a constant whose
        estimate grows without bound is None.
    source : dict
        For each of alpha, rho, beta: ``"analytic"``, ``"sampled"``, ``"sampled (analytic
        disproved)"`` or ``"unbounded"``.
    violations : list of Violation
        Claimed constants a sample violates.
    disproved : list of Violation
        Analytic constants (the plant's ``bounds``) a sample violates: they never certify.
    channel_violations : list of Violation
        Declared channel slope bounds a sample violates (name ``"channel i slope"``).
    unbounded : dict
        Constant name -> why its sampled estimate is taken as unbounded.
    prechecks : list of str
        Problems of the linear part that no design can overcome (e.g. not stabilizable).
    seed, n_samples : int
        Sampler settings, for reproducibility.
    """

    claimed: Constants
    analytic: Constants | None
    sampled: Constants
    valid: Constants
    source: dict[str, str]
    violations: list[Violation] = field(default_factory=list)
    disproved: list[Violation] = field(default_factory=list)
    channel_violations: list[Violation] = field(default_factory=list)
    unbounded: dict[str, str] = field(default_factory=dict)
    prechecks: list[str] = field(default_factory=list)
    seed: int = 0
    n_samples: int = 0

    def violated(self, name: str) -> Violation | None:
        """The violation of claimed constant ``name``, if any."""
        return next((v for v in self.violations if v.name == name), None)

    def to_dict(self) -> dict:
        """A JSON-ready description (for the cache and run.json); :meth:`from_dict` inverts it."""
        def viol(vs):
            return [{"name": v.name, "claimed": float(v.claimed), "sampled": float(v.sampled),
                     "x1": [float(a) for a in v.x1], "x2": [float(a) for a in v.x2]} for v in vs]

        return {**{k: (None if getattr(self, k) is None else getattr(self, k).as_dict())
                   for k in ("claimed", "analytic", "sampled", "valid")},
                "source": dict(self.source), "violations": viol(self.violations), "disproved": viol(self.disproved),
                "channel_violations": viol(self.channel_violations), "unbounded": dict(self.unbounded),
                "prechecks": list(self.prechecks), "seed": self.seed, "n_samples": self.n_samples,
                "trust": self.trust}

    @classmethod
    def from_dict(cls, doc: dict) -> "ConstantsReport":
        """The report :meth:`to_dict` described."""
        def viol(vs):
            return [Violation(v["name"], v["claimed"], v["sampled"], tuple(v["x1"]), tuple(v["x2"])) for v in vs]

        cs = {k: None if doc[k] is None else Constants(**doc[k]) for k in ("claimed", "analytic", "sampled", "valid")}
        return cls(**cs, source=doc["source"], violations=viol(doc["violations"]), disproved=viol(doc["disproved"]),
                   channel_violations=viol(doc["channel_violations"]), unbounded=doc["unbounded"],
                   prechecks=doc["prechecks"], seed=doc["seed"], n_samples=doc["n_samples"])

    def knowledge(self, plant: Plant) -> Knowledge:
        """The trusted part for ``plant``: analytic constants no sample disproved, and the plant's
        channels unless a sample disproved their slopes."""
        an = self.analytic or Constants()
        bad = {v.name for v in self.disproved}
        notes = [v.describe("analytic") + ": not used by certificates" for v in self.disproved]
        kept = {k: getattr(an, k) for k in ("alpha", "rho") if k not in bad}
        qib_ok = "beta" not in bad and an.beta is not None
        sampled_only = [k for k in ("alpha", "rho", "beta") if self.source.get(k, "").startswith("sampled")]
        if sampled_only:
            notes.append(f"{', '.join(sampled_only)} only sampled (lower bounds): never used by certificates")
        consts = Constants(**kept, beta=an.beta if qib_ok else None, gamma=an.gamma if qib_ok else None,
                           radius=an.radius)
        ch = plant.channels if not self.channel_violations else None
        notes += [v.describe("declared") + ": channels not used by certificates" for v in self.channel_violations]
        return Knowledge(consts, ch, tuple(notes))

    @property
    def trust(self) -> str:
        """One phrase for a results row: where the constants came from and what certificates may use."""
        parts = []
        by: dict[str, list[str]] = {}
        for k in ("alpha", "rho", "beta"):
            by.setdefault(self.source.get(k, "none"), []).append(k)
        for src in ("analytic", "sampled", "sampled (analytic disproved)", "unbounded", "none"):
            if src in by:
                label = {"sampled": "sampled (lower bounds, not certifying)",
                         "sampled (analytic disproved)": "analytic DISPROVED by a sample (not certifying)",
                         "none": "unknown"}.get(src, src)
                parts.append(f"{'/'.join(by[src])} {label}")
        if self.channel_violations:
            parts.append("channels DISPROVED by a sample (not certifying)")
        if self.valid.radius is not None:
            parts.append(f"on ||x|| <= {self.valid.radius:g}")
        return "; ".join(parts)


def _values(f: Callable, X: np.ndarray) -> np.ndarray:
    """``f(X)`` for a batch, as real numbers; a complex or non-finite value raises :class:`PlantError`
    naming the state (the sampler never skips a broken value silently)."""
    import warnings

    raw = np.asarray(f(X.copy()))
    if np.iscomplexobj(raw):
        bad = np.flatnonzero(np.any(raw.imag != 0, axis=0)) if raw.shape == X.shape else []
        where = (f" at the sampled state x = {np.round(X[:, bad[0]], 6).tolist()}: {np.round(raw[:, bad[0]], 6).tolist()}"
                 if len(bad) else " on sampled states")
        raise PlantError(f"f: returned complex values{where}; f must be real")
    with warnings.catch_warnings():
        warnings.simplefilter("error", np.exceptions.ComplexWarning)
        try:
            out = np.asarray(raw, dtype=float)
        except (np.exceptions.ComplexWarning, TypeError, ValueError) as exc:
            raise PlantError(f"f: returned values that are not real numbers ({exc})") from None
    if out.shape != X.shape:
        raise PlantError(f"f: a batch of shape {X.shape} gave shape {out.shape}")
    bad = ~np.all(np.isfinite(out), axis=0)
    if bad.any():
        j = int(np.argmax(bad))
        raise PlantError(f"f: not finite at the sampled state x = {np.round(X[:, j], 6).tolist()}: "
                         f"{np.round(out[:, j], 6).tolist()}")
    return out


def _ratios(f: Callable, x1: np.ndarray, x2: np.ndarray, gamma: float):
    """alpha, rho and beta(gamma) ratios for batches of pairs, shape (n, N) each."""
    dx = x1 - x2
    with np.errstate(over="ignore", invalid="ignore"):
        df = _values(f, x1) - _values(f, x2)
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
        order = np.argsort(r)[::-1][:max(n_refine, 1)]
        top = (float(r[order[0]]), x1[:, order[0]], x2[:, order[0]])
        order = order[:n_refine]
        for k in order:
            a, b, val = _local_max(f, which, gamma, x1[:, k], x2[:, k], radius, n)
            if val > top[0]:
                top = (float(val), a, b)
        best[name] = top
    return best


def _growth(f, x1, x2, gamma, which: int) -> tuple[float, float]:
    """Sampled sup of one ratio over pairs inside ``||x|| <= 1`` and over pairs outside ``||x|| >= 10``."""
    r = _ratios(f, x1, x2, gamma)[which]
    r = np.where(np.isfinite(r), r, -np.inf)
    s = np.maximum(np.linalg.norm(x1, axis=0), np.linalg.norm(x2, axis=0))
    small, large = r[s <= 1.0], r[np.minimum(np.linalg.norm(x1, axis=0), np.linalg.norm(x2, axis=0)) >= 10.0]
    return (float(small.max()) if small.size else -np.inf, float(large.max()) if large.size else -np.inf)


def _unbounded(f, x1, x2, gamma, sampled: dict) -> dict[str, str]:
    """Constants whose global estimate grows with the sampled radius (see :data:`GROWTH_FACTOR`)."""
    out = {}
    for which, name in enumerate(("alpha", "rho", "beta")):
        small, large = _growth(f, x1, x2, gamma, which)
        if large > GROWTH_FACTOR * max(small, 1e-12) and large > 1e-9:
            kind = {"alpha": "globally Lipschitz", "rho": "one-sided Lipschitz with any constant",
                    "beta": "quadratically inner-bounded at this gamma"}[name]
            out[name] = (f"f is not {kind} (the sampled {name} grows with the sampled radius: {small:.3g} for "
                         f"||x|| <= 1, {large:.3g} for ||x|| >= 10): declare bounds with a radius")
    return out


def _channel_check(plant: Plant, rng: np.random.Generator, n_pairs: int = 2000) -> list[Violation]:
    """Sampled slopes of each declared channel against its bounds (inside the channels' region)."""
    ch = plant.channels
    if ch is None:
        return []
    out = []
    for i in range(ch.q):
        h = float(np.linalg.norm(ch.H[i]))
        zmax = (ch.radius * h) if ch.radius is not None else 30.0
        a = rng.uniform(-zmax, zmax, n_pairs)
        b = a + rng.normal(0, 1, n_pairs) * np.maximum(0.05 * zmax, 1e-3) * 10.0 ** rng.uniform(-4, 0, n_pairs)
        b = np.clip(b, -zmax, zmax)
        Z = np.zeros((ch.q, 2 * n_pairs))
        Z[i, :n_pairs], Z[i, n_pairs:] = a, b
        with np.errstate(invalid="ignore", divide="ignore"):
            phi = np.asarray(ch.phi(Z), dtype=float)[i]
            slope = (phi[:n_pairs] - phi[n_pairs:]) / (a - b)
        ok = np.isfinite(slope)
        tol = _REL_TOL * max(1.0, abs(ch.lo[i]), abs(ch.hi[i])) + 1e-9
        for bound, worst, name in ((ch.hi[i], np.max(np.where(ok, slope, -np.inf)), "max"),
                                   (ch.lo[i], np.min(np.where(ok, slope, np.inf)), "min")):
            if (name == "max" and worst > bound + tol) or (name == "min" and worst < bound - tol):
                k = int(np.nanargmax(np.where(ok, slope if name == "max" else -slope, -np.inf)))
                x1 = tuple(float(v) for v in np.linalg.pinv(ch.H) @ Z[:, k])
                x2 = tuple(float(v) for v in np.linalg.pinv(ch.H) @ Z[:, n_pairs + k])
                label = f"channel {i} {'upper' if name == 'max' else 'lower'} slope bound"
                out.append(Violation(label, float(bound), float(worst), x1, x2))
    return out


def linear_prechecks(plant: Plant) -> list[str]:
    """Problems of the linear part that no observer-based controller can overcome.

    ``(A, B)`` must be stabilizable and ``(A, C)`` detectable (PBH test on the eigenvalues with
    ``Re >= 0``); the messages name the eigenvalue.

    Parameters
    ----------
    plant : Plant

    Returns
    -------
    list of str
        Empty when both hold.
    """
    A, B, C = plant.A, plant.B, plant.C
    n = plant.n
    scale = max(1.0, float(np.linalg.norm(A, 2)))
    out = []
    for lam in np.linalg.eigvals(A):
        if lam.real < -1e-9 * scale or lam.imag < -1e-12:  # one of each conjugate pair
            continue
        shown = f"{lam.real:.4g}" + (f" +- {lam.imag:.4g}j" if abs(lam.imag) > 1e-12 else "")
        for name, M, what in (("(A, B)", np.hstack([lam * np.eye(n) - A, B]), "stabilizable"),
                              ("(A, C)", np.vstack([lam * np.eye(n) - A, C]), "detectable")):
            if float(np.linalg.svd(M, compute_uv=False)[-1]) <= 1e-9 * scale:
                word = "uncontrollable" if what == "stabilizable" else "unobservable"
                msg = f"{name} is not {what}: eigenvalue {shown} of A is {word}"
                if msg not in out:
                    out.append(msg)
    return out


def compute_constants(
    plant: Plant,
    *,
    seed: int = 0,
    n_samples: int = 20000,
    n_refine: int = 5,
) -> ConstantsReport:
    """Compute the constants of ``plant.f``: analytic, sampled, flags, and what is trusted.

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

    Raises
    ------
    PlantError
        If f returns a complex or non-finite value at a sampled state (the message names it).
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
    unbounded = _unbounded(plant.f, x1, x2, gamma, best) if radius is None else {}
    disproved = []
    for name in ("alpha", "rho", "beta"):
        av = getattr(analytic, name) if analytic is not None else None
        val, a, b = best[name]
        if av is not None and val > av + _REL_TOL * max(1.0, abs(av)):
            disproved.append(Violation(name, av, val, tuple(a), tuple(b)))
    violations = _claimed_violations(plant, best, x1, x2, gamma, radius, seed, n_samples, n_refine)
    valid_kw, source = {}, {}
    bad = {v.name for v in disproved}
    for name in ("alpha", "rho", "beta"):
        av = getattr(analytic, name) if analytic is not None else None
        if av is not None and name not in bad:
            valid_kw[name], source[name] = av, "analytic"
        elif av is not None:
            valid_kw[name], source[name] = getattr(sampled, name), "sampled (analytic disproved)"
        elif name in unbounded:
            valid_kw[name], source[name] = None, "unbounded"
        else:
            valid_kw[name], source[name] = getattr(sampled, name), "sampled"
    if valid_kw["beta"] is None:
        valid = Constants(**valid_kw, radius=radius)
    else:
        valid = Constants(**valid_kw, gamma=gamma, radius=radius)
    return ConstantsReport(
        claimed=plant.claimed, analytic=analytic, sampled=sampled, valid=valid, source=source,
        violations=violations, disproved=disproved,
        channel_violations=_channel_check(plant, np.random.default_rng([seed, 2])), unbounded=unbounded,
        prechecks=linear_prechecks(plant), seed=seed, n_samples=n_samples,
    )


def _claimed_violations(plant, best, x1, x2, gamma, radius, seed, n_samples, n_refine) -> list[Violation]:
    """Claimed constants a sample violates, checked on the region the source claims them for."""
    violations: list[Violation] = []
    claimed = plant.claimed
    n = plant.n
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
    return violations


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
