"""The checks of the suite's inputs at its boundary: numbers, horizon, plant and gains.

Each check returns its input converted or raises an error whose message starts with the input's name
(``"t_final: must be finite and > 0, got -1"``): a :class:`ValueError`, or ``error(name, message)`` when
the caller passes one (e.g. ``StudyError``). :func:`argtype` makes a check an ``argparse`` type.
"""

from __future__ import annotations

import argparse
import math
import numbers
from dataclasses import dataclass
from typing import Any, Callable

__all__ = ["ClosedLoop", "argtype", "closed_loop", "gains", "horizon", "integer", "real"]

ErrorFactory = Callable[[str, str], Exception]


def _value_error(name: str, message: str) -> Exception:
    return ValueError(f"{name}: {message}")


def brief(value: Any, limit: int = 80) -> str:
    """``repr(value)`` cut to ``limit`` characters, for messages."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def vector(v, spec: str = ".4g") -> str:
    """A vector for messages: ``(a, b, ...)``, each entry formatted with ``spec``."""
    return "(" + ", ".join(format(float(a), spec) for a in v) + ")"


def real(name: str, value: Any, *, lo: float | None = None, strict: bool = False, hi: float | None = None,
         error: ErrorFactory = _value_error) -> float:
    """``value`` as a finite float with ``lo <= value`` (``lo < value`` if ``strict``) and ``value < hi``.

    Parameters
    ----------
    name : str
        The input's name, first in the message.
    value : object
        A real number (not a bool or a string).
    lo, hi : float, optional
        Bounds (None: none); ``hi`` is always strict.
    strict : bool
        ``lo`` is excluded.
    error : callable, optional
        ``(name, message) -> Exception``; default :class:`ValueError` ``"name: message"``.

    Returns
    -------
    float
    """
    if isinstance(value, (bool, str, bytes)):
        raise error(name, f"expected a real number, got {brief(value)}")
    try:
        v = float(value)
    except (TypeError, ValueError, OverflowError):
        raise error(name, f"expected a real number, got {brief(value)}") from None
    if not math.isfinite(v):
        raise error(name, f"must be finite, got {brief(value)}")
    if (lo is not None and (v < lo or (strict and v == lo))) or (hi is not None and v >= hi):
        bounds = [f"{'>' if strict else '>='} {lo:g}" if lo is not None else "", f"< {hi:g}" if hi is not None else ""]
        raise error(name, f"must be finite and {' and '.join(b for b in bounds if b)}, got {brief(value)}")
    return v


def integer(name: str, value: Any, *, lo: int, error: ErrorFactory = _value_error) -> int:
    """``value`` as an int ``>= lo``: integers only (Python or numpy, not bool), never truncated or parsed."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise error(name, f"expected an integer, got {brief(value)}")
    if int(value) < lo:
        raise error(name, f"must be >= {lo}, got {value!r}")
    return int(value)


def horizon(value: Any, *, default: float | None = None, name: str = "t_final",
            error: ErrorFactory = _value_error) -> float | None:
    """A simulation horizon: ``default`` when ``value`` is None, else a finite number of seconds > 0."""
    if value is None:
        return None if default is None else float(default)
    return real(name, value, lo=0.0, strict=True, error=error)


def gains(plant, K: Any, F: Any, *, optional_K: bool = False):
    """Observer gain K (n x p) and feedback F (m x n) of ``plant`` as float arrays.

    Parameters
    ----------
    plant : Plant
    K, F : array_like
        ``u = F x_hat``; K may be None when ``optional_K`` (a run-time estimator instead).
    optional_K : bool

    Returns
    -------
    K, F : ndarray (K None when it was)

    Raises
    ------
    ValueError
        Naming the matrix, the expected shape and the dimensions, a complex entry (never truncated to
        its real part) or a non-finite entry.
    """
    import numpy as np  # here: the command line's argument types import this module, not numpy

    n, m, p = plant.n, plant.m, plant.p
    out = []
    for name, value, shape, what in (("K", K, (n, p), "n x p"), ("F", F, (m, n), "m x n")):
        if value is None and name == "K" and optional_K:
            out.append(None)
            continue
        arr = _real_array(name, value, f"a real array of shape {shape} ({what})")
        if arr.shape != shape:
            raise ValueError(f"{name}: expected shape {shape} ({what} for plant {plant.id!r} with n={n}, m={m}, "
                             f"p={p}), got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name}: entries must be finite, got {brief(arr.tolist())}")
        out.append(arr)
    return out[0], out[1]


