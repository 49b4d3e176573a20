"""One executor abstraction for pairs, sweeps and studies: serial in-process (``jobs == 1``), forked
local workers that inherit the registries and never outlive their parent (``jobs > 1``), or a Dask
distributed cluster (``scheduler``). Results are identical whatever the executor.
"""

from __future__ import annotations

import os
from concurrent.futures import Executor, Future
from contextlib import contextmanager, suppress
from typing import Callable, Iterator

from bench._env import cores
from bench.errors import ExecutorError

__all__ = ["default_jobs", "executor"]


#: All cores available to this process (the default number of local workers).
default_jobs = cores


class SerialExecutor(Executor):
    """Runs each task immediately in the calling process."""

    def submit(self, fn: Callable, /, *args, **kwargs) -> Future:
        fut: Future = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - delivered through the future
            fut.set_exception(exc)
        return fut


def _worker_init(parent: int) -> None:
    """Set up a local worker: SIGINT ignored (the parent handles Ctrl-C), and death with the parent."""
    import ctypes
    import signal
    import threading
    import time

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    with suppress(OSError, AttributeError):  # not Linux: the thread below alone
        ctypes.CDLL(None).prctl(1, int(signal.SIGKILL))  # 1: PR_SET_PDEATHSIG

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    if os.getppid() != parent:  # the parent died before this worker was set up
        os._exit(1)
    threading.Thread(target=watch, name="oslbench-parent-watch", daemon=True).start()


def warm_imports() -> None:
    """Import the heavy modules before forking, so that workers inherit them."""
    import control  # noqa: F401
    import cvxpy  # noqa: F401
    import filterpy.kalman  # noqa: F401
    import scipy.integrate  # noqa: F401
    import scipy.linalg  # noqa: F401
    import scipy.optimize  # noqa: F401


@contextmanager
def executor(jobs: int | None = None, scheduler: str | None = None, *, connect_timeout: float = 5.0) -> Iterator[Executor]:
    """Context manager yielding an executor.

    Parameters
    ----------
    jobs : int, optional
        Number of local workers (default: all cores); 1 runs serially in-process.
    scheduler : str, optional
        Address of a Dask distributed scheduler (``tcp://host:8786``); overrides ``jobs``.
    connect_timeout : float
        Seconds to wait for the scheduler before failing with :class:`ExecutorError`.

    Raises
    ------
    ExecutorError
        ``jobs < 1``, Dask not installed, or scheduler unreachable.
    """
    if scheduler is not None:
        try:
            from distributed import Client
        except ImportError:
            raise ExecutorError("--scheduler needs Dask distributed: pip install '.[dist]'") from None
        try:
            client = Client(scheduler, timeout=connect_timeout, set_as_default=False)
        except (OSError, TimeoutError, ValueError) as exc:
            raise ExecutorError(f"cannot reach the Dask scheduler at {scheduler!r} within {connect_timeout:g} s: {exc}") from None
        with client:  # closed on the way out
            yield client.get_executor()
        return
    jobs = default_jobs() if jobs is None else jobs
    if not isinstance(jobs, int) or jobs < 1:
        raise ExecutorError(f"jobs: must be an integer >= 1, got {jobs!r}")
    if jobs == 1:
        yield SerialExecutor()
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    warm_imports()
    pool = ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("fork"),
                               initializer=_worker_init, initargs=(os.getpid(),))
    try:
        yield pool
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
