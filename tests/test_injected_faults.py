"""Injected faults: solvers that crash or lie, nonlinearities that fail mid-simulation, diverging
simulations, a worker process that dies.

Property, for every pair run under a fault: it is never reported feasible (when its evidence
came from the faulty solver), certified or converged (when the fault hit the certificate or the
simulation); it becomes a row with a reason; the run finishes with one row per pair. The totals
(``faults: N faulty pairs ...``) are printed at the end of the module.
"""

from __future__ import annotations

import dataclasses
import math
import multiprocessing
import os

import numpy as np
import pytest

from bench import lmi as _lmi
from bench import pipeline
from bench.harness import RunOptions, run
from bench.registry import DESIGNS, PLANTS
from designs import GAIN_STATUSES, STATUSES, Design, DesignResult

STATS = {"faulty_pairs": 0, "corrupted_solves": 0, "misreported": 0}

#: designs whose gains come from an LMI solve (their "feasible" rests on the solver)
LMI_DESIGNS = ["thm1", "thm1_sep", "cor1", "cor1_sep", "cor1_printed", "lqr+rajamani", "lqr+zhang_osl"]
#: designs without an LMI solve of their own (the certificate still solves one); their gains are
#: "given" (printed) or "computed" (LQR/LQE), never "feasible"
OTHER_DESIGNS = ["paper_gains", "lqr+lqe"]
OPTS = RunOptions(n_samples=500)


@pytest.fixture(scope="module", autouse=True)
def _summary(request):
    yield
    rep = request.config.pluginmanager.get_plugin("terminalreporter")
    capman = request.config.pluginmanager.get_plugin("capturemanager")
    if rep is not None and capman is not None:
        with capman.global_and_fixture_disabled():
            rep.write_line(f"\nfaults: {STATS['faulty_pairs']} faulty pairs run ({STATS['corrupted_solves']} faulty "
                           f"solver calls), {STATS['misreported']} mis-reported")


def _audit(result, plant_ids, design_ids, *, solver_fault=False, sim_fault=False) -> None:
    """Check the property on every row; count faulty pairs and mis-reports."""
    df = result.frame()
    problems = []
    if len(df) != len(plant_ids) * len(design_ids):
        problems.append(f"{len(df)} rows for {len(plant_ids) * len(design_ids)} pairs")
    for r in df.itertuples(index=False):
        STATS["faulty_pairs"] += 1
        bad = []
        if r.status not in STATUSES:
            bad.append(f"unknown status {r.status!r}")
        if solver_fault and r.design in LMI_DESIGNS and r.feasible:
            bad.append("feasible from a faulty solver")
        if solver_fault and r.certified:
            bad.append("certified by a faulty solver")
        if sim_fault and r.converged:
            bad.append("converged although the simulation failed")
        # a row that is not a full success (gains, certified, converged) must say why; gains may now
        # be "feasible", "computed" (LQR/LQE) or "given" (printed gains)
        if not (r.status in GAIN_STATUSES and r.certified and r.converged) \
                and not (isinstance(r.reason, str) and r.reason):
            bad.append("no reason")
        if bad:
            STATS["misreported"] += 1
            problems.append(f"{r.plant} x {r.design} ({r.status}): {', '.join(bad)}")
    assert not problems, "\n".join(problems)


# -- solver faults ------------------------------------------------------------------------------
def _corrupt(problem, rng) -> None:
    """Replace the solver's point by random values (the scalars, the margin t among them, = 0.5)."""
    for v in problem.variables():
        if v.shape == ():
            v.value = 0.5
            continue
        G = rng.standard_normal(v.shape)
        if len(v.shape) == 2 and v.shape[0] == v.shape[1] and v.is_symmetric():
            G = (G + G.T) / 2
        v.value = G


@pytest.fixture
def lying_solver(monkeypatch):
    """``lying_solver(status)``: every solve returns ``status`` with a random point claiming t = 0.5."""

    def install(status: str):
        rng = np.random.default_rng(7)
        real = _lmi.solve_timed

        def fake(problem, solver="CLARABEL", **opts):
            out = real(problem, solver, **opts)
            _corrupt(problem, rng)
            STATS["corrupted_solves"] += 1
            return _lmi.SolveOutcome(status, out.compile_s, out.solve_s, "", 0.5)

        monkeypatch.setattr(_lmi, "solve_timed", fake)

    return install


@pytest.mark.parametrize("status", ["optimal", "optimal_inaccurate"])
def test_a_solver_point_with_a_positive_verified_margin_is_never_feasible(lying_solver, status):
    lying_solver(status)
    plants, designs = ["flexible_link", "random_osl_v1"], LMI_DESIGNS + OTHER_DESIGNS
    res = run(plants, designs, OPTS)
    _audit(res, plants, designs, solver_fault=True)
    df = res.frame()
    lmi = df[df["design"].isin(LMI_DESIGNS) & df["status"].isin(["undecided", "infeasible"])]
    assert len(lmi) > 0
    # the recomputed margin exposes the lie: positive (or the decision matrices are not positive)
    assert (lmi["lmi_margin"].isna() | (lmi["lmi_margin"] > 0) | lmi["reason"].str.contains("min eig")).all()
    # designs without an LMI of their own keep their gains ("given" / "computed", no longer "feasible"),
    # and the lying certificate solver leaves them uncertified, with the reason naming the certificate
    other = df[df["design"].isin(OTHER_DESIGNS) & df["status"].isin(["given", "computed"])]
    assert len(other) > 0 and other["reason"].str.contains("certificate").all()


