"""Progress where the user is: a tqdm bar behind the ``progress(done, total, label)`` callback.

The harness and the studies report progress by calling ``progress(done, total, label)`` after
each finished task. :class:`Progress` is such a callable, drawn by ``tqdm.auto``: a widget in a
Jupyter notebook, a text bar on a terminal, and nothing at all when stderr is not a terminal
(a log file, CI, a pipe), as ``disable=None`` asks of tqdm.
"""

from __future__ import annotations

import numbers

__all__ = ["Progress"]


def _count(name: str, value, *, allow_none: bool = False) -> int | None:
    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 0:
        raise ValueError(f"{name}: expected an integer >= 0{' or None' if allow_none else ''}, got {value!r}")
    return int(value)


class Progress:
    """A progress bar for ``progress(done, total, label)`` callbacks, built on ``tqdm.auto``.

    The bar is created at the first call (so an unused Progress draws nothing); each call moves
    it to ``done`` of ``total`` and shows ``label`` as the postfix.

    Parameters
    ----------
    total : int, optional
        Number of tasks, if known before the first call (each call's ``total`` replaces it).
    desc : str
        Text before the bar.
    file : file-like, optional
        Where to draw (default ``sys.stderr``; a notebook draws a widget instead).
    disable : bool or None
        None (the default): draw only when ``file`` is a terminal (always in a notebook);
        True: never; False: always.
    max_label : int
        Labels longer than this are cut (with "...") so that the bar fits on a line.
    **tqdm_kwargs
        Passed to ``tqdm`` (e.g. ``delay=1.0`` to stay quiet for the first second,
        ``leave=False``, ``unit="pair"``, ``mininterval``).

    Raises
    ------
    ValueError
        If ``total`` or ``max_label`` is not a non-negative integer.

    Examples
    --------
    As a callback (the harness's and the studies' ``progress=`` argument):

    >>> bar = Progress(desc="pairs")
    >>> for i in range(1, 4):
    ...     bar(i, 3, f"flexible_link x design {i}")
    >>> bar.close()

    or as a context manager, which closes the bar on exit:

    >>> with Progress(desc="pairs") as bar:
    ...     bar(1, 1, "done")
    """

    def __init__(self, total: int | None = None, desc: str = "", *, file=None, disable: bool | None = None,
                 max_label: int = 60, **tqdm_kwargs):
        self.total = _count("total", total, allow_none=True)
        self.desc = str(desc)
        self.file = file
        if disable not in (None, True, False):
            raise ValueError(f"disable: expected None, True or False, got {disable!r}")
        self.disable = disable
        self.max_label = _count("max_label", max_label)
        self.tqdm_kwargs = dict(tqdm_kwargs)
        self.label = ""
        self._bar = None
        self._closed = False

    def _make(self):
        from tqdm.auto import tqdm

        kwargs = {"unit": "task", "dynamic_ncols": True}
        kwargs.update(self.tqdm_kwargs)
        return tqdm(total=self.total, desc=self.desc or None, file=self.file, disable=self.disable, **kwargs)

    def _short(self, label) -> str:
        text = " ".join(str(label).split())  # one line
        if len(text) > self.max_label:
            text = text[: max(self.max_label - 3, 0)] + "..."
        return text

    def __call__(self, done: int, total: int | None, label: str = "") -> None:
        """Show ``done`` of ``total`` tasks finished, the last being ``label``.

        Parameters
        ----------
        done : int
            Tasks finished so far (absolute, not an increment).
        total : int or None
            Number of tasks (None: unknown).
        label : str
            What just finished; shown as the postfix.

        Raises
        ------
        ValueError
            If ``done`` or ``total`` is not a non-negative integer.

        Notes
        -----
        After :meth:`close` a call does nothing (a late callback never breaks a run).
        """
        done = _count("done", done)
        total = _count("total", total, allow_none=True)
        if self._closed:
            return
        if total is not None:
            self.total = total
        if self._bar is None:
            self._bar = self._make()
        bar = self._bar
        if self.total is not None and bar.total != self.total:
            bar.total = self.total
        self.label = self._short(label)
        bar.set_postfix_str(self.label, refresh=False)
        if done >= bar.n:
            bar.update(done - bar.n)  # also redraws (subject to tqdm's mininterval)
        else:  # counted down (a new stage restarting at 0): move back and redraw
            bar.n = done
            bar.refresh()

    @property
    def n(self) -> int:
        """Tasks finished so far (0 before the first call)."""
        return 0 if self._bar is None else int(self._bar.n)

    def close(self) -> None:
        """Finish the bar (its final state stays drawn unless ``leave=False``). Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        if self._bar is not None:
            self._bar.close()

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"Progress(desc={self.desc!r}, n={self.n}, total={self.total}, {state})"
