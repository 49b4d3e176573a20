"""The suite as a library: :func:`run` from a notebook or a script (example: :mod:`bench`), the command line on top."""

from __future__ import annotations

import contextlib
import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

__all__ = ["Results", "progress_label", "run"]


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
        computed. Read from a folder (:meth:`load`): gains.json's entry of the pair (``K``, ``F``, ``status``,
        ``certified``, ...), its arrays as read-only arrays, ``certificate`` as level -> that level's entry
        (with its ``P``), and ``result``, ``trajectory`` and ``plant`` None (a folder holds none of them).
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
    source : Path or None
        The report folder these results were read from (:meth:`load`); None for a run's own.
    """

    table: object
    gains: dict
    constants: dict
    findings: dict
    run_result: object
    command: str = ""
    info: dict = field(default_factory=dict)
    source: Path | None = None

    @classmethod
    def load(cls, folder: str | os.PathLike) -> "Results":
        """The results of a report folder, read from its files (results.csv, gains.json, run.json), as
        :func:`run` returned them, computing nothing (:func:`bench.reload.read_report`).

        Parameters
        ----------
        folder : path
            A folder written by ``python -m bench run`` or :meth:`write`.

        Returns
        -------
        Results
            ``table`` equal to the run's (each cell of its column's kind), ``gains`` from gains.json (see the
            attribute), ``constants`` and ``findings`` from run.json, ``run_result`` holding the records,
            constants and options (no design results or trajectories), ``command`` and ``info`` from run.json.

        Raises
        ------
        bench.errors.OutDirError
            Not a report folder.
        ValueError
            A file that cannot be read (the message names it).
        """
        from bench.reload import read_report

        loaded = read_report(folder)
        gains = {}
        for entry in loaded.gains:
            if isinstance(entry, dict) and "plant" in entry and "design" in entry:
                g = _arrays(entry)
                g.setdefault("K", None)
                g.setdefault("F", None)
                gains[entry["plant"], entry["design"]] = {**g, "result": None, "trajectory": None, "plant": None}
        _read_only([gains, loaded.result.constants], set())
        run = loaded.run_info
        return cls(loaded.table.copy(), gains, dict(loaded.result.constants), run.get("findings") or {},
                   loaded.result, command=str(run.get("command", "")), info=loaded.info, source=loaded.folder)

    def write(self, out_dir: str | os.PathLike = "reports", *, figures: bool = True,
              figure_format: str | Iterable[str] = "png") -> Path:
        """Write the report files of this run into ``out_dir`` (:func:`bench.report.write_report`, same options);
        return the REPORT.md path. Results read from a folder (:meth:`load`) are written by
        :func:`bench.report.redraw`: the folder's result files copied, the pages and figures drawn again.
        """
        from bench.outdir import check_out_dir
        from bench.report import redraw, write_report

        if self.source is not None:
            return redraw(self.source, out_dir, figures=figures, figure_format=figure_format)
        check_out_dir(out_dir)
        info = {"command": self.command or "bench.run(...)", **self.info}
        return write_report(self.run_result, out_dir, info, figures=figures, figure_format=figure_format)

    def controller(self, plant: str, design: str):
        """The observer-based controller of a pair as a python-control system (:func:`bench.interop.controller_ss`)."""
        from bench.interop import controller_ss

        g = self._with_plant(plant, design)
        return controller_ss(g["plant"], g["K"], g["F"])

    def closed_loop(self, plant: str, design: str):
        """The nonlinear closed loop of a pair as a python-control ``NonlinearIOSystem``."""
        from bench.interop import closed_loop_nlsys

        g = self._with_plant(plant, design)
        return closed_loop_nlsys(g["plant"], g["K"], g["F"])

    def _with_plant(self, plant: str, design: str) -> dict:
        g = self.gains[plant, design]
        if g["plant"] is None or g["K"] is None:
            raise ValueError(f"({plant!r}, {design!r}): no plant object or no fixed gain K here (results read from "
                             f"{self.source}, or a run-time estimator); build the system with "
                             "bench.interop.controller_ss(plant, K, F)")
        return g


def _selection(name: str, value, kind: str) -> tuple[list[str], dict]:
    """The ids ``value`` selects, in the order given (each once), and the objects among them that run from an
    overlay (id -> object; :func:`bench.registry.object_id`).

    Raises
    ------
    ValueError
        Not None, a string, an object or an iterable of those; an empty list; two different objects of one id.
    bench.registry.UnknownIdError
        A string that matches no registered id.
    """
    from collections.abc import Iterable, Mapping

    from bench.checks import brief
    from bench.errors import RegistryError
    from bench.registry import DESIGNS, PLANTS, _same_plant, object_id
    from designs import Design
    from plants import Plant

    cls, registry = (Plant, PLANTS) if kind == "plant" else (Design, DESIGNS)
    if value is None:
        return registry.select(None), {}
    if isinstance(value, (str, cls)):
        items = [value]
    elif isinstance(value, (bytes, Mapping)) or not isinstance(value, Iterable):
        raise ValueError(f"{name}: expected None (every {kind}), an id or glob, a {cls.__name__} object, or a list "
                         f"of them; got {brief(value)}")
    else:
        items = list(value)
    if not items:
        raise ValueError(f"{name}: an empty list selects nothing; pass None for every {kind}")
    ids: list[str] = []
    objects: dict = {}
    for k, item in enumerate(items):
        if isinstance(item, str):
            found = registry.select([item], keep_order=True)
        elif isinstance(item, cls):
            i, registered = object_id(item, kind)
            if not registered:
                other = objects.setdefault(i, item)
                if other is not item and kind == "plant" and not _same_plant(other, item):
                    raise RegistryError(f"{name}: two different Plant objects have the id {i!r}; give one another id, "
                                        f"e.g. dataclasses.replace(plant, id={(i + '_2')!r})")
            found = [i]
        else:
            raise ValueError(f"{name}[{k}]: expected an id or glob (a str) or a {cls.__name__} object, got "
                             f"{brief(item)}")
        ids.extend(i for i in found if i not in ids)
    return ids, objects


def progress_label(n_plants: int, n_pairs: int) -> str:
    """The progress bar's label of a run: ``constants of P plants + N pairs``."""
    return f"constants of {n_plants} plant{'s' * (n_plants != 1)} + {n_pairs} pair{'s' * (n_pairs != 1)}"


