"""The suite as a library: :func:`run` from a notebook or a script (example: :mod:`bench`), the command line on top."""

from __future__ import annotations

import contextlib
import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

__all__ = ["Results", "run"]


@dataclass
class Results:
    """What :func:`run` returns.

    Attributes
    ----------
    table : pandas.DataFrame
        results.csv: one row per pair in the order asked for (:func:`bench.report.results_table`); a copy, so
        changing it changes nothing :meth:`write` writes.
    gains : dict
        ``(plant, design) -> {"K", "F", "result", "certificate", "trajectory", "plant"}`` for every pair
        with a controller. Every array of the run's results (gains, certificates, trajectories, constants;
        not the plants, which are the run's input) is read-only: what :meth:`write` writes is what the run
        computed.
    constants : dict
        Plant id -> :class:`bench.constants.ConstantsReport`.
    findings : dict
        :func:`bench.findings.findings` (:meth:`write` computes them again from the records).
    run_result : bench.harness.RunResult
        Everything, including the outcomes and timings.
    command : str
        How the run was asked for (recorded in run.json).
    info : dict
        The run's selection and settings (plants, designs, jobs, ...), recorded in run.json.
    """

    table: object
    gains: dict
    constants: dict
    findings: dict
    run_result: object
    command: str = ""
    info: dict = field(default_factory=dict)

    def write(self, out_dir: str | os.PathLike = "reports", *, figures: bool = True,
              figure_format: str | Iterable[str] = "png") -> Path:
        """Write the report files of this run into ``out_dir`` (:func:`bench.report.write_report`, same options);
        return the REPORT.md path.
        """
        from bench.outdir import check_out_dir
        from bench.report import write_report

        check_out_dir(out_dir)
        info = {"command": self.command or "bench.run(...)", **self.info}
        return write_report(self.run_result, out_dir, info, figures=figures, figure_format=figure_format)

    def controller(self, plant: str, design: str):
        """The observer-based controller of a pair as a python-control system (:func:`bench.interop.controller_ss`)."""
        from bench.interop import controller_ss

        g = self.gains[plant, design]
        return controller_ss(g["plant"], g["K"], g["F"])

    def closed_loop(self, plant: str, design: str):
        """The nonlinear closed loop of a pair as a python-control ``NonlinearIOSystem``."""
        from bench.interop import closed_loop_nlsys

        g = self.gains[plant, design]
        return closed_loop_nlsys(g["plant"], g["K"], g["F"])


def _register_objects(items, registry, kind: str) -> list[str]:
    """Ids and globs as they are; Plant or Design objects registered under their id for this process."""
    from plants import Plant

    out = []
    for it in items:
        if isinstance(it, str):
            out.append(it)
            continue
        obj_id = it.id if isinstance(it, Plant) else type(it).__name__.lower()
        if obj_id in registry:
            if getattr(registry[obj_id].factory, "_bench_object", None) is not it:
                raise ValueError(f"{kind}s: the id {obj_id!r} is already registered (the catalog's, or another "
                                 f"object's); give your {kind} another id")
        else:
            def factory(obj=it):
                return obj

            factory._bench_object = it
            registry.register(obj_id, factory, f"{kind} passed to bench.run", order=200)
        out.append(obj_id)
    return out


