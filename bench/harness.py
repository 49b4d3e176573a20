"""The harness: for every (plant, design) pair, design -> verify -> certify -> simulate -> metrics.

Each pair becomes one flat record with a fixed set of columns (:data:`COLUMNS`), NaN where a
value does not apply. An exception inside one pair becomes a row with status ``error`` and the
message; the run goes on (``fail_fast=True`` re-raises instead).

Time limits (``RunOptions.timeout``, ``--timeout``): a pair that runs longer becomes a row with
status ``timeout`` (never feasible, certified or converged) and the run goes on. The limit is
enforced cooperatively where the time goes - every SDP solve gets the remaining time as the
solver's own limit (Clarabel ``time_limit``, SCS ``time_limit_secs``) and the simulation checks
a wall-clock budget at every right-hand-side evaluation (:class:`bench.simulate.SimOptions`
``max_wall_s``) - plus, where the pair runs in the main thread of its process (serial runs and
``--jobs N`` worker processes), a ``SIGALRM`` hard stop shortly after the deadline for code that
checks nothing (a design stuck in a Python loop, cvxpy's compilation). Code stuck inside a
native call that checks no limit cannot be interrupted in-process (documented limitation).
A plant's constants, computed once per plant and shared by its pairs, get ``CONSTANTS_TIMEOUT_FACTOR``
times the pair limit; when they time out, every pair of the plant is a ``timeout`` row.

Caching (``run(..., cache=...)``, :mod:`bench.cache`): finished pairs and constants are stored
on disk as they finish, so an interrupted run resumes where it stopped.
"""

from __future__ import annotations

import json
import math
import sys
import time
import traceback
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Callable, Iterator

import numpy as np

from bench.certify import certify
from bench.constants import ConstantsReport, compute_constants, resolve_constants
from bench.metrics import trajectory_metrics
from bench.registry import DESIGNS, PLANTS
from bench.simulate import SimOptions, Trajectory, simulate, simulate_sampled
from designs._core import DesignResult
from designs._lmi import DeadlineExceeded, remaining_time, time_limit
from plants._core import Plant

__all__ = ["COLUMNS", "CONSTANTS_TIMEOUT_FACTOR", "PairOutcome", "RunOptions", "RunResult", "run", "run_pair"]

#: A plant's constants may take this many times the per-pair ``timeout`` (they are computed once
#: for all the plant's pairs, with thousands of evaluations of f).
CONSTANTS_TIMEOUT_FACTOR = 10

#: Columns of every record, in order.
COLUMNS = [
    "plant", "design", "status", "reason", "feasible", "stabilizing", "certified", "converged",
    "decay_rate", "cert_margin", "lmi_margin", "lmi_size", "solver", "solver_status", "n_solves",
    "compile_s", "solve_s", "design_s", "cert_s", "sim_s", "max_re_eig_x", "max_re_eig_e",
    "sim_status", "settling_x_s", "settling_e_s", "final_x", "final_e", "iae_e", "rms_e", "peak_u",
    "noise", "norm_K", "norm_F", "constants", "params",
]


