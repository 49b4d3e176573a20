"""bench.progress: a tqdm bar behind the progress(done, total, label) callback."""

from __future__ import annotations

import io
import re

import pytest

from bench.progress import Progress


class FakeTTY(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_quiet_when_not_a_terminal():
    stream = io.StringIO()  # isatty() is False: disable=None turns the bar off
    bar = Progress(desc="pairs", file=stream)
    for i in range(1, 6):
        bar(i, 5, f"plant_{i} x thm1")
    bar.close()
    assert stream.getvalue() == ""
    assert bar.label == "plant_5 x thm1"


def test_draws_on_a_terminal_by_default():
    stream = FakeTTY()
    with Progress(desc="pairs", file=stream, mininterval=0) as bar:
        bar(2, 3, "flexible_link x cor1")
    assert "2/3" in stream.getvalue() or "3/3" in stream.getvalue()


def test_writes_count_and_label_when_forced():
    stream = io.StringIO()
    bar = Progress(desc="pairs", file=stream, disable=False, mininterval=0)
    bar(1, 4, "flexible_link x thm1")
    bar(3, 4, "pendulum_v1 x lqr+lqe")
    assert bar.n == 3
    bar.close()
    out = stream.getvalue()
    assert "pairs" in out
    assert re.search(r"\b3/4\b", out), out
    assert "pendulum_v1 x lqr+lqe" in out
    assert "75%" in out


def test_total_from_calls_and_counting_back():
    stream = io.StringIO()
    bar = Progress(file=stream, disable=False, mininterval=0)
    assert bar.total is None and bar.n == 0
    bar(2, 10, "a")
    assert bar.total == 10 and bar.n == 2
    bar(1, 7, "second stage")  # a new stage: total changes, count goes back
    assert bar.total == 7 and bar.n == 1
    bar.close()
    assert "1/7" in stream.getvalue()


def test_long_labels_are_cut_to_one_line():
    bar = Progress(file=io.StringIO(), max_label=20)
    bar(1, 1, "x" * 50 + "\nsecond line")
    assert bar.label == "x" * 17 + "..."
    bar.close()


def test_close_is_idempotent_and_late_calls_are_ignored():
    stream = io.StringIO()
    bar = Progress(file=stream, disable=False, mininterval=0)
    bar(1, 2, "a")
    bar.close()
    text = stream.getvalue()
    bar.close()
    bar(2, 2, "late")
    assert stream.getvalue() == text
    Progress().close()  # never drawn: nothing to close
    with Progress(file=io.StringIO()) as unused:
        pass
    unused.close()


def test_context_manager_closes_on_error():
    stream = io.StringIO()
    with pytest.raises(KeyError):
        with Progress(file=stream, disable=False, mininterval=0) as bar:
            bar(1, 2, "a")
            raise KeyError("boom")
    assert bar._closed
    assert "1/2" in stream.getvalue()


@pytest.mark.parametrize("args, name", [((-1, 2, "a"), "done"), ((1, 2.5, "a"), "total"), ((True, 2, "a"), "done")])
def test_bad_counts(args, name):
    with pytest.raises(ValueError, match=name):
        Progress(file=io.StringIO())(*args)


def test_bad_constructor_arguments():
    with pytest.raises(ValueError, match="total"):
        Progress(total=-3)
    with pytest.raises(ValueError, match="disable"):
        Progress(disable="yes")
    with pytest.raises(ValueError, match="max_label"):
        Progress(max_label=-1)