def _check_options(seed, claimed_constants, t_final, noise, disturbance, timeout, jobs, scheduler, cache, progress,
                   fail_fast, command, start_method) -> dict:
    """The options of :func:`run` checked, each error naming its option; returns them converted."""
    from bench import checks
    from bench.executors import check_start_method

    if timeout is not None:
        timeout = checks.real("timeout", timeout, lo=0.0, strict=True)
    if jobs is not None:
        jobs = checks.integer("jobs", jobs, lo=1)
    if scheduler is not None and not isinstance(scheduler, str):
        raise ValueError(f"scheduler: expected an address like 'tcp://host:8786' (a str) or None, got "
                         f"{checks.brief(scheduler)}")
    if cache is not None and not isinstance(cache, (str, os.PathLike)):
        raise ValueError(f"cache: expected a folder path (str or path-like) or None, got {checks.brief(cache)}")
    if not (isinstance(progress, bool) or callable(progress)):
        raise ValueError(f"progress: expected True, False or a callable progress(done, total, label), got "
                         f"{checks.brief(progress)}")
    if not isinstance(command, str):
        raise ValueError(f"command: expected a str, got {checks.brief(command)}")
    check_start_method(start_method)
    return dict(seed=checks.integer("seed", seed, lo=0), claimed_constants=checks.flag("claimed_constants",
                claimed_constants), t_final=checks.horizon(t_final), noise=checks.real("noise", noise, lo=0.0),
                disturbance=checks.real("disturbance", disturbance, lo=0.0), timeout=timeout, jobs=jobs,
                fail_fast=checks.flag("fail_fast", fail_fast))