@dataclass(frozen=True, kw_only=True)
class RunOptions:
    """Options of a run.

    Parameters
    ----------
    seed : int
        Seed of the constants sampler (the only randomness of a default run).
    use_claimed : bool
        Design with the constants the source claims instead of the valid ones (the
        certificate always uses the valid ones).
    n_samples : int
        Random pairs for the sampled constants.
    sim : SimOptions
    fail_fast : bool
        Re-raise the first exception instead of recording an ``error`` row.
    t_final : float, optional
        Simulation horizon for every plant (default: each plant's own ``t_final``).
    noise : float
        Standard deviation of a seeded Gaussian measurement noise (0: noise-free). With noise,
        fixed-gain observers are simulated with the noise held over ``noise_dt`` intervals
        (:func:`bench.simulate.simulate_sampled`), and the EKF at its own sample time.
    noise_dt : float
        Sample period of the noise for fixed-gain observers.
    timeout : float, optional
        Wall-clock limit in seconds of each pair (a plant's constants get
        :data:`CONSTANTS_TIMEOUT_FACTOR` times as long); a pair that exceeds it becomes a
        ``timeout`` row. None: no limit. Not part of the cache key: a cached pair finished
        within whatever limit it had.
    """

    seed: int = 0
    use_claimed: bool = False
    n_samples: int = 20000
    sim: SimOptions = field(default_factory=SimOptions)
    fail_fast: bool = False
    t_final: float | None = None
    noise: float = 0.0
    noise_dt: float = 0.01
    timeout: float | None = None

    def __post_init__(self) -> None:
        if self.timeout is not None and not (isinstance(self.timeout, (int, float)) and math.isfinite(self.timeout)
                                             and self.timeout > 0):
            raise ValueError(f"timeout: must be None or a finite number of seconds > 0, got {self.timeout!r}")
        if not (math.isfinite(self.noise) and self.noise >= 0):
            raise ValueError(f"noise: must be finite and >= 0, got {self.noise!r}")
        if not (math.isfinite(self.noise_dt) and self.noise_dt > 0):
            raise ValueError(f"noise_dt: must be finite and > 0, got {self.noise_dt!r}")
        if self.t_final is not None and not (math.isfinite(self.t_final) and self.t_final > 0):
            raise ValueError(f"t_final: must be finite and > 0, got {self.t_final!r}")
        if self.n_samples < 1:
            raise ValueError(f"n_samples: must be >= 1, got {self.n_samples!r}")


@dataclass
class PairOutcome:
    """One pair's record plus what the report needs beyond the table."""

    record: dict
    result: DesignResult | None = None
    trajectory: Trajectory | None = None
    plant: Plant | None = None


@dataclass
class RunResult:
    """Everything a run produced.

    ``cache_hits`` / ``cache_misses`` count pairs taken from / computed despite an enabled
    cache (both 0 without one); ``cache_dir`` is the cache folder or None.
    """

    outcomes: list[PairOutcome]
    constants: dict[str, ConstantsReport]
    constants_errors: dict[str, str]
    options: RunOptions
    wall_s: float
    cache_hits: int = 0
    cache_misses: int = 0
    cache_dir: str | None = None

    def frame(self):
        """The records as a pandas DataFrame with columns :data:`COLUMNS`."""
        import pandas as pd

        return pd.DataFrame([o.record for o in self.outcomes], columns=COLUMNS)


def _blank(plant_id: str, design_id: str) -> dict:
    rec = {c: math.nan for c in COLUMNS}
    rec.update(plant=plant_id, design=design_id, status="", reason="", solver="", solver_status="",
               sim_status="", constants="", params="", feasible=False, stabilizing=False, certified=False,
               converged=False)
    return rec


def _jsonable(d: dict) -> str:
    def conv(v):
        if isinstance(v, (np.floating, float)):
            return None if not math.isfinite(float(v)) else float(v)
        if isinstance(v, (np.integer,)):
            return int(v)
        return v

    return json.dumps({k: conv(v) for k, v in d.items()}, sort_keys=True)


@contextmanager
def _hard_stop(seconds: float | None) -> Iterator[None]:
    """Raise :class:`DeadlineExceeded` from a ``SIGALRM`` after ``seconds`` (main thread only).

    Does nothing off the main thread, without ``setitimer`` (Windows), or when someone else
    already uses ``SIGALRM`` (e.g. pytest-timeout).
    """
    import signal
    import threading

    usable = (seconds is not None and hasattr(signal, "setitimer")
              and threading.current_thread() is threading.main_thread()
              and signal.getsignal(signal.SIGALRM) in (signal.SIG_DFL, None)
              and signal.getitimer(signal.ITIMER_REAL)[0] == 0)
    if not usable:
        yield
        return

    def stop(signum, frame):
        raise DeadlineExceeded("code that checks no time limit (hard stop by SIGALRM)")

    signal.signal(signal.SIGALRM, stop)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, signal.SIG_DFL)


