"""Time limits of the runner: a pair's ``--timeout``, checked where the time goes.

A limit is a scope (:func:`time_limit`) held in a context variable, so threads (Dask workers)
each have their own. Code that spends time checks it: every SDP solve gets the remaining time
as the solver's own limit (:func:`bench.lmi.solve_timed`), the simulators check a wall-clock
budget, and :func:`hard_stop` raises for code that checks nothing (from a ``SIGALRM`` in the main
thread, from a timer in any other). A limit that runs out raises :class:`DeadlineExceeded`, a
``BaseException``, so that no ``except Exception`` in a design can turn a timeout into an "infeasible" row.
"""

from __future__ import annotations

import contextvars
import math
import threading
import time
from contextlib import contextmanager
from typing import Iterator

from bench.errors import DeadlineExceeded, HardStop as _HardStop

__all__ = ["check_deadline", "hard_stop", "time_limit"]


#: The monotonic deadline of the innermost scope of this thread or task.
_DEADLINE: contextvars.ContextVar[float | None] = contextvars.ContextVar("oslbench_deadline", default=None)


@contextmanager
def time_limit(seconds: float | None) -> Iterator[None]:
    """Scope with a wall-clock limit of ``seconds`` (None: no limit).

    Parameters
    ----------
    seconds : float or None
        The limit; must be finite and > 0.

    Raises
    ------
    ValueError
        If ``seconds`` is not None and not a finite number > 0.
    """
    if seconds is None:
        yield
        return
    if not (isinstance(seconds, (int, float)) and math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"timeout: must be a finite number of seconds > 0, got {seconds!r}")
    token = _DEADLINE.set(time.monotonic() + float(seconds))
    try:
        yield
    finally:
        _DEADLINE.reset(token)


def remaining_time() -> float | None:
    """Seconds left in the current :func:`time_limit` scope (None: no limit; may be negative)."""
    deadline = _DEADLINE.get()
    return None if deadline is None else deadline - time.monotonic()


def check_deadline(where: str) -> None:
    """Raise :class:`DeadlineExceeded` if the current :func:`time_limit` has run out."""
    left = remaining_time()
    if left is not None and left <= 0:
        raise DeadlineExceeded(where)


@contextmanager
def hard_stop(seconds: float | None) -> Iterator[None]:
    """Raise :class:`DeadlineExceeded` in the calling thread after ``seconds``.

    In the main thread by ``SIGALRM``; in any other thread (``bench.run`` called from a worker
    thread) a timer raises it asynchronously in the calling thread
    (``PyThreadState_SetAsyncExc``: delivered at the next Python bytecode, so a long call into C
    ends first). Does nothing for ``seconds=None``, or in the main thread without ``setitimer``
    (Windows) or when someone else already uses ``SIGALRM`` (e.g. pytest-timeout).
    """
    import signal

    if seconds is not None and threading.current_thread() is not threading.main_thread():
        with _thread_stop(seconds):
            yield
        return
    usable = seconds is not None and hasattr(signal, "setitimer") and (
        signal.getsignal(signal.SIGALRM) in (signal.SIG_DFL, None) and signal.getitimer(signal.ITIMER_REAL)[0] == 0)
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


@contextmanager
def _thread_stop(seconds: float) -> Iterator[None]:
    """:func:`hard_stop` off the main thread: a timer raises :class:`_HardStop` into this thread."""
    import ctypes

    tid = threading.get_ident()
    lock = threading.Lock()
    state = {"inside": True, "fired": False}

    def fire():
        with lock:
            if state["inside"]:
                state["fired"] = True
                ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(tid), ctypes.py_object(_HardStop))

    timer = threading.Timer(seconds, fire)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        with lock:
            state["inside"] = False
            timer.cancel()
            pending = state["fired"] and ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(tid), None)
        if pending:  # fired but not yet delivered: deliver it here, inside the scope
            raise _HardStop()
