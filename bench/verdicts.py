"""The judgements of a pair, each a pure function of numbers the pipeline already has: how long to
simulate (:func:`simulation_horizon`), what a certificate proves from the initial condition
(:func:`certificate_scope`), why a pair did not converge (:func:`convergence_note`), whether a simulation
keeps the decay its certificate proves (:func:`lyapunov_note`), and whether a certified L2 gain
contradicts the measured attenuation (:func:`attenuation_note`).
"""

from __future__ import annotations

import math

import numpy as np

from bench.metrics import CONVERGED_RATIO

__all__ = ["attenuation_note", "certificate_scope", "certified_horizon", "convergence_note", "lyapunov_note",
           "simulation_horizon"]

#: An uncertified pair is simulated this many times what its linearisation's rate needs (:func:`simulation_horizon`).
LINEAR_FACTOR = 2.0


def simulation_horizon(t_plant: float, *, fixed: float | None, cap_factor: float, cert_rate: float, cond_p: float,
            linear_rate: float) -> tuple[float, str]:
    """The simulation horizon of a pair and the rule that set it.

    Long enough to decay by :data:`bench.metrics.CONVERGED_RATIO` at the certified rate
    (:func:`certified_horizon`), or uncertified at ``LINEAR_FACTOR`` times the linearisation's; at least
    ``t_plant``, at most ``cap_factor * t_plant``.

    Parameters
    ----------
    t_plant : float
        The plant's own horizon.
    fixed : float, optional
        A horizon the user fixed (``--t-final``): used as it is.
    cap_factor : float
    cert_rate : float
        Certified decay rate (NaN or <= 0: none).
    cond_p : float
        Condition number of the certificate's P.
    linear_rate : float
        Decay rate of the loop linearised at the origin (NaN or <= 0: not stable).

    Returns
    -------
    T : float
    rule : str
        ``"fixed"``, ``"plant"``, ``"certified rate"``, ``"linearised rate"`` or ``"cut at cap (...)"``.
    """
    if fixed is not None:
        return float(fixed), "fixed"
    need, rule = None, "plant"
    if math.isfinite(cert_rate) and cert_rate > 0:
        need, rule = certified_horizon(cert_rate, cond_p), "certified rate"
    elif math.isfinite(linear_rate) and linear_rate > 0:
        need, rule = LINEAR_FACTOR * math.log(1.0 / CONVERGED_RATIO) / linear_rate, "linearised rate"
    if need is None or need <= t_plant:
        return float(t_plant), "plant"
    cap = cap_factor * t_plant
    if need > cap:
        return float(cap), f"cut at cap ({rule} asks for {need:.3g} s)"
    return float(math.ceil(need)), rule


def certificate_scope(P: np.ndarray | None, radius: float | None, x0: np.ndarray, x_hat0: np.ndarray,
                      H: np.ndarray | None = None) -> dict:
    """What a certificate with Lyapunov matrix ``P`` proves from ``(x0, x_hat0)``.

    Parameters
    ----------
    P : ndarray (2n, 2n) or None
        ``V = z' P z``, ``z = (x, e)``; None when nothing is certified.
    radius : float or None
        The certificate's constraints hold on ``||x|| <= radius`` (None: globally).
    x0, x_hat0 : ndarray (n,)
    H : ndarray (q, n), optional
        The region is ``|(H x)_i|, |(H x_hat)_i| <= radius`` instead.

    Returns
    -------
    dict
        ``cert_scope`` (``"global"``, ``"from x0"`` when ``V(z0)`` is below the largest level set inside
        the region, ``"local"``, or ``""``), ``cert_radius``, ``level_set``, ``level_x0``.
    """
    from bench.certify import level_set

    out = {"cert_scope": "", "cert_radius": math.nan, "level_set": math.nan, "level_x0": math.nan}
    if P is None:
        return out
    z0 = np.concatenate([x0, x0 - x_hat0])
    out["level_x0"] = float(z0 @ P @ z0)
    if radius is None:
        out["cert_scope"] = "global"
        return out
    v = level_set(P, radius, H)
    out.update(cert_radius=float(radius), level_set=v,
               cert_scope="from x0" if out["level_x0"] <= v else "local")
    return out


