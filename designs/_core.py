"""The design interface: a design maps a plant (and its constants) to gains plus evidence.

Nothing here simulates. Infeasibility is a result (a status with a reason), not an exception.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any

import numpy as np

from plants._core import Constants, Plant

__all__ = ["Design", "DesignError", "DesignResult", "STATUSES", "check_positive", "missing_constants"]

#: Possible design statuses.
STATUSES = ("feasible", "infeasible", "inapplicable", "undecided", "error")


class DesignError(ValueError):
    """A design parameter is invalid; the message names the parameter."""


def check_positive(name: str, value: Any, *, allow_zero: bool = False) -> float:
    """Return ``value`` as a float, or raise :class:`DesignError` naming ``name``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise DesignError(f"{name}: expected a real number, got {value!r}") from None
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise DesignError(f"{name}: must be finite and {bound}, got {value!r}")
    return v


@dataclass
class DesignResult:
    """Gains plus the evidence behind them.

    Attributes
    ----------
    status : str
        One of :data:`STATUSES`.
    reason : str
        Why, in words (always set unless feasible).
    K, F : ndarray or None
        Observer gain (n x p) and feedback gain (m x n), ``u = F x_hat``.
    solver, solver_status : str or None
        The SDP solver and its final status.
    compile_s, solve_s : float
        Seconds spent compiling (cvxpy canonicalisation) and solving, summed over all solves.
    n_solves : int
        Number of LMI solves (searches over scalars solve several times).
    margin : float
        Verified margin: the largest eigenvalue of the numeric LMI matrix, recomputed with numpy
        at the solution (negative = strictly feasible). NaN when there is no LMI.
    lmi_size : int
        Dimension of the LMI matrix.
    min_eig : dict
        Smallest eigenvalues of the decision matrices (e.g. ``{"Q": .., "R": ..}``).
    params : dict
        Every scalar the design used (fixed, searched or solved for).
    estimator : object, optional
        A run-time estimator specification (e.g. :class:`designs.ekf.EKFSpec`) for designs whose
        estimator is not a fixed gain K; the harness simulates it in sampled time.
    """

    status: str
    reason: str = ""
    K: np.ndarray | None = None
    F: np.ndarray | None = None
    solver: str | None = None
    solver_status: str | None = None
    compile_s: float = 0.0
    solve_s: float = 0.0
    n_solves: int = 0
    margin: float = float("nan")
    lmi_size: int = 0
    min_eig: dict[str, float] = field(default_factory=dict)
    params: dict[str, float] = field(default_factory=dict)
    estimator: Any = None

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"status: must be one of {STATUSES}, got {self.status!r}")

    @property
    def has_gains(self) -> bool:
        """True when both K and F are present."""
        return self.K is not None and self.F is not None

    @property
    def has_controller(self) -> bool:
        """True when there is a feedback F and an estimator (a gain K or a run-time estimator)."""
        return self.F is not None and (self.K is not None or self.estimator is not None)


def missing_constants(needs, constants: Constants) -> str | None:
    """None if every constant named in ``needs`` is known, else the reason in words."""
    missing = [k for k in needs if getattr(constants, k) is None]
    if missing:
        return f"needs the constant(s) {', '.join(missing)}, which the plant does not provide"
    return None


@dataclass(frozen=True, kw_only=True)
class Design:
    """Base class of designs: hyperparameters are dataclass fields; the plant is an argument.

    Subclasses set :attr:`needs` (the constants they require) and implement :meth:`design`.
    """

    #: Constants the design needs (names of :class:`plants.Constants` fields).
    needs = ()

    def applicable(self, plant: Plant, constants: Constants) -> str | None:
        """None if the design applies to ``plant``, else the reason it does not."""
        return missing_constants(self.needs, constants)

    def design(self, plant: Plant, constants: Constants) -> DesignResult:  # pragma: no cover
        """Compute gains for ``plant`` with ``constants``."""
        raise NotImplementedError

    def hyperparameters(self) -> dict[str, Any]:
        """The design's hyperparameters (its dataclass fields)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def describe(self) -> str:
        """The first line of the class docstring."""
        return (type(self).__doc__ or "").strip().splitlines()[0]


def result_dict(res: DesignResult) -> dict[str, Any]:
    """A JSON-friendly dict of a result (arrays as nested lists)."""
    d = asdict(res)
    d["estimator"] = repr(res.estimator) if res.estimator is not None else None
    for k in ("K", "F"):
        if d[k] is not None:
            d[k] = np.asarray(d[k]).tolist()
    return d
