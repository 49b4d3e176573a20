"""The plant type: x' = A x + B u + f(x), y = C x, validated when built; the constants and channels of f."""

from __future__ import annotations

import dataclasses
import math
import numbers
import re
import warnings
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from bench import checks
from bench.errors import PlantError, RegistryError
from bench.registry import check_id


def _finite_scalar(name: str, value, *, positive: bool = False):
    """``value`` as a finite float (> 0 if ``positive``), None passed through."""
    return None if value is None else check_real(name, value, lo=0.0 if positive else None, strict=positive)


def check_int(name: str, value, lo: int, hi: int | None = None, *, what: str = "") -> int:
    """``value`` as an int in ``[lo, hi]`` (a float with an integer value too; not bool), else
    :class:`PlantError`; ``what`` describes the parameter in the message."""
    if isinstance(value, bool) or not isinstance(value, (numbers.Integral, float)) \
            or isinstance(value, float) and not (math.isfinite(value) and value.is_integer()):
        raise PlantError(f"{name}: {what}must be an integer, got {value!r}")
    v = int(value)
    if v < lo or (hi is not None and v > hi):
        rng = f">= {lo}" if hi is None else f"between {lo} and {hi}"
        raise PlantError(f"{name}: {what}must be {rng}, got {value!r}")
    return v


def check_real(name: str, value, *, lo: float | None = None, strict: bool = False) -> float:
    """:func:`bench.checks.real` raising :class:`PlantError`."""
    return checks.real(name, value, lo=lo, strict=strict,
                       error=lambda name, message: PlantError(f"{name}: {message}"))


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
        for name in ("alpha", "rho", "beta", "gamma", "radius"):
            object.__setattr__(self, name, _finite_scalar(f"constants.{name}", getattr(self, name),
                                                          positive=name == "radius"))
        if self.alpha is not None and self.alpha < 0:
            raise PlantError(f"constants.alpha: a Lipschitz constant is >= 0, got {self.alpha}")
        if (self.beta is None) != (self.gamma is None):
            raise PlantError("constants.beta/gamma: the QIB pair needs both beta and gamma (or neither)")


@dataclass(frozen=True, kw_only=True)
class Channels:
    """The nonlinearity as slope-restricted channels: ``f(x) = G phi(H x)``, phi acting channel-wise.

    Channel i maps ``z_i = (H x)_i`` to ``phi_i(z_i)`` with ``phi(0) = 0`` and
    ``lo_i <= (phi_i(a) - phi_i(b)) / (a - b) <= hi_i`` for all ``a != b`` (globally, or while
    ``||x|| <= radius``); see ``docs/structured.md``.

    Parameters
    ----------
    G : array_like, shape (n, q)
        Where each channel acts.
    H : array_like, shape (q, n)
        What each channel reads.
    phi : callable
        ``phi(z)`` for ``z`` of shape (q,) or a batch (q, N), returning the same shape.
    lo, hi : float or array_like, shape (q,)
        Slope bounds of each channel (a scalar applies to every channel); ``lo <= hi``.
    radius : float, optional
        The slopes hold on the ball ``||x|| <= radius``, so channel i's on ``|z_i| <= radius ||H_i||``
        (:attr:`reach`); None means globally.
    narrow : callable, optional
        ``narrow(r) -> (lo_r, hi_r)`` (scalars or shape (q,)): analytic slopes of each channel on
        ``|z_i| <= r`` (e.g. :func:`sine_slopes`), for certificates on that region; beyond a channel's
        reach they are all a certificate uses there (:meth:`slopes_on`).
    """

    G: np.ndarray
    H: np.ndarray
    phi: Callable[[np.ndarray], np.ndarray]
    lo: np.ndarray | float
    hi: np.ndarray | float
    radius: float | None = None
    narrow: Callable[[float], tuple] | None = None

    def __post_init__(self) -> None:
        if self.narrow is not None and not callable(self.narrow):
            raise PlantError(f"channels.narrow: must be callable r -> (lo, hi) or None, got {type(self.narrow).__name__}")
        G, H = (_matrix(f"channels.{name}", getattr(self, name)) for name in "GH")
        q = G.shape[1]
        if H.shape[0] != q:
            raise PlantError(f"channels.H: must have q = {q} rows (G is {G.shape}), got shape {H.shape}")
        if not callable(self.phi):
            raise PlantError(f"channels.phi: must be callable, got {type(self.phi).__name__}")
        bounds = []
        for name in ("lo", "hi"):
            v = getattr(self, name)
            try:
                arr = _real_array(v)
            except (TypeError, ValueError, OverflowError, np.exceptions.ComplexWarning):
                raise PlantError(f"channels.{name}: not a real number or array, got {checks.brief(v)}") from None
            arr = np.broadcast_to(arr, (q,)).copy() if arr.ndim == 0 else arr
            if arr.shape != (q,):
                raise PlantError(f"channels.{name}: expected a scalar or shape ({q},), got {arr.shape}")
            if not np.all(np.isfinite(arr)):
                raise PlantError(f"channels.{name}: slope bounds must be finite, got {arr.tolist()}")
            arr.setflags(write=False)
            bounds.append(arr)
        lo, hi = bounds
        bad = np.nonzero(lo > hi)[0]
        if bad.size:
            i = int(bad[0])
            raise PlantError(f"channels.lo/hi: channel {i} has lo = {lo[i]:g} > hi = {hi[i]:g}")
        for name, value in (("G", G), ("H", H), ("lo", lo), ("hi", hi)):
            object.__setattr__(self, name, value)
        object.__setattr__(self, "radius", _finite_scalar("channels.radius", self.radius, positive=True))

    @property
    def q(self) -> int:
        """Number of channels."""
        return self.G.shape[1]

    @property
    def center(self) -> np.ndarray:
        """Mid slopes ``c0 = (lo + hi) / 2`` (the loop transformation's linear part)."""
        return (self.lo + self.hi) / 2

    @property
    def spread(self) -> np.ndarray:
        """Half widths ``r = (hi - lo) / 2``: ``|psi_i(a) - psi_i(b)| <= r_i |a - b|``."""
        return (self.hi - self.lo) / 2

    @property
    def reach(self) -> np.ndarray:
        """How far each channel's declared slopes ``[lo_i, hi_i]`` hold: ``|z_i| <= radius ||H_i||`` (the inputs
        ``(H x)_i`` of ``||x|| <= radius``; phi acts channel-wise), infinite for global channels."""
        if self.radius is None:
            return np.full(self.q, np.inf)
        return self.radius * np.linalg.norm(self.H, axis=1)

    def slopes_on(self, r: float) -> tuple[np.ndarray, np.ndarray] | None:
        """Slope bounds of each channel on ``|z_i| <= r`` (None without a narrowing): ``narrow(r)`` intersected
        with ``[lo, hi]`` where the declared slopes hold (``r <=`` :attr:`reach`), ``narrow(r)`` alone beyond;
        PlantError when ``narrow(r)`` is not a valid pair."""
        if self.narrow is None:
            return None
        try:
            lo_r, hi_r = (np.broadcast_to(_real_array(v), (self.q,)) for v in self.narrow(float(r)))
        except Exception as exc:
            raise PlantError(f"channels.narrow: narrow({r:g}) must return (lo, hi), scalars or shape ({self.q},): "
                             f"{type(exc).__name__}: {exc}") from None
        held = r <= self.reach
        lo, hi = np.where(held, np.maximum(self.lo, lo_r), lo_r), np.where(held, np.minimum(self.hi, hi_r), hi_r)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo <= hi)):
            raise PlantError(f"channels.narrow: narrow({r:g}) gives slopes {lo_r.tolist()}, {hi_r.tolist()} that are "
                             f"not finite or leave no slope inside [lo, hi]")
        return lo, hi

    def apply(self, x: np.ndarray) -> np.ndarray:
        """``G phi(H x)`` for a state (n,) or a batch (n, N)."""
        return self.G @ np.asarray(self.phi(self.H @ np.asarray(x, dtype=float)), dtype=float)


