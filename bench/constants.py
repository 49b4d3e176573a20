"""Constants of a plant's nonlinearity: analytic where known, sampled lower bounds always.

For difference pairs ``dx = x1 - x2``, ``df = f(x1) - f(x2)`` the sampled quantities are

- Lipschitz: ``alpha >= ||df|| / ||dx||``;
- one-sided Lipschitz: ``rho >= <df, dx> / ||dx||^2``;
- quadratic inner-boundedness for a given gamma: ``beta >= (||df||^2 - gamma <dx, df>) / ||dx||^2``.

Each supremum is estimated from seeded random pairs (inside ``||x|| <= radius`` for local
constants, else out to :func:`sampled_range`), refined by L-BFGS-B from the best pairs. A sampled
value is a *lower bound*: it can prove a stated constant wrong, never right. Claimed constants are
checked on the region they are claimed for; :func:`check_trajectory` checks the trusted
declarations along a simulation.
"""

from __future__ import annotations

import warnings
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Callable

import numpy as np

from bench.checks import vector
from plants import Channels, Constants, Plant, PlantError, jacobian_mismatch

__all__ = ["ConstantsReport", "Knowledge", "check_trajectory", "compute_constants"]

_REL_TOL = 1e-7  # a constant is flagged when a sample exceeds it by more than this (relative)

#: The growth with the sampled radius that :func:`_unbounded` takes as unbounded (the constant is not provided).
GROWTH_FACTOR = 4.0

#: Global declarations are sampled out to ``||x|| <= GLOBAL_RANGE`` and ``REACH_FACTOR`` times the
#: largest initial state (after a simulation, the largest state reached).
GLOBAL_RANGE = 10.0 ** 1.5
REACH_FACTOR = 10.0


def sampled_range(plant: Plant) -> float:
    """How far (``||x||``) the samplers check a global declaration before any simulation."""
    return max(GLOBAL_RANGE, REACH_FACTOR * float(max(np.linalg.norm(plant.x0), np.linalg.norm(plant.x_hat0))))


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
        return (f"{what} {self.name} = {self.claimed:.4g} is violated: the pair x1 = {vector(self.x1)}, "
                f"x2 = {vector(self.x2)} gives {self.sampled:.4g}")


def _exceeds(value: float, stated: float) -> bool:
    """Whether a sampled ``value`` exceeds a ``stated`` constant beyond the relative tolerance."""
    return value > stated + _REL_TOL * max(1.0, abs(stated))