def test_an_inaccurate_status_with_a_verified_point_is_judged_by_the_point(monkeypatch):
    """``optimal_inaccurate`` alone proves nothing either way: a feasible row needs a verified negative margin."""
    real = _lmi.solve_timed

    def inaccurate(problem, solver="CLARABEL", **opts):
        out = real(problem, solver, **opts)
        STATS["corrupted_solves"] += 1
        status = "optimal_inaccurate" if out.solved else out.status
        return _lmi.SolveOutcome(status, out.compile_s, out.solve_s, out.error, out.value)

    monkeypatch.setattr(_lmi, "solve_timed", inaccurate)
    plants, designs = ["flexible_link"], LMI_DESIGNS
    res = run(plants, designs, OPTS)
    _audit(res, plants, designs)
    df = res.frame()
    feas = df[df["feasible"]]
    assert len(feas) > 0 and (feas["lmi_margin"] < 0).all()
    assert feas["solver_status"].str.contains("inaccurate").all()


@pytest.mark.parametrize("crash", ["solver_error", "exception"])
def test_a_solver_that_raises_becomes_a_row_with_a_reason(monkeypatch, crash):
    import cvxpy as cp

    def broken(self, *a, **k):
        STATS["corrupted_solves"] += 1
        if crash == "solver_error":
            raise cp.error.SolverError("injected: the solver crashed")
        raise np.linalg.LinAlgError("injected: singular KKT system")

    monkeypatch.setattr(cp.Problem, "solve", broken)
    plants, designs = ["flexible_link"], LMI_DESIGNS + OTHER_DESIGNS
    res = run(plants, designs, OPTS)
    _audit(res, plants, designs, solver_fault=True)
    df = res.frame().set_index("design")
    assert "injected" in " ".join(df["reason"])
    if crash == "solver_error":  # a solver failure is a status: undecided, not an error
        assert (df.loc[["thm1", "cor1", "lqr+rajamani"], "status"] == "undecided").all()
    else:  # an unexpected exception is an error row naming it
        assert df.loc["thm1", "status"] == "error" and "LinAlgError" in df.loc["thm1", "reason"]


# -- simulation faults ---------------------------------------------------------------------------
ARMED = {"on": False, "calls": 0, "mode": ""}


def _armed_plant():
    """flexible_link with an f that misbehaves only while the harness simulates (constants stay sane)."""
    base = PLANTS.create("flexible_link")
    f0 = base.f

    def f(x):
        if ARMED["on"]:
            ARMED["calls"] += 1
            if ARMED["calls"] > 30:
                x = np.asarray(x, dtype=float)
                if ARMED["mode"] == "raise":
                    raise RuntimeError("injected: f failed mid-simulation")
                if ARMED["mode"] == "nan":
                    return np.full_like(x, math.nan)
                if ARMED["mode"] == "diverge":
                    return 50.0 * x + f0(x)
        return f0(x)

    # no declared Jacobian: the injected f would contradict it along the simulation (a PlantError)
    return dataclasses.replace(base, id="_fault_sim", f=f, channels=None, jacobian=None)


@pytest.fixture
def armed_simulation(monkeypatch):
    PLANTS.register("_fault_sim", _armed_plant)

    def arm(sim):
        def wrapped(*a, **k):
            ARMED.update(on=True, calls=0)
            try:
                return sim(*a, **k)
            finally:
                ARMED["on"] = False

        return wrapped

    # every simulation of a pair (fixed gains or a run-time estimator) goes through the pipeline's
    # simulate_controller
    monkeypatch.setattr(pipeline, "simulate_controller", arm(pipeline.simulate_controller))
    yield
    PLANTS.unregister("_fault_sim")
    ARMED.update(on=False, mode="")


@pytest.mark.parametrize("mode", ["raise", "nan", "diverge"])
def test_a_failing_or_diverging_simulation_never_converges(armed_simulation, mode):
    ARMED["mode"] = mode
    designs = ["paper_gains", "lqr+lqe", "lqr+ekf", "cor1_sep"]
    res = run(["_fault_sim"], designs, OPTS)
    _audit(res, ["_fault_sim"], designs, sim_fault=True)
    df = res.frame().set_index("design")
    if mode == "raise":
        assert (df["status"] == "error").all() and df["reason"].str.contains("injected").all()
    else:
        assert (df["sim_status"] == "diverged").all(), df["sim_status"].to_dict()
        assert df["reason"].str.contains("simulation diverged").all()
        # the design's own evidence survives: the printed gains keep their status ("given"; no
        # longer "feasible", which is only for solved feasibility problems), only the simulation failed
        assert df.loc["paper_gains", "status"] == "given"


# -- a worker process that dies -----------------------------------------------------------------
@dataclasses.dataclass(frozen=True, kw_only=True)
class _DiesInWorker(Design):
    """A design whose worker process dies (os._exit) - only ever in a child process."""

    def design(self, plant, constants):
        if multiprocessing.parent_process() is not None:
            os._exit(3)
        return DesignResult(status="error", reason="not in a worker")


def test_a_dead_worker_becomes_rows_and_the_run_finishes():
    DESIGNS.register("_dies_in_worker", _DiesInWorker)
    try:
        designs = ["_dies_in_worker", "paper_gains", "lqr+lqe"]
        res = run(["flexible_link"], designs, OPTS, jobs=2)
    finally:
        DESIGNS.unregister("_dies_in_worker")
    _audit(res, ["flexible_link"], designs)
    row = res.frame().set_index("design").loc["_dies_in_worker"]
    assert row["status"] == "error" and "worker failed" in row["reason"]