def sine_slopes(coef: float) -> Callable[[float], tuple[float, float]]:
    """Slopes of ``phi(z) = coef sin(z)`` on ``|z| <= r``: ``coef`` times ``[cos(min(r, pi)), 1]``
    (the secant of sin is ``cos(xi)`` for some ``|xi| <= r``)."""
    def narrow(r: float) -> tuple[float, float]:
        ends = (coef, coef * math.cos(min(r, math.pi)))
        return min(ends), max(ends)
    return narrow


def saturation_slopes(k: float) -> Callable[[float], tuple[float, float]]:
    """Slopes of ``phi(z) = k sat(z)`` (unit saturation) on ``|z| <= r``: exactly ``k`` for
    ``r <= 1`` (the linear zone), between ``0`` and ``k`` beyond."""
    def narrow(r: float) -> tuple[float, float]:
        return (k, k) if r <= 1.0 else (min(k, 0.0), max(k, 0.0))
    return narrow


def cubic_slopes(c: float) -> Callable[[float], tuple[float, float]]:
    """Slopes of ``phi(z) = -c z^3`` on ``|z| <= r``: the secant ``-c (a^2 + a b + b^2)`` lies in
    ``[-3 c r^2, 0]`` for ``c >= 0`` (``a^2 + a b + b^2`` is in ``[0, 3 r^2]``)."""
    def narrow(r: float) -> tuple[float, float]:
        ends = (-3.0 * c * r * r, 0.0)
        return min(ends), max(ends)
    return narrow


