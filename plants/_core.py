"""The plant type: x' = A x + B u + f(x), y = C x, validated when built.

A plant is data plus the nonlinearity ``f`` (and optionally its Jacobian). Nothing in this
package solves LMIs or simulates: that is the job of ``designs`` and ``bench``.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, fields
from typing import Callable, Mapping

import numpy as np

__all__ = ["Constants", "Plant", "PlantError"]


class PlantError(ValueError):
    """A plant (or one of its fields) is invalid. The message names the field."""


def _finite_scalar(name: str, value, *, allow_none: bool = True, positive: bool = False):
    if value is None:
        if allow_none:
            return None
        raise PlantError(f"{name}: a number is required, got None")
    try:
        v = float(value)
    except (TypeError, ValueError, OverflowError):
        raise PlantError(f"{name}: expected a finite real number, got {_short(value)}") from None
    if not math.isfinite(v):
        raise PlantError(f"{name}: must be finite, got {v}")
    if positive and v <= 0:
        raise PlantError(f"{name}: must be > 0, got {v}")
    return v


@dataclass(frozen=True, kw_only=True)
class Constants:
    """Constants of the nonlinearity f, any of which may be unknown (None).

    Parameters
    ----------
    alpha : float, optional
        Lipschitz constant, ``||f(x1) - f(x2)|| <= alpha ||x1 - x2||`` (2).
    rho : float, optional
        One-sided Lipschitz constant, ``<f(x1) - f(x2), x1 - x2> <= rho ||x1 - x2||^2`` (3).
    beta, gamma : float, optional
        Quadratic inner-boundedness pair,
        ``||df||^2 <= beta ||dx||^2 + gamma <dx, df>`` (4). Both or neither.
    radius : float, optional
        The constants hold on the ball ``||x|| <= radius``; None means globally.
    """

    alpha: float | None = None
    rho: float | None = None
    beta: float | None = None
    gamma: float | None = None
    radius: float | None = None

    def __post_init__(self) -> None:
        for name in ("alpha", "rho", "beta", "gamma"):
            object.__setattr__(self, name, _finite_scalar(f"constants.{name}", getattr(self, name)))
        object.__setattr__(
            self, "radius", _finite_scalar("constants.radius", self.radius, positive=True)
        )
        if self.alpha is not None and self.alpha < 0:
            raise PlantError(f"constants.alpha: a Lipschitz constant is >= 0, got {self.alpha}")
        if (self.beta is None) != (self.gamma is None):
            raise PlantError("constants.beta/gamma: the QIB pair needs both beta and gamma (or neither)")

    @property
    def has_osl(self) -> bool:
        """True when rho, beta and gamma are all known (Theorem 1 needs them)."""
        return self.rho is not None and self.beta is not None and self.gamma is not None

    def as_dict(self) -> dict[str, float | None]:
        """The constants as a plain dict (for tables and JSON)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def _short(value, limit: int = 80) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _real_array(value) -> np.ndarray:
    """``np.array(value, dtype=float)``, refusing complex values (numpy would drop the imaginary part)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", np.exceptions.ComplexWarning)
        return np.array(value, dtype=float)


def _matrix(name: str, value, *, ndim: int = 2) -> np.ndarray:
    try:
        arr = _real_array(value)
    except (TypeError, ValueError, OverflowError, np.exceptions.ComplexWarning) as exc:
        raise PlantError(f"{name}: not a real numeric array ({exc})") from None
    if ndim == 2 and arr.ndim == 1:
        raise PlantError(f"{name}: expected a 2-D matrix, got a 1-D array of shape {arr.shape}")
    if arr.ndim != ndim:
        raise PlantError(f"{name}: expected {ndim}-D, got shape {arr.shape}")
    if arr.size == 0:
        raise PlantError(f"{name}: is empty (shape {arr.shape})")
    if not np.all(np.isfinite(arr)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise PlantError(f"{name}: entries must be finite; {name}{list(bad)} = {arr[bad]}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, kw_only=True)
class Plant:
    """A plant ``x' = A x + B u + f(x)``, ``y = C x`` with ``f(0) = 0``.

    Parameters
    ----------
    id : str
        Registry id.
    A, B, C : array_like
        System matrices, shapes (n, n), (n, m), (p, n).
    f : callable
        Nonlinearity. Must accept a state of shape (n,) and return (n,), and accept a batch
        of shape (n, N) and return (n, N).
    x0, x_hat0 : array_like
        Initial state and initial estimate, shape (n,).
    jacobian : callable, optional
        ``jacobian(x) -> (n, n)``, the Jacobian of f (used by the EKF).
    claimed : Constants
        Constants as the source claims them (kept as claimed, right or wrong).
    bounds : Constants, optional
        Analytic, valid constants where known (used by designs in preference to sampling).
    t_final : float
        Simulation horizon in seconds.
    family : str
        Plant family (e.g. ``"flexible_link"``); designs tied to one family check it.
    params : mapping
        The scalar parameters the plant was built with (e.g. the scale ``c`` of f).
    source, notes : str
        Citation and remarks.

    Raises
    ------
    PlantError
        On inconsistent shapes, non-finite entries, ``f(0) != 0`` or an f returning a wrong
        shape; the message names the field.
    """

    id: str
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    f: Callable[[np.ndarray], np.ndarray]
    x0: np.ndarray
    x_hat0: np.ndarray
    jacobian: Callable[[np.ndarray], np.ndarray] | None = None
    claimed: Constants = field(default_factory=Constants)
    bounds: Constants | None = None
    t_final: float = 20.0
    family: str = ""
    params: Mapping[str, float] = field(default_factory=dict)
    source: str = ""
    notes: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.id, str) or not self.id:
            raise PlantError(f"id: a non-empty string is required, got {self.id!r}")
        A = _matrix("A", self.A)
        B = _matrix("B", self.B)
        C = _matrix("C", self.C)
        n = A.shape[0]
        if A.shape != (n, n):
            raise PlantError(f"A: must be square, got shape {A.shape}")
        if B.shape[0] != n:
            raise PlantError(f"B: must have n = {n} rows (A is {A.shape}), got shape {B.shape}")
        if C.shape[1] != n:
            raise PlantError(f"C: must have n = {n} columns (A is {A.shape}), got shape {C.shape}")
        x0 = _matrix("x0", self.x0, ndim=1)
        xh0 = _matrix("x_hat0", self.x_hat0, ndim=1)
        for name, v in (("x0", x0), ("x_hat0", xh0)):
            if v.shape != (n,):
                raise PlantError(f"{name}: expected shape ({n},) to match A {A.shape}, got {v.shape}")
        for name, value in (("A", A), ("B", B), ("C", C), ("x0", x0), ("x_hat0", xh0)):
            object.__setattr__(self, name, value)
        t_final = _finite_scalar("t_final", self.t_final, allow_none=False, positive=True)
        object.__setattr__(self, "t_final", t_final)
        if not isinstance(self.claimed, Constants):
            raise PlantError(f"claimed: expected a Constants, got {type(self.claimed).__name__}")
        if self.bounds is not None and not isinstance(self.bounds, Constants):
            raise PlantError(f"bounds: expected a Constants or None, got {type(self.bounds).__name__}")
        try:
            object.__setattr__(self, "params", dict(self.params))
        except (TypeError, ValueError):
            raise PlantError(f"params: expected a mapping of parameter names to numbers, "
                             f"got {_short(self.params)}") from None
        for key, val in self.params.items():
            _finite_scalar(f"params[{key!r}]", val, allow_none=False)
        self._check_f(n)

    def _check_f(self, n: int) -> None:
        if not callable(self.f):
            raise PlantError(f"f: must be callable, got {type(self.f).__name__}")
        checks = (
            ("f(0)", np.zeros(n), (n,)),
            ("f(x0)", np.array(self.x0), (n,)),
            ("f(batch)", np.stack([self.x0, self.x_hat0, np.zeros(n)], axis=1), (n, 3)),
        )
        for label, arg, shape in checks:
            try:
                raw = self.f(arg)
            except Exception as exc:  # the user's f failed: say where
                raise PlantError(f"f: raised {type(exc).__name__} when evaluating {label}: {exc}") from exc
            try:
                out = _real_array(raw)
            except Exception as exc:  # None, a string, complex values, ...: not a real array
                raise PlantError(f"f: {label} is not a real numeric array ({type(exc).__name__}: {exc}); "
                                 f"got {_short(raw)}") from None
            if out.shape != shape:
                raise PlantError(f"f: {label} must have shape {shape}, got {out.shape}")
            if not np.all(np.isfinite(out)):
                raise PlantError(f"f: {label} is not finite: {out}")
            if label == "f(0)" and np.linalg.norm(out) > 1e-12:
                raise PlantError(f"f: f(0) must be 0 (origin an equilibrium), got {out}")
        if self.jacobian is not None:
            if not callable(self.jacobian):
                raise PlantError("jacobian: must be callable or None")
            try:
                raw = self.jacobian(np.array(self.x0))
            except Exception as exc:
                raise PlantError(f"jacobian: raised {type(exc).__name__} at x0: {exc}") from exc
            try:
                J = _real_array(raw)
            except Exception as exc:
                raise PlantError(f"jacobian: not a real numeric array at x0 ({type(exc).__name__}: {exc}); "
                                 f"got {_short(raw)}") from None
            if J.shape != (n, n):
                raise PlantError(f"jacobian: must return shape ({n}, {n}), got {J.shape}")
            if not np.all(np.isfinite(J)):
                raise PlantError(f"jacobian: not finite at x0: {J}")

    @property
    def n(self) -> int:
        """Number of states."""
        return self.A.shape[0]

    @property
    def m(self) -> int:
        """Number of inputs."""
        return self.B.shape[1]

    @property
    def p(self) -> int:
        """Number of outputs."""
        return self.C.shape[0]

    def summary(self) -> str:
        """One line: id, dimensions and source."""
        return f"{self.id}: n={self.n}, m={self.m}, p={self.p}; {self.source}"