def _sim_options(options: RunOptions) -> SimOptions:
    """``options.sim`` with a wall-clock budget of what is left of the pair's time limit."""
    left = remaining_time()
    if left is None:
        return options.sim
    own = options.sim.max_wall_s
    return replace(options.sim, max_wall_s=max(min(left, own if own is not None else math.inf), 1e-3))


def _timed_out(rec: dict, exc: DeadlineExceeded, options: RunOptions, phase: str) -> None:
    """Turn ``rec`` into a ``timeout`` row: no claim survives, the reason says how far it got."""
    got = [rec["status"]] if rec["status"] else []
    if rec["certified"]:
        got.append("certified")
    note = f" (reached before: {', '.join(got)})" if got else ""
    rec.update(status="timeout", feasible=False, certified=False, converged=False, stabilizing=False,
               reason=f"timeout: the pair exceeded {options.timeout:g} s during the {phase}, in {exc.where}{note}")


def run_pair(plant: Plant, design_id: str, report: ConstantsReport, options: RunOptions) -> PairOutcome:
    """Run one (plant, design) pair; never raises unless ``options.fail_fast``.

    With ``options.timeout`` the pair runs under that wall-clock limit (see the module
    docstring) and becomes a ``timeout`` row when it exceeds it.

    Parameters
    ----------
    plant : Plant
    design_id : str
    report : ConstantsReport
        The plant's constants (computed once per plant).
    options : RunOptions

    Returns
    -------
    PairOutcome
    """
    if options.timeout is None:
        return _run_pair(plant, design_id, report, options)
    try:
        with time_limit(options.timeout), _hard_stop(1.1 * options.timeout + 0.5):
            return _run_pair(plant, design_id, report, options)
    except DeadlineExceeded as exc:  # the hard stop fired outside _run_pair's own handler
        rec = _blank(plant.id, design_id)
        _timed_out(rec, exc, options, "pair")
        return PairOutcome(rec, plant=plant)