def sine_terms(n: int, acts, reads, coef: float, *, scale: float = 1.0) -> dict:
    """Sine terms ``f_{acts[l]}(x) = (coef / scale) sin(x_{reads[l]})``: a pendulum (gravity) per channel.

    Parameters
    ----------
    n : int
        Number of states.
    acts, reads : sequence of int
        The states each term acts on and reads; each sequence without repeats, and no state in
        both (the bound on rho below needs it).
    coef : float
        Coefficient of the sine in the channels: ``phi_l(z) = coef sin(z)``, slope in ``[-|coef|, |coef|]``.
    scale : float
        Divides every term (a mass): ``G = E_acts / scale``.

    Returns
    -------
    dict
        The :class:`Plant` fields ``f``, ``jacobian``, ``channels``, ``bounds``. Global constants,
        ``a = |coef| / scale``: alpha = a (``|sin u - sin v| <= |u - v|``); rho = a / 2, since
        ``<df, dx> = a sum_l s_l d_{acts[l]}`` with ``|s_l| <= |d_{reads[l]}|`` and ``|d_i d_j| <=
        (d_i^2 + d_j^2) / 2`` over disjoint pairs; ``(beta, gamma) = (a^2, 0)``. Channels
        ``G = E_acts / scale``, ``H = E_reads'`` (none without a term).

    Raises
    ------
    PlantError
        If ``acts`` and ``reads`` differ in length, repeat a state or share one.
    """
    acts = np.asarray(acts, dtype=np.intp).reshape(-1)
    reads = np.asarray(reads, dtype=np.intp).reshape(-1)
    if acts.size != reads.size or len(set(acts.tolist()) | set(reads.tolist())) != 2 * acts.size:
        raise PlantError(f"sine terms: acts {acts.tolist()} and reads {reads.tolist()} must have the same length, "
                         "no repeats and no common state")
    gain = coef / scale
    put, take = _as_slice(acts, n), _as_slice(reads, n)

    def f(x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        out = np.empty_like(x)  # np.zeros_like's layout without its cost (f is on a simulation's every step)
        out.fill(0.0)
        if x.shape[:1] == (n,):  # the same entries by slices (views) where they can: cheaper than fancy indexing
            out[put] = gain * np.sin(x[take])
        else:  # fancy indexing: a wrong shape fails as it always did
            out[acts] = gain * np.sin(x[reads])
        return out

    def jacobian(x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float).reshape(-1)
        J = np.zeros((n, n))
        J[acts, reads] = gain * np.cos(x[reads])
        return J

    q = acts.size
    channels = None
    if q:
        G = np.zeros((n, q))
        G[acts, np.arange(q)] = 1.0 / scale
        H = np.zeros((q, n))
        H[np.arange(q), reads] = 1.0
        channels = Channels(G=G, H=H, phi=lambda z: coef * np.sin(z), lo=-abs(coef), hi=abs(coef),
                            narrow=sine_slopes(coef))
    a = abs(coef) / scale if q else 0.0
    return {"f": f, "jacobian": jacobian, "channels": channels,
            "bounds": Constants(alpha=a, rho=a / 2, beta=a**2, gamma=0.0)}


def _as_slice(index: np.ndarray, n: int):
    """``index`` (distinct states in ``0..n-1``) as a slice selecting the same rows in the same order when it is
    an increasing arithmetic progression (one state, a run, every k-th), else ``index`` itself."""
    i = index.tolist()
    if not i or not all(0 <= v < n for v in i):
        return index
    step = i[1] - i[0] if len(i) > 1 else 1
    if step <= 0 or any(b - a != step for a, b in zip(i, i[1:])):
        return index
    return slice(i[0], i[-1] + 1, step)


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
        Analytic, valid constants where known (used by designs in preference to sampling,
        and by certificates; constants that were only sampled never certify).
    channels : Channels, optional
        The nonlinearity as slope-restricted channels ``f(x) = G phi(H x)``, when known
        (checked against f on seeded samples when the plant is built).
    t_final : float
        Simulation horizon in seconds.
    dt : float
        Sample time in seconds: 0 (the default) for a continuous-time plant ``x' = A x + B u + f(x)``,
        ``dt > 0`` for a discrete-time plant ``x_{k+1} = A x_k + B u_k + f(x_k)`` sampled every ``dt``
        seconds (as python-control's ``StateSpace.dt``).
    Bw, Dw : array_like, optional
        Disturbance inputs, shapes (n, q) and (p, q): ``x' = A x + B u + f(x) + Bw w``,
        ``y = C x + Dw w``. Either alone is allowed (the other is zero); None for both: no disturbance.
    family : str
        Plant family (e.g. ``"flexible_link"``); designs tied to one family check it.
    params : mapping
        The scalar parameters the plant was built with (e.g. the scale ``c`` of f).
    source, notes : str
        Citation and remarks.
    state_names : sequence of str, optional
        One label per state with its unit in brackets (``"theta_m [rad]"``; ``[-]``: no unit), for figures and
        the plant's page; None: ``x1 ... xn``.

    Raises
    ------
    PlantError
        Naming the field: bad shapes or entries, ``f(0) != 0``, an f that is not deterministic,
        writes into its argument or mixes a batch's columns, a Jacobian that is not f's
        derivative, channels that do not reproduce f.
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
    channels: Channels | None = None
    t_final: float = 20.0
    dt: float = 0.0
    Bw: np.ndarray | None = None
    Dw: np.ndarray | None = None
    family: str = ""
    params: Mapping[str, float] = field(default_factory=dict)
    source: str = ""
    notes: str = ""
    state_names: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        try:
            check_id(self.id, "plant")
        except RegistryError as exc:
            raise PlantError(f"id: {exc}") from None
        A, B, C = (_matrix(name, getattr(self, name)) for name in "ABC")
        n = A.shape[0]
        if A.shape != (n, n):
            raise PlantError(f"A: must be square, got shape {A.shape}")
        if B.shape[0] != n:
            raise PlantError(f"B: must have n = {n} rows (A is {A.shape}), got shape {B.shape}")
        if C.shape[1] != n:
            raise PlantError(f"C: must have n = {n} columns (A is {A.shape}), got shape {C.shape}")
        x0, xh0 = (_matrix(name, getattr(self, name), ndim=1) for name in ("x0", "x_hat0"))
        for name, v in (("x0", x0), ("x_hat0", xh0)):
            if v.shape != (n,):
                raise PlantError(f"{name}: expected shape ({n},) to match A {A.shape}, got {v.shape}")
        for name, value in (("A", A), ("B", B), ("C", C), ("x0", x0), ("x_hat0", xh0)):
            object.__setattr__(self, name, value)
        object.__setattr__(self, "t_final", check_real("t_final", self.t_final, lo=0.0, strict=True))
        self._check_time_and_disturbance(n, B.shape[1], C.shape[0])
        if not isinstance(self.claimed, Constants):
            raise PlantError(f"claimed: expected a Constants, got {type(self.claimed).__name__}")
        if self.bounds is not None and not isinstance(self.bounds, Constants):
            raise PlantError(f"bounds: expected a Constants or None, got {type(self.bounds).__name__}")
        try:
            object.__setattr__(self, "params", dict(self.params))
        except (TypeError, ValueError):
            raise PlantError(f"params: expected a mapping of parameter names to numbers, "
                             f"got {checks.brief(self.params)}") from None
        for key, val in self.params.items():
            check_real(f"params[{key!r}]", val)
        if self.state_names is not None:
            try:
                names = None if isinstance(self.state_names, str) else tuple(self.state_names)
            except TypeError:
                names = None
            if names is None or len(names) != n or not all(isinstance(s, str) and s.strip() for s in names):
                raise PlantError(f"state_names: expected {n} non-empty strings (one per state), got "
                                 f"{checks.brief(self.state_names)}")
            object.__setattr__(self, "state_names", names)
        self._check_f(n)
        self._check_contract(n)
        self._check_jacobian(n)
        if self.channels is not None:
            self._check_channels(n)

    def _check_time_and_disturbance(self, n: int, m: int, p: int) -> None:
        """``dt`` a sample time (0: continuous) not longer than the horizon; ``Bw`` (n, q) and ``Dw`` (p, q)."""
        if isinstance(self.dt, bool) or self.dt is None:
            raise PlantError(f"dt: must be a number of seconds (0 for a continuous-time plant), got {self.dt!r}")
        dt = check_real("dt", self.dt, lo=0.0)
        if dt > self.t_final:
            raise PlantError(f"dt: the sample time {dt:g} s is longer than the horizon t_final = {self.t_final:g} s")
        object.__setattr__(self, "dt", dt)
        if self.Bw is None and self.Dw is None:
            return
        Bw = _matrix("Bw", self.Bw) if self.Bw is not None else None
        Dw = _matrix("Dw", self.Dw) if self.Dw is not None else None
        if Bw is not None and Bw.shape[0] != n:
            raise PlantError(f"Bw: must have n = {n} rows (A is {(n, n)}), got shape {Bw.shape}")
        if Dw is not None and Dw.shape[0] != p:
            raise PlantError(f"Dw: must have p = {p} rows (C is {(p, n)}), got shape {Dw.shape}")
        q = (Bw if Bw is not None else Dw).shape[1]
        if Bw is not None and Dw is not None and Bw.shape[1] != Dw.shape[1]:
            raise PlantError(f"Bw/Dw: must have the same number of disturbance inputs (columns), got Bw {Bw.shape} "
                             f"and Dw {Dw.shape}")
        for name, M, rows in (("Bw", Bw, n), ("Dw", Dw, p)):
            if M is None:
                M = np.zeros((rows, q))
                M.setflags(write=False)
            object.__setattr__(self, name, M)

    def _check_f(self, n: int) -> None:
        if not callable(self.f):
            raise PlantError(f"f: must be callable, got {type(self.f).__name__}")
        probes = (
            ("f(0)", np.zeros(n), (n,)),
            ("f(x0)", np.array(self.x0), (n,)),
            ("f(batch)", np.stack([self.x0, self.x_hat0, np.zeros(n)], axis=1), (n, 3)),
        )
        for label, arg, shape in probes:
            try:
                raw = self.f(arg)
            except Exception as exc:  # the user's f failed: say where
                raise PlantError(f"f: raised {type(exc).__name__} when evaluating {label}: {exc}") from exc
            try:
                out = _real_array(raw)
            except Exception as exc:  # None, a string, complex values, ...: not a real array
                raise PlantError(f"f: {label} is not a real numeric array ({type(exc).__name__}: {exc}); "
                                 f"got {checks.brief(raw)}") from None
            if out.shape != shape:
                raise PlantError(f"f: {label} must have shape {shape}, got {out.shape}")
            if not np.all(np.isfinite(out)):
                raise PlantError(f"f: {label} is not finite: {out}")
            if label == "f(0)" and np.linalg.norm(out) > 1e-12:
                raise PlantError(f"f: f(0) must be 0 (origin an equilibrium), got {out}")
        if self.jacobian is not None and not callable(self.jacobian):
            raise PlantError("jacobian: must be callable or None")

    def _check_jacobian(self, n: int) -> None:
        """The declared Jacobian against central differences of f at the probe states, 0 and x0."""
        if self.jacobian is None:
            return
        X = np.concatenate([np.zeros((n, 1)), np.asarray(self.x0, dtype=float)[:, None], self._probe_points(n)], axis=1)
        why = jacobian_mismatch(self.f, self.jacobian, X)
        if why:
            raise PlantError(why)

    def _probe_points(self, n: int, count: int = 6) -> np.ndarray:
        """Seeded states (n, count) at several scales, inside ``radius`` when the constants are local."""
        rng = np.random.default_rng(12345)
        X = rng.standard_normal((n, count))
        X /= np.linalg.norm(X, axis=0)
        radius = next((c.radius for c in (self.bounds, self.claimed, self.channels)
                       if c is not None and c.radius is not None), None)
        scales = np.geomspace(0.05, 3.0, count) if radius is None else radius * np.linspace(0.1, 0.9, count)
        return X * scales

    def _check_contract(self, n: int) -> None:
        """f must not write into its argument, and its batch form must act column by column."""
        X = self._probe_points(n)
        singles = []
        for j in range(X.shape[1]):
            arg = X[:, j].copy()
            out = _real_array(self.f(arg))
            if not np.array_equal(arg, X[:, j]):
                raise PlantError("f: writes into its argument (f(x) changed x); f must not modify its input")
            if not np.all(np.isfinite(out)):
                raise PlantError(f"f: not finite at x = {np.round(X[:, j], 4).tolist()}: {out}")
            again = _real_array(self.f(X[:, j].copy()))
            if not np.array_equal(out, again):
                raise PlantError(f"f is not deterministic: at the state x = {np.round(X[:, j], 6).tolist()} it gave "
                                 f"{np.round(out, 6).tolist()}, then {np.round(again, 6).tolist()}; f must be a "
                                 "function of x alone (no random or hidden state)")
            singles.append(out)
        arg = X.copy()
        batch = _real_array(self.f(arg))
        if not np.array_equal(arg, X):
            raise PlantError("f: writes into its batch argument; f must not modify its input")
        if batch.shape != X.shape:
            raise PlantError(f"f: a batch of shape {X.shape} gave shape {batch.shape}; a batch (n, N) must "
                             "give (n, N), one column per state")
        for j, single in enumerate(singles):
            if not np.allclose(batch[:, j], single, rtol=1e-9, atol=1e-12 * max(1.0, float(np.abs(single).max()))):
                raise PlantError(
                    f"f: the batch form mixes columns: column {j} of f(X) is {np.round(batch[:, j], 6).tolist()} "
                    f"but f(X[:, {j}]) is {np.round(single, 6).tolist()}; a batch (n, N) must be N independent "
                    "states (e.g. use np.sum(x * x, axis=0), not np.linalg.norm(x))")

    def _check_channels(self, n: int) -> None:
        ch = self.channels
        if not isinstance(ch, Channels):
            raise PlantError(f"channels: expected a Channels or None, got {type(ch).__name__}")
        if ch.G.shape[0] != n or ch.H.shape[1] != n:
            raise PlantError(f"channels: G must be ({n}, q) and H (q, {n}) to match A {self.A.shape}, "
                             f"got G {ch.G.shape}, H {ch.H.shape}")
        try:
            zero = _real_array(ch.phi(np.zeros(ch.q)))
        except Exception as exc:
            raise PlantError(f"channels.phi: raised {type(exc).__name__} at z = 0: {exc}") from exc
        if zero.shape != (ch.q,) or np.linalg.norm(zero) > 1e-12:
            raise PlantError(f"channels.phi: phi(0) must be 0 with shape ({ch.q},), got {zero}")
        X = np.concatenate([self._probe_points(n), np.asarray(self.x0, dtype=float)[:, None]], axis=1)
        try:
            got = _real_array(ch.apply(X))
        except Exception as exc:
            raise PlantError(f"channels: G phi(H x) raised {type(exc).__name__} on a batch: {exc}") from exc
        want = _real_array(self.f(X))
        if got.shape != want.shape:
            raise PlantError(f"channels: G phi(H x) has shape {got.shape} on a batch, f has {want.shape}")
        err = np.abs(got - want).max(axis=0)
        tol = 1e-9 * np.maximum(1.0, np.abs(want).max(axis=0))
        if np.any(err > tol):
            j = int(np.argmax(err - tol))
            raise PlantError(f"channels: G phi(H x) differs from f at x = {np.round(X[:, j], 4).tolist()} "
                             f"(by {err[j]:.3g}); the channels must reproduce f exactly")

    @classmethod
    def from_statespace(cls, sys, *, f: Callable[[np.ndarray], np.ndarray] | None = None, x0=None,
                        x_hat0=None, id: str | None = None, disturbances=None, **fields) -> "Plant":
        """Build a plant from a python-control ``StateSpace`` (its A, B, C, D and dt) and a nonlinearity.

        Parameters
        ----------
        sys : control.StateSpace
            ``x' = A x + B u`` (continuous, ``dt = 0``) or ``x_{k+1} = A x_k + B u_k`` (discrete, ``dt > 0``
            seconds), ``y = C x + D u``. The columns of D for the control inputs must be zero.
        f : callable, optional
            The nonlinearity (default 0).
        x0 : array_like, optional
            Initial state (default: all ones).
        x_hat0 : array_like, optional
            Initial estimate (default: zeros).
        id : str, optional
            Plant id (default: the system's name).
        disturbances : int, str or sequence, optional
            The inputs of ``sys`` that are disturbances ``w`` (indices or input names): their columns of B
            and D become ``Bw`` and ``Dw``; the others are the control inputs ``u``.
        **fields
            Any other :class:`Plant` field.

        Returns
        -------
        Plant

        Raises
        ------
        PlantError
            If ``sys`` is not a state-space system, has an unspecified sample time (``dt = True``), a
            nonzero D column for a control input, or names a disturbance input it does not have.

        Examples
        --------
        >>> import control, numpy as np
        >>> sys = control.ss([[0, 1], [-1, -0.5]], [[0], [1]], [[1, 0]], 0, name="osc")
        >>> plant = Plant.from_statespace(sys, f=lambda x: np.stack([0 * x[0], -0.5 * np.sin(x[0])]),
        ...                               bounds=Constants(alpha=0.5, rho=0.25, beta=0.25, gamma=0.0))
        >>> plant.n, plant.m, plant.p
        (2, 1, 1)
        """
        if not all(hasattr(sys, name) for name in "ABCD"):
            raise PlantError(f"sys: expected a control.StateSpace (with A, B, C, D), got {type(sys).__name__}")
        dt = getattr(sys, "dt", 0)
        if dt is None:
            dt = 0.0
        if isinstance(dt, bool) or not isinstance(dt, numbers.Real):
            raise PlantError(f"sys: a discrete-time system needs its sample time in seconds, got dt = {dt!r}")
        A = _matrix("A", sys.A)
        n = A.shape[0]
        Ball = _real_array(sys.B).reshape(n, -1)
        Dall = _real_array(sys.D).reshape(-1, Ball.shape[1]) if np.size(sys.D) else np.zeros((0, Ball.shape[1]))
        w_idx = _input_indices(sys, disturbances, Ball.shape[1])
        u_idx = [j for j in range(Ball.shape[1]) if j not in w_idx]
        if not u_idx:
            raise PlantError("disturbances: every input of sys is a disturbance; the plant needs a control input")
        Du = Dall[:, u_idx] if Dall.size else Dall
        if Du.size and np.any(Du != 0):
            raise PlantError(f"D: the columns of the control inputs must be zero (no feedthrough from u to y), got "
                             f"max |D| = {np.abs(Du).max():g}")
        if w_idx:
            fields.setdefault("Bw", Ball[:, w_idx])
            fields.setdefault("Dw", Dall[:, w_idx] if Dall.size else np.zeros((np.shape(sys.C)[0], len(w_idx))))
        if f is None:
            f = _zero_f
        # python-control names systems "sys[3]": the default id keeps its letters, digits and _-.+ only
        name = id if id is not None else (re.sub(r"[^A-Za-z0-9_.+-]+", "_", str(getattr(sys, "name", None) or ""))
                                          .strip("_.-") or "statespace_plant")
        fields.setdefault("dt", float(dt))
        return cls(id=name, A=A, B=Ball[:, u_idx], C=sys.C, f=f, x0=np.ones(n) if x0 is None else x0,
                   x_hat0=np.zeros(n) if x_hat0 is None else x_hat0, **fields)

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

    @property
    def q(self) -> int:
        """Number of disturbance inputs (0 without ``Bw``, ``Dw``)."""
        return 0 if self.Bw is None else self.Bw.shape[1]

    @property
    def discrete(self) -> bool:
        """True for a discrete-time plant (``dt > 0``)."""
        return self.dt > 0

    def discretise(self, h: float, method: str = "zoh", *, id: str | None = None) -> "Plant":
        """The discrete-time plant ``x_{k+1} = A_d x_k + B_d u_k + f_d(x_k)`` sampled every ``h`` seconds.

        Parameters
        ----------
        h : float
            Sample time in seconds (> 0).
        method : {"zoh", "euler"}
            ``"euler"`` (forward difference): ``A_d = I + h A``, ``B_d = h B``, ``f_d = h f``,
            ``Bw_d = h Bw``, Jacobian ``h J``. ``"zoh"``: the linear part exact under a zero-order hold,
            ``A_d = expm(h A)``, ``B_d = Gamma B``, ``Bw_d = Gamma Bw`` with ``Gamma = int_0^h expm(A s) ds``
            (what python-control's ``c2d(sys, h, "zoh")`` gives), and ``f_d = Gamma f``, Jacobian
            ``Gamma J``: f held over the step like u (exact for the linear part only; for the nonlinear
            plant it is the discrete model the suite then studies, not the sampled continuous flow).
            C, Dw, x0, x_hat0 are kept.
        id : str, optional
            The new plant's id (default ``"<id>_d<h in ms>ms"``, e.g. ``flexible_link_d10ms``).

        Returns
        -------
        Plant
            With ``dt = h``, ``t_final`` rounded up to a multiple of ``h``, ``params`` adding ``h`` and
            ``zoh`` (1 for zoh, 0 for Euler), the source and notes stating the discretisation.
            Constants of ``f_d`` (``bounds`` transported, None where no rule applies, the radius kept;
            ``claimed`` transported by Euler, whose rules are exact, so a claim stays right or wrong,
            and dropped by zoh, whose rules are bounds nobody claimed), with ``g = ||Gamma||_2`` and
            ``d = ||Gamma - h I||_2``:

            - Euler (exact): Lipschitz ``h alpha``; OSL ``h rho``; QIB ``(h^2 beta, h gamma)`` (multiply
              the QIB inequality by ``h^2``).
            - zoh: Lipschitz ``g alpha`` (``|Gamma df| <= g |df|``); OSL the smaller of ``g alpha``
              (Cauchy-Schwarz) and ``h rho + d alpha`` (``<Gamma df, dx> = h <df, dx> + <(Gamma - h I) df,
              dx>``), so it tends to ``h rho`` as ``h -> 0``; QIB ``(g^2 alpha^2, 0)`` from the Lipschitz
              bound. Without alpha, zoh gives no OSL or QIB constant.

            Channels ``f_d = G_d phi(H x)`` with ``G_d = h G`` (Euler) or ``Gamma G`` (zoh), phi, H, the slopes
            and their narrowing unchanged (exact). The suite's sampler checks the transported constants as
            every plant's.

        Raises
        ------
        PlantError
            If the plant is already discrete, ``h`` is not a positive number or ``method`` is unknown.

        Examples
        --------
        >>> from bench.registry import PLANTS
        >>> d = PLANTS.create("flexible_link").discretise(0.01, "zoh")
        >>> d.id, d.dt, d.discrete
        ('flexible_link_d10ms', 0.01, True)
        """
        if self.discrete:
            raise PlantError(f"discretise: plant {self.id!r} is already discrete (dt = {self.dt:g} s)")
        h = check_real("h", h, lo=0.0, strict=True)
        if method not in DISCRETISATIONS:
            raise PlantError(f"method: must be one of {', '.join(map(repr, DISCRETISATIONS))}, got {checks.brief(method)}")
        n = self.n
        if method == "euler":
            Ad, Gam = np.eye(n) + h * self.A, h * np.eye(n)
        else:
            from scipy.linalg import expm

            M = np.zeros((2 * n, 2 * n))
            M[:n, :n], M[:n, n:] = self.A, np.eye(n)
            E = expm(h * M)  # [[expm(hA), Gamma], [0, I]] (Van Loan)
            Ad, Gam = E[:n, :n], E[:n, n:]
        scale = h if method == "euler" else Gam  # a scalar keeps f_d = h f exact
        ch = self.channels
        channels = None if ch is None else Channels(G=scale * ch.G if method == "euler" else Gam @ ch.G, H=ch.H,
                                                    phi=ch.phi, lo=ch.lo, hi=ch.hi, radius=ch.radius,
                                                    narrow=ch.narrow)
        has_w = self.q > 0
        steps = math.ceil(self.t_final / h - 1e-9)
        how = f"{'Euler' if method == 'euler' else 'zero-order hold'} discretisation at h = {h:g} s"
        return Plant(
            id=id if id is not None else f"{self.id}_d{h * 1000:g}ms",
            A=Ad, B=Gam @ self.B, C=self.C, f=_Mapped(self.f, scale), x0=self.x0, x_hat0=self.x_hat0,
            jacobian=None if self.jacobian is None else _Mapped(self.jacobian, scale),
            claimed=_discrete_constants(self.claimed, h, Gam, method) if method == "euler" else Constants(),
            bounds=None if self.bounds is None else _discrete_constants(self.bounds, h, Gam, method),
            channels=channels, t_final=max(steps, 1) * h, dt=h,
            Bw=Gam @ self.Bw if has_w else None, Dw=self.Dw if has_w else None, family=self.family,
            params={**self.params, "h": h, "zoh": float(method == "zoh")}, state_names=self.state_names,
            source=f"{self.source}; {how}" if self.source else how,
            notes=f"{how} of {self.id}" + (f" ({self.notes})" if self.notes else ""))

    def scaled(self, c: float, *, id: str | None = None) -> "Plant":
        """The plant with its nonlinearity, and so its class, multiplied by ``c``: ``f -> c f``.

        A, B, C, the disturbance inputs, x0, x_hat0, the horizon and the sample time are kept: this is the
        axis of the largest admissible nonlinearity (``python -m bench study scale``), on which a design is
        given the scaled class of the same linear part.

        Parameters
        ----------
        c : float
            The factor, finite and ``>= 0`` (``c = 0`` is the linear plant; a negative factor would flip f,
            whose one-sided Lipschitz constant does not follow from rho).
        id : str, optional
            The new plant's id (default ``"<id>_scaled<c>"``, e.g. ``flexible_link_scaled2.5``).

        Returns
        -------
        Plant
            f and its Jacobian times c; ``params`` adding ``scale`` (the product with an earlier one); the
            source and notes stating the factor. The constants scale as the class does, exactly, for
            ``bounds`` and ``claimed`` alike (a claim stays right or wrong), the radius kept: Lipschitz
            ``c alpha``, OSL ``c rho``, QIB ``(c^2 beta, c gamma)`` (multiply the QIB inequality by
            ``c^2``: ``|c df|^2 <= c^2 beta |dx|^2 + c gamma <dx, c df>``). Channels ``G (c phi)(H x)``
            with slopes ``[c lo, c hi]`` and the narrowing ``narrow(r)`` times c.

        Raises
        ------
        PlantError
            If ``c`` is not a finite number ``>= 0``, or the default id is too long (pass ``id``).

        Examples
        --------
        >>> from bench.registry import PLANTS
        >>> p = PLANTS.create("flexible_link").scaled(2.0)
        >>> p.id, p.params["scale"], p.bounds.alpha, round(p.bounds.beta, 6)
        ('flexible_link_scaled2', 2.0, 0.666, 0.443556)
        """
        c = check_real("c", c, lo=0.0)
        ch = self.channels
        channels = None if ch is None else Channels(
            G=ch.G, H=ch.H, phi=_Mapped(ch.phi, c), lo=c * ch.lo, hi=c * ch.hi, radius=ch.radius,
            narrow=None if ch.narrow is None else _ScaledNarrow(ch.narrow, c))
        how = (f"f scaled by c = {c:g} (the class: Lipschitz c alpha, OSL c rho, QIB (c^2 beta, c gamma), "
               "slopes c [lo, hi])")
        return dataclasses.replace(  # every other field (A, B, C, Bw, Dw, x0, dt, state names, ...) kept
            self, id=id if id is not None else f"{self.id}_scaled{c:g}", f=_Mapped(self.f, c),
            jacobian=None if self.jacobian is None else _Mapped(self.jacobian, c),
            claimed=_scaled_constants(self.claimed, c),
            bounds=None if self.bounds is None else _scaled_constants(self.bounds, c), channels=channels,
            params={**self.params, "scale": c * float(self.params.get("scale", 1.0))},
            source=f"{self.source}; {how}" if self.source else how,
            notes=f"{how} of {self.id}" + (f" ({self.notes})" if self.notes else ""))

    def summary(self) -> str:
        """One line: id, dimensions and source."""
        return f"{self.id}: n={self.n}, m={self.m}, p={self.p}; {self.source}"

    def jacobian_at(self, x: np.ndarray) -> np.ndarray:
        """``df/dx`` at ``x``: the declared Jacobian, else central differences (step 1e-6, one batch call of f)."""
        x = np.asarray(x, dtype=float)
        if self.jacobian is not None:
            return np.asarray(self.jacobian(x), dtype=float)
        return _central_differences(self.f, x, 1e-6)


#: The discretisations of :meth:`Plant.discretise`.
DISCRETISATIONS = ("zoh", "euler")


class _Mapped:
    """``x -> M @ g(x)`` (or ``M * g(x)`` for a scalar M): a discretised f or Jacobian (picklable when g is)."""

    def __init__(self, g: Callable, M):
        self.g, self.M = g, M

    def __call__(self, x):
        out = np.asarray(self.g(x), dtype=float)
        return self.M * out if np.ndim(self.M) == 0 else self.M @ out


class _ScaledNarrow:
    """``r -> c narrow(r)``: the narrowed slopes of a channel scaled by ``c >= 0`` (picklable when narrow is)."""

    def __init__(self, narrow: Callable[[float], tuple], c: float):
        self.narrow, self.c = narrow, c

    def __call__(self, r: float) -> tuple:
        lo, hi = self.narrow(r)
        return self.c * np.asarray(lo, dtype=float), self.c * np.asarray(hi, dtype=float)


def _scaled_constants(k: Constants, c: float) -> Constants:
    """The constants of ``c f`` from those of ``f`` (:meth:`Plant.scaled`, ``c >= 0``)."""
    def times(v: float | None, by: float) -> float | None:
        return None if v is None else by * v

    return Constants(alpha=times(k.alpha, c), rho=times(k.rho, c), beta=times(k.beta, c * c),
                     gamma=times(k.gamma, c), radius=k.radius)


def _discrete_constants(c: Constants, h: float, Gam: np.ndarray, method: str) -> Constants:
    """The constants of ``f_d`` from those of ``f`` (the rules of :meth:`Plant.discretise`)."""
    if method == "euler":
        return Constants(alpha=None if c.alpha is None else h * c.alpha, rho=None if c.rho is None else h * c.rho,
                         beta=None if c.beta is None else h * h * c.beta,
                         gamma=None if c.gamma is None else h * c.gamma, radius=c.radius)
    if c.alpha is None:
        return Constants(radius=c.radius)
    g = float(np.linalg.norm(Gam, 2))
    rho = g * c.alpha
    if c.rho is not None:
        rho = min(rho, h * c.rho + float(np.linalg.norm(Gam - h * np.eye(Gam.shape[0]), 2)) * c.alpha)
    return Constants(alpha=g * c.alpha, rho=rho, beta=(g * c.alpha) ** 2, gamma=0.0, radius=c.radius)


def jacobian_mismatch(f: Callable, jacobian: Callable, X: np.ndarray, *, rtol: float = 1e-4) -> str | None:
    """Where a declared Jacobian disagrees with central differences of ``f`` at the columns of ``X``
    (a message naming the entry and the state; None: nowhere).

    At each column ``x`` the difference ``(f(x + h e_j) - f(x - h e_j)) / 2h``, ``h = 1e-6 max(1, ||x||)``,
    must match ``jacobian(x)`` within ``rtol (1 + max |J_fd|)``.
    """
    X = np.asarray(X, dtype=float)
    n = X.shape[0]
    for j in range(X.shape[1]):
        x = X[:, j]
        try:
            fd = _central_differences(f, x, 1e-6 * max(1.0, float(np.linalg.norm(x))))
            J = _real_array(jacobian(x.copy()))
        except Exception as exc:  # noqa: BLE001 - the user's code failed: say where
            return f"jacobian: could not be checked at x = {np.round(x, 4).tolist()} ({type(exc).__name__}: {exc})"
        if J.shape != (n, n) or fd.shape != (n, n):
            return f"jacobian: must return shape ({n}, {n}), got {J.shape} at x = {np.round(x, 4).tolist()}"
        err = np.abs(J - fd)
        tol = rtol * (1.0 + float(np.abs(fd).max()))
        if np.nanmax(err) > tol or not np.all(np.isfinite(J)):
            r, c = (int(v) for v in np.unravel_index(int(np.nanargmax(np.where(np.isfinite(err), err, np.inf))),
                                                      err.shape))
            return (f"jacobian: entry [{r}, {c}] at x = {np.round(x, 4).tolist()} is {J[r, c]:.6g}, but finite "
                    f"differences of f give {fd[r, c]:.6g}: the declared Jacobian is not the derivative of f")
    return None


def _central_differences(f: Callable, x: np.ndarray, h: float) -> np.ndarray:
    """``(f(x + h e_j) - f(x - h e_j)) / 2h`` for every j, f evaluated once on the batch of 2n states."""
    n = x.size
    E = np.eye(n) * h
    FX = _real_array(f(np.concatenate([x[:, None] + E, x[:, None] - E], axis=1)))
    return (FX[:, :n] - FX[:, n:]) / (2 * h)


def _input_indices(sys, which, m_all: int) -> list[int]:
    """The input indices of ``sys`` named by ``which`` (None, an index, a name, or a sequence of them)."""
    if which is None:
        return []
    items = [which] if isinstance(which, (str, numbers.Integral)) else list(which)
    labels = list(getattr(sys, "input_labels", []) or [])
    out = []
    for it in items:
        if isinstance(it, str):
            if it not in labels:
                raise PlantError(f"disturbances: sys has no input named {it!r} (inputs: {', '.join(labels) or 'none'})")
            j = labels.index(it)
        elif isinstance(it, numbers.Integral) and not isinstance(it, bool) and 0 <= int(it) < m_all:
            j = int(it)
        else:
            raise PlantError(f"disturbances: {it!r} is not an input of sys (indices 0..{m_all - 1} or input names)")
        if j not in out:
            out.append(j)
    return out


def _zero_f(x: np.ndarray) -> np.ndarray:
    """``f(x) = 0``, a linear plant's nonlinearity."""
    return np.zeros_like(np.asarray(x, dtype=float))
