"""One executor abstraction for pairs, sweeps and studies: serial in-process (``jobs == 1``), local worker
processes that never outlive their parent (``jobs > 1``), or a Dask distributed cluster (``scheduler``).
Results are identical whatever the executor.

**Start methods.** Local workers start by ``fork``, ``forkserver`` or ``spawn`` (:mod:`multiprocessing`);
``start_method=`` (``--start-method`` on the command line) chooses, and :func:`default_start_method` picks a
safe one per platform: ``spawn`` on Windows (no fork) and macOS (Python's own default there: system
frameworks are not fork-safe); elsewhere ``fork`` while this process runs a single thread (the suite pins
BLAS and Rayon to one thread, and a command-line run forks before any solve), else ``forkserver`` (a notebook
kernel, or a process that has solved an SDP, runs threads, and forking a multi-threaded process may
deadlock; Python 3.12+ warns about it).

A forked worker inherits everything, the registries included. A worker started by spawn or forkserver is a
fresh interpreter: it loads the plugin files again (:func:`bench.plugins.loaded_plugins`) and re-registers
every other entry of the registries that pickles (a Plant or Design object given to :func:`bench.run`, an entry
of the call's overlay of the registries, is sent pickled and put in the same overlay there). An entry that
cannot be sent to a fresh process (a factory defined in a notebook cell or a ``python -c`` script, an object
holding a lambda) cannot be rebuilt there: the tasks that name it run in this process instead, with a warning
naming the ids; the others still run in the workers.
"""

from __future__ import annotations

import gc
import io
import os
import pickle
import sys
import warnings
from concurrent.futures import Executor, Future
from contextlib import ExitStack, contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

from bench.errors import ExecutorError
from bench.threads import cores

__all__ = ["AffinePool", "START_METHODS", "check_start_method", "default_jobs", "default_start_method", "executor", "use_start_method"]


#: All cores available to this process (the default number of local workers).
default_jobs = cores

#: The start methods of local workers (those this platform offers: ``multiprocessing.get_all_start_methods()``).
START_METHODS = ("fork", "forkserver", "spawn")

#: Module names of plugin files (:mod:`bench.plugins`): a fresh worker knows them only by loading the file.
PLUGIN_PREFIX = "oslbench_plugin_"

#: The start method :func:`use_start_method` set for this process (None: :func:`default_start_method`).
_chosen: str | None = None


class SerialExecutor(Executor):
    """Runs each task immediately in the calling process."""

    def submit(self, fn: Callable, /, *args, **kwargs) -> Future:
        fut: Future = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - delivered through the future
            fut.set_exception(exc)
        return fut


# -- start methods ----------------------------------------------------------------------------------
def _threads() -> int:
    """The threads of this process: the operating system's count where it gives one (Linux), else Python's."""
    try:
        return len(os.listdir("/proc/self/task"))
    except OSError:
        import threading

        return threading.active_count()


def default_start_method() -> str:
    """The start method local workers use unless told otherwise (see the module docstring).

    Returns
    -------
    str
        ``"spawn"`` on Windows and macOS; elsewhere ``"fork"`` while this process runs one thread, else
        ``"forkserver"`` (``"spawn"`` where neither is available).
    """
    import multiprocessing

    available = multiprocessing.get_all_start_methods()
    if sys.platform in ("win32", "darwin") or "fork" not in available:
        return "spawn"
    if _threads() == 1:
        return "fork"
    return "forkserver" if "forkserver" in available else "spawn"


def check_start_method(start_method: str | None) -> str | None:
    """``start_method`` if it is None or a start method this platform offers, else :class:`ExecutorError`
    naming the ones it offers."""
    import multiprocessing

    if start_method is None:
        return None
    available = [m for m in START_METHODS if m in multiprocessing.get_all_start_methods()]
    if start_method not in START_METHODS:
        raise ExecutorError(f"start_method: expected one of {', '.join(START_METHODS)} (or None: the default), "
                            f"got {start_method!r}")
    if start_method not in available:
        raise ExecutorError(f"start_method: {start_method!r} is not available on this platform "
                            f"({sys.platform}); use one of {', '.join(available)}")
    return start_method


@contextmanager
def use_start_method(start_method: str | None) -> Iterator[str]:
    """Within the block, local workers of every :func:`executor` that is not given a start method start by
    ``start_method`` (None: :func:`default_start_method`); yields the method in force.

    Raises
    ------
    ExecutorError
        An unknown method, or one this platform does not offer.
    """
    global _chosen
    start_method = check_start_method(start_method)
    before = _chosen
    _chosen = start_method if start_method is not None else before
    try:
        yield _chosen or default_start_method()
    finally:
        _chosen = before