def _run_pair(plant: Plant, design_id: str, report: ConstantsReport, options: RunOptions) -> PairOutcome:
    rec = _blank(plant.id, design_id)
    out = PairOutcome(rec, plant=plant)
    phase = "design"
    try:
        design = DESIGNS.create(design_id)
        consts = resolve_constants(report, use_claimed=options.use_claimed)
        rec["constants"] = "claimed" if options.use_claimed else "valid"
        why = design.applicable(plant, consts)
        if why is not None:
            rec.update(status="inapplicable", reason=why)
            return out
        t0 = time.perf_counter()
        res = design.design(plant, consts)
        rec["design_s"] = time.perf_counter() - t0
        out.result = res
        rec.update(
            status=res.status, reason=res.reason, feasible=res.status == "feasible", lmi_margin=res.margin,
            lmi_size=res.lmi_size or math.nan, solver=res.solver or "", solver_status=res.solver_status or "",
            n_solves=res.n_solves, compile_s=res.compile_s, solve_s=res.solve_s, params=_jsonable(res.params),
        )
        if not res.has_controller:
            return out
        F = np.asarray(res.F, dtype=float)
        if F.shape != (plant.m, plant.n):
            raise ValueError(f"design {design_id!r} returned F of shape {F.shape}; expected ({plant.m}, {plant.n})")
        ex = float(np.linalg.eigvals(plant.A + plant.B @ F).real.max())
        rec.update(max_re_eig_x=ex, norm_F=float(np.linalg.norm(F, 2)), noise=options.noise)
        T = options.t_final if options.t_final is not None else plant.t_final
        phase = "simulation"
        if res.estimator is not None:  # a run-time estimator (EKF): sampled time, no fixed K
            from bench.estimators import ContinuousDiscreteEKF

            spec = res.estimator
            spec.check_horizon(T)
            rec.update(stabilizing=bool(ex < 0), certified=False)
            note = ("no fixed observer gain: the EKF is time-varying, so the quadratic certificate of (20) does "
                    "not apply; stabilizing refers to A+BF only")
            rec["reason"] = (rec["reason"] + "; " if rec["reason"] else "") + note
            ekf = ContinuousDiscreteEKF(plant, spec, plant.x_hat0, rtol=options.sim.rtol, atol=options.sim.atol)
            traj = simulate_sampled(plant, F, ekf=ekf, dt=spec.dt, t_final=T, noise=options.noise,
                                    seed=options.seed, options=_sim_options(options))
        else:
            K = np.asarray(res.K, dtype=float)
            if K.shape != (plant.n, plant.p):
                raise ValueError(f"design {design_id!r} returned K of shape {K.shape}; expected ({plant.n}, {plant.p})")
            ee = float(np.linalg.eigvals(plant.A - K @ plant.C).real.max())
            rec.update(max_re_eig_e=ee, stabilizing=bool(ex < 0 and ee < 0), norm_K=float(np.linalg.norm(K, 2)))
            t0 = time.perf_counter()
            phase = "certificate"
            cert = certify(plant, K, F, report.valid)
            phase = "simulation"
            rec["cert_s"] = time.perf_counter() - t0
            rec.update(certified=cert.certified, cert_margin=cert.margin, decay_rate=cert.decay_rate)
            if not cert.certified:
                rec["reason"] = (rec["reason"] + "; " if rec["reason"] else "") + f"certificate: {cert.reason}"
            if options.noise > 0:
                traj = simulate_sampled(plant, F, K=K, dt=options.noise_dt, t_final=T, noise=options.noise,
                                        seed=options.seed, options=_sim_options(options))
            else:
                traj = simulate(plant, K, F, t_final=T, options=_sim_options(options))
        if traj.status == "timeout" and options.timeout is not None:
            rec["sim_s"], rec["sim_status"] = traj.wall_s, traj.status
            raise DeadlineExceeded(f"the simulation ({traj.message})")
        out.trajectory = traj
        rec["sim_s"] = traj.wall_s
        rec["sim_status"] = traj.status
        m = trajectory_metrics(traj.t, traj.x, traj.x_hat, traj.u, finished=traj.status == "ok",
                               noisy=options.noise > 0)
        rec.update(m)
        if traj.status != "ok":
            rec["reason"] = (rec["reason"] + "; " if rec["reason"] else "") + f"simulation {traj.status}: {traj.message}"
    except DeadlineExceeded as exc:  # --timeout: a row, never a claim
        if options.timeout is None:
            raise
        _timed_out(rec, exc, options, phase)
        out.result = out.trajectory = None
    except Exception as exc:  # one failing pair never kills a run
        if options.fail_fast:
            raise
        rec.update(status="error", reason=f"{type(exc).__name__}: {exc}", feasible=False, certified=False,
                   converged=False, stabilizing=False)
        rec["params"] = rec["params"] or ""
        tb = traceback.extract_tb(exc.__traceback__)
        if tb:
            frame = tb[-1]
            rec["reason"] += f" (at {frame.filename.rsplit('/', 1)[-1]}:{frame.lineno})"
    return out


def _constants_task(pid: str, seed: int, n_samples: int, timeout: float | None = None):
    """Worker task: the constants of one plant (or the error message, ``"timeout: ..."`` on a timeout)."""
    try:
        with time_limit(timeout), _hard_stop(timeout):
            return compute_constants(PLANTS.create(pid), seed=seed, n_samples=n_samples), ""
    except DeadlineExceeded:
        return None, f"timeout: the constants took more than {timeout:g} s"
    except Exception as exc:
        return None, f"{type(exc).__name__}: {exc}"


def _pair_task(pid: str, did: str, report: ConstantsReport, options: RunOptions) -> PairOutcome:
    """Worker task: one pair; the plant is rebuilt from the registry (plants hold closures)."""
    out = run_pair(PLANTS.create(pid), did, report, options)
    out.plant = None  # the parent re-attaches its own plant object
    return out