def run(plants: Iterable | None = None, designs: Iterable | None = None, *, seed: int = 0,
        claimed_constants: bool = False, t_final: float | None = None, noise: float = 0.0,
        disturbance: float = 0.0, timeout: float | None = None, jobs: int | None = None, scheduler: str | None = None,
        cache: str | os.PathLike | None = None, progress: bool | Callable = True, fail_fast: bool = False,
        command: str = "", start_method: str | None = None) -> Results:
    """Run (plant, design) pairs and return the results (the library form of ``python -m bench run``).

    Parameters
    ----------
    plants, designs : iterable, optional
        Registry ids or globs, :class:`plants.Plant` or :class:`designs.Design` objects (registered for this
        process); default: every registered one. The table keeps the order given.
    seed : int
        Seed of the constants sampler and of the noise.
    claimed_constants : bool
        Design with the constants the sources claim (certificates still use the trusted ones).
    t_final : float, optional
        A fixed horizon for every pair (default: :func:`bench.verdicts.simulation_horizon`).
    noise : float
        Standard deviation of a seeded measurement noise.
    disturbance : float
        Peak amplitude of the seeded L2 disturbance (:mod:`bench.disturbance`; 0: none): each pair of a
        plant with disturbance inputs is simulated again from ``z(0) = 0`` with it, for the measured
        ratios ``l2_measured_e``, ``l2_measured_x``.
    timeout : float, optional
        Wall-clock limit per pair, seconds.
    jobs : int, optional
        Local worker processes (default: all cores; 1: in this process).
    scheduler : str, optional
        A Dask scheduler address.
    cache : path, optional
        A cache folder of finished pairs (None: no cache).
    progress : bool or callable
        True: a progress bar; or ``progress(done, total, label)``.
    fail_fast : bool
        Raise the first exception instead of recording an ``error`` row.
    command : str
        Recorded in run.json.
    start_method : {"fork", "forkserver", "spawn"}, optional
        How local worker processes start (default: :func:`bench.executors.default_start_method`); results are
        the same whichever.

    Returns
    -------
    Results

    Raises
    ------
    bench.registry.UnknownIdError
        An id or glob that matches nothing.
    ValueError
        A bad option (the message names it).
    bench.errors.ExecutorError
        A start method this platform does not offer.
    """
    from bench.cache import Cache
    from bench.executors import check_start_method, default_jobs, use_start_method
    from bench.findings import findings
    from bench.harness import RunOptions
    from bench.registry import DESIGNS, PLANTS
    from bench.report import check_cells, results_table

    check_start_method(start_method)

    plant_ids = PLANTS.select(_register_objects(plants or [], PLANTS, "plant") or None, keep_order=True)
    design_ids = DESIGNS.select(_register_objects(designs or [], DESIGNS, "design") or None, keep_order=True)
    options = RunOptions(seed=seed, use_claimed=claimed_constants, fail_fast=fail_fast, t_final=t_final, noise=noise,
                         disturbance=disturbance, timeout=timeout)
    jobs = min(jobs or default_jobs(), max(1, len(plant_ids) * len(design_ids)))
    store = None if cache is None else Cache(cache)
    with use_start_method(start_method):
        result = _run_in_registry_order(plant_ids, design_ids, options, progress, jobs, scheduler, store)
    check_cells(result.outcomes)
    _read_only([result.outcomes, result.constants], set())
    records = result.frame()
    info = {"plants": plant_ids, "designs": design_ids, "jobs": jobs, "scheduler": scheduler,
            "cache_errors": list(store.errors) if store is not None else []}
    return Results(results_table(records), _controllers(result), dict(result.constants),
                   findings(records, result.constants), result, command=command, info=info)


def _run_in_registry_order(plant_ids: list[str], design_ids: list[str], options, progress, jobs: int,
                           scheduler: str | None, store):
    """The pairs computed in the registry's order, then put in the order asked for; the progress bar closed."""
    from bench.harness import run as run_pairs
    from bench.progress import Progress
    from bench.registry import DESIGNS, PLANTS

    bar = Progress(desc="pairs") if progress is True else progress or None
    with contextlib.closing(bar) if hasattr(bar, "close") else contextlib.nullcontext():
        result = run_pairs([p for p in PLANTS.ids() if p in plant_ids],
                           [d for d in DESIGNS.ids() if d in design_ids], options, progress=bar, jobs=jobs,
                           scheduler=scheduler, cache=store)
    result.outcomes.sort(key=lambda o: (plant_ids.index(o.record["plant"]),
                                        design_ids.index(o.record["design"])))
    result.constants = {p: result.constants[p] for p in plant_ids if p in result.constants}
    result.constants_errors = {p: result.constants_errors[p] for p in plant_ids if p in result.constants_errors}
    return result


def _read_only(obj, seen: set) -> None:
    """Make every array reachable from ``obj`` (through dataclass fields, dicts, lists and tuples) read-only, in place;
    plants are not entered (they are the run's input, not its results)."""
    import numpy as np

    from plants import Plant

    if isinstance(obj, np.ndarray):
        obj.flags.writeable = False
        return
    if id(obj) in seen or isinstance(obj, (Plant, str, bytes, type)):
        return
    seen.add(id(obj))
    if dataclasses.is_dataclass(obj):
        items = [getattr(obj, f.name) for f in dataclasses.fields(obj)]
    elif isinstance(obj, dict):
        items = list(obj.values())
    elif isinstance(obj, (list, tuple)):
        items = obj
    else:
        return
    for item in items:
        _read_only(item, seen)


def _controllers(result) -> dict:
    """(plant, design) -> gains, design result, certificate, trajectory and plant, for pairs with a controller."""
    return {(o.record["plant"], o.record["design"]): {"K": o.result.K, "F": o.result.F, "result": o.result,
                                                        "certificate": o.certificate, "trajectory": o.trajectory,
                                                        "plant": o.plant}
            for o in result.outcomes if o.result is not None and o.result.has_controller}