def _real_array(name: str, value: Any, what: str):
    """``value`` as a new float array; ValueError naming ``name`` when it does not convert or has an entry with a
    nonzero imaginary part (a complex dtype whose imaginary parts are all zero converts)."""
    import numpy as np

    try:
        raw = np.asarray(value)
        if raw.dtype.kind == "O":  # Python complex numbers among other objects
            raw = np.asarray(raw.tolist())
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: expected {what}, could not convert ({exc})") from None
    if raw.dtype.kind == "c":
        imag = np.abs(raw.imag)
        if np.any(imag > 0):
            raise ValueError(f"{name}: complex entries (largest imaginary part {float(np.nanmax(imag)):.3g}, e.g. "
                             f"{complex(raw.flat[int(np.nanargmax(imag))]):.4g}): the gains must be real")
        raw = raw.real
    try:
        return np.array(raw, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: expected {what}, could not convert ({exc})") from None


@dataclass(frozen=True)
class ClosedLoop:
    """Checked gains of a plant and the spectra of their linear closed loop, computed once per pair.

    The linear part ``[[A, BF], [KC, A + BF - KC]]`` of the loop (6) is block triangular in ``(x, e)``:
    its eigenvalues are those of ``A + B F`` and ``A - K C``.

    Attributes
    ----------
    K : ndarray (n, p) or None
        None for a run-time estimator.
    F : ndarray (m, n)
    eig_x, eig_e : ndarray
        Eigenvalues of ``A + B F`` and ``A - K C`` (``eig_e`` empty without K).
    linearised_rate : float
        ``-max Re`` of the eigenvalues of ``A + Df(0) + B F`` and ``A + Df(0) - K C``, the rate no
        certificate can beat (NaN without K); for a discrete-time plant (``dt > 0``) ``-ln(max |eig|) / dt``,
        per second as well, so discrete and continuous rows compare (``inf`` for a deadbeat loop).
    dt : float
        The plant's sample time (0: continuous time).

    Notes
    -----
    In discrete time ``x_{k+1} = (A + B F) x_k`` decays like ``max |eig|^k = exp(-lam k dt)`` with
    ``lam = -ln(max |eig|) / dt``: the continuous-time equivalent eigenvalue of ``z`` is ``ln(z) / dt``,
    whose real part is ``ln|z| / dt``. :attr:`growth_x`, :attr:`growth_e` and :attr:`stable` use it.
    """

    K: Any
    F: Any
    eig_x: Any
    eig_e: Any
    linearised_rate: float
    dt: float = 0.0

    def _growth(self, eig) -> float:
        import numpy as np

        if len(eig) == 0:
            return math.nan
        if self.dt > 0:
            with np.errstate(divide="ignore"):
                return float(np.log(np.abs(eig)).max() / self.dt)
        return float(np.real(eig).max())

    @property
    def growth_x(self) -> float:
        """Growth rate per second of ``A + B F``: the largest real part of its eigenvalues (continuous) or
        ``ln(max |eig|) / dt`` (discrete; ``-inf`` for a deadbeat loop). Negative iff ``A + B F`` is stable."""
        return self._growth(self.eig_x)

    @property
    def growth_e(self) -> float:
        """:attr:`growth_x` of ``A - K C`` (NaN without K)."""
        return self._growth(self.eig_e)

    @property
    def stable(self) -> bool | None:
        """Whether ``A + B F`` and ``A - K C`` are Hurwitz (continuous) or Schur (discrete: spectral radius
        < 1); None without K."""
        if self.K is None:
            return None
        return bool(self.growth_x < 0 and self.growth_e < 0)


def closed_loop(plant, K: Any, F: Any, *, optional_K: bool = False) -> ClosedLoop:
    """Check ``K``, ``F`` (:func:`gains`) and compute their :class:`ClosedLoop`."""
    import numpy as np

    from bench._env import parallel

    K, F = gains(plant, K, F, optional_K=optional_K)
    dt = float(getattr(plant, "dt", 0.0) or 0.0)
    if K is None:
        return ClosedLoop(K, F, np.linalg.eigvals(plant.A + plant.B @ F), np.empty(0, dtype=complex), math.nan, dt)
    J = plant.jacobian_at(np.zeros(plant.n))
    loops = [plant.A + plant.B @ F, plant.A - K @ plant.C]
    if np.any(J):
        loops += [plant.A + J + plant.B @ F, plant.A + J - K @ plant.C]
    eigs = parallel([lambda M=M: np.linalg.eigvals(M) for M in loops], plant.n)
    lin = ClosedLoop(K, F, np.concatenate(eigs[-2:]), eigs[1], math.nan, dt).growth_x  # of both linearised loops
    return ClosedLoop(K, F, eigs[0], eigs[1], -lin, dt)


def argtype(check: Callable[..., Any], **bounds: Any) -> Callable[[str], Any]:
    """An ``argparse`` type: the text parsed by ``float`` (``int`` for :func:`integer`), then ``check``."""
    kind = int if check is integer else float

    def parse(text: str):
        def fail(name: str, message: str) -> Exception:
            return argparse.ArgumentTypeError(message)

        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {'an integer' if kind is int else 'a number'}, got {text!r}") \
                from None
        return check("value", value, **bounds, error=fail)

    return parse
