"""Where a pair is judged: design -> verify -> certify -> simulate -> metrics -> verdicts.

:func:`evaluate_pair` is the only place a (plant, design) pair is judged; it returns one
:class:`PairOutcome` whose ``record`` is a flat row with the columns :data:`COLUMNS` (NaN where a
value does not apply). Every verdict is computed here (the rules are in :mod:`bench.verdicts`) and
stored in the record, so results.csv says everything the report shows.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import sys
import time
import traceback
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from bench import checks, lmi
from bench.certify import LEVELS, Certificate, LevelResult, adopt, ceiling, certify, explain
from bench.constants import ConstantsReport, Knowledge, check_trajectory, resolve_constants
from bench.errors import DesignError
from bench.limits import DeadlineExceeded, hard_stop, remaining_time, time_limit
from bench.metrics import trajectory_metrics
from bench.simulate import SimOptions, simulate_controller
from bench.verdicts import (attenuation_note, certificate_scope, certified_horizon, convergence_note, lyapunov_note,
                            simulation_horizon)
from designs import GAIN_STATUSES, Design, DesignResult
from plants import Plant

__all__ = ["PairOutcome", "RunOptions", "Scenario", "evaluate_pair", "time_domain_mismatch"]

#: Columns of every record, in order.
COLUMNS = [
    "plant", "design", "status", "reason", "feasible", "stabilizing", "certified", "cert_level", "decay_rate",
    "contraction", "dt", "cert_scope", "converged", "witness", "rate_ceiling", "rate_ratio", "ceiling_how",
    "l2_gain_e", "l2_gain_x", "l2_measured_e", "l2_measured_x", "disturbance", "l2_radius", "l2_max_norm",
    *[c for lv in LEVELS for c in (f"cert_{lv}", f"decay_{lv}")],
    "cert_margin", "cert_radius", "level_set", "level_x0", "in_region", "max_norm",
    "route", "lmi_margin", "lmi_size", "solver", "solver_status", "n_solves", "sdp_solves", "compile_s", "solve_s",
    "design_s",
    "cert_s", "sim_s", "max_re_eig_x", "max_re_eig_e", "horizon_s", "horizon_rule", "cert_horizon_s", "sim_status", "sim_witness",
    "settling_x_s",
    "settling_e_s", "final_x", "final_e", "tail_rate", "iae_e", "rms_e", "peak_u", "noise", "norm_K", "norm_F",
    "constants", "checked_on", "disproved", "params",
]

#: The columns of what a certificate claims: blank in an ``error`` or ``timeout`` row (:func:`blank_record`).
CERT_COLUMNS = ("certified", "cert_level", "decay_rate", "contraction", "cert_scope", "witness", "rate_ceiling",
                "rate_ratio", "ceiling_how", "l2_gain_e", "l2_gain_x", "l2_radius",
                *[c for lv in LEVELS for c in (f"cert_{lv}", f"decay_{lv}")], "cert_margin",
                "cert_radius", "level_set", "level_x0", "in_region", "cert_horizon_s")

#: Columns of what a pair cost, not of what it found: seconds, and the SDP solver calls made (a solve this process
#: made before, at the same parameter values, is remembered, :meth:`bench.lmi.Program.solve`). Two runs agree on
#: every other column.
COST_COLUMNS = ("compile_s", "solve_s", "design_s", "cert_s", "sim_s", "sdp_solves")

#: The disturbance amplitude of a run (``python -m bench run``, :func:`bench.run`) by default: each pair of a plant
#: with disturbance inputs is simulated a second time from ``z(0) = 0``, so that the certified L2 gains are checked
#: against measured ratios (docs/results.md says why). :class:`RunOptions` itself defaults to 0 (studies, tests).
RUN_DISTURBANCE = 0.1

#: What the ``certificate`` option computes: every level with its rate, or only whether some level
#: certifies at rate 0 (the strongest first), or only the design's own verified certificate, or nothing.
CERTIFICATE_MODES = ("ladder", "verdict", "own", "none")


@dataclass(frozen=True, kw_only=True)
class RunOptions:
    """Options of a pair (and of a run).

    Parameters
    ----------
    seed : int
        Seed of the constants sampler and of the measurement noise.
    use_claimed : bool
        Design with the constants the source claims instead of the valid ones (certificates
        always use the trusted ones).
    n_samples : int
        Random pairs for the sampled constants.
    sim : SimOptions
    fail_fast : bool
        Re-raise the first exception instead of recording an ``error`` row.
    t_final : float, optional
        A fixed simulation horizon for every plant (default: the rule of
        :func:`bench.verdicts.simulation_horizon`, from the certified or linearised rate).
    horizon_cap : float
        The rule's horizon is at most this many times the plant's ``t_final``.
    noise : float
        Standard deviation of a seeded Gaussian measurement noise (0: noise-free).
    noise_dt : float
        Sample period of the noise for fixed-gain observers (a discrete plant draws one per step).
    disturbance : float
        Peak amplitude of the seeded L2 disturbance (:mod:`bench.disturbance`; 0: none; a run's default is
        :data:`RUN_DISTURBANCE`). With it, each pair of a plant with disturbance inputs (``Bw``, ``Dw``) is
        simulated a second time from ``z(0) = 0`` with w (noise-free) for the measured ratios ``l2_measured_e``,
        ``l2_measured_x``; a plant without them is not disturbed (its ``disturbance`` column is 0).
    timeout : float, optional
        Wall-clock limit in seconds of each pair; a pair over it becomes a ``timeout`` row.
    certificate : {"ladder", "verdict", "own", "none"}
        See :data:`CERTIFICATE_MODES`.
    simulate : bool
        Simulate the closed loop (False: design and certificate only).
    """

    seed: int = 0
    use_claimed: bool = False
    n_samples: int = 20000
    sim: SimOptions = field(default_factory=SimOptions)
    fail_fast: bool = False
    t_final: float | None = None
    horizon_cap: float = 10.0
    noise: float = 0.0
    noise_dt: float = 0.01
    disturbance: float = 0.0
    timeout: float | None = None
    certificate: str = "ladder"
    simulate: bool = True

    def __post_init__(self) -> None:
        checks.horizon(self.timeout, name="timeout")
        checks.horizon(self.t_final)
        checks.real("noise", self.noise, lo=0.0)
        checks.real("disturbance", self.disturbance, lo=0.0)
        checks.real("noise_dt", self.noise_dt, lo=0.0, strict=True)
        checks.real("horizon_cap", self.horizon_cap, lo=1.0)  # a multiple of the plant's horizon
        checks.integer("n_samples", self.n_samples, lo=1)
        if self.certificate not in CERTIFICATE_MODES:
            raise ValueError(f"certificate: must be one of {CERTIFICATE_MODES}, got {self.certificate!r}")


@dataclass(frozen=True)
class Scenario:
    """What to simulate besides the plant's own initial condition (studies).

    Parameters
    ----------
    x0, x_hat0 : ndarray (n, N), optional
        A batch of initial conditions, simulated as one ODE (:mod:`bench.batch`); None: the
        plant's own.
    sample_period : float, optional
        Run observer and controller in discrete time at this period (zero-order hold;
        :func:`bench.batch.simulate_digital_batch`); None: continuous.
    discretisation : {"zoh", "euler"}
        Observer discretisation of the digital loop.
    options : SimOptions, optional
        Integration settings of a continuous batch (:func:`bench.batch.simulate_batch`; None:
        :data:`bench.batch.BATCH_OPTIONS`); the pair's time limit still applies.
    """

    x0: np.ndarray | None = None
    x_hat0: np.ndarray | None = None
    sample_period: float | None = None
    discretisation: str = "zoh"
    options: SimOptions | None = None

    @property
    def batch(self) -> bool:
        """True when the scenario needs the batch simulators."""
        return self.x0 is not None or self.sample_period is not None


@dataclass
class PairOutcome:
    """One pair's record plus what reports and studies need beyond the table.

    Attributes
    ----------
    record : dict
        The flat row (:data:`COLUMNS`).
    result : DesignResult or None
    trajectory : Trajectory or BatchTrajectory or None
    plant : Plant or None
    certificate : Certificate or None
    metrics : dict or None
        Per-member metric arrays (:func:`bench.metrics.batch_metrics`) of a batch scenario.
    disproved : dict
        Declarations the pair's own or another pair's simulation disproved (name -> why): the
        certificate uses ``report.knowledge(plant).without(disproved)``.
    loop : ClosedLoop or None
        The design's gains, checked, and the spectra of their linear closed loop (:func:`bench.checks.closed_loop`).
    lyapunov : str
        The INCONSISTENT sentence of :func:`bench.verdicts.lyapunov_note` along the simulation (empty: none).
    attenuation : str
        The sentence of :func:`bench.verdicts.attenuation_note` on the certified and measured L2 gains (empty: none).
    """

    record: dict
    result: DesignResult | None = None
    trajectory: object = None
    plant: Plant | None = None
    certificate: Certificate | None = None
    metrics: dict | None = None
    disproved: dict = field(default_factory=dict)
    loop: checks.ClosedLoop | None = None
    lyapunov: str = ""
    attenuation: str = ""


def blank_record(plant_id: str, design_id: str, **values) -> dict:
    """A record with every column NaN (flags False, text empty), then ``values``."""
    rec = {c: math.nan for c in COLUMNS}
    rec.update(plant=plant_id, design=design_id, status="", reason="", solver="", solver_status="", route="",
               sim_status="", constants="", params="", cert_level="", cert_scope="", horizon_rule="", witness="",
               sim_witness="", ceiling_how="", checked_on="", disproved="",
               feasible=False, stabilizing=None, certified=False, converged=None, in_region=None,
               **{f"cert_{lv}": "" for lv in LEVELS})
    rec.update(values)
    return rec


def _note(rec: dict, text: str) -> None:
    if text:
        rec["reason"] = (rec["reason"] + "; " if rec["reason"] else "") + text


def _jsonable(d: dict) -> str:
    """``d`` as sorted JSON: numpy scalars as Python ones, a non-finite float as null; a :class:`DesignError`
    naming ``params`` when it cannot be written."""
    try:
        d = {k: v.item() if isinstance(v, np.generic) else v for k, v in dict(d).items()}
        return json.dumps({k: None if isinstance(v, float) and not math.isfinite(v) else v for k, v in d.items()},
                          sort_keys=True, allow_nan=False)
    except (TypeError, ValueError, AttributeError) as exc:
        raise DesignError(f"params: the design's parameters cannot be written as JSON ({type(exc).__name__}: "
                          f"{exc})") from None


# -- the plant a design sees -------------------------------------------------------------------
#: Seeded states at which f and its Jacobian are probed before and after a design (:func:`_probe`).
PROBE_STATES = 3


def _own_copy(obj):
    """A copy of ``obj`` (a plant) whose arrays, dataclasses, dicts and lists are its own; callables are shared."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        new = copy.copy(obj)
        for f in dataclasses.fields(obj):
            object.__setattr__(new, f.name, _own_copy(getattr(obj, f.name)))
        return new
    if isinstance(obj, np.ndarray):
        arr = obj.copy()
        arr.setflags(write=obj.flags.writeable)
        return arr
    if isinstance(obj, dict):
        return {k: _own_copy(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_own_copy(v) for v in obj]
    return obj


def _probe(plant: Plant) -> list:
    """f and its Jacobian (when declared) at :data:`PROBE_STATES` seeded states of the initial condition's scale
    (an exception raised there is recorded as its message)."""
    rng = np.random.default_rng([0, 31])
    scale = max(1e-3, float(np.abs(plant.x0).max()), float(np.abs(plant.x_hat0).max()))
    out = []
    for x in scale * rng.standard_normal((PROBE_STATES, plant.n)):
        for fn in (plant.f, plant.jacobian):
            try:
                out.append(None if fn is None else np.array(fn(x), dtype=float))
            except Exception as exc:  # noqa: BLE001 - compared, not raised: the pipeline's own steps report it
                out.append(f"{type(exc).__name__}: {exc}")
    return out


def _differences(a, b, name: str) -> list[str]:
    """The names of the fields in which ``a`` and ``b`` differ: arrays by value, callables by identity."""
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        if type(a) is not type(b):
            return [name]
        return [d for f in dataclasses.fields(a)
                for d in _differences(getattr(a, f.name), getattr(b, f.name), f"{name}.{f.name}".lstrip("."))]
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        same = (isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.shape == b.shape and a.dtype == b.dtype
                and np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"))
        return [] if same else [name]
    if callable(a) or callable(b):
        return [] if a is b else [name]
    if isinstance(a, (dict, list, tuple)):
        if type(a) is not type(b) or len(a) != len(b) or (isinstance(a, dict) and a.keys() != b.keys()):
            return [name]
        pairs = ((f"{name}[{k!r}]", a[k], b[k]) for k in a) if isinstance(a, dict) else (
            (f"{name}[{i}]", x, y) for i, (x, y) in enumerate(zip(a, b)))
        return [d for key, x, y in pairs for d in _differences(x, y, key)]
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return []
    return [] if type(a) is type(b) and a == b else [name]


def _check_unchanged(plant: Plant, seen: Plant, before: list[np.ndarray]) -> None:
    """A :class:`DesignError` naming what differs between ``plant`` and the copy ``seen`` a design worked on
    (every field, arrays by value, callables by identity; then f and its Jacobian probed by :func:`_probe`)."""
    changed = _differences(plant, seen, "")
    if not changed and not _same_probes(before, _probe(seen)):
        changed = ["what f or its Jacobian computes"]
    if changed:
        raise DesignError(f"the design changed the plant: {', '.join(changed)} "
                          f"{'differs' if len(changed) == 1 else 'differ'}")


def _same_probes(a: list, b: list) -> bool:
    """True when two :func:`_probe` results are equal (arrays by value, NaN equal to NaN)."""
    def same(u, v) -> bool:
        if isinstance(u, np.ndarray) and isinstance(v, np.ndarray):
            return u.shape == v.shape and np.array_equal(u, v, equal_nan=True)
        return type(u) is type(v) and u == v

    return len(a) == len(b) and all(same(u, v) for u, v in zip(a, b))


def _suite_design(design) -> bool:
    """True when ``design``'s class is one of the suite's own (its module is a file of the ``designs`` package)."""
    import designs

    name = type(design).__module__
    path = getattr(sys.modules.get(name), "__file__", None)
    return (name.startswith("designs.") and path is not None
            and Path(path).resolve().is_relative_to(Path(designs.__file__).resolve().parent))


# -- the steps ---------------------------------------------------------------------------------
def _design(rec: dict, plant: Plant, design: Design, report: ConstantsReport,
            options: RunOptions) -> DesignResult | None:
    """Applicability, then the design (timed); None when there is nothing to design."""
    rec["constants"] = ("claimed by the source, checked: " if options.use_claimed else "") + report.trust
    if report.prechecks:
        rec.update(status="inapplicable", reason="; ".join(report.prechecks)
                   + ": no observer-based controller stabilizes the linear part")
        return None
    consts = resolve_constants(report, use_claimed=options.use_claimed)
    seen, before = _own_copy(plant), _probe(plant)  # the design works on a copy, compared afterwards
    why = design.applicable(seen, consts)
    if why is not None:
        _check_unchanged(plant, seen, before)
        missing = [report.unbounded[k] for k in getattr(design, "needs", ()) if k in report.unbounded]
        rec.update(status="inapplicable", reason="; ".join([why, *missing]))
        return None
    t0 = time.perf_counter()
    res = design.design(seen, consts)
    rec["design_s"] = time.perf_counter() - t0
    _check_unchanged(plant, seen, before)
    if not isinstance(res, DesignResult):
        raise DesignError(f"design: must return a DesignResult, got {checks.brief(res)}")
    params = _jsonable(res.params)
    if res.status == "feasible" and not _suite_design(design):
        res = replace(res, status="unverified")
        _note(rec, "the design says 'feasible', but the suite did not verify the design's own LMI (it is not one of "
                   "the suite's designs): unverified")
    sampled = [k for k in getattr(design, "needs", ()) if report.source.get(k, "").startswith("sampled")]
    rec.update(status=res.status, reason="; ".join(r for r in (res.reason, rec["reason"]) if r),
               feasible=res.status == "feasible", route=res.route or "",
               lmi_margin=res.margin, lmi_size=res.lmi_size or math.nan, solver=res.solver or "",
               solver_status=res.solver_status or "", n_solves=res.n_solves, compile_s=res.compile_s,
               solve_s=res.solve_s, params=params)
    if sampled and res.status in GAIN_STATUSES:
        _note(rec, f"designed with sampled {', '.join(sampled)} (lower bounds): the design itself guarantees nothing")
    return res


def _certify(rec: dict, plant: Plant, res: DesignResult, report: ConstantsReport, options: RunOptions,
             loop: checks.ClosedLoop, know: Knowledge | None = None) -> Certificate | None:
    """The certificate ladder (or what ``options.certificate`` asks) of ``loop``'s gains, recorded level by level."""
    if options.certificate == "none":
        return None
    if res.K is None:
        rec.update({f"cert_{lv}": "inapplicable" for lv in LEVELS})
        _note(rec, "certificate: no fixed observer gain (the estimator is time-varying): no quadratic certificate "
                   "applies")
        return None
    know = know if know is not None else report.knowledge(plant)
    t0 = time.perf_counter()
    if options.certificate == "ladder":
        cert = certify(plant, loop.K, loop.F, know, loop=loop)
    elif options.certificate == "own":  # no SDP: only the design's own verified certificate, if any
        cert = Certificate({lv: LevelResult(lv, "inapplicable", reason="the ladder was not run (certificate='own')")
                            for lv in LEVELS})
    else:  # strongest level first, at rate 0, until one certifies
        cert = Certificate({})
        for lv in reversed(LEVELS):
            cert.levels.update(certify(plant, loop.K, loop.F, know, levels=(lv,), rates=False, loop=loop).levels)
            if cert.levels[lv].certified:
                break
        cert.levels = {lv: cert.levels[lv] for lv in LEVELS if lv in cert.levels}
    refused = adopt(cert, res.certificate, plant, loop, know)
    if options.certificate == "ladder":
        explain(cert, plant, loop.K, loop.F, know, loop=loop)
        rec["rate_ceiling"], rec["ceiling_how"] = ceiling(cert, plant, loop.K, loop.F, know)
    rec["cert_s"] = time.perf_counter() - t0
    for lv, r in cert.levels.items():
        rec[f"cert_{lv}"], rec[f"decay_{lv}"] = r.status, r.decay_rate
    best = cert.best
    applicable = [r for r in cert.levels.values() if r.status != "inapplicable"]
    shown = best or (applicable[-1] if applicable else None)
    rec.update(certified=best is not None, cert_level=best.level if best else "",
               decay_rate=best.decay_rate if best else math.nan,
               contraction=math.exp(-best.decay_rate * plant.dt) if best and plant.discrete else math.nan,
               cert_margin=shown.margin if shown is not None else math.nan)
    _record_gains(rec, cert, plant)
    rec.update(certificate_scope(best.P if best else None, best.radius if best else None, plant.x0, plant.x_hat0,
                                 H=best.region_H if best else None))
    rec["witness"] = "; ".join(w.kind for w in cert.witnesses)
    if best is not None and math.isfinite(rec["rate_ceiling"]):
        rec["rate_ratio"] = best.decay_rate / rec["rate_ceiling"] if rec["rate_ceiling"] > 0 else math.nan
    _note(rec, refused)
    if cert.witnesses:
        _note(rec, "no global certificate exists: " + "; and ".join(w.text for w in cert.witnesses))
    if best is None:
        _note(rec, f"certificate: {cert.reason(witnessed=bool(cert.witnesses))}")
        _note(rec, cert.local_note)
    elif best is cert.local:
        _note(rec, f"{best.reason}, rate {best.decay_rate:.3g}")
    elif rec["cert_scope"] == "local":
        _note(rec, f"certified locally: the level set V <= {rec['level_set']:.3g} stays in ||x||, ||x_hat|| <= "
                   f"{rec['cert_radius']:g}, but V(x0, e0) = {rec['level_x0']:.3g} lies outside it")
    return cert


def _record_gains(rec: dict, cert: Certificate, plant: Plant) -> None:
    """The strongest certified level's L2 gains (:meth:`bench.certify.Certificate.gain`) and the radius they hold
    on (NaN: globally); a note when a plant with disturbance inputs gets none."""
    gains = {z: cert.gain(z) for z in ("e", "x")}
    rec.update(l2_gain_e=math.nan, l2_gain_x=math.nan, l2_radius=math.nan)
    radii = []
    for z, g in gains.items():
        if g is not None and g.certified:
            rec[f"l2_gain_{z}"] = g.gain
            radii.append(math.inf if g.radius is None else g.radius)
    if radii and min(radii) < math.inf:
        rec["l2_radius"] = min(radii)
    if plant.q == 0 or not any(r.l2 for r in cert.levels.values()):
        return
    missing = [f"{z}: {g.status}: {g.reason}" for z, g in gains.items() if g is not None and not g.certified]
    if not cert.certified:
        _note(rec, "L2 gains: no level certifies stability, so none proves a finite gain")
    elif cert.best is cert.local and not any(g is not None and g.certified for g in gains.values()):
        _note(rec, "L2 gains: only a certificate from x0 (no level of the ladder): no gain certified")
    elif missing:
        _note(rec, "L2 gain not certified (" + "; ".join(missing) + ")")


def _simulate(out: PairOutcome, options: RunOptions, scenario: Scenario | None, report: ConstantsReport) -> None:
    """Simulate (one trajectory or the scenario's batch), record the metrics, check the declarations."""
    rec, plant, res = out.record, out.plant, out.result
    own = res.estimator is None  # a sampled-time estimator keeps the plant's horizon (a multiple of its dt)
    best = out.certificate.best if out.certificate is not None and own else None
    T, rule = simulation_horizon(plant.t_final, fixed=options.t_final, cap_factor=options.horizon_cap,
                                 cert_rate=best.decay_rate if best is not None else math.nan,
                                 cond_p=_cond(best), linear_rate=out.loop.linearised_rate if own else math.nan)
    rec.update(horizon_s=T, horizon_rule=rule)
    sim = options.sim  # with the plant horizon's grid density and what is left of the pair's time limit
    if T > plant.t_final:
        sim = replace(sim, n_points=int(min(20 * sim.n_points, math.ceil(sim.n_points * T / plant.t_final))))
    left = remaining_time()
    if left is not None:  # max_wall_s is None or > 0
        sim = replace(sim, max_wall_s=max(min(left, sim.max_wall_s or math.inf), 1e-3))
    rec["noise"] = options.noise
    batch = scenario is not None and scenario.batch
    if batch:
        m = _simulate_batch(out, plant, res, T, scenario, sim.max_wall_s)
    else:
        traj = simulate_controller(plant, out.loop.F, K=out.loop.K, estimator=res.estimator, t_final=T,
                                   noise=options.noise, noise_dt=options.noise_dt, seed=options.seed, options=sim,
                                   loop=out.loop)
        out.trajectory = traj
        rec.update(sim_s=traj.wall_s, sim_status=traj.status)
        if traj.status == "timeout" and options.timeout is not None:
            raise DeadlineExceeded(f"the simulation ({traj.message})")
        m = trajectory_metrics(traj.t, traj.x, traj.x_hat, traj.u, finished=traj.status == "ok",
                               noisy=options.noise > 0, dense=traj.dense)
        traj.dense = None  # measured: the rest of the run needs the grid only (and pickles it to the parent)
        if traj.status != "ok":
            _note(rec, f"simulation {traj.status}: {traj.message}")
        _attenuation(out, options, T, sim)
    rec.update({k: m[k] for k in ("converged", "settling_x_s", "settling_e_s", "final_x", "final_e", "tail_rate",
                                  "iae_e", "rms_e", "peak_u", "max_norm")})
    tr = out.trajectory
    X, XH = np.asarray(tr.x, dtype=float), np.asarray(tr.x_hat, dtype=float)
    _check_declarations(out, report, options, X, XH)
    radius = rec["cert_radius"]
    best = out.certificate.best if out.certificate is not None else None
    H = best.region_H if best is not None else None
    rec["in_region"] = _in_region(rec["max_norm"], radius, H, tr)
    rec["sim_witness"] = _witness(np.asarray(tr.t, dtype=float), X, XH, radius, H)
    applies = best is not None and res.K is not None and res.estimator is None and options.noise == 0 and (
        not batch or (scenario.sample_period is None and rec["cert_scope"] == "global"))
    if applies:
        rec["cert_horizon_s"] = certified_horizon(best.decay_rate, _cond(best))
        opts = sim if not batch else (scenario.options or _batch_options())
        out.lyapunov = _lyapunov(tr, best, opts)
        _note(rec, out.lyapunov)


def _batch_options() -> SimOptions:
    from bench.batch import BATCH_OPTIONS

    return BATCH_OPTIONS


#: The relative rounding :func:`_lyapunov` allows per component of a stepped (discrete-time) run, which has no
#: integrator error: ``V(z_k) <= r^(2k) V(z_0)`` holds up to the floating point of the steps.
STEP_RTOL = 1e-12


def _lyapunov(tr, best: LevelResult, sim: SimOptions) -> str:
    """:func:`bench.verdicts.lyapunov_note` of a certificate along a simulation, inside its region (a discrete
    certificate, ``best.dt > 0``, at the steps ``t_k = k dt``: ``V(z_k) <= r^(2k) V(z_0) = exp(-2 lam t_k) V(z_0)``,
    with the rounding of the steps, :data:`STEP_RTOL`, instead of an integrator's tolerances)."""
    X, XH = np.asarray(tr.x, dtype=float), np.asarray(tr.x_hat, dtype=float)
    inside = None
    if best.radius is not None:
        with np.errstate(invalid="ignore"):
            inside = _region_size(X, XH, best.region_H) <= best.radius * (1 + 1e-9)
    atol, rtol = (0.0, STEP_RTOL) if best.dt > 0 else (sim.atol, sim.rtol)
    return lyapunov_note(np.asarray(tr.t, dtype=float), X, XH, best.P, best.decay_rate, inside=inside,
                         atol=atol, rtol=rtol)


def _region_size(X: np.ndarray, XH: np.ndarray, H: np.ndarray | None) -> np.ndarray:
    """``max(||x||, ||x_hat||)``, or ``max |H x|, |H x_hat|`` with H, at each sample (axis 0 the state)."""
    if H is None:
        return np.maximum(np.linalg.norm(X, axis=0), np.linalg.norm(XH, axis=0))
    return np.maximum(np.abs(np.tensordot(H, X, axes=(1, 0))).max(axis=0),
                      np.abs(np.tensordot(H, XH, axes=(1, 0))).max(axis=0))


def _attenuation(out: PairOutcome, options: RunOptions, T: float, sim: SimOptions) -> None:
    """With ``options.disturbance``: the pair simulated from ``z(0) = 0`` with the seeded disturbance
    (:mod:`bench.disturbance`, noise-free), its ratios ``l2_measured_e``, ``l2_measured_x`` and their verdict."""
    from bench.disturbance import SeededDisturbance, measured_attenuation, window

    rec, plant, res = out.record, out.plant, out.result
    rec["disturbance"] = options.disturbance if plant.q > 0 else 0.0  # the amplitude applied
    if options.disturbance <= 0 or plant.q == 0:
        return
    w = SeededDisturbance(options.disturbance, plant.q, window(plant.t_final, options.t_final), seed=options.seed,
                          dt=plant.dt)
    zero = np.zeros(plant.n)
    traj = simulate_controller(plant, out.loop.F, K=out.loop.K, estimator=res.estimator, t_final=T, seed=options.seed,
                               options=sim, loop=out.loop, x0=zero, x_hat0=zero, disturbance=w)
    if traj.status == "timeout" and options.timeout is not None:
        raise DeadlineExceeded(f"the disturbance simulation ({traj.message})")
    rec["l2_measured_e"], rec["l2_measured_x"] = measured_attenuation(traj.t, traj.x, traj.x_hat, w(traj.t),
                                                                      plant.dt)
    with np.errstate(invalid="ignore"):
        size = _region_size(np.asarray(traj.x, dtype=float), np.asarray(traj.x_hat, dtype=float), None)
    rec["l2_max_norm"] = float(np.max(size)) if size.size and np.all(np.isfinite(size)) else math.inf
    if traj.status != "ok":
        _note(rec, f"disturbance simulation {traj.status} ({traj.message}): the measured L2 ratios cover "
                   f"[0, {float(traj.t[-1]):.4g} s] only")
    _judge_attenuation(out)


def _judge_attenuation(out: PairOutcome) -> None:
    """The verdict of the certified L2 gains on the measured ratios (:func:`bench.verdicts.attenuation_note`), in the
    record's reason and in ``out.attenuation``; an earlier verdict (before a re-certification) is replaced."""
    rec = out.record
    if out.attenuation:
        rec["reason"] = rec["reason"].replace(f"; {out.attenuation}", "").replace(out.attenuation, "")
    out.attenuation = attenuation_note(rec)
    r, size = rec.get("l2_radius", math.nan), rec.get("l2_max_norm", math.nan)
    if math.isfinite(r) and math.isfinite(rec.get("l2_measured_x", math.nan)) and not size <= r:
        out.attenuation = (f"the disturbance run left ||x||, ||x_hat|| <= {r:g} (it reached {size:.4g}), where the "
                           "certified L2 gains hold: measured and certified gains not compared")
    _note(rec, out.attenuation)


def _cond(best: LevelResult | None) -> float:
    """The condition number of a certificate's P (NaN without one)."""
    return float(np.linalg.cond(best.P)) if best is not None and best.P is not None else math.nan


def _check_declarations(out: PairOutcome, report: ConstantsReport, options: RunOptions, X: np.ndarray,
                        XH: np.ndarray) -> None:
    """Check the certificate's declarations along the simulation; re-certify without any disproved."""
    rec, plant = out.record, out.plant
    if out.certificate is None:  # nothing certified uses a declaration: the Jacobian alone (the EKF uses it)
        know = Knowledge()
    else:
        know = report.knowledge(plant).without(out.disproved)
    bad, checked = check_trajectory(plant, know, X, XH, checked_on=report.checked_on, seed=options.seed)
    rec["checked_on"] = checked
    if not bad:
        return
    rec["disproved"] = json.dumps(bad, sort_keys=True)
    _note(rec, "DECLARATION DISPROVED by the simulation: " + "; ".join(bad.values())
          + ": the pair is re-certified without it")
    out.disproved = {**out.disproved, **bad}
    out.certificate = _certify(rec, plant, out.result, report, options, out.loop, know=know.without(bad))
    _judge_attenuation(out)


def _witness(t: np.ndarray, X: np.ndarray, XH: np.ndarray, radius: float, H: np.ndarray | None = None) -> str:
    """Time and state of the first exit from the certified region, else of the last finite state."""
    if X.ndim == 3:  # (n, N, T): the member with the largest last finite state
        last = np.nan_to_num(np.linalg.norm(X[:, :, -1], axis=0), nan=np.inf)
        j = int(np.argmax(last))
        X, XH = X[:, j, :], XH[:, j, :]
    if X.shape[1] == 0:
        return ""
    size = _region_size(X, XH, H)
    finite = np.isfinite(size)
    k = int(np.flatnonzero(finite)[-1]) if finite.any() else X.shape[1] - 1
    if math.isfinite(radius) and np.any(finite & (size > radius)):
        k = int(np.argmax(finite & (size > radius)))
    return f"t = {t[min(k, t.size - 1)]:.4g} s, x = {checks.vector(X[:, k])}, x_hat = {checks.vector(XH[:, k])}"


def _simulate_batch(out: PairOutcome, plant: Plant, res: DesignResult, T: float, scenario: Scenario,
                    max_wall_s: float | None) -> dict:
    """A batch scenario: per-member metrics in ``out.metrics``; the record holds the worst member."""
    from bench.batch import BATCH_OPTIONS, simulate_batch, simulate_digital_batch

    if res.K is None:
        raise ValueError("a batch scenario needs fixed gains K, F (the estimator is not a fixed gain)")
    X = scenario.x0 if scenario.x0 is not None else plant.x0[:, None]
    XH = scenario.x_hat0 if scenario.x_hat0 is not None else plant.x_hat0[:, None]
    if scenario.sample_period is not None:
        tr = simulate_digital_batch(plant, res.K, res.F, X, XH, h=scenario.sample_period, t_final=T,
                                    discretisation=scenario.discretisation)
    else:
        opts = replace(scenario.options or BATCH_OPTIONS, max_wall_s=max_wall_s)
        tr = simulate_batch(plant, res.K, res.F, X, XH, t_final=T, options=opts)
    out.trajectory = tr
    m = tr.metrics()
    out.metrics = m
    out.record.update(sim_s=tr.wall_s, sim_status=tr.status if not tr.diverged.any() else "diverged")
    worst = {k: float(np.max(v)) for k, v in m.items() if k != "converged"}
    worst["tail_rate"] = float(np.min(m["tail_rate"]))
    return {"converged": bool(np.all(m["converged"])), **worst}


def _in_region(max_norm: float, radius: float, H, tr) -> bool | None:
    """Whether ``|H x|, |H x_hat| <= radius`` along ``tr`` (given H), else ``max_norm <= radius``; None if unknown."""
    if not math.isfinite(radius):
        return None
    if H is None:
        return bool(max_norm <= radius)
    if tr is None:
        return None
    size = _region_size(np.asarray(tr.x, dtype=float), np.asarray(tr.x_hat, dtype=float), H)
    return bool(size.max() <= radius * (1 + 1e-9))


def rejudge(outcomes: list[PairOutcome], reports: dict, options: RunOptions) -> list[PairOutcome]:
    """Re-certify every certified pair of a plant without the declarations (true or false for the plant, not
    for one pair) another pair's simulation disproved, and judge its convergence again (``outcomes`` changed
    in place and returned; ``reports``: plant id -> constants).
    """
    found: dict[str, dict[str, str]] = {}
    for o in outcomes:
        if o.record.get("disproved"):
            for k, why in json.loads(o.record["disproved"]).items():
                found.setdefault(o.record["plant"], {}).setdefault(k, f"{why} (simulation of {o.record['design']})")
    for o in outcomes:
        rec, pid = o.record, o.record["plant"]
        plant, res = o.plant, o.result
        if pid not in found or not rec["certified"] or plant is None or res is None or res.K is None \
                or pid not in reports:
            continue
        if rec["disproved"]:  # an outcome from the cache carries its own disproofs in the record only
            o.disproved = {**json.loads(rec["disproved"]), **o.disproved}
        know = reports[pid].knowledge(plant).without(o.disproved)
        extra = {k: v for k, v in found[pid].items() if k not in know.untrusted}
        if not extra:
            continue
        try:
            _rejudge(o, reports[pid], options, know, extra)
        except KeyboardInterrupt:
            raise
        except BaseException as exc:  # plugin code (f in the equilibrium search) never ends the run
            if options.fail_fast:
                raise
            _failed(o, exc, "re-certification")
    return outcomes


def time_domain_mismatch(design, plant: Plant, design_id: str) -> str:
    """Why ``design`` does not apply to ``plant``'s time domain (empty if it does): a design lists the
    domains it has a form for in ``time_domains`` (default ``("continuous",)``, :class:`designs.Design`)."""
    domain = "discrete" if plant.discrete else "continuous"
    domains = getattr(design, "time_domains", ("continuous",))
    if domain in domains:
        return ""
    return f"{design_id} has no {domain}-time form" + (f" (the plant is sampled every dt = {plant.dt:g} s)"
                                                       if plant.discrete else "")


def _rejudge(o: PairOutcome, report: ConstantsReport, options: RunOptions, know: Knowledge, extra: dict) -> None:
    """Re-certify one pair without the declarations ``extra`` and judge its simulation again (:func:`rejudge`)."""
    rec, plant, res = o.record, o.plant, o.result
    old = convergence_note(rec) if rec["sim_status"] else ""
    if old and rec["reason"].endswith(old):
        rec["reason"] = rec["reason"][: -len(old)].rstrip("; ")
    if o.lyapunov:
        rec["reason"] = rec["reason"].replace(f"; {o.lyapunov}", "").replace(o.lyapunov, "")
        o.lyapunov = ""
    _note(rec, "DECLARATION DISPROVED by another pair's simulation: " + "; ".join(extra.values())
          + ": the pair is re-certified without it")
    o.disproved = {**o.disproved, **extra}
    loop = o.loop if o.loop is not None else checks.closed_loop(plant, res.K, res.F)  # a cached outcome
    o.certificate = _certify(rec, plant, res, report, options, loop, know=know.without(extra))
    _judge_attenuation(o)
    best = o.certificate.best if o.certificate is not None else None
    if math.isfinite(rec["cert_horizon_s"]):
        rec["cert_horizon_s"] = certified_horizon(best.decay_rate, _cond(best)) if best is not None else math.nan
        tr = o.trajectory
        if best is not None and tr is not None and np.ndim(tr.x) == 2:
            o.lyapunov = _lyapunov(tr, best, options.sim)
            _note(rec, o.lyapunov)
    if rec["sim_status"]:
        rec["in_region"] = _in_region(rec["max_norm"], rec["cert_radius"],
                                      best.region_H if best is not None else None, o.trajectory)
        _note(rec, convergence_note(rec))


# -- the pair ----------------------------------------------------------------------------------
def evaluate_pair(
    plant: Plant,
    design: Design | str,
    report: ConstantsReport,
    options: RunOptions = RunOptions(),
    *,
    design_id: str | None = None,
    prior: PairOutcome | None = None,
    scenario: Scenario | None = None,
) -> PairOutcome:
    """Evaluate one (plant, design) pair: design, verify, certify, simulate, measure, judge.

    Never raises (unless ``options.fail_fast``): a failure is a row with status ``error`` and the message, a
    pair over ``options.timeout`` a ``timeout`` row that claims nothing.

    Parameters
    ----------
    plant : Plant
    design : Design or str
        The design object, or a registry id.
    report : ConstantsReport
        The plant's constants (computed once per plant, :func:`bench.constants.compute_constants`).
    options : RunOptions
    design_id : str, optional
        The id shown in the record (default: ``design`` when it is an id, else its class name).
    prior : PairOutcome, optional
        An earlier outcome of the same pair: its design result and certificate are re-used (they
        do not depend on the scenario, the noise or the sample period).
    scenario : Scenario, optional
        A batch of initial conditions or a digital implementation to simulate.

    Returns
    -------
    PairOutcome
    """
    if design_id is None:
        design_id = design if isinstance(design, str) else type(design).__name__
    if options.timeout is None:
        return _evaluate(plant, design, design_id, report, options, prior, scenario)
    try:
        with time_limit(options.timeout), hard_stop(1.1 * options.timeout + 0.5):
            return _evaluate(plant, design, design_id, report, options, prior, scenario)
    except DeadlineExceeded as exc:  # the hard stop fired outside the pair's own handler
        rec = blank_record(plant.id, design_id, dt=float(plant.dt))
        _timed_out(rec, exc, options, "pair")
        return PairOutcome(rec, plant=plant)


def _timed_out(rec: dict, exc: DeadlineExceeded, options: RunOptions, phase: str) -> None:
    """Turn ``rec`` into a ``timeout`` row: no claim survives, the reason says how far it got."""
    got = [s for s in (rec["status"], "certified" if rec["certified"] else "") if s]
    note = f" (reached before: {', '.join(got)})" if got else ""
    _no_claims(rec, status="timeout",
               reason=f"timeout: the pair exceeded {options.timeout:g} s during the {phase}, in {exc.where}{note}")


def _failed(out: PairOutcome, exc: BaseException, phase: str) -> None:
    """Turn ``out`` into an ``error`` row (any exception of plugin code, SystemExit included): no claim survives,
    the reason names the exception and where it was raised."""
    reason = f"{type(exc).__name__}: {exc}"
    tb = traceback.extract_tb(exc.__traceback__)
    if tb:
        reason += f" (at {tb[-1].filename.rsplit('/', 1)[-1]}:{tb[-1].lineno}, during the {phase})"
    _no_claims(out.record, status="error", reason=reason)
    out.result = out.trajectory = out.certificate = None


def _no_claims(rec: dict, **values) -> None:
    """Blank every claim of ``rec`` (feasible, stabilizing, converged and :data:`CERT_COLUMNS`), then ``values``."""
    blank = blank_record(rec["plant"], rec["design"])
    rec.update({c: blank[c] for c in ("feasible", "stabilizing", "converged", *CERT_COLUMNS)}, **values)


#: Record columns a ``prior`` does not give: the pair's ids and what the simulation measures.
_NOT_PRIOR = {"plant", "design", "converged", "in_region", "max_norm", "sim_s", "horizon_s", "horizon_rule",
              "cert_horizon_s", "sim_status", "sim_witness", "settling_x_s", "settling_e_s", "final_x",
              "final_e", "tail_rate", "iae_e", "rms_e", "peak_u", "noise", "checked_on", "disproved",
              "l2_measured_e", "l2_measured_x", "disturbance", "l2_max_norm"}


def _evaluate(plant, design, design_id, report, options, prior, scenario) -> PairOutcome:
    from bench.registry import DESIGNS

    rec = blank_record(plant.id, design_id, dt=float(plant.dt))
    out = PairOutcome(rec, plant=plant)
    phase = "design"
    solves = lmi.solve_tally()["n"]
    try:
        if prior is not None:
            rec.update({k: prior.record[k] for k in COLUMNS if k not in _NOT_PRIOR})
            out.result, out.certificate, out.disproved = prior.result, prior.certificate, dict(prior.disproved)
        else:
            obj = DESIGNS.create(design) if isinstance(design, str) else design
            why = time_domain_mismatch(obj, plant, design_id)
            if why:
                rec.update(status="inapplicable", reason=why)
                return out
            out.result = _design(rec, plant, obj, report, options)
            phase = "verification"
        if out.result is None or not out.result.has_controller:
            return out
        # the gains' shapes (of this plant) and, for a new design, the eigenvalues of their linear closed loop
        out.loop = loop = checks.closed_loop(plant, out.result.K, out.result.F, optional_K=True)
        if prior is None:
            # max Re of the eigenvalues; discrete time: ln(max |eig|) / dt, the continuous equivalent's
            rec.update(max_re_eig_x=loop.growth_x, norm_F=float(np.linalg.norm(loop.F, 2)))
            if loop.K is not None:  # else a run-time estimator: no fixed observer matrix to check
                rec.update(max_re_eig_e=loop.growth_e, stabilizing=loop.stable,
                           norm_K=float(np.linalg.norm(loop.K, 2)))
            phase = "certificate"
            out.certificate = _certify(rec, plant, out.result, report, options, loop)
        if options.simulate:
            phase = "simulation"
            _simulate(out, options, scenario, report)
        if rec["sim_status"]:
            _note(rec, convergence_note(rec))
    except DeadlineExceeded as exc:  # --timeout: a row, never a claim
        if options.timeout is None:
            raise
        _timed_out(rec, exc, options, phase)
        out.result = out.trajectory = out.certificate = None
    except KeyboardInterrupt:  # the user's Ctrl-C stops the run
        raise
    except BaseException as exc:  # one failing pair never kills a run (nor a plugin's SystemExit)
        if options.fail_fast:
            raise
        _failed(out, exc, phase)
    finally:
        rec["sdp_solves"] = lmi.solve_tally()["n"] - solves
    return out
