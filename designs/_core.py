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

#: Possible design statuses.
#:
#: - ``feasible``: a feasibility problem (an LMI, or a Riccati equation's existence condition)
#:   was solved and its solution verified;
#: - ``computed``: gains computed by a method that has no feasibility question (LQR, a Kalman
#:   gain): nothing was found feasible;
#: - ``given``: gains (or an estimator's settings) taken as given, nothing solved (printed gains);
#: - ``infeasible``: verified not strictly feasible under the stated normalisation;
#: - ``marginal``: the best margin is within the verification tolerance of zero;
#: - ``inapplicable``: the design does not apply to the plant (the reason says why);
#: - ``undecided``: the solver failed or claimed what its point does not show;
#: - ``error``, ``timeout``: set by the pipeline for a failure or a pair over its ``--timeout``.
STATUSES = ("feasible", "computed", "given", "infeasible", "marginal", "inapplicable", "undecided", "error",
            "timeout")

#: Statuses that come with gains (or an estimator) to simulate and certify.
GAIN_STATUSES = ("feasible", "computed", "given")


def _design_error(name: str, message: str) -> DesignError:
    return DesignError(f"{name}: {message}")


def check_positive(name: str, value: Any, *, allow_zero: bool = False) -> float:
    """Return ``value`` as a finite float ``> 0`` (``>= 0`` with ``allow_zero``), or raise
    :class:`DesignError` naming ``name`` (:func:`bench.checks.real`)."""
    return checks.real(name, value, lo=0.0, strict=not allow_zero, error=_design_error)


def _short(value: Any, limit: int = 80) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def check_int(name: str, value: Any, *, minimum: int) -> int:
    """Return ``value`` as an int ``>= minimum``, or raise :class:`DesignError` naming ``name``
    (:func:`bench.checks.integer`: ``2.5`` or ``"7"`` are rejected rather than truncated or parsed)."""
    return checks.integer(name, value, lo=minimum, error=_design_error)


def _is_sequence(value: Any) -> bool:
    return isinstance(value, (tuple, list)) or (isinstance(value, np.ndarray) and value.ndim == 1)


def check_range(name: str, value: Any, *, strict: bool = True) -> tuple[float, float]:
    """Return ``(lo, hi)`` with ``0 < lo < hi < inf`` (``lo <= hi`` unless ``strict``).

    Raises :class:`DesignError` naming ``name`` for anything else (a scalar, a string, three
    values, a non-finite or non-positive end, reversed ends).
    """
    if not _is_sequence(value) or len(value) != 2:
        raise DesignError(f"{name}: expected a pair (lo, hi) of positive numbers, got {_short(value)}")
    lo, hi = (check_positive(name, v) for v in value)
    if lo > hi or (strict and lo == hi):
        rel = "<" if strict else "<="
        raise DesignError(f"{name}: must be (lo, hi) with lo {rel} hi, got {_short(value)}")
    return lo, hi


def check_values_in(name: str, value: Any, lo: float, hi: float) -> tuple[float, ...]:
    """Return a non-empty sequence of numbers, each in the open interval ``(lo, hi)`` with ``lo >= 0``.

    Raises :class:`DesignError` naming ``name`` otherwise.
    """
    if not _is_sequence(value):
        raise DesignError(f"{name}: expected a sequence of numbers in ({lo:g}, {hi:g}), got {_short(value)}")
    if len(value) == 0:
        raise DesignError(f"{name}: at least one value is needed")
    out = []
    for x in value:
        v = check_positive(name, x, allow_zero=True)
        if not lo < v < hi:
            raise DesignError(f"{name}: each value must be in ({lo:g}, {hi:g}), got {_short(x)}")
        out.append(v)
    return tuple(out)


def check_choice(name: str, value: Any, choices: tuple[str, ...]) -> str:
    """Return ``value`` if it is one of the strings ``choices``, else raise :class:`DesignError`."""
    if not isinstance(value, str) or value not in choices:
        raise DesignError(f"{name}: must be one of {', '.join(repr(c) for c in choices)}, got {_short(value)}")
    return value


def check_hyperparameter_names(cls: type, args: tuple, kwargs: dict) -> None:
    """Reject positional arguments and unknown keyword hyperparameters of a dataclass design or part.

    Called from ``__new__``, before the dataclass ``__init__`` (which would raise a bare
    ``TypeError``); the :class:`DesignError` names the unknown parameter and suggests a close
    match.
    """
    known = [k for k, f in getattr(cls, "__dataclass_fields__", {}).items() if f.init]
    if args:
        raise DesignError(f"{cls.__name__}: hyperparameters are keyword-only ({', '.join(known) or 'none'}), "
                          f"got {len(args)} positional argument(s)")
    if not hasattr(cls, "__dataclass_fields__"):
        return
    for key in kwargs:
        if key not in known:
            close = difflib.get_close_matches(str(key), known, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            shown = key if key.isidentifier() else repr(key)
            raise DesignError(f"{shown}: unknown hyperparameter of {cls.__name__} "
                              f"(valid: {', '.join(known) or 'none'}){hint}")


@dataclass
class DesignResult:
    """Gains plus the evidence behind them.

    Attributes
    ----------
    status : str
        One of :data:`STATUSES`.
    reason : str
        Why, in words (always set unless feasible).
    route : str
        How the gains were produced: ``"sdp"`` (an LMI solved by an SDP solver), ``"riccati"``
        (algebraic Riccati equations), ``"formula"`` (a closed form, e.g. LQR), ``"given"``.
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
    certificate : dict, optional
        The design's own joint certificate, verified by the design with numpy: ``level`` (the
        certificate ladder's level whose knowledge it uses), ``P`` (2n x 2n, ``V = z' P z``),
        ``decay_rate``, ``margin``, ``radius``, ``how``. The pipeline keeps it where the ladder's
        own LMI certifies less (or cannot run, for large n).
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


def missing_constants(needs, constants: Constants) -> str | None:
    """None if every constant named in ``needs`` is known, else the reason in words."""
    missing = [k for k in needs if getattr(constants, k) is None]
    if missing:
        return f"needs the constant(s) {', '.join(missing)}, which the plant does not provide"
    return None


@dataclass(frozen=True, kw_only=True)
class Configurable:
    """Base of designs and design parts: hyperparameters are keyword-only dataclass fields.

    Unknown or positional hyperparameters raise :class:`DesignError` naming them (before the
    dataclass ``__init__`` would raise a bare ``TypeError``). Subclasses set :attr:`needs`, the
    constants they require.
    """

    #: Constants required (names of :class:`plants.Constants` fields).
    needs = ()

    def __new__(cls, *args: Any, **kwargs: Any):
        check_hyperparameter_names(cls, args, kwargs)
        return super().__new__(cls)

    def applicable(self, plant: Plant, constants: Constants) -> str | None:
        """None if this applies to ``plant`` with ``constants``, else the reason it does not."""
        return missing_constants(self.needs, constants)


@dataclass(frozen=True, kw_only=True)
class Design(Configurable):
    """Base class of designs: hyperparameters are dataclass fields; the plant is an argument.

    Subclasses set :attr:`needs` and implement :meth:`design`.
    """

    def design(self, plant: Plant, constants: Constants) -> DesignResult:  # pragma: no cover
        """Compute gains for ``plant`` with ``constants``."""
        raise NotImplementedError