@dataclass(frozen=True)
class Knowledge:
    """What is trusted about f, the ``constants`` (analytic, not disproved; others None) and ``channels``
    a certificate may use, with ``notes`` on what was not trusted and ``untrusted``: declaration
    (``"alpha"``, ..., ``"channels"``) -> why a certificate must not use it."""

    constants: Constants = field(default_factory=Constants)
    channels: Channels | None = None
    notes: tuple[str, ...] = ()
    untrusted: dict[str, str] = field(default_factory=dict)

    def without(self, untrusted: dict[str, str]) -> "Knowledge":
        """This knowledge with the declarations named in ``untrusted`` (name -> why) removed."""
        qib = {"beta", "gamma"} if {"beta", "gamma"} & set(untrusted) else set()  # both or neither
        consts = replace(self.constants, **dict.fromkeys({"alpha", "rho"} & set(untrusted) | qib))
        ch = None if "channels" in untrusted else self.channels
        if ch is not None and "channels.narrow" in untrusted:  # the global slopes hold: only the narrowing goes
            ch = replace(ch, narrow=None)
        notes = self.notes + tuple(f"{why}: not used by certificates" for why in untrusted.values())
        return Knowledge(consts, ch, notes, {**self.untrusted, **untrusted})

    @staticmethod
    def trusting(plant: Plant) -> "Knowledge":
        """The plant's own declarations, trusted unchecked (the pipeline uses :meth:`ConstantsReport.knowledge`)."""
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
        Sampled lower bounds (beta at ``gamma = used.gamma``).
    used : Constants
        What designs use: analytic unless disproved, else sampled (no guarantee), None where
        unbounded.
    source : dict
        alpha, rho, beta -> ``"analytic"``, ``"sampled"``, ``"sampled (analytic disproved)"`` or
        ``"unbounded"``.
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
    checked_on : float, optional
        How far global declarations were sampled (None: on the region ``used.radius``, whole).
    """

    claimed: Constants
    analytic: Constants | None
    sampled: Constants
    used: Constants
    source: dict[str, str]
    violations: list[Violation] = field(default_factory=list)
    disproved: list[Violation] = field(default_factory=list)
    channel_violations: list[Violation] = field(default_factory=list)
    unbounded: dict[str, str] = field(default_factory=dict)
    prechecks: list[str] = field(default_factory=list)
    seed: int = 0
    n_samples: int = 0
    checked_on: float | None = None

    @property
    def region(self) -> str:
        """Where the declarations hold and how far they were checked, in words."""
        if self.used.radius is not None:
            return f"||x|| <= {self.used.radius:g} (sampled whole)"
        far = f" (sampled on ||x|| <= {self.checked_on:.3g})" if self.checked_on is not None else ""
        return "everywhere" + far

    def violated(self, name: str) -> Violation | None:
        """The violation of claimed constant ``name``, if any."""
        return next((v for v in self.violations if v.name == name), None)

    def to_dict(self) -> dict:
        """A JSON-ready description (for run.json); :meth:`from_dict` inverts it."""
        return {**asdict(self), "trust": self.trust}

    @classmethod
    def from_dict(cls, doc: dict) -> "ConstantsReport":
        """The report :meth:`to_dict` described."""
        doc = {"used": doc.get("valid"), **doc}  # "valid": the field's former name in run.json
        kw = {f.name: doc[f.name] for f in fields(cls) if f.name in doc}
        for k in ("claimed", "analytic", "sampled", "used"):
            kw[k] = None if kw[k] is None else Constants(**kw[k])
        for k in ("violations", "disproved", "channel_violations"):
            kw[k] = [Violation(**{**v, "x1": tuple(v["x1"]), "x2": tuple(v["x2"])}) for v in kw[k]]
        return cls(**kw)

    def knowledge(self, plant: Plant) -> Knowledge:
        """The trusted part for ``plant``: analytic constants no sample disproved, and the plant's
        channels unless a sample disproved their slopes."""
        untrusted = {v.name: v.describe("analytic") for v in self.disproved}
        for key, what, narrowed in (("channels", "channels", False), ("channels.narrow", "narrowing", True)):
            vs = [v for v in self.channel_violations if (NARROWED in v.name) == narrowed]
            if vs and "channels" not in untrusted:
                untrusted[key] = f"the declared {what}: " + "; ".join(v.describe("declared") for v in vs)
        sampled_only = ", ".join(k for k in ("alpha", "rho", "beta") if self.source.get(k, "").startswith("sampled"))
        notes = (f"{sampled_only} only sampled (lower bounds): never used by certificates",) if sampled_only else ()
        return Knowledge(self.analytic or Constants(), plant.channels, notes).without(untrusted)

    @property
    def trust(self) -> str:
        """One phrase for a results row: where the constants came from and what certificates may use."""
        labels = {"analytic": "analytic", "sampled": "sampled (lower bounds, not certifying)",
                  "sampled (analytic disproved)": "analytic DISPROVED by a sample (not certifying)",
                  "unbounded": "unbounded", "none": "unknown"}
        by = {src: [k for k in ("alpha", "rho", "beta") if self.source.get(k, "none") == src] for src in labels}
        parts = [f"{'/'.join(ks)} {labels[src]}" for src, ks in by.items() if ks]
        if self.channel_violations:
            parts.append("channels DISPROVED by a sample (not certifying)")
        if self.used.radius is not None:
            parts.append(f"on ||x|| <= {self.used.radius:g}")
        return "; ".join(parts)


def _values(f: Callable, X: np.ndarray) -> np.ndarray:
    """``f(X)`` for a batch as real numbers; PlantError naming the state at a complex or non-finite value."""
    raw = np.asarray(f(X.copy()))
    if raw.dtype.kind in "biuf":  # real numbers (the usual case): the conversion can neither warn nor fail
        out = np.asarray(raw, dtype=float)
    else:
        if np.iscomplexobj(raw):
            bad = np.flatnonzero(np.any(raw.imag != 0, axis=0)) if raw.shape == X.shape else []
            where = (f" at the sampled state x = {np.round(X[:, bad[0]], 6).tolist()}: "
                     f"{np.round(raw[:, bad[0]], 6).tolist()}" if len(bad) else " on sampled states")
            raise PlantError(f"f: returned complex values{where}; f must be real")
        with warnings.catch_warnings():
            warnings.simplefilter("error", np.exceptions.ComplexWarning)
            try:
                out = np.asarray(raw, dtype=float)
            except (np.exceptions.ComplexWarning, TypeError, ValueError) as exc:
                raise PlantError(f"f: returned values that are not real numbers ({exc})") from None
    if out.shape != X.shape:
        raise PlantError(f"f: a batch of shape {X.shape} gave shape {out.shape}")
    if not np.isfinite(out).all():
        bad = ~np.all(np.isfinite(out), axis=0)
        j = int(np.argmax(bad))
        raise PlantError(f"f: not finite at the sampled state x = {np.round(X[:, j], 6).tolist()}: "
                         f"{np.round(out[:, j], 6).tolist()}")
    return out


def _ratios(f: Callable, x1: np.ndarray, x2: np.ndarray, gamma: float):
    """alpha, rho and beta(gamma) ratios for batches of pairs, shape (N,) each, -inf where not finite."""
    dx = x1 - x2
    with np.errstate(over="ignore", invalid="ignore"):
        df = _values(f, x1) - _values(f, x2)
        nx2 = (dx * dx).sum(axis=0)
        nx2 = np.where(nx2 > 0, nx2, np.nan)
        inner = (dx * df).sum(axis=0)
        nf2 = (df * df).sum(axis=0)
        ratios = np.sqrt(nf2 / nx2), inner / nx2, (nf2 - gamma * inner) / nx2
    return [np.where(np.isfinite(r), r, -np.inf) for r in ratios]


def _project(x: np.ndarray, radius: float | None) -> np.ndarray:
    if radius is None:
        return x
    norms = np.linalg.norm(x, axis=0)
    scale = np.where(norms > radius, radius / np.maximum(norms, 1e-300), 1.0)
    return x * scale


def _random_pairs(rng: np.random.Generator, n: int, N: int, radius: float | None, far: float = GLOBAL_RANGE):
    if radius is None:
        scale = 10.0 ** rng.uniform(-2, np.log10(far), size=N)  # point scales 0.01 .. far
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


#: Forward-difference steps of the refinement: scipy's L-BFGS-B ones (its option ``eps = 1e-8``, an absolute
#: step; where ``z + 1e-8 == z``, scipy's relative step ``sqrt(eps_float64) * sign0(z) * max(1, |z|)``).
_FD_ABS_STEP = 1e-8
_FD_REL_STEP = np.finfo(np.float64).eps ** 0.5

#: The evaluation budget of the former finite-difference refinement (scipy's L-BFGS-B ``maxfun`` default), counted
#: there as 2n + 1 calls per point: :func:`_local_max` keeps its stopping point with ``maxfun = _MAXFUN // (2n + 1)``.
_MAXFUN = 15000


def _unpack(Z: np.ndarray, radius: float | None, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The pairs ``(x1, x2)``, each projected on ``||x|| <= radius``, of the columns ``z = (x1, x2 - x1)`` of ``Z``."""
    return _project(Z[:n], radius), _project(Z[:n] + Z[n:], radius)