# -- what a fresh worker needs ----------------------------------------------------------------------
class _Returns:
    """A picklable factory returning one object (a Plant or Design object given to :func:`bench.run`)."""

    def __init__(self, obj: Any):
        self.obj = obj

    def __call__(self, **overrides: Any) -> Any:
        return self.obj


def _main_importable() -> bool:
    """Whether a fresh worker can import this process's ``__main__`` (a script or ``-m`` module: yes; a
    notebook, a REPL or ``python -c``: no), as :mod:`multiprocessing` prepares spawned children."""
    if "ipykernel" in sys.modules:  # a notebook: its cells are in no module a worker can import
        return False
    main = sys.modules.get("__main__")
    if getattr(getattr(main, "__spec__", None), "name", None):
        return True
    path = getattr(main, "__file__", None)
    return bool(path) and os.path.isfile(path)


class _Loadable(pickle.Unpickler):
    """Unpickles as a fresh worker would: names in a ``__main__`` it cannot import are missing."""

    main_ok = True

    def find_class(self, module: str, name: str):
        if module == "__main__" and not self.main_ok:
            raise pickle.UnpicklingError(f"{name} is defined in __main__ (a notebook or python -c)")
        return super().find_class(module, name)


def _portable(payload: Any, main_ok: bool) -> bytes | None:
    """``payload`` pickled, if a fresh worker can unpickle it; else None."""
    try:
        blob = pickle.dumps(payload)
        loader = _Loadable(io.BytesIO(blob))
        loader.main_ok = main_ok
        loader.load()
    except Exception:  # noqa: BLE001 - whatever fails, the entry is not portable
        return None
    return blob


@dataclass
class WorkerSetup:
    """What a worker started by spawn or forkserver rebuilds: the plugin files (in load order) and the other
    registry entries as ``(kind, id, pickled factory, summary, order)``; ``local``: the ids that cannot be sent."""

    plugins: list[str] = field(default_factory=list)
    entries: list[tuple[str, str, bytes, str, int]] = field(default_factory=list)
    local: set[str] = field(default_factory=set)


def worker_setup() -> WorkerSetup:
    """The :class:`WorkerSetup` of this process's registries and plugins."""
    from bench.plugins import loaded_plugins
    from bench.registry import DESIGNS, PLANTS

    plugins = loaded_plugins()
    setup = WorkerSetup(plugins=[str(p) for p in plugins])
    main_ok = _main_importable()
    for kind, reg in (("plant", PLANTS), ("design", DESIGNS)):
        for i in reg.ids():
            entry = reg[i]
            where = getattr(sys.modules.get(entry.module), "__file__", None)
            if where and Path(where).resolve() in plugins:  # the worker loads the file again
                continue
            obj = getattr(entry.factory, "_bench_object", None)
            blob = None if entry.module.startswith(PLUGIN_PREFIX) else _portable(
                _Returns(obj) if obj is not None else entry.factory, main_ok)
            if blob is None and obj is None and entry.module.split(".")[0] in ("plants", "designs"):
                continue  # registered when the package's modules are imported (the pairings' closures)
            if blob is None:
                setup.local.add(i)
            else:
                setup.entries.append((kind, i, blob, entry.summary, entry.order))
    return setup


#: The overlays of the objects a fresh worker rebuilt (:func:`_rebuild`), open until the worker exits.
_WORKER_OVERLAYS = ExitStack()


def _rebuild(setup: WorkerSetup) -> None:
    """In a fresh worker: load the plugins, then register every entry the package's modules did not."""
    from bench.plugins import PluginError, load_plugins
    from bench.registry import DESIGNS, PLANTS

    try:
        load_plugins(setup.plugins)
    except PluginError as exc:  # its pairs become error rows (unknown id) in the parent's table
        print(f"oslbench worker {os.getpid()}: {exc}", file=sys.stderr, flush=True)
    registries = {"plant": PLANTS, "design": DESIGNS}
    objects: dict[str, dict[str, Any]] = {"plant": {}, "design": {}}
    for kind, i, blob, summary, order in setup.entries:
        reg = registries[kind]
        if i in reg:  # the package (or the re-imported __main__) registered it already
            continue
        try:
            factory = pickle.loads(blob)
            if isinstance(factory, _Returns):  # an object given to bench.run: in the overlay, as in the parent
                objects[kind][i] = factory.obj
            else:
                reg.register(i, factory, summary, order=order)
        except Exception as exc:  # noqa: BLE001 - its pairs become error rows (unknown id)
            print(f"oslbench worker {os.getpid()}: cannot rebuild {kind} {i!r}: {type(exc).__name__}: {exc}",
                  file=sys.stderr, flush=True)
    for kind, found in objects.items():  # held for the worker's life (a worker serves one run)
        if found:
            _WORKER_OVERLAYS.enter_context(registries[kind].overlay(found, f"{kind} passed to bench.run"))


