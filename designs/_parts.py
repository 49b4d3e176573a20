"""Observer-based controllers composed of a feedback part (F) and an estimator part (K or EKF)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from bench.registry import DESIGNS, Registry
from designs._core import GAIN_STATUSES, Configurable, Design, DesignError, DesignResult
from plants import Constants, Plant

__all__ = ["Part", "register_estimator", "register_feedback", "register_pairing"]

FEEDBACKS = Registry("feedback part", "designs")
ESTIMATORS = Registry("estimator part", "designs")


@dataclass(frozen=True, kw_only=True)
class Part(Configurable):
    """Base of feedback and estimator parts; subclasses set ``needs`` and implement ``compute``."""

    def compute(self, plant: Plant, constants: Constants) -> DesignResult:  # pragma: no cover
        """Compute the part for ``plant``: a result holding ``F`` (feedback) or ``K``/``estimator``."""
        raise NotImplementedError


def check_weight(name: str, W, size: int | None, *, definite: bool) -> np.ndarray:
    """A weight matrix: None is the identity, a scalar s is s I; square (``size`` x ``size`` when given), finite,
    symmetric, PSD (PD with ``definite``); else a :class:`DesignError` naming ``name``."""
    if W is None:
        return np.eye(size)
    try:
        M = np.atleast_2d(np.array(W, dtype=float))
    except (TypeError, ValueError, OverflowError):
        raise DesignError(f"{name}: not a numeric matrix, got {W!r}"[:200]) from None
    if M.shape == (1, 1) and size is not None and size > 1:
        M = M[0, 0] * np.eye(size)  # a scalar weight means scalar * I
    k = M.shape[0] if size is None else size
    if M.shape != (k, k) or M.size == 0:
        raise DesignError(f"{name}: expected shape ({k}, {k}), got {M.shape}")
    if not np.all(np.isfinite(M)):
        raise DesignError(f"{name}: entries must be finite")
    if not np.allclose(M, M.T, rtol=1e-10, atol=1e-12):
        raise DesignError(f"{name}: must be symmetric")
    lo = float(np.linalg.eigvalsh(M)[0])
    tol = 1e-12 * max(1.0, float(np.abs(M).max()))
    if lo <= tol if definite else lo < -tol:
        kind = "definite" if definite else "semidefinite"
        raise DesignError(f"{name}: must be positive {kind} (smallest eigenvalue {lo:.3g})")
    return M


def _registrar(registry: Registry, kind: str):
    def register(id: str):
        def deco(cls):
            registry.register(id, cls)
            return cls

        return deco

    register.__doc__ = f"Decorator registering {kind} part class under ``id``."
    return register


register_feedback = _registrar(FEEDBACKS, "a feedback")
register_estimator = _registrar(ESTIMATORS, "an estimator")


@dataclass(frozen=True, kw_only=True)
class Composite(Design):
    """An observer-based controller: a feedback part (F) paired with an estimator part (K or EKF)."""

    feedback: Part
    estimator: Part

    @property
    def needs(self) -> tuple[str, ...]:
        """The constants either part needs (feedback part's first, no repeats)."""
        return tuple(dict.fromkeys((*self.feedback.needs, *self.estimator.needs)))

    @property
    def time_domains(self) -> tuple[str, ...]:
        """The time domains both parts have a form for."""
        return tuple(d for d in self.feedback.time_domains if d in self.estimator.time_domains)

    def applicable(self, plant: Plant, constants: Constants) -> str | None:
        for role, part in (("feedback", self.feedback), ("estimator", self.estimator)):
            why = part.applicable(plant, constants)
            if why is not None:
                return f"{role} part {type(part).__name__}: {why}"
        return None

    def design(self, plant: Plant, constants: Constants) -> DesignResult:
        """Compute both parts and merge their evidence: the worst part's status (with gains: the strongest of
        feasible, computed, given), timings added, the worst LMI margin."""
        fb = self.feedback.compute(plant, constants)
        es = self.estimator.compute(plant, constants)
        parts = (("feedback", fb), ("estimator", es))
        bad = [(role, r) for role, r in parts if r.status not in GAIN_STATUSES]
        order = ("error", "undecided", "inapplicable", "infeasible", "marginal")
        if bad:
            status = min((r.status for _, r in bad), key=order.index)
        else:
            status = next((s for s in GAIN_STATUSES if s in (fb.status, es.status)))
        reason = "; ".join(f"{role}: {r.reason}" for role, r in parts if r.reason)
        margins = [r.margin for _, r in parts if math.isfinite(r.margin)]
        ok = not bad
        return DesignResult(
            status=status,
            reason=reason,
            route="+".join(dict.fromkeys(r.route for _, r in parts if r.route)),
            K=es.K if ok else None,
            F=fb.F if ok else None,
            estimator=es.estimator if ok else None,
            solver="+".join(dict.fromkeys(r.solver for _, r in parts if r.solver)) or None,
            solver_status="+".join(f"{r.solver_status}" for _, r in parts if r.solver_status) or None,
            compile_s=fb.compile_s + es.compile_s,
            solve_s=fb.solve_s + es.solve_s,
            n_solves=fb.n_solves + es.n_solves,
            margin=max(margins) if margins else float("nan"),
            lmi_size=max(fb.lmi_size, es.lmi_size),
            min_eig={f"{role}.{k}": v for role, r in parts for k, v in r.min_eig.items()},
            params={f"{role}.{k}": v for role, r in parts for k, v in r.params.items()},
        )


def register_pairing(feedback: str, estimator: str) -> str:
    """Register the design ``"feedback+estimator"`` (hyperparameters: the dicts ``feedback_params`` and
    ``estimator_params``); returns its id."""
    did = f"{feedback}+{estimator}"

    def factory(*, feedback_params: dict | None = None, estimator_params: dict | None = None,
                **unknown) -> Composite:
        for key in unknown:
            shown = key if key.isidentifier() else repr(key)
            raise DesignError(f"{shown}: unknown hyperparameter of the pairing {did!r} "
                              "(valid: feedback_params, estimator_params)")
        parts = []
        for key, reg, part, params in (("feedback_params", FEEDBACKS, feedback, feedback_params),
                                       ("estimator_params", ESTIMATORS, estimator, estimator_params)):
            if params is not None and not (isinstance(params, Mapping) and all(isinstance(k, str) for k in params)):
                raise DesignError(f"{key}: expected a dict of the part's hyperparameters by name, got {params!r}")
            try:
                parts.append(reg.create(part, **(params or {})))
            except DesignError as exc:  # say which dict the bad parameter came from
                raise DesignError(f"{key}: {exc}") from None
        return Composite(feedback=parts[0], estimator=parts[1])

    factory.__module__ = "designs.pairings"
    factory.__doc__ = f"observer-based controller: {feedback} feedback with the {estimator} estimator"
    DESIGNS.register(did, factory, factory.__doc__, order=50)
    return did