def _flags(r: dict) -> str:
    flags = [r["status"]]
    if r["status"] == "feasible":
        flags.append("certified" if r["certified"] else "not certified")
        flags.append("converged" if r["converged"] else f"not converged ({r['sim_status']})")
    return ", ".join(flags)


def _stop_workers(ex) -> None:
    """Terminate a process pool's workers (after a Ctrl-C), so that shutting it down does not
    wait for the pairs already handed to them; other executors are left to their own shutdown."""
    for proc in list((getattr(ex, "_processes", None) or {}).values()):
        try:
            proc.terminate()
        except Exception:  # noqa: BLE001 - already gone
            pass


def _drain(ex, tasks, finish) -> None:
    """Submit ``(fn, args, tag)`` tasks and call ``finish(future, tag)`` as each completes.

    A future that is already done when submitted (the serial executor runs the task inside
    ``submit``) is finished at once, before the next task is submitted: a serial run then
    stores each pair as it finishes and stops at a ``KeyboardInterrupt`` where it happens.
    """
    from concurrent.futures import as_completed

    pending = {}
    for fn, args, tag in tasks:
        fut = ex.submit(fn, *args)
        if fut.done():
            finish(fut, tag)
        else:
            pending[fut] = tag
    for fut in as_completed(pending):
        finish(fut, pending[fut])