def _worker_init(parent: int, method: str = "fork", setup: WorkerSetup | None = None) -> None:
    """Set up a local worker: SIGINT ignored (the parent handles Ctrl-C), death with the parent, and (not forked)
    the registries rebuilt."""
    import ctypes
    import signal
    import threading
    import time

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if method != "forkserver":  # a forkserver's worker is the server's child: the server dies with the parent
        with suppress(OSError, AttributeError, TypeError):  # not Linux: the thread below alone
            ctypes.CDLL(None).prctl(1, int(signal.SIGKILL))  # 1: PR_SET_PDEATHSIG

    def alive() -> bool:
        if method == "forkserver":  # not our parent process: ask the system whether it still runs (POSIX)
            try:
                os.kill(parent, 0)
            except ProcessLookupError:
                return False
            except PermissionError:
                return True
            try:  # Linux: a killed parent not yet reaped is a zombie, which signal 0 still finds
                with open(f"/proc/{parent}/stat", "rb") as fh:
                    return fh.read().rpartition(b")")[2].split()[0] != b"Z"
            except (OSError, IndexError):
                return True
        return os.getppid() == parent

    def watch() -> None:
        while alive():
            time.sleep(0.5)
        os._exit(1)

    if not alive():  # the parent died before this worker was set up
        os._exit(1)
    threading.Thread(target=watch, name="oslbench-parent-watch", daemon=True).start()
    if setup is not None:
        _rebuild(setup)


#: Modules a worker needs: imported before forking (inherited), or by the fork server before it forks workers.
WARM_MODULES = ("control", "cvxpy", "filterpy.kalman", "scipy.integrate", "scipy.linalg", "scipy.optimize",
                "bench.pipeline")


def warm_imports() -> None:
    """Import the heavy modules before forking, so that workers inherit them."""
    import importlib

    for name in WARM_MODULES:
        importlib.import_module(name)


class _Routed(Executor):
    """A process pool whose tasks naming an id in ``local`` (or an outcome of such a pair) run in this process."""

    def __init__(self, pool: Executor, local: set[str]):
        self.pool, self.local = pool, local

    @property
    def _processes(self):  # the harness terminates the pool's workers on Ctrl-C
        return getattr(self.pool, "_processes", None)

    def _here(self, args: tuple) -> bool:
        for a in args:
            if isinstance(a, str) and a in self.local:
                return True
            rec = getattr(a, "record", None)
            if isinstance(rec, dict) and (rec.get("plant") in self.local or rec.get("design") in self.local):
                return True
        return False

    def submit(self, fn: Callable, /, *args, **kwargs) -> Future:
        if self._here(args) or self._here(tuple(kwargs.values())):
            return SerialExecutor().submit(fn, *args, **kwargs)
        return self.pool.submit(fn, *args, **kwargs)

    def submit_to(self, key: Any, fn: Callable, /, *args, **kwargs) -> Future:
        """:meth:`AffinePool.submit_to`, or in this process as :meth:`submit` routes it."""
        if self._here(args) or self._here(tuple(kwargs.values())) or not hasattr(self.pool, "submit_to"):
            return self.submit(fn, *args, **kwargs)
        return self.pool.submit_to(key, fn, *args, **kwargs)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        self.pool.shutdown(wait=wait, cancel_futures=cancel_futures)


#: The key of a task that any worker may run (:meth:`AffinePool.submit`).
_ANY = object()

#: A task queued for a worker that has run one task this many seconds may be taken by an idle worker instead.
STEAL_AFTER_S = 10.0