def certified_horizon(cert_rate: float, cond_p: float) -> float:
    """The time by which a certified pair has decayed by :data:`bench.metrics.CONVERGED_RATIO`:
    ``(ln(1 / CONVERGED_RATIO) + ln(cond P) / 2) / lam`` (NaN without a positive rate)."""
    if not (math.isfinite(cert_rate) and cert_rate > 0):
        return math.nan
    kappa = cond_p if math.isfinite(cond_p) and cond_p >= 1 else 1.0
    return (math.log(1.0 / CONVERGED_RATIO) + 0.5 * math.log(kappa)) / cert_rate


def convergence_note(rec: dict) -> str:
    """Why the pair of record ``rec`` did not converge (empty when it converged).

    A certified pair whose certificate covers the simulation (scope ``"global"`` or ``"from x0"``, a finite
    ``cert_horizon_s``) that diverged, left the region, or ended unconverged after at least
    ``cert_horizon_s`` is INCONSISTENT (the note gives the witness); a shorter horizon is "horizon too short".
    """
    if rec.get("converged"):
        return ""
    status = rec.get("sim_status", "")
    rule = str(rec.get("horizon_rule", ""))
    T = float(rec.get("horizon_s", math.nan))
    need = float(rec.get("cert_horizon_s", math.nan))
    covered = bool(rec.get("certified")) and rec.get("cert_scope") in ("global", "from x0") and math.isfinite(need)
    left = rec.get("in_region") is False
    why = []
    if status and status != "ok":
        why.append(f"the simulation {status}")
    if left:
        why.append("the trajectory left the region where the constants hold")
    if status in ("", "ok"):
        tail = rec.get("tail_rate", math.nan)
        if rule.startswith("cut"):
            why.append(f"the horizon was {rule} at {T:.3g} s")
        if isinstance(tail, float) and math.isfinite(tail):
            why.append(f"tail rate {tail:.3g} /s ({'decaying' if tail > 0 else 'not decaying'})")
    note = "not converged" + (": " + "; ".join(why) if why else " within the horizon")
    if not covered:
        return note
    witness = rec.get("sim_witness") or "no state recorded"
    if status == "diverged" or left:
        what = "diverged" if status == "diverged" else "left the certified region"
        return f"{note} (INCONSISTENT with the certificate: a certified pair {what}; witness {witness})"
    if status not in ("", "ok"):  # the simulator stopped (budget, timeout, failure): nothing contradicted
        return note
    if T < need * (1 - 1e-9):
        return (f"{note} (horizon too short: the certified rate {float(rec.get('decay_rate', math.nan)):.3g} /s "
                f"needs {need:.3g} s to decay by {1 / CONVERGED_RATIO:g}, the horizon was {T:.3g} s ({rule}))")
    return (f"{note} (INCONSISTENT with the certificate: not converged after {T:.3g} s although the certified "
            f"rate needs {need:.3g} s; witness {witness})")


#: A certified L2 gain below a measured ratio by more than this fraction of the ratio is INCONSISTENT: the
#: margin of the norms' quadrature on the trajectory's grid (:mod:`bench.disturbance`).
ATTENUATION_RTOL = 0.01


def attenuation_note(rec: dict, rtol: float = ATTENUATION_RTOL) -> str:
    """INCONSISTENT when a certified L2 gain is below its measured ratio (empty otherwise).

    From ``z(0) = 0`` a certified gain ``g`` from w to ``zeta`` bounds ``||zeta||_L2 / ||w||_L2`` for every
    w, so ``measured > g (1 + rtol)`` contradicts the certificate. Pairs compared: ``l2_gain_e`` with
    ``l2_measured_e`` (``zeta = e``) and ``l2_gain_x`` with ``l2_measured_x`` (``zeta = x``); a NaN on
    either side (nothing certified, nothing measured) proves nothing. Gains whose class holds on a region only
    (``l2_radius`` finite) bound the trajectories that stay in it: they are compared only when the disturbance run
    did (``l2_max_norm <= l2_radius``).

    Parameters
    ----------
    rec : dict
        A record with (some of) the four columns, and ``l2_radius``, ``l2_max_norm``.
    rtol : float
        Relative tolerance of the measurement.

    Returns
    -------
    str
    """
    out = []
    radius = _number(rec.get("l2_radius"))
    if math.isfinite(radius) and not _number(rec.get("l2_max_norm")) <= radius:
        return ""  # the run left the region where the certified gains hold (or its size is unknown)
    for which, what in (("e", "the estimation error e"), ("x", "the state x")):
        g, r = (_number(rec.get(f"{col}_{which}")) for col in ("l2_gain", "l2_measured"))
        if math.isfinite(g) and math.isfinite(r) and r > g * (1 + rtol):
            out.append(f"INCONSISTENT with the certificate: the measured L2 ratio from w to {what} is {r:.4g}, above "
                       f"the certified gain {g:.4g} (run from z(0) = 0 with the seeded disturbance)")
    return "; ".join(out)


