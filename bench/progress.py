"""A tqdm bar behind the ``progress(done, total, label)`` callback of the harness and the studies."""

from __future__ import annotations

from bench import checks

__all__ = ["Progress"]


def _count(name: str, value, *, allow_none: bool = False) -> int | None:
    return None if value is None and allow_none else checks.integer(name, value, lo=0)


class Progress:
    """A progress bar for ``progress(done, total, label)`` callbacks (``tqdm.auto``: a widget in a
    notebook, a text bar on a terminal), created at the first call; also a context manager.

    Parameters
    ----------
    total : int, optional
        Number of tasks, if known before the first call (each call's ``total`` replaces it).
    desc : str
        Text before the bar.
    file : file-like, optional
        Where to draw (default ``sys.stderr``; a notebook draws a widget instead).
    disable : bool or None
        None: draw only on a terminal or in a notebook; True: never; False: always.
    max_label : int
        Labels longer than this are cut.
    **tqdm_kwargs
        Passed to ``tqdm``.
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

    def __call__(self, done: int, total: int | None, label: str = "") -> None:
        """Show ``done`` (absolute) of ``total`` (None: unknown) tasks finished, the last being ``label``;
        nothing after :meth:`close`."""
        done = _count("done", done)
        total = _count("total", total, allow_none=True)
        if self._closed:
            return
        if total is not None:
            self.total = total
        if self._bar is None:
            from tqdm.auto import tqdm

            self._bar = tqdm(total=self.total, desc=self.desc or None, file=self.file, disable=self.disable,
                             **{"unit": "task", "dynamic_ncols": True, **self.tqdm_kwargs})
        bar = self._bar
        if self.total is not None:
            bar.total = self.total
        self.label = " ".join(str(label).split())  # one line
        if len(self.label) > self.max_label:
            self.label = self.label[: max(self.max_label - 3, 0)] + "..."
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
        """Finish the bar (safe to call twice)."""
        if self._bar is not None and not self._closed:
            self._bar.close()
        self._closed = True

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"Progress(desc={self.desc!r}, n={self.n}, total={self.total}, {state})"
