"""The design interface: a design maps a plant (and its constants) to gains plus evidence.

Nothing here simulates. Infeasibility is a result (a status with a reason), not an exception.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench import checks
from bench.errors import DesignError
from plants import Constants, Plant

#: Design statuses: ``feasible`` (a feasibility problem solved and verified), ``computed`` (gains with no
#: feasibility question: LQR, Kalman), ``given`` (printed gains), ``unverified`` (set by the pipeline: a design
#: from outside the suite's package said "feasible", which the suite did not verify), ``infeasible`` (under
#: the stated normalisation), ``marginal`` (best margin within the verification tolerance of zero),
#: ``inapplicable``, ``undecided`` (solver trouble), ``error`` and ``timeout`` (set by the pipeline).
STATUSES = ("feasible", "computed", "given", "unverified", "infeasible", "marginal", "inapplicable", "undecided",
            "error", "timeout")

#: Statuses that come with gains (or an estimator) to simulate and certify.
GAIN_STATUSES = ("feasible", "computed", "given", "unverified")


def _design_error(name: str, message: str) -> DesignError:
    return DesignError(f"{name}: {message}")


def check_positive(name: str, value: Any, *, allow_zero: bool = False) -> float:
    """``value`` as a finite float ``> 0`` (``>= 0`` with ``allow_zero``), else a :class:`DesignError`."""
    return checks.real(name, value, lo=0.0, strict=not allow_zero, error=_design_error)


def check_int(name: str, value: Any, *, minimum: int) -> int:
    """``value`` as an int ``>= minimum`` (never truncated or parsed), else a :class:`DesignError`."""
    return checks.integer(name, value, lo=minimum, error=_design_error)


def _is_sequence(value: Any) -> bool:
    return isinstance(value, (tuple, list)) or (isinstance(value, np.ndarray) and value.ndim == 1)


def check_range(name: str, value: Any, *, strict: bool = True) -> tuple[float, float]:
    """``(lo, hi)`` with ``0 < lo < hi < inf`` (``lo <= hi`` unless ``strict``), else a :class:`DesignError`."""
    if not _is_sequence(value) or len(value) != 2:
        raise DesignError(f"{name}: expected a pair (lo, hi) of positive numbers, got {checks.brief(value)}")
    lo, hi = (check_positive(name, v) for v in value)
    if lo > hi or (strict and lo == hi):
        rel = "<" if strict else "<="
        raise DesignError(f"{name}: must be (lo, hi) with lo {rel} hi, got {checks.brief(value)}")
    return lo, hi


def check_values_in(name: str, value: Any, lo: float, hi: float) -> tuple[float, ...]:
    """A non-empty sequence of numbers, each in the open interval ``(lo, hi)``, else a :class:`DesignError`."""
    if not _is_sequence(value):
        raise DesignError(f"{name}: expected a sequence of numbers in ({lo:g}, {hi:g}), got {checks.brief(value)}")
    if len(value) == 0:
        raise DesignError(f"{name}: at least one value is needed")
    out = []
    for x in value:
        v = check_positive(name, x, allow_zero=True)
        if not lo < v < hi:
            raise DesignError(f"{name}: each value must be in ({lo:g}, {hi:g}), got {checks.brief(x)}")
        out.append(v)
    return tuple(out)


def check_choice(name: str, value: Any, choices: tuple[str, ...]) -> str:
    """Return ``value`` if it is one of the strings ``choices``, else raise :class:`DesignError`."""
    if not isinstance(value, str) or value not in choices:
        raise DesignError(f"{name}: must be one of {', '.join(repr(c) for c in choices)}, got {checks.brief(value)}")
    return value


@dataclass
class DesignResult:
    """Gains plus the evidence behind them.

    Attributes
    ----------
    K, F : ndarray or None
        Observer gain (n x p) and feedback gain (m x n), ``u = F x_hat``.
    status : str
        One of :data:`STATUSES`.
    reason : str
        Why, in words (always set unless feasible).
    route : str
        ``"sdp"`` (an LMI), ``"riccati"`` (algebraic Riccati equations), ``"formula"`` (e.g. LQR), ``"given"``.
    solver, solver_status : str or None
        The SDP solver and its final status.
    compile_s, solve_s : float
        Seconds compiling (cvxpy canonicalisation) and solving, summed over all solves.
    n_solves : int
        Number of LMI solves.
    margin : float
        Largest eigenvalue of the numeric LMI matrix recomputed at the solution (negative: strictly
        feasible; NaN without an LMI).
    lmi_size : int
        Dimension of the LMI matrix.
    min_eig : dict
        Smallest eigenvalues of the decision matrices (e.g. ``{"Q": .., "R": ..}``).
    params : dict
        Every scalar the design used (fixed, searched or solved for).
    estimator : object, optional
        A run-time estimator (e.g. :class:`designs.ekf.EKFSpec`) instead of a fixed gain K.
    certificate : dict, optional
        The design's own certificate: ``level``, ``P`` (2n x 2n, ``V = z' P z``), ``decay_rate``, ``how``,
        optionally ``uses`` (the declarations it rests on), ``multipliers`` (in the level's variable
        names) or ``joint`` (``P``, ``R``, ``mu``, ``s``, ``t`` of :mod:`bench.joint`); verified by the suite
        (:func:`bench.certify.verify_certificate`) and kept where the ladder certifies less. On a discrete
        plant also ``contraction`` (``r``: ``V(z_{k+1}) <= r^2 V(z_k)``; ``decay_rate = -ln(r) / dt``). An
        H-infinity design's bounded-real certificate has ``level = "l2"`` (not a decay level: the ladder's
        adoption ignores it) with ``P``, ``gamma_x`` and ``how``.
    """

    status: str
    reason: str = ""
    route: str = ""
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
    certificate: dict | None = None

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"status: must be one of {STATUSES}, got {self.status!r}")

    @property
    def has_gains(self) -> bool:
        """True when both fixed gains K and F are present."""
        return self.K is not None and self.F is not None

    @property
    def has_controller(self) -> bool:
        """True when there is a feedback F and an estimator (a gain K or a run-time estimator)."""
        return self.status in GAIN_STATUSES and self.F is not None and (self.K is not None or
                                                                         self.estimator is not None)


@dataclass(frozen=True, kw_only=True)
class Configurable:
    """Base of designs and design parts: hyperparameters are keyword-only dataclass fields (unknown or
    positional ones raise :class:`DesignError`); :attr:`needs` names the constants required.
    """

    #: Constants required (names of :class:`plants.Constants` fields).
    needs = ()
    #: The time domains this has a form for: ``"continuous"`` (``plant.dt == 0``) and/or ``"discrete"``
    #: (``plant.dt > 0``, ``x_{k+1} = A x_k + B u_k + f(x_k)``). The pipeline marks a discrete plant's pair
    #: "inapplicable: no discrete-time form" when ``"discrete"`` is missing.
    time_domains = ("continuous",)

    def __new__(cls, *args: Any, **kwargs: Any):
        # positional and unknown hyperparameters: a DesignError naming the parameter and a close match, before
        # the bare TypeError of the dataclass __init__
        known = [k for k, f in cls.__dataclass_fields__.items() if f.init]
        if args:
            raise DesignError(f"{cls.__name__}: hyperparameters are keyword-only ({', '.join(known) or 'none'}), "
                              f"got {len(args)} positional argument(s)")
        for key in kwargs:
            if key not in known:
                close = difflib.get_close_matches(str(key), known, n=1)
                hint = f"; did you mean {close[0]!r}?" if close else ""
                shown = key if key.isidentifier() else repr(key)
                raise DesignError(f"{shown}: unknown hyperparameter of {cls.__name__} "
                                  f"(valid: {', '.join(known) or 'none'}){hint}")
        return super().__new__(cls)

    def applicable(self, plant: Plant, constants: Constants) -> str | None:
        """None if this applies to ``plant`` with ``constants``, else the reason it does not (a constant missing)."""
        missing = [k for k in self.needs if getattr(constants, k) is None]
        return f"needs the constant(s) {', '.join(missing)}, which the plant does not provide" if missing else None


@dataclass(frozen=True, kw_only=True)
class Design(Configurable):
    """Base class of designs: hyperparameters are dataclass fields; subclasses implement :meth:`design`."""

    def design(self, plant: Plant, constants: Constants) -> DesignResult:  # pragma: no cover
        """Compute gains for ``plant`` with ``constants``."""
        raise NotImplementedError