def _number(v) -> float:
    """``v`` as a float (None, text or a missing value: NaN)."""
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


#: :func:`lyapunov_note` allows each sample of z this many times the integrator's own tolerance
#: (``atol + rtol |z_i|`` per component), for the error accumulated over the steps.
LYAPUNOV_SAFETY = 1e3

#: and this relative slack on ``V(z0) exp(-2 lam t)`` (the sum of rounding errors in V).
LYAPUNOV_RTOL = 1e-6


def lyapunov_note(t: np.ndarray, x: np.ndarray, x_hat: np.ndarray, P: np.ndarray, lam: float, *,
                  inside: np.ndarray | None, atol: float, rtol: float) -> str:
    """Whether a simulation keeps the decay its certificate proves: ``V(z(t)) <= V(z0) exp(-2 lam t)``.

    In discrete time the samples are the steps ``t_k = k dt`` and the bound is ``V(z_k) <= r^(2k) V(z_0)`` with
    ``r = exp(-lam dt)``, the same expression (the caller passes the steps' rounding as ``rtol``, ``atol = 0``).

    A certificate ``V = z' P z`` with rate ``lam`` proves ``V' <= -2 lam V`` wherever its constraints hold,
    so along a trajectory that stays in its region ``V(z(t)) <= V(z0) exp(-2 lam t)`` at every t. Each
    stored sample up to the first one outside the region is checked against that bound times
    ``1 + LYAPUNOV_RTOL``, plus what the integrator's error can add to V: with
    ``dz = LYAPUNOV_SAFETY (atol sqrt(2n) + rtol ||z||)``, ``||P|| (2 ||z|| dz + dz^2)``.

    Parameters
    ----------
    t : ndarray (T,)
    x, x_hat : ndarray (n, T) or (n, N, T)
        The states and estimates (a batch: N initial conditions).
    P : ndarray (2n, 2n)
        ``V = z' P z``, ``z = (x, x - x_hat)``.
    lam : float
        The certified rate.
    inside : ndarray of bool, (T,) or (N, T), optional
        Samples in the certified region (None: a global certificate, every sample).
    atol, rtol : float
        The integrator's tolerances.

    Returns
    -------
    str
        ``""``, or the INCONSISTENT sentence with the largest ratio ``V(z(t)) / (V(z0) exp(-2 lam t))`` beyond the
        tolerance and its time.
    """
    x, x_hat = np.asarray(x, dtype=float), np.asarray(x_hat, dtype=float)
    if x.ndim == 2:
        x, x_hat = x[:, None, :], x_hat[:, None, :]
        inside = None if inside is None else np.asarray(inside)[None, :]
    z = np.concatenate([x, x - x_hat])  # (2n, N, T)
    with np.errstate(all="ignore"):
        V = np.einsum("inT,ij,jnT->nT", z, P, z)
        bound = V[:, :1] * np.exp(-2.0 * lam * np.asarray(t, dtype=float))[None, :]
        size = np.linalg.norm(z, axis=0)
        dz = LYAPUNOV_SAFETY * (atol * math.sqrt(z.shape[0]) + rtol * size)
        allowed = bound * (1 + LYAPUNOV_RTOL) + np.linalg.norm(P, 2) * (2 * size * dz + dz**2)
        checked = np.isfinite(V) & (True if inside is None else np.cumprod(np.asarray(inside, dtype=bool), axis=1) > 0)
        excess = np.where(checked & (V > allowed), V / np.maximum(bound, np.finfo(float).tiny), -np.inf)
    if not np.any(np.isfinite(excess)):
        return ""
    j, k = np.unravel_index(int(np.argmax(excess)), excess.shape)
    member = f" (member {j})" if excess.shape[0] > 1 else ""
    return (f"INCONSISTENT with the certificate: V(z(t)) exceeds V(z0) e^(-2 lam t) by a factor {excess[j, k]:.4g} "
            f"at t = {t[k]:.4g} s{member} (lam = {lam:.4g})")