def _neg_ratios(f: Callable, which: int, gamma: float, Z: np.ndarray, radius: float | None, n: int) -> np.ndarray:
    """Minus ratio ``which`` at the pairs of the columns of ``Z`` (2n, N) (see :func:`_unpack`); 0 where the pair
    coincides (``||x1 - x2|| < 1e-12``: f is not evaluated there) or the ratio is not finite."""
    a, b = _unpack(Z, radius, n)
    d = a - b
    with np.errstate(over="ignore", invalid="ignore"):
        near = (d * d).sum(axis=0) < 4e-24  # ||a - b|| < 2e-12: decided by np.linalg.norm, as for a lone pair
    keep = ~near
    for j in np.flatnonzero(near):
        keep[j] = not np.linalg.norm(d[:, j]) < 1e-12
    out = np.zeros(Z.shape[1])
    if keep.all():
        val = _ratios(f, a, b, gamma)[which]
    elif keep.any():
        val = _ratios(f, a[:, keep], b[:, keep], gamma)[which]
    else:
        return out
    out[keep] = np.where(np.isfinite(val), -val, 0.0)
    return out


def _neg_and_gradient(f: Callable, which: int, gamma: float, z: np.ndarray, radius: float | None, n: int,
                      lb: np.ndarray | None, ub: np.ndarray | None) -> tuple[float, np.ndarray]:
    """:func:`_neg_ratios` at ``z`` and its forward-difference gradient, from one batch of 2n + 1 columns.

    The steps are those of scipy's L-BFGS-B without a gradient (``approx_derivative(method='2-point',
    abs_step=1e-8)``), turned back or shortened to stay in the box ``lb <= z <= ub`` when one is given (scipy's
    ``_adjust_scheme_to_bounds``, one-sided), so L-BFGS-B takes the same path as with scipy's own finite differences
    (which evaluate the same points one call each).
    """
    h = np.full(z.shape, _FD_ABS_STEP)
    lost = (z + h) - z == 0
    h[lost] = _FD_REL_STEP * ((z[lost] >= 0).astype(float) * 2 - 1) * np.maximum(1.0, np.abs(z[lost]))
    if lb is not None:
        if np.any((z < lb) | (z > ub)):  # scipy's differences refuse such a point (the refinement then keeps z0)
            raise ValueError("`x0` violates bound constraints.")
        lower, upper = z - lb, ub - z
        stepped = z + h
        fitting = np.abs(h) <= np.maximum(lower, upper)
        h[((stepped < lb) | (stepped > ub)) & fitting] *= -1
        forward, backward = (upper >= lower) & ~fitting, (upper < lower) & ~fitting
        h[forward], h[backward] = upper[forward], -lower[backward]
    m = z.size
    Z = np.repeat(z[:, None], m + 1, axis=1)
    idx = np.arange(m)
    Z[idx, idx + 1] = z + h
    v = _neg_ratios(f, which, gamma, Z, radius, n)
    return v[0], (v[1:] - v[0]) / ((z + h) - z)