class AffinePool(Executor):
    """Local worker processes, one single-process pool each, with tasks routed by key (:meth:`submit_to`).

    The tasks of one key run in one worker, in the order submitted, so that what a worker keeps in memory (compiled
    programs, solver answers: :mod:`bench.lmi`) serves all of them, as in a serial run. A key belongs to the first
    worker that, free of its own keys' queued tasks, takes one of its tasks (keys submitted costliest first are so
    spread as the longest-processing-time rule spreads jobs, on the times the tasks really take). A task without a
    key (:meth:`submit`) runs in any free worker. A free worker also takes a queued task of another worker's key
    when that worker has run its current task for :data:`STEAL_AFTER_S` or more (a slow or stuck task delays the
    others for that long at most) or has died (its pool is broken: the task it ran fails, those queued for it run
    elsewhere). Results are those of a serial run whatever the routing (module docstring).
    """

    #: Tasks handed to a worker's pool at once (more would queue there, where no other worker can take them).
    DEPTH = 1

    def __init__(self, pools: list[Executor], steal_after: float | None = None):
        import threading

        self.pools = pools
        self.steal_after = STEAL_AFTER_S if steal_after is None else steal_after
        self._lock = threading.RLock()
        self._queue: list[tuple] = []  # (key, fn, args, kwargs, future), in submission order
        self._inflight = [0] * len(pools)  # tasks handed to each worker's pool (at most DEPTH)
        self._since: list[float] = [0.0] * len(pools)  # when each worker began its current task
        self._dead: set[int] = set()
        self._home: dict[Any, int] = {}  # key -> the worker that claimed it
        self._timer = None
        self._closed = False
        # forked workers: every worker forks now, while this process runs one thread, then each pool's manager
        # thread starts (as one pool of several workers does it: cpython issue 90622); a pool whose worker started
        # without its manager would never stop it (the interpreter would wait for it at exit)
        forked = [p for p in pools if not getattr(p, "_safe_to_dynamically_spawn_children", True)
                  and callable(getattr(p, "_launch_processes", None))
                  and callable(getattr(p, "_start_executor_manager_thread", None))]
        for pool in forked:
            pool._launch_processes()
        for pool in forked:
            pool._start_executor_manager_thread()

    @property
    def _processes(self) -> dict:  # the harness terminates the workers on Ctrl-C
        out: dict = {}
        for pool in self.pools:
            out.update(getattr(pool, "_processes", None) or {})
        return out

    def submit(self, fn: Callable, /, *args, **kwargs) -> Future:
        return self._enqueue(_ANY, fn, args, kwargs)

    def submit_to(self, key: Any, fn: Callable, /, *args, **kwargs) -> Future:
        """Submit ``fn(*args, **kwargs)`` to the worker of ``key``: the first worker that is free of its own keys'
        tasks claims the key at its first task (keys submitted costliest first are then spread as the
        longest-processing-time rule spreads them, on the times the tasks really take)."""
        return self._enqueue(key, fn, args, kwargs)

    def _enqueue(self, key: Any, fn: Callable, args: tuple, kwargs: dict) -> Future:
        fut: Future = Future()
        with self._lock:
            if self._closed:
                raise RuntimeError("cannot schedule new futures after shutdown")
            self._queue.append((key, fn, args, kwargs, fut))
            self._dispatch()
        return fut

    def _takes(self, i: int, key: Any, now: float) -> bool:
        """Whether worker ``i``, with no task of its own keys queued, may run a task of ``key``: a task without a key,
        a key no worker has claimed yet (``i`` then claims it), or another worker's that died or has run its current
        task for :data:`STEAL_AFTER_S`."""
        if key is _ANY:
            return True
        home = self._home.get(key)
        if home is None:
            self._home[key] = i
            return True
        return home in self._dead or (self._inflight[home] > 0 and now - self._since[home] >= self.steal_after)

    def _dispatch(self) -> None:
        """Start a queued task on every idle worker that may take one; wake up later for the stealing rule."""
        import threading
        import time

        now = time.monotonic()
        for i, pool in enumerate(self.pools):
            if i in self._dead or self._inflight[i] >= self.DEPTH:
                continue
            pick = next((k for k, t in enumerate(self._queue) if t[0] is not _ANY and self._home.get(t[0]) == i), None)
            if pick is None:
                pick = next((k for k, t in enumerate(self._queue) if self._takes(i, t[0], now)), None)
            if pick is None:
                continue
            _, fn, args, kwargs, fut = self._queue.pop(pick)
            if not fut.set_running_or_notify_cancel():
                continue
            try:
                inner = pool.submit(fn, *args, **kwargs)
            except Exception as exc:  # noqa: BLE001 - a broken pool: this worker is gone
                self._dead.add(i)
                fut.set_exception(exc)
                continue
            if self._inflight[i] == 0:
                self._since[i] = now
            self._inflight[i] += 1
            inner.add_done_callback(lambda f, i=i, fut=fut: self._finished(i, f, fut))
        waiting = [t for t in self._queue if self._home.get(t[0]) not in (None, *self._dead)]
        idle = any(k == 0 and i not in self._dead for i, k in enumerate(self._inflight))
        if waiting and idle and self._timer is None and not self._closed:
            busy = [self._since[i] for i, k in enumerate(self._inflight) if k > 0]
            if busy:
                self._timer = threading.Timer(max(0.05, min(busy) + self.steal_after - now), self._wake)
                self._timer.daemon = True
                self._timer.start()

    def _wake(self) -> None:
        with self._lock:
            self._timer = None
            self._dispatch()

    def _finished(self, i: int, inner: Future, fut: Future) -> None:
        from concurrent.futures.process import BrokenProcessPool

        exc = inner.exception()
        import time

        with self._lock:
            self._inflight[i] -= 1
            self._since[i] = time.monotonic()  # its next task (if one is in flight) begins now
            if isinstance(exc, BrokenProcessPool):
                self._dead.add(i)
            if len(self._dead) == len(self.pools):  # no worker left: what is queued fails as its worker did
                for *_, f in self._queue:
                    if f.set_running_or_notify_cancel():
                        f.set_exception(BrokenProcessPool("every worker process died"))
                self._queue.clear()
            self._dispatch()
        if exc is not None:
            fut.set_exception(exc)
        else:
            fut.set_result(inner.result())

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        with self._lock:
            self._closed = True
            if self._timer is not None:
                self._timer.cancel()
            if cancel_futures:
                for *_, f in self._queue:
                    f.cancel()
                self._queue.clear()
        for pool in self.pools:
            pool.shutdown(wait=wait, cancel_futures=cancel_futures)