def run(plants: Iterable | None = None, designs: Iterable | None = None, *, seed: int = 0,
        claimed_constants: bool = False, t_final: float | None = None, noise: float = 0.0,
        disturbance: float = 0.1, timeout: float | None = None, jobs: int | None = None, scheduler: str | None = None,
        cache: str | os.PathLike | None = None, progress: bool | Callable = True, fail_fast: bool = False,
        command: str = "", start_method: str | None = None) -> Results:
    """Run (plant, design) pairs and return the results (the library form of ``python -m bench run``).

    Parameters
    ----------
    plants, designs : str, object or iterable of them, optional
        Registry ids or globs (a string is one id or glob), :class:`plants.Plant` or :class:`designs.Design`
        objects; default (None): every registered one. The table keeps the order given. Objects are not
        registered: each is named by :func:`bench.registry.object_id` (a design by its class's registered id
        and the hyperparameters that differ from the defaults, ``thm1[phi1=0.05]``; a plant by its ``id``) and
        runs from an overlay of the registries for this call only, so the same call runs again.
    seed : int
        Seed of the constants sampler and of the noise.
    claimed_constants : bool
        Design with the constants the sources claim (certificates still use the trusted ones).
    t_final : float, optional
        A fixed horizon for every pair (default: :func:`bench.verdicts.simulation_horizon`).
    noise : float
        Standard deviation of a seeded measurement noise.
    disturbance : float
        Peak amplitude of the seeded L2 disturbance (:mod:`bench.disturbance`; default 0.1,
        :data:`bench.pipeline.RUN_DISTURBANCE`; 0: none): each pair of a plant with disturbance inputs is simulated
        again from ``z(0) = 0`` with it, for the measured ratios ``l2_measured_e``, ``l2_measured_x``.
    timeout : float, optional
        Wall-clock limit per pair, seconds.
    jobs : int, optional
        Local worker processes (default: all cores; 1: in this process).
    scheduler : str, optional
        A Dask scheduler address.
    cache : path, optional
        A cache folder of finished pairs (None: no cache).
    progress : bool or callable
        True: a progress bar (``constants of P plants + N pairs``); or ``progress(done, total, label)``.
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
        A bad option (the message names it: ``jobs: expected an integer, got '2'``), an empty list of plants or
        designs, a Plant object whose id is a registered plant's that it is not.
    bench.errors.ExecutorError
        A start method this platform does not offer.
    """
    from bench.cache import Cache
    from bench.executors import default_jobs, use_start_method
    from bench.findings import findings
    from bench.harness import RunOptions
    from bench.registry import DESIGNS, PLANTS
    from bench.report import check_cells, results_table

    opts = _check_options(seed, claimed_constants, t_final, noise, disturbance, timeout, jobs, scheduler, cache,
                          progress, fail_fast, command, start_method)
    plant_ids, plant_objects = _selection("plants", plants, "plant")
    design_ids, design_objects = _selection("designs", designs, "design")
    options = RunOptions(seed=opts["seed"], use_claimed=opts["claimed_constants"], fail_fast=opts["fail_fast"],
                         t_final=opts["t_final"], noise=opts["noise"], disturbance=opts["disturbance"],
                         timeout=opts["timeout"])
    jobs = min(opts["jobs"] or default_jobs(), max(1, len(plant_ids) * len(design_ids)))
    store = None if cache is None else Cache(cache)
    with PLANTS.overlay(plant_objects, "plant passed to bench.run"), \
            DESIGNS.overlay(design_objects, "design passed to bench.run"), use_start_method(start_method):
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
    """The pairs computed in the registry's order (objects given to :func:`run` after the registered entries), then put
    in the order asked for; the progress bar closed."""
    from bench.harness import run as run_pairs
    from bench.progress import Progress
    from bench.registry import DESIGNS, PLANTS

    pairs = len(plant_ids) * len(design_ids)
    bar = Progress(desc=progress_label(len(plant_ids), pairs)) if progress is True else progress or None
    with contextlib.closing(bar) if hasattr(bar, "close") else contextlib.nullcontext():
        result = run_pairs([p for p in PLANTS.ids() if p in plant_ids],
                           [d for d in DESIGNS.ids() if d in design_ids], options, progress=bar, jobs=jobs,
                           scheduler=scheduler, cache=store)
    result.outcomes.sort(key=lambda o: (plant_ids.index(o.record["plant"]),
                                        design_ids.index(o.record["design"])))
    result.constants = {p: result.constants[p] for p in plant_ids if p in result.constants}
    result.constants_errors = {p: result.constants_errors[p] for p in plant_ids if p in result.constants_errors}
    return result


def _arrays(v):
    """A gains.json value with its matrices and vectors (lists of numbers, or of lists of numbers) as arrays."""
    import numbers

    import numpy as np

    if isinstance(v, dict):
        return {k: _arrays(x) for k, x in v.items()}
    if isinstance(v, list) and v and all(isinstance(x, numbers.Real) and not isinstance(x, bool) or
                                         isinstance(x, list) and all(isinstance(y, numbers.Real) and
                                                                     not isinstance(y, bool) for y in x) for x in v):
        try:
            return np.array(v, dtype=float)
        except ValueError:  # ragged
            return v
    return v


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
