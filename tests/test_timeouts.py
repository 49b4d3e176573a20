"""A pair over its --timeout becomes a timeout row: stuck design, stuck solve (the solver gets the time
left), stuck simulation, and the command-line option (bench.limits, bench.pipeline, bench.harness)."""

from __future__ import annotations

import dataclasses
import json
import signal
import time

import numpy as np
import pandas as pd
import pytest

from bench.cli import main
from bench.harness import RunOptions, run
from bench.registry import DESIGNS, PLANTS
from bench import limits
from bench import lmi as _lmi
from designs import Design, DesignResult

FAST = RunOptions(n_samples=500)


@pytest.fixture
def register():
    """``register(id, cls_or_factory, registry=DESIGNS)``; everything is unregistered afterwards."""
    done = []

    def reg(id_, obj, registry=DESIGNS, **kw):
        registry.register(id_, obj, **kw)
        done.append((registry, id_))

    yield reg
    for registry, id_ in done:
        registry.unregister(id_)


# -- timeouts -----------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, kw_only=True)
class _Sleeps(Design):
    """A design stuck in Python code that checks no time limit."""

    def design(self, plant, constants):
        time.sleep(60)
        return DesignResult(status="infeasible", reason="woke up")


@dataclasses.dataclass(frozen=True, kw_only=True)
class _BigSolve(Design):
    """A design whose single SDP solve takes seconds (Clarabel, n = 25 Lyapunov-type LMI)."""

    def design(self, plant, constants):
        import cvxpy as cp

        n = 25
        A = np.random.default_rng(0).standard_normal((n, n))
        P, t = cp.Variable((n, n), symmetric=True), cp.Variable()
        prob = cp.Problem(cp.Maximize(t), [cp.bmat([[A.T @ P + P @ A, P], [P, -np.eye(n)]]) << -t * np.eye(2 * n),
                                           P >> t * np.eye(n), P << np.eye(n), t <= 1])
        out = _lmi.solve_timed(prob)
        return DesignResult(status="undecided", reason=f"solved: {out.status}")


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_stuck_design_becomes_a_timeout_row(register, jobs):
    register("_sleeps", _Sleeps)
    # no wall-clock assertion (project rule): the design sleeps 60 s and would return "infeasible",
    # so a "timeout" row is itself the proof that it was stopped
    res = run(["flexible_link"], ["thm1_printed", "_sleeps"], dataclasses.replace(FAST, timeout=1.0), jobs=jobs)
    df = res.frame().set_index("design")
    row = df.loc["_sleeps"]
    assert row["status"] == "timeout" and not row["feasible"] and not row["certified"] and not row["converged"]
    assert "timeout" in row["reason"] and "1 s" in row["reason"] and "during the design" in row["reason"]
    assert df.loc["thm1_printed", "status"] == "infeasible"  # the other pair is untouched


def test_a_stuck_solve_is_stopped_by_the_solver_time_limit(register):
    import signal

    register("_big_solve", _BigSolve)
    # Isolate the solver's own limit from the SIGALRM fallback: bench.limits.hard_stop stands aside
    # when SIGALRM already has a handler. Clarabel checks its limit between iterations, and on a
    # loaded machine its first iteration alone can outlast the hard stop (1.1 * 0.4 + 0.5 s).
    old = signal.signal(signal.SIGALRM, signal.SIG_IGN)
    try:
        res = run(["flexible_link"], ["_big_solve"], dataclasses.replace(FAST, timeout=0.4))
    finally:
        signal.signal(signal.SIGALRM, old)
    row = res.frame().iloc[0]
    assert row["status"] == "timeout" and "SDP solve" in row["reason"], row["reason"]


def test_the_solver_gets_the_remaining_time_as_its_own_limit(monkeypatch):
    import cvxpy as cp

    seen = {}

    def fake_solve(self, **kw):
        seen.update(kw)
        self._status = "optimal"

    x = cp.Variable()
    prob = cp.Problem(cp.Minimize(x), [x >= 1])
    monkeypatch.setattr(cp.Problem, "solve", fake_solve)
    monkeypatch.setattr(cp.Problem, "status", property(lambda self: getattr(self, "_status", None)))
    monkeypatch.setattr(cp.Problem, "value", property(lambda self: 1.0))
    with limits.time_limit(30.0):
        _lmi.solve_timed(prob, "CLARABEL")
        assert 25 < seen["time_limit"] <= 30
        _lmi.solve_timed(prob, "SCS")
        assert 25 < seen["time_limit_secs"] <= 30
    seen.clear()
    _lmi.solve_timed(prob, "CLARABEL")  # no scope: no limit
    assert "time_limit" not in seen


SLOW = {"on": False}


def _slow_in_simulation():
    base = PLANTS.create("flexible_link")
    f0 = base.f

    def f(x):
        if SLOW["on"]:
            time.sleep(0.005)
        return f0(x)

    return dataclasses.replace(base, id="_slow_sim", f=f, channels=None)


def test_a_stuck_simulation_becomes_a_timeout_row(register, monkeypatch):
    from bench import pipeline

    register("_slow_sim", _slow_in_simulation, registry=PLANTS)
    real = pipeline.simulate_controller  # every pair's simulation goes through the pipeline

    def slow(*a, **k):
        SLOW["on"] = True
        try:
            return real(*a, **k)
        finally:
            SLOW["on"] = False

    monkeypatch.setattr(pipeline, "simulate_controller", slow)
    res = run(["_slow_sim"], ["paper_gains"], dataclasses.replace(FAST, timeout=1.5))
    row = res.frame().iloc[0]
    assert row["status"] == "timeout" and row["sim_status"] == "timeout"
    # the printed gains are "given" now ("feasible" is only for a solved feasibility problem)
    assert "during the simulation" in row["reason"] and "reached before: given, certified" in row["reason"]
    assert not row["certified"] and not row["converged"] and not row["feasible"]


def test_cli_timeout_option(tmp_path, register, capsys):
    register("_sleeps", _Sleeps)
    assert main(["run", "--timeout", "0", "--out", str(tmp_path)]) == 2
    assert main(["run", "--timeout", "nan", "--out", str(tmp_path)]) == 2
    assert "--timeout" in capsys.readouterr().err
    rc = main(["run", "-j", "1", "--no-cache", "--no-figures", "--timeout", "1", "--plant", "flexible_link",
               "--design", "_sleeps", "--out", str(tmp_path)])
    assert rc == 0
    assert "1 without (1 timeout)" in capsys.readouterr().err
    df = pd.read_csv(tmp_path / "results.csv")
    assert df.loc[0, "status"] == "timeout"
    assert "timeout" in (tmp_path / "REPORT.md").read_text()
    assert json.loads((tmp_path / "run.json").read_text())["timeout"] == 1.0
