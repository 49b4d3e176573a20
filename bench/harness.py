"""The harness: every (plant, design) pair through :func:`bench.pipeline.evaluate_pair`.

The harness owns what is about many pairs: each plant's constants (computed once, shared by its
pairs), the executor (:mod:`bench.executors`), the cache of finished pairs (:mod:`bench.cache`),
time limits (:data:`CONSTANTS_TIMEOUT_FACTOR`), progress, and the order of the results. It judges nothing.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass
from functools import partial
from typing import Callable

import numpy as np

from bench.constants import ConstantsReport, compute_constants
from bench.limits import DeadlineExceeded, hard_stop, time_limit
from bench.pipeline import COLUMNS, PairOutcome, RunOptions, blank_record, evaluate_pair, rejudge
from bench.registry import DESIGNS, PLANTS
from plants import Plant

__all__ = ["RunResult", "run"]

#: A plant's constants may take this many times the per-pair ``timeout``.
CONSTANTS_TIMEOUT_FACTOR = 10


@dataclass
class RunResult:
    """Everything a run produced; ``cache_hits`` / ``cache_misses`` count pairs from / not from an enabled cache."""

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


def _constants_task(pid: str, seed: int, n_samples: int, timeout: float | None = None):
    """The constants of one plant, or the error message (``"timeout: ..."`` on a timeout)."""
    try:
        with time_limit(timeout), hard_stop(timeout):
            return compute_constants(PLANTS.create(pid), seed=seed, n_samples=n_samples), ""
    except DeadlineExceeded:
        return None, f"timeout: the constants took more than {timeout:g} s"
    except KeyboardInterrupt:
        raise
    except BaseException as exc:  # plugin code (f, the plant's factory) never ends the run, SystemExit included
        return None, f"{type(exc).__name__}: {exc}"


def _pair_task(pid: str, did: str, report: ConstantsReport, options: RunOptions) -> PairOutcome:
    """One pair; the plant is rebuilt from the registry (plants hold closures)."""
    out = evaluate_pair(PLANTS.create(pid), did, report, options)
    out.plant = None  # the parent re-attaches its own plant object
    return out


def _flags(r: dict) -> str:
    flags = [r["status"]]
    if r["certified"]:
        flags.append(f"certified ({r['cert_level']})")
    if r["sim_status"]:
        flags.append("converged" if r["converged"] else "not converged")
    return ", ".join(flags)


def expected_cost(plant: Plant | None, design_id: str) -> float:
    """A rough cost of a pair, for scheduling longest first."""
    n = plant.n if plant is not None else 4
    weight = 3.0 if "ekf" in design_id else 2.0 if design_id in ("thm1", "cor1", "thm1_scaled", "cor1_scaled") else 1.0
    return weight * n


def _drain(ex, tasks) -> None:
    """Submit ``(fn, args, then)`` tasks, and the tasks ``then(future)`` returns as each completes. A task
    ``(fn, args, then, key)`` goes to the worker of its key where the executor has one
    (:meth:`bench.executors.AffinePool.submit_to`)."""
    from concurrent.futures import FIRST_COMPLETED, wait

    pending = {}
    routed = hasattr(ex, "submit_to")

    def submit(batch) -> None:
        for fn, args, then, *affinity in batch or ():
            fut = ex.submit_to(*affinity, fn, *args) if routed and affinity else ex.submit(fn, *args)
            if fut.done():
                submit(then(fut))
            else:
                pending[fut] = then

    submit(tasks)
    while pending:
        done, _ = wait(pending, return_when=FIRST_COMPLETED)
        for fut in done:
            submit(pending.pop(fut)(fut))


class _Run:
    """The state of one :func:`run`: constants, results, cache keys, progress."""

    def __init__(self, plant_ids, design_ids, options, progress, cache):
        self.plant_ids, self.design_ids, self.options = plant_ids, design_ids, options
        self.routed = False  # the executor routes tasks by key: pairs go out by family (family_tasks)
        self.waiting: dict[str, list[str]] = {}
        self.progress, self.cache = progress, cache
        self.constants: dict[str, ConstantsReport] = {}
        self.errors: dict[str, str] = {}
        self.results: dict[tuple[str, str], PairOutcome] = {}
        self.keys: dict[object, str | None] = {}
        self.done = 0
        self.total = len(plant_ids) * (1 + len(design_ids))
        self.plants: dict[str, Plant] = {}
        for pid in plant_ids:  # the parent's own plant objects: for the report and the cache keys
            try:
                self.plants[pid] = PLANTS.create(pid)
            except KeyboardInterrupt:
                raise
            except BaseException:  # noqa: BLE001 - the constants task reports it (SystemExit included)
                pass

    def tick(self, label: str) -> None:
        self.done += 1
        if self.progress:
            self.progress(self.done, self.total, label)

    # -- constants ------------------------------------------------------------------------------
    def constants_tasks(self):
        """The constants tasks of the plants not in the cache (cached plants' pairs follow at once)."""
        for pid in self.plant_ids:
            key = None
            if self.cache is not None and pid in self.plants:
                key = self._constants_key(pid)
                rep = self.cache.load_constants(key) if key else None
                if rep is not None:
                    self.constants[pid] = rep
                    self.tick(f"constants of {pid} (cached)")
                    yield from self.pair_tasks([pid])
                    continue
            self.keys[pid] = key
            limit = None if self.options.timeout is None else CONSTANTS_TIMEOUT_FACTOR * self.options.timeout
            yield _constants_task, (pid, self.options.seed, self.options.n_samples, limit), partial(
                self.finish_constants, pid)

    def _constants_key(self, pid: str) -> str | None:
        """The cache key of a plant's constants (None when the plant's own code fails while it is keyed)."""
        try:
            return self.cache.constants_key(self.plants[pid], pid, self.options)
        except KeyboardInterrupt:
            raise
        except BaseException:  # noqa: BLE001 - the constants task reports the failure
            return None

    def finish_constants(self, pid: str, fut):
        """Store a plant's constants; return the tasks of its pairs."""
        try:
            rep, err = fut.result()
        except KeyboardInterrupt:
            raise
        except BaseException as exc:  # a worker died
            rep, err = None, f"{type(exc).__name__}: {exc}"
        if rep is None:
            if self.options.fail_fast:
                raise RuntimeError(f"plant {pid!r}: {err}")
            self.errors[pid] = err
        else:
            self.constants[pid] = rep
            if self.keys.get(pid):
                self.cache.store_constants(self.keys[pid], rep)
        self.tick(f"constants of {pid}" + (f": error ({err})" if err else ""))
        return self.pair_tasks([pid])

    # -- pairs ----------------------------------------------------------------------------------
    def _from_cache(self, pid: str, did: str) -> bool:
        try:
            key = self.cache.pair_key(self.plants[pid], pid, DESIGNS.create(did), did, self.options)
        except KeyboardInterrupt:
            raise
        except BaseException:  # noqa: BLE001 - a design that cannot be built errors in the pipeline; no key
            key = None
        cached = self.cache.load_pair(key) if key else None
        if cached is not None:
            self.results[(pid, did)] = cached
            cached.plant = self.plants[pid]
            self.tick(f"{pid} x {did}: {_flags(cached.record)} (cached)")
            return True
        self.keys[(pid, did)] = key
        return False

    def pair_tasks(self, plant_ids) -> list:
        """The pair tasks of these plants, longest first; cached pairs and those of failed plants are recorded at once."""
        todo = []
        for pid in plant_ids:
            for did in self.design_ids:
                if pid in self.errors:
                    status = "timeout" if self.errors[pid].startswith("timeout") else "error"
                    reason = f"plant {pid!r}: {self.errors[pid]}"
                    self.results[(pid, did)] = PairOutcome(blank_record(pid, did, status=status, reason=reason))
                    self.tick(f"{pid} x {did}: {status}")
                elif not (self.cache is not None and pid in self.plants and self._from_cache(pid, did)):
                    todo.append((pid, did))
        todo.sort(key=lambda pd: -expected_cost(self.plants.get(pd[0]), pd[1]))
        if self.routed:
            return self.family_tasks(plant_ids, todo)
        return [(_pair_task, (pid, did, self.constants[pid], self.options), partial(self.finish_pair, pid, did))
                for pid, did in todo]

    def family_tasks(self, plant_ids, todo) -> list:
        """With an executor that routes tasks by key (:class:`bench.executors.AffinePool`): the pair tasks wait
        until every plant has its constants (those tasks are ahead of them in the workers' queues anyway), then go
        out family by family (:meth:`family`), the costliest family first (expected), each family's to one worker
        (its key)."""
        for pid in plant_ids:
            self.waiting[pid] = [d for p, d in todo if p == pid]
        if len(self.waiting) < len(self.plant_ids):
            return []
        families: dict[str, list[tuple[str, str]]] = {}
        for pid in self.plant_ids:
            families.setdefault(self.family(pid), []).extend((pid, d) for d in self.waiting.pop(pid))
        cost = {k: sum(expected_cost(self.plants.get(p), d) for p, d in v) for k, v in families.items()}
        return [(_pair_task, (pid, did, self.constants[pid], self.options), partial(self.finish_pair, pid, did),
                 key) for key in sorted(families, key=lambda k: -cost[k]) for pid, did in families[key]]

    def family(self, pid: str) -> str:
        """The first plant of the run that shares ``pid``'s linear part (A, B, C, dt): the key of the worker that
        runs its pairs (:class:`bench.executors.AffinePool`). Designs that use only the linear part and scalar
        constants make the same programs on each plant of a family, which one process then solves once."""
        def key(q: str):
            p = self.plants.get(q)
            if p is None:
                return q
            return tuple(np.asarray(M, dtype=float).tobytes() + repr(np.shape(M)).encode()
                         for M in (p.A, p.B, p.C)) + (float(p.dt),)
        mine = key(pid)
        return next((q for q in self.plant_ids if q == pid or (q in self.plants and key(q) == mine)), pid)

    def finish_pair(self, pid: str, did: str, fut) -> None:
        try:
            o = fut.result()
        except KeyboardInterrupt:
            raise
        except BaseException as exc:  # fail_fast re-raise, or a worker that died mid-run
            if self.options.fail_fast:
                raise
            o = PairOutcome(blank_record(pid, did, status="error",
                                         reason=f"worker failed: {type(exc).__name__}: {exc}"))
        self.results[(pid, did)] = o
        if self.keys.get((pid, did)):
            self.cache.store_pair(self.keys[(pid, did)], o)
        o.plant = self.plants.get(pid)  # the parent's own plant object (the worker dropped its copy)
        self.tick(f"{pid} x {did}: {_flags(o.record)}")


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
        Dask distributed scheduler address.
    cache : bench.cache.Cache, optional
        Take finished pairs and constants from it, store new ones as they finish.

    Returns
    -------
    RunResult
        Outcomes in (plant, design) order.

    Raises
    ------
    bench.executors.ExecutorError
        If the executor cannot be created.
    KeyboardInterrupt
        Passed on; pairs finished before it are in the cache.
    """
    from bench.executors import executor

    t_start = time.perf_counter()
    state = _Run(plant_ids, design_ids, options, progress, cache)
    with executor(jobs, scheduler) as ex:
        state.routed = hasattr(ex, "submit_to")
        try:
            _drain(ex, state.constants_tasks())
        except KeyboardInterrupt:  # the pool's workers terminated, so that shutting it down does not wait for them
            for proc in list((getattr(ex, "_processes", None) or {}).values()):
                with contextlib.suppress(Exception):  # already gone
                    proc.terminate()
            raise
    constants = {pid: state.constants[pid] for pid in plant_ids if pid in state.constants}  # in the order asked for
    errors = {pid: state.errors[pid] for pid in plant_ids if pid in state.errors}
    outcomes = rejudge([state.results[pid, did] for pid in plant_ids for did in design_ids], constants, options)
    return RunResult(outcomes, constants, errors, options, time.perf_counter() - t_start,
                     cache_hits=cache.hits if cache is not None else 0,
                     cache_misses=cache.misses if cache is not None else 0,
                     cache_dir=None if cache is None else str(cache.root))