@contextmanager
def executor(jobs: int | None = None, scheduler: str | None = None, *, connect_timeout: float = 5.0,
             start_method: str | None = None) -> Iterator[Executor]:
    """Context manager yielding an executor.

    Parameters
    ----------
    jobs : int, optional
        Number of local workers (default: all cores); 1 runs serially in-process.
    scheduler : str, optional
        Address of a Dask distributed scheduler (``tcp://host:8786``); overrides ``jobs``.
    connect_timeout : float
        Seconds to wait for the scheduler before failing with :class:`ExecutorError`.
    start_method : {"fork", "forkserver", "spawn"}, optional
        How local workers start (default: the one :func:`use_start_method` set, else
        :func:`default_start_method`).

    Raises
    ------
    ExecutorError
        ``jobs < 1``, a start method this platform does not offer, Dask not installed, or scheduler unreachable.
    """
    if scheduler is not None:
        try:
            from distributed import Client
        except ImportError:
            raise ExecutorError("--scheduler needs Dask distributed: pip install 'oslbench[dist]'") from None
        try:
            client = Client(scheduler, timeout=connect_timeout, set_as_default=False)
        except (OSError, TimeoutError, ValueError) as exc:
            raise ExecutorError(f"cannot reach the Dask scheduler at {scheduler!r} within {connect_timeout:g} s: {exc}") from None
        with client:  # closed on the way out
            yield client.get_executor()
        return
    jobs = default_jobs() if jobs is None else jobs
    if not isinstance(jobs, int) or isinstance(jobs, bool) or jobs < 1:
        raise ExecutorError(f"jobs: must be an integer >= 1, got {jobs!r}")
    method = check_start_method(start_method) or _chosen or default_start_method()
    if jobs == 1:
        yield SerialExecutor()
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    ctx = multiprocessing.get_context(method)
    setup = None
    if method == "fork":
        warm_imports()
        # the workers' full collections need not scan what they inherit (Python's advice before forking, see
        # gc.freeze): a few tenths of a CPU second a worker. This process unfreezes once the pool is shut down.
        gc.freeze()
    else:
        setup = worker_setup()
        if method == "forkserver":  # the server imports them once; each worker forks from it (used at its start)
            ctx.set_forkserver_preload(list(WARM_MODULES))
        if setup.local:
            warnings.warn(f"{', '.join(sorted(setup.local))}: cannot be sent to a worker started by {method} "
                          "(defined in a notebook or python -c, or not picklable); their tasks run in this process",
                          RuntimeWarning, stacklevel=3)
    try:
        pool = AffinePool([ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=_worker_init,
                                               initargs=(os.getpid(), method, setup)) for _ in range(jobs)])
    except BaseException:
        if method == "fork":
            gc.unfreeze()
        raise
    try:
        yield _Routed(pool, setup.local) if setup is not None and setup.local else pool
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        if method == "fork":
            gc.unfreeze()