def run(
    plant_ids: list[str],
    design_ids: list[str],
    options: RunOptions = RunOptions(),
    *,
    progress: Callable[[int, int, str], None] | None = None,
    jobs: int = 1,
    scheduler: str | None = None,
    cache=None,
) -> RunResult:
    """Run every (plant, design) pair.

    Parameters
    ----------
    plant_ids, design_ids : list of str
        Registry ids (already resolved from globs).
    options : RunOptions
    progress : callable, optional
        ``progress(done, total, label)`` after each finished task.
    jobs : int
        Local worker processes (1: serial, in-process).
    scheduler : str, optional
        Dask distributed scheduler address (see :mod:`bench.executors`).
    cache : bench.cache.Cache, optional
        Take finished pairs and constants from this cache and store new ones as they finish
        (None: no cache).

    Returns
    -------
    RunResult
        Outcomes in (plant, design) order, whatever the order in which they finished.

    Raises
    ------
    bench.executors.ExecutorError
        If the executor cannot be created.
    KeyboardInterrupt
        Passed on; pairs finished before it are already in the cache.
    """
    from bench.executors import executor

    t_start = time.perf_counter()
    constants: dict[str, ConstantsReport] = {}
    cerrors: dict[str, str] = {}
    total = len(plant_ids) + len(plant_ids) * len(design_ids)
    count = {"done": 0, "hits": 0, "misses": 0}
    results: dict[tuple[str, str], PairOutcome] = {}
    keys: dict[object, str | None] = {}
    plants: dict[str, Plant] = {}
    for pid in plant_ids:  # the parent's own plant objects: for the report and the cache keys
        try:
            plants[pid] = PLANTS.create(pid)
        except Exception:  # noqa: BLE001 - the constants task reports it
            pass

    def tick(label: str) -> None:
        count["done"] += 1
        if progress:
            progress(count["done"], total, label)

    def constants_tasks():
        for pid in plant_ids:
            key = None
            if cache is not None and pid in plants:
                key = cache.constants_key(plants[pid], pid, options)
                rep = cache.load_constants(key)
                if rep is not None:
                    constants[pid] = rep
                    tick(f"constants of {pid} (cached)")
                    continue
            keys[pid] = key
            limit = None if options.timeout is None else CONSTANTS_TIMEOUT_FACTOR * options.timeout
            yield _constants_task, (pid, options.seed, options.n_samples, limit), pid

    def finish_constants(fut, pid: str) -> None:
        try:
            rep, err = fut.result()
        except Exception as exc:  # a worker died
            rep, err = None, f"{type(exc).__name__}: {exc}"
        if rep is None:
            if options.fail_fast:
                raise RuntimeError(f"plant {pid!r}: {err}")
            cerrors[pid] = err
        else:
            constants[pid] = rep
            if keys.get(pid):
                cache.store_constants(keys[pid], rep)
        tick(f"constants of {pid}" + (f": error ({err})" if err else ""))

    def pair_key(pid: str, did: str) -> str | None:
        try:
            return cache.pair_key(plants[pid], pid, DESIGNS.create(did), did, options)
        except Exception:  # noqa: BLE001 - a design that cannot be built errors in run_pair; no key
            return None

    def pair_tasks():
        for pid in plant_ids:
            for did in design_ids:
                if pid in cerrors:
                    rec = _blank(pid, did)
                    status = "timeout" if cerrors[pid].startswith("timeout") else "error"
                    rec.update(status=status, reason=f"plant {pid!r}: {cerrors[pid]}")
                    results[(pid, did)] = PairOutcome(rec)
                    tick(f"{pid} x {did}: {status}")
                    continue
                key = None
                if cache is not None and pid in plants:
                    key = pair_key(pid, did)
                    cached = cache.load_pair(key) if key else None
                    if cached is not None:
                        count["hits"] += 1
                        results[(pid, did)] = cached
                        tick(f"{pid} x {did}: {_flags(cached.record)} (cached)")
                        continue
                    count["misses"] += 1
                keys[(pid, did)] = key
                yield _pair_task, (pid, did, constants[pid], options), (pid, did)

    def finish_pair(fut, tag: tuple[str, str]) -> None:
        pid, did = tag
        try:
            o = fut.result()
        except Exception as exc:  # fail_fast re-raise, or a worker that died mid-run
            if options.fail_fast:
                raise
            rec = _blank(pid, did)
            rec.update(status="error", reason=f"worker failed: {type(exc).__name__}: {exc}")
            o = PairOutcome(rec)
        results[(pid, did)] = o
        if keys.get((pid, did)):
            cache.store_pair(keys[(pid, did)], o)
        tick(f"{pid} x {did}: {_flags(o.record)}")

    with executor(jobs, scheduler) as ex:
        try:
            _drain(ex, constants_tasks(), finish_constants)
            _drain(ex, pair_tasks(), finish_pair)
        except KeyboardInterrupt:
            _stop_workers(ex)
            raise
    outcomes = []
    for pid in plant_ids:
        for did in design_ids:
            o = results[(pid, did)]
            o.plant = plants.get(pid) if pid not in cerrors else None
            outcomes.append(o)
    return RunResult(outcomes, constants, cerrors, options, time.perf_counter() - t_start,
                     cache_hits=count["hits"], cache_misses=count["misses"],
                     cache_dir=None if cache is None else str(cache.root))


class ProgressBar:
    """A progress bar on stderr, drawn only when stderr is a terminal (quiet otherwise).

    Parameters
    ----------
    stream : file, optional
        Default ``sys.stderr``.
    min_seconds : float
        Nothing is drawn before this many seconds have passed (short runs stay quiet).
    """

    def __init__(self, stream=None, *, min_seconds: float = 1.0, width: int = 30):
        self.stream = stream or sys.stderr
        self.enabled = bool(getattr(self.stream, "isatty", lambda: False)())
        self.t0 = time.perf_counter()
        self.min_seconds = min_seconds
        self.width = width
        self.drawn = False

    def __call__(self, done: int, total: int, label: str) -> None:
        elapsed = time.perf_counter() - self.t0
        if not self.enabled or (elapsed < self.min_seconds and done < total):
            return
        filled = int(self.width * done / max(total, 1))
        bar = "#" * filled + "." * (self.width - filled)
        line = f"\r[{bar}] {done}/{total} {elapsed:5.1f}s {label[:60]:<60}"
        self.stream.write(line)
        self.stream.flush()
        self.drawn = True

    def close(self) -> None:
        """End the bar's line."""
        if self.drawn:
            self.stream.write("\n")
            self.stream.flush()