def _local_max(f, which: int, gamma: float, x1, x2, radius, n):
    """Maximise one ratio from a starting pair with L-BFGS-B, on forward-difference gradients of batched values."""
    from scipy.optimize import minimize

    z0 = np.concatenate([x1, x2 - x1])
    # globally a box keeps an unbounded ratio (a cubic f's) from running to overflow
    box = None if radius is not None else [(-b, b) for b in [1e3 * max(1.0, float(np.abs(z0).max()))] * (2 * n)]
    lb, ub = (None, None) if box is None else (np.array([lo for lo, _ in box]), np.array([hi for _, hi in box]))
    try:
        z = minimize(lambda z: _neg_and_gradient(f, which, gamma, z, radius, n, lb, ub), z0, method="L-BFGS-B",
                     jac=True, bounds=box, options={"maxiter": 200, "maxfun": _MAXFUN // (2 * n + 1)}).x
    except Exception:  # a user f that fails away from the samples: keep the sample
        z = z0
    a, b = _unpack(z[:, None], radius, n)
    return a[:, 0], b[:, 0], -_neg_ratios(f, which, gamma, z[:, None], radius, n)[0]


def _best_pairs(f, x1, x2, gamma, radius, n, n_refine) -> dict[str, tuple[float, np.ndarray, np.ndarray]]:
    """For alpha, rho and beta(gamma): the largest ratio over the pairs, refined locally."""
    best: dict[str, tuple[float, np.ndarray, np.ndarray]] = {}
    for which, (name, r) in enumerate(zip(("alpha", "rho", "beta"), _ratios(f, x1, x2, gamma))):
        order = np.argsort(r)[::-1][:max(n_refine, 1)]
        top = (float(r[order[0]]), x1[:, order[0]], x2[:, order[0]])
        for k in order[:n_refine]:
            a, b, val = _local_max(f, which, gamma, x1[:, k], x2[:, k], radius, n)
            if val > top[0]:
                top = (float(val), a, b)
        best[name] = top
    return best


def _unbounded(f, x1, x2, gamma) -> dict[str, str]:
    """Constants whose sampled sup at ``||x|| >= 10`` exceeds :data:`GROWTH_FACTOR` times the one at ``||x|| <= 1``."""
    out = {}
    s1, s2 = np.linalg.norm(x1, axis=0), np.linalg.norm(x2, axis=0)
    for name, r in zip(("alpha", "rho", "beta"), _ratios(f, x1, x2, gamma)):
        small = float(r[np.maximum(s1, s2) <= 1.0].max(initial=-np.inf))
        large = float(r[np.minimum(s1, s2) >= 10.0].max(initial=-np.inf))
        if large > GROWTH_FACTOR * max(small, 1e-12) and large > 1e-9:
            kind = {"alpha": "globally Lipschitz", "rho": "one-sided Lipschitz with any constant",
                    "beta": "quadratically inner-bounded at this gamma"}[name]
            out[name] = (f"f is not {kind} (the sampled {name} grows with the sampled radius: {small:.3g} for "
                         f"||x|| <= 1, {large:.3g} for ||x|| >= 10): declare bounds with a radius")
    return out


#: Marks a violated narrowing (``Channels.narrow``): certificates then drop the narrowing only.
NARROWED = "narrowed"


def _channel_check(plant: Plant, rng: np.random.Generator, n_pairs: int = 2000,
                   far: float = GLOBAL_RANGE) -> list[Violation]:
    """Each channel's sampled slopes on the range of its input (on its region, else out to ``||H_i|| far``, at least
    ``far``) against its bounds, on |z| <= r against slopes_on(r)."""
    ch = plant.channels
    if ch is None:
        return []
    out = []
    zmaxes = [ch.radius * h if ch.radius is not None else max(far * h, far) for h in map(np.linalg.norm, ch.H)]
    for i in range(ch.q):
        zmax = zmaxes[i]
        a = rng.uniform(-zmax, zmax, n_pairs)
        b = a + rng.normal(0, 1, n_pairs) * np.maximum(0.05 * zmax, 1e-3) * 10.0 ** rng.uniform(-4, 0, n_pairs)
        out += _pair_violations(ch, i, a, np.clip(b, -zmax, zmax))
    for i in range(ch.q if ch.narrow is not None else 0):
        for r in np.geomspace(min(1e-2, zmaxes[i]), zmaxes[i], 9):
            lo, hi = ch.slopes_on(float(r))
            a = rng.uniform(-r, r, n_pairs // 4)
            b = np.clip(a + rng.normal(0, 1, a.size) * r * 10.0 ** rng.uniform(-4, 0, a.size), -r, r)
            out += [replace(v, name=f"{v.name} {NARROWED} on |z| <= {r:.3g}")
                    for v in _pair_violations(replace(ch, lo=lo, hi=hi, narrow=None), i, a, b)]
    return out


def _pair_violations(ch: Channels, i: int, a: np.ndarray, b: np.ndarray) -> list[Violation]:
    """Channel ``i``'s slope violations over the input pairs ``(a_j, b_j)``, the other channels at 0."""
    Z = np.zeros((ch.q, 2 * a.size))
    Z[i, :a.size], Z[i, a.size:] = a, b
    with np.errstate(invalid="ignore", divide="ignore"):
        phi = np.asarray(ch.phi(Z), dtype=float)[i]
    return _slope_violations(ch, i, phi[:a.size], phi[a.size:], Z[:, :a.size], Z[:, a.size:])


def _slope_violations(ch: Channels, i: int, p1: np.ndarray, p2: np.ndarray, Z1: np.ndarray,
                      Z2: np.ndarray) -> list[Violation]:
    """Channel ``i``'s slopes over the input pairs ``Z1``, ``Z2`` (q, N): a :class:`Violation` per bound broken."""
    a, b = Z1[i], Z2[i]
    dz = a - b
    with np.errstate(invalid="ignore", divide="ignore"):  # pairs closer than round-off can resolve say nothing
        slope = np.where(np.abs(dz) > _MIN_STEP * (1 + np.abs(a) + np.abs(b)), (p1 - p2) / dz, np.nan)
    ok = np.isfinite(slope)
    if not ok.any():
        return []
    tol = _REL_TOL * max(1.0, abs(ch.lo[i]), abs(ch.hi[i])) + 1e-9
    out = []
    for bound, sign, word in ((ch.hi[i], 1.0, "upper"), (ch.lo[i], -1.0, "lower")):
        k = int(np.argmax(np.where(ok, sign * slope, -np.inf)))
        if sign * (slope[k] - bound) > tol:
            Hp = np.linalg.pinv(ch.H)
            out.append(Violation(f"channel {i} {word} slope bound", float(bound), float(slope[k]),
                                 tuple(float(v) for v in Hp @ Z1[:, k]), tuple(float(v) for v in Hp @ Z2[:, k])))
    return out


def check_trajectory(plant: Plant, know: Knowledge, X: np.ndarray, XH: np.ndarray, *,
                     checked_on: float | None = None, seed: int = 0, max_points: int = 2000) -> tuple[dict, str]:
    """Check the declarations a certificate uses where a simulation went.

    Along the trajectory: the declared Jacobian (finite differences at 8 states), the channels'
    identity and slope bounds, and the trusted scalar constants, over the pairs ``(x, x_hat)`` and
    ``(x, 0)`` the certificate's inequalities use. A global declaration sampled only out to
    ``checked_on`` is sampled again out to :data:`REACH_FACTOR` times the largest state reached.

    Parameters
    ----------
    plant : Plant
    know : Knowledge
        The trusted declarations (only these are checked).
    X, XH : ndarray (n, T)
    checked_on : float, optional
        How far the constants' samplers went (:attr:`ConstantsReport.checked_on`).
    seed : int

    Returns
    -------
    disproved : dict
        Declaration (``"channels"``, ``"alpha"``, ``"rho"``, ``"beta"``) -> why, with the state.
    checked : str
        The range checked, in words.

    Raises
    ------
    PlantError
        A declared Jacobian that is not f's derivative at a simulated state.
    """
    X, XH = _finite_instants(plant.n, X, XH, max_points)
    reach = float(max(np.linalg.norm(X, axis=0).max(initial=0.0), np.linalg.norm(XH, axis=0).max(initial=0.0)))
    if plant.jacobian is not None and X.shape[1]:  # at 8 simulated states and estimates
        pts = np.concatenate([X, XH], axis=1)[:, np.linspace(0, 2 * X.shape[1] - 1, 8).astype(int)]
        why = jacobian_mismatch(plant.f, plant.jacobian, pts)
        if why:
            raise PlantError(f"{why} (a state along the simulation)")
    ch, c = know.channels, know.constants
    bad = _channels_along(plant, ch, X, XH) if ch is not None and X.shape[1] else {}
    scalars = {k: getattr(c, k) for k in ("alpha", "rho", "beta") if getattr(c, k) is not None}
    if scalars and X.shape[1]:
        for X2 in (XH, np.zeros_like(X)):
            apart = np.linalg.norm(X - X2, axis=0) > _MIN_STEP * (1 + np.linalg.norm(X, axis=0)
                                                                  + np.linalg.norm(X2, axis=0))
            inside = _inside(X, c.radius) & _inside(X2, c.radius) & apart
            for k, v in _scalar_violations(plant.f, X[:, inside], X2[:, inside], c.gamma, scalars).items():
                bad.setdefault(k, v.describe("analytic") + " (along the simulation)")
    far = REACH_FACTOR * reach
    glob = {k: v for k, v in scalars.items() if k not in bad and c.radius is None}
    glob_channels = ch is not None and ch.radius is None and "channels" not in bad
    checked = f"along the simulation (||x||, ||x_hat|| <= {reach:.3g})"
    if (glob or glob_channels) and (checked_on is None or far > checked_on):
        bad.update(_sampled_far(plant, glob_channels, glob, c.gamma, far, seed))
        checked += f" and sampled on ||x|| <= {far:.3g}"
    return bad, checked


def _sampled_far(plant: Plant, channels: bool, scalars: dict[str, float], gamma: float | None, far: float,
                 seed: int) -> dict[str, str]:
    """The global declarations sampled again out to ``||x|| <= far``: declaration -> why, for those disproved."""
    bad = {}
    rng = np.random.default_rng([seed, 3])
    if channels:
        vs = _channel_check(plant, rng, far=far)
        if vs:
            bad["channels"] = "the declared channels: " + vs[0].describe("declared")
    if scalars:
        x1, x2 = _random_pairs(rng, plant.n, 4000, None, far=far)
        for k, v in _scalar_violations(plant.f, x1, x2, gamma, scalars).items():
            bad[k] = v.describe("analytic")
    return bad


def _finite_instants(n: int, X, XH, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """The instants of a trajectory where state and estimate are finite, thinned evenly to ``max_points``."""
    X, XH = (np.asarray(M, dtype=float).reshape(n, -1) for M in (X, XH))
    keep = np.all(np.isfinite(X), axis=0) & np.all(np.isfinite(XH), axis=0)
    X, XH = X[:, keep], XH[:, keep]
    if X.shape[1] > max_points:
        idx = np.unique(np.linspace(0, X.shape[1] - 1, max_points).astype(int))
        X, XH = X[:, idx], XH[:, idx]
    return X, XH


def _channels_along(plant: Plant, ch, X: np.ndarray, XH: np.ndarray) -> dict[str, str]:
    """``{"channels": why}`` when ``f = G phi(H x)`` or the slopes (to ``H x_hat`` and 0) fail along a trajectory."""
    P = np.concatenate([X, XH], axis=1)
    P = P[:, _inside(P, ch.radius)]
    if P.shape[1]:
        fP = _values(plant.f, P)
        with np.errstate(all="ignore"):
            err = np.abs(ch.apply(P) - fP)
        scale = np.maximum(1.0, np.abs(fP))
        worst = np.max(err / scale, axis=0)
        if worst.max() > 1e-9:
            j = int(np.argmax(worst))
            return {"channels": f"the declared channels: G phi(H x) differs from f by {err[:, j].max():.3g} at the "
                                f"simulated state x = {vector(P[:, j])}"}
    for X2 in (XH, np.zeros_like(X)):
        inside = _inside(X, ch.radius) & _inside(X2, ch.radius)
        Z1, Z2 = ch.H @ X[:, inside], ch.H @ X2[:, inside]
        with np.errstate(all="ignore"):
            p1, p2 = np.asarray(ch.phi(Z1), dtype=float), np.asarray(ch.phi(Z2), dtype=float)
        vs = [v for i in range(ch.q) for v in _slope_violations(ch, i, p1[i], p2[i], Z1, Z2)]
        if vs:
            return {"channels": "the declared channels: " + vs[0].describe("declared") + " (along the simulation)"}
    return {}


def _scalar_violations(f: Callable, a: np.ndarray, b: np.ndarray, gamma: float | None,
                       stated: dict[str, float]) -> dict[str, Violation]:
    """The stated constants the pairs ``(a_j, b_j)`` exceed, each with its worst pair."""
    if not a.shape[1]:
        return {}
    with np.errstate(all="ignore"):
        ratios = dict(zip(("alpha", "rho", "beta"), _ratios(f, a, b, gamma or 0.0)))
    out = {}
    for k, value in stated.items():
        j = int(np.argmax(ratios[k]))
        if _exceeds(ratios[k][j], value):
            out[k] = Violation(k, value, float(ratios[k][j]), tuple(a[:, j]), tuple(b[:, j]))
    return out


#: Pairs closer than this (relative) are not used: round-off would swamp the difference quotient.
_MIN_STEP = 1e-6


def _inside(X: np.ndarray, radius: float | None) -> np.ndarray:
    """Columns of ``X`` with ``||x|| <= radius`` (all of them when ``radius`` is None)."""
    if radius is None:
        return np.ones(X.shape[1], dtype=bool)
    return np.linalg.norm(X, axis=0) <= radius * (1 + 1e-12)


def linear_prechecks(plant: Plant) -> list[str]:
    """Why (A, B) is not stabilizable or (A, C) not detectable (PBH test, naming the eigenvalue); empty if both hold.

    The eigenvalues tested are the unstable ones: ``Re lam >= 0`` in continuous time, ``|lam| >= 1`` for a
    discrete-time plant (``dt > 0``).
    """
    A, B, C = plant.A, plant.B, plant.C
    scale = max(1.0, float(np.linalg.norm(A, 2)))
    discrete = getattr(plant, "dt", 0) > 0
    out = []
    for lam in np.linalg.eigvals(A):
        stable = abs(lam) < 1 - 1e-9 if discrete else lam.real < -1e-9 * scale
        if stable or lam.imag < -1e-12:  # one of each conjugate pair
            continue
        shown = f"{lam.real:.4g}" + (f" +- {lam.imag:.4g}j" if abs(lam.imag) > 1e-12 else "")
        for name, M, what in (("(A, B)", np.hstack([lam * np.eye(plant.n) - A, B]), "stabilizable"),
                              ("(A, C)", np.vstack([lam * np.eye(plant.n) - A, C]), "detectable")):
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
        ``plant.bounds`` gives the analytic constants and, with ``plant.claimed``, the region.
    seed : int
        Seed of the sampler.
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
        If f is complex or not finite at a sampled state.
    """
    if n_samples < 1:
        raise ValueError(f"n_samples: must be >= 1, got {n_samples}")
    rng = np.random.default_rng(seed)
    analytic = plant.bounds
    radius = (analytic.radius if analytic is not None else None) or plant.claimed.radius
    gamma = next((g.gamma for g in (analytic, plant.claimed) if g is not None and g.gamma is not None), 0.0)

    far = sampled_range(plant)
    x1, x2 = _random_pairs(rng, plant.n, n_samples, radius, far)
    best = _best_pairs(plant.f, x1, x2, gamma, radius, plant.n, n_refine)
    sampled = Constants(
        alpha=max(best["alpha"][0], 0.0), rho=best["rho"][0], beta=best["beta"][0], gamma=gamma, radius=radius
    )
    unbounded = _unbounded(plant.f, x1, x2, gamma) if radius is None else {}
    disproved = _violations(analytic, best)
    violations = _claimed_violations(plant, best, x1, x2, gamma, radius, seed, n_samples, n_refine)
    valid, source = _trusted(analytic, sampled, {v.name for v in disproved}, unbounded, gamma, radius)
    return ConstantsReport(
        claimed=plant.claimed, analytic=analytic, sampled=sampled, used=valid, source=source,
        violations=violations, disproved=disproved,
        channel_violations=_channel_check(plant, np.random.default_rng([seed, 2]), far=far), unbounded=unbounded,
        prechecks=linear_prechecks(plant), seed=seed, n_samples=n_samples, checked_on=None if radius else far,
    )


def _violations(stated: Constants | None, best: dict) -> list[Violation]:
    """The constants of ``stated`` that the best sampled pair of each (``best``: name -> value, x1, x2) exceeds."""
    out = []
    for name, (val, a, b) in best.items():
        value = getattr(stated, name, None)
        if value is not None and _exceeds(val, value):
            out.append(Violation(name, value, val, tuple(a), tuple(b)))
    return out


def _trusted(analytic: Constants | None, sampled: Constants, bad: set, unbounded: dict, gamma: float,
             radius) -> tuple[Constants, dict]:
    """The used constants and their sources (:attr:`ConstantsReport.used`)."""
    valid_kw, source = {}, {}
    for name in ("alpha", "rho", "beta"):
        av = getattr(analytic, name, None)
        if av is not None:
            source[name] = "sampled (analytic disproved)" if name in bad else "analytic"
        else:
            source[name] = "unbounded" if name in unbounded else "sampled"
        valid_kw[name] = {"analytic": av, "unbounded": None}.get(source[name], getattr(sampled, name))
    return Constants(**valid_kw, gamma=None if valid_kw["beta"] is None else gamma, radius=radius), source


def _claimed_violations(plant, best, x1, x2, gamma, radius, seed, n_samples, n_refine) -> list[Violation]:
    """Claimed constants a sample violates, checked on the region the source claims them for."""
    claimed = plant.claimed
    c_radius = claimed.radius
    if c_radius != radius and any(getattr(claimed, k) is not None for k in ("alpha", "rho", "beta")):
        crng = np.random.default_rng([seed, 1])
        x1, x2 = _random_pairs(crng, plant.n, n_samples, c_radius, sampled_range(plant))
        best = _best_pairs(plant.f, x1, x2, gamma, c_radius, plant.n, n_refine)
    if claimed.beta is not None and claimed.gamma != gamma:  # beta is checked at the claimed gamma
        r = _ratios(plant.f, x1, x2, claimed.gamma)[2]
        k = int(np.argmax(r))
        a, b, val = _local_max(plant.f, 2, claimed.gamma, x1[:, k], x2[:, k], c_radius, plant.n)
        best = {**best, "beta": (val, a, b)}
    return _violations(claimed, best)


def resolve_constants(report: ConstantsReport, *, use_claimed: bool = False) -> Constants:
    """The constants a design uses: ``report.used``, or with ``use_claimed`` the claimed ones where given."""
    if not use_claimed:
        return report.used
    c, v = report.claimed, report.used
    pick = lambda k: getattr(c, k) if getattr(c, k) is not None else getattr(v, k)  # noqa: E731
    qib = c if c.beta is not None else v
    return Constants(alpha=pick("alpha"), rho=pick("rho"), beta=qib.beta, gamma=qib.gamma, radius=pick("radius"))
