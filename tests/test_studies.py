"""Studies (issue 5): vectorised batch simulation, digital implementation, admissible scale, noise, CLI.

Expectations are derived independently of the code under test: per-member ``solve_ivp`` runs
(:func:`bench.simulate.simulate`), the exact one-period matrix from ``scipy.linalg.expm``, the
Lipschitz small-gain bound from a frequency sweep, the harness's own noisy run.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.linalg import expm

from bench.cli import main
from bench.metrics import batch_settling_time, settling_time, trajectory_metrics
from bench.registry import DESIGNS, PLANTS
from bench.simulate import SimOptions, simulate
from bench.studies._common import StudyError, bisect_largest, check_box, check_levels, check_range, write_study
from bench.batch import BATCH_OPTIONS, digital_matrix, simulate_batch, simulate_digital_batch


@pytest.fixture(scope="module")
def paper_gains():
    plant = PLANTS.create("flexible_link")
    r = DESIGNS.create("paper_gains").design(plant, plant.bounds)
    return r.K, r.F


@pytest.fixture(scope="module")
def lqr_gains():
    plant = PLANTS.create("flexible_link")
    r = DESIGNS.create("lqr+lqe").design(plant, plant.bounds)
    return r.K, r.F


# -- continuous batch ---------------------------------------------------------------------------
@pytest.mark.parametrize("pid", ["flexible_link", "moving_object_v1"])
def test_batch_matches_solve_ivp_per_initial_condition(pid, paper_gains):
    plant = PLANTS.create(pid)
    if pid == "flexible_link":
        K, F = paper_gains
    else:
        r = DESIGNS.create("lqr+lqe").design(plant, plant.bounds)
        K, F = r.K, r.F
    rng = np.random.default_rng(1)
    X = np.column_stack([plant.x0, rng.uniform(-1, 1, (plant.n, 4))])
    XH = np.column_stack([plant.x_hat0, rng.uniform(-1, 1, (plant.n, 4))])
    T = 8.0
    tr = simulate_batch(plant, K, F, X, XH, t_final=T,
                        options=SimOptions(method="RK45", rtol=1e-9, atol=1e-12, n_points=801))
    assert tr.status == "ok" and not tr.diverged.any()
    bm = tr.metrics()
    opts = SimOptions(n_points=801)  # DOP853, rtol 1e-8, atol 1e-12: a different method and layout
    for j in range(X.shape[1]):
        ref = simulate(plant, K, F, t_final=T, x0=X[:, j], x_hat0=XH[:, j], options=opts)
        np.testing.assert_allclose(tr.t, ref.t)
        scale = np.abs(ref.x).max()
        assert np.abs(tr.x[:, j, :] - ref.x).max() <= 1e-6 * scale
        assert np.abs(tr.x_hat[:, j, :] - ref.x_hat).max() <= 1e-6 * max(scale, np.abs(ref.x_hat).max())
        m = trajectory_metrics(ref.t, ref.x, ref.x_hat, ref.u)
        assert bm["converged"][j] == m["converged"]
        for key in ("settling_x_s", "settling_e_s"):
            a, b = bm[key][j], m[key]
            assert (math.isnan(a) and math.isnan(b)) or abs(a - b) <= 1.01 * (ref.t[1] - ref.t[0])


def test_batch_settling_time_equals_the_scalar_metric():
    rng = np.random.default_rng(0)
    t = np.linspace(0, 5, 101)
    rows = [np.exp(-t) * (1 + 0.3 * np.sin(7 * t)), np.zeros_like(t), np.ones_like(t), rng.random(t.size),
            np.where(t < 2, 1.0, 0.0), np.concatenate([[0.0], np.full(t.size - 1, 1e-3)])]
    bad = np.exp(-t)
    bad[10] = np.nan
    S = np.array(rows + [bad])
    got = batch_settling_time(t, S)
    for i, s in enumerate(S):
        want = settling_time(t, s)
        assert (math.isnan(got[i]) and math.isnan(want)) or got[i] == want, (i, got[i], want)


def test_a_diverging_member_is_frozen_and_does_not_stop_the_others():
    plant = PLANTS.create("flexible_link", c=0.0)
    K = np.zeros((4, 2))
    F = np.array([[5.0, 0.0, 0.0, 0.0]])  # A + BF unstable
    assert np.linalg.eigvals(plant.A + plant.B @ F).real.max() > 0
    X = np.column_stack([np.zeros(4), [0.1, 0, 0, 0]])
    tr = simulate_batch(plant, K, F, X, X.copy(), t_final=20.0, options=replace(BATCH_OPTIONS, blowup=1e3))
    assert tr.status == "ok"
    assert tr.diverged.tolist() == [False, True]
    m = tr.metrics()
    assert m["converged"].tolist() == [True, False]  # the zero state stays at the equilibrium


def test_a_batch_past_its_budget_stops_with_that_status():
    """The options' budget of right-hand sides applies to a batch as to one trajectory (a
    DOP853 step is 12 right-hand sides: 20 cannot reach 20 s)."""
    plant = PLANTS.create("flexible_link")
    r = DESIGNS.create("lqr+lqe").design(plant, plant.bounds)
    X = np.column_stack([plant.x0, plant.x0 / 2])
    tr = simulate_batch(plant, r.K, r.F, X, X.copy(), options=replace(BATCH_OPTIONS, method="DOP853", max_nfev=20))
    assert tr.status == "budget" and "20 right-hand-side" in tr.message
    assert tr.t.size == 1 and np.array_equal(tr.x[:, :, 0], X)


# -- digital implementation ---------------------------------------------------------------------
@pytest.mark.parametrize("disc", ["zoh", "euler"])
@pytest.mark.parametrize("h", [0.01, 0.05])
def test_one_sample_period_equals_the_exact_discrete_matrix(disc, h, paper_gains):
    """For a linear plant (c = 0) one period of the simulator is the matrix built from expm."""
    plant = PLANTS.create("flexible_link", c=0.0)
    K, F = paper_gains
    n = plant.n
    E = np.eye(2 * n)
    tr = simulate_digital_batch(plant, K, F, E[:n], E[n:], h=h, t_final=h, discretisation=disc)
    Phi_sim = np.vstack([tr.x[:, :, -1], tr.x_hat[:, :, -1]])
    # independent construction: expm of the held-input augmented system (x, x_hat, x_k, x_hat_k)
    A, B, C = plant.A, plant.B, plant.C
    Z = np.zeros((n, n))
    if disc == "zoh":
        M = np.block([[A, Z, Z, B @ F], [Z, A, K @ C, B @ F - K @ C], [Z, Z, Z, Z], [Z, Z, Z, Z]])
        Phi = (expm(M * h) @ np.vstack([np.eye(2 * n), np.eye(2 * n)]))[: 2 * n]
    else:
        M = np.block([[A, Z, Z, B @ F], [Z, Z, Z, Z], [Z, Z, Z, Z], [Z, Z, Z, Z]])
        top = (expm(M * h) @ np.vstack([np.eye(2 * n), np.eye(2 * n)]))[:n]
        bot = np.hstack([h * K @ C, np.eye(n) + h * (A + B @ F - K @ C)])
        Phi = np.vstack([top, bot])
    np.testing.assert_allclose(Phi_sim, Phi, atol=1e-8 * np.abs(Phi).max())
    np.testing.assert_allclose(digital_matrix(A, B, C, K, F, h, disc), Phi, atol=1e-10 * np.abs(Phi).max())


@pytest.mark.parametrize("disc", ["zoh", "euler"])
def test_linear_sampled_loop_converges_iff_spectral_radius_below_one(disc, lqr_gains):
    plant = PLANTS.create("flexible_link", c=0.0)
    K, F = lqr_gains
    A, B, C = plant.A, plant.B, plant.C
    T = 20.0
    checked = {True: 0, False: 0}
    for h in (0.02, 0.05, 0.08, 0.1, 0.12, 0.15, 0.2):
        n = plant.n
        M = np.zeros((2 * n, 2 * n))
        M[:n, :n], M[:n, n:] = A, np.eye(n)
        E = expm(M * h)
        Ad, G = E[:n, :n], E[:n, n:]
        if disc == "zoh":
            Phi = np.block([[Ad, G @ B @ F], [G @ K @ C, Ad + G @ B @ F - G @ K @ C]])
        else:
            Phi = np.block([[Ad, G @ B @ F], [h * K @ C, np.eye(n) + h * (A + B @ F - K @ C)]])
        rho = float(np.abs(np.linalg.eigvals(Phi)).max())
        if abs(rho - 1) < 0.02 or (rho < 1 and rho ** (T / h) > 1e-6):
            continue  # too close to the boundary to decide within the horizon
        tr = simulate_digital_batch(plant, K, F, plant.x0, plant.x_hat0, h=h, t_final=T, discretisation=disc)
        conv = bool(tr.metrics()["converged"][0])
        assert conv == (rho < 1), (h, rho)
        checked[rho < 1] += 1
    assert checked[True] >= 2 and checked[False] >= 2


def test_small_h_approaches_the_continuous_loop(lqr_gains):
    """Emulation: the sampled loop tends to the continuous one as h -> 0 (first order in h)."""
    plant = PLANTS.create("flexible_link")
    K, F = lqr_gains
    T = 10.0
    cont = simulate(plant, K, F, t_final=T, options=SimOptions(n_points=5001))
    errs = []
    for h in (2e-3, 4e-3):
        tr = simulate_digital_batch(plant, K, F, plant.x0, plant.x_hat0, h=h, t_final=T)
        k = np.searchsorted(cont.t, tr.t)
        assert np.allclose(cont.t[k], tr.t)
        errs.append(np.abs(tr.x[:, 0, :] - cont.x[:, k]).max())
        m = tr.metrics()
        ref = trajectory_metrics(cont.t, cont.x, cont.x_hat, cont.u)
        assert m["converged"][0] and abs(m["settling_x_s"][0] - ref["settling_x_s"]) <= 0.02 * ref["settling_x_s"]
    assert errs[0] < 0.05 * np.abs(cont.x).max()
    assert 1.6 < errs[1] / errs[0] < 2.4  # halving h halves the error


def test_sampling_study_bound_is_consistent_with_linearisation(tmp_path):
    from bench.studies.sampling import linear_h_bound, run_sampling

    res = run_sampling(["flexible_link"], ["lqr+lqe"], n_ics=3, t_final=10.0, jobs=1)
    row = res.rows[0]
    assert row["kind"] == "bracketed"
    assert row["h_fail"] / row["h_max"] - 1 <= 0.01 + 1e-12
    plant = PLANTS.create("flexible_link")
    d = DESIGNS.create("lqr+lqe").design(plant, plant.bounds)
    h_lin = linear_h_bound(plant, d.K, d.F)
    assert h_lin == pytest.approx(row["h_lin"])
    assert row["h_max"] <= h_lin  # no convergence without local exponential stability
    # just above h_lin the origin of the sampled loop is unstable: the plant's initial conditions cannot converge
    tr = simulate_digital_batch(plant, d.K, d.F, plant.x0, plant.x_hat0, h=1.05 * h_lin, t_final=10.0)
    assert not tr.metrics()["converged"][0]
    evals = {e["h"]: e for e in res.evals}
    assert evals[row["h_max"]]["ok"] and not evals[row["h_fail"]]["ok"]


# -- admissible scale ---------------------------------------------------------------------------
def test_admissible_scale_brackets_the_channel_small_gain_bound_of_lqr_lqe():
    """With K, F fixed (LQR + LQE) and one symmetric channel [-c, c], the structured certificate exists iff
    both sides pass the circle criterion: c < 1 / max(||H(sI - A - BF)^-1 G||_inf, ||H(sI - A + KC)^-1 G||_inf)."""
    from bench.studies.admissible import _pair_task, evaluate_at

    out = _pair_task("flexible_link", "c", "lqr+lqe", {}, None, 0.01)
    row = out["row"]
    lo, hi = row["admissible_lo"], row["failing_hi"]
    assert row["kind"] == "bracketed" and hi / lo - 1 <= 0.01 + 1e-12
    assert evaluate_at("flexible_link", "c", lo, "lqr+lqe")["certified"]
    assert not evaluate_at("flexible_link", "c", hi, "lqr+lqe")["certified"]
    plant = PLANTS.create("flexible_link")
    d = DESIGNS.create("lqr+lqe").design(plant, plant.bounds)
    G, H = np.eye(4)[:, [3]], np.eye(4)[[2]]  # f4 = -c sin(x3): acts on x4, reads x3 (independent of the plant code)
    ws = np.linspace(0, 40, 40001)
    peak = 0.0
    for M in (plant.A + plant.B @ d.F, plant.A - d.K @ plant.C):  # one batched solve over the frequency grid
        peak = max(peak, float(np.abs(H @ np.linalg.solve(1j * ws[:, None, None] * np.eye(4) - M, G)).max()))
    c_sg = 1 / peak
    assert lo * 0.995 <= c_sg <= hi * 1.005
    assert row["small_gain"] == pytest.approx(c_sg, rel=1e-3)


def test_admissible_separated_designs_feasible_below_and_not_above():
    from bench.studies.admissible import _pair_task, evaluate_at as evaluate

    rows = {}
    for did in ("thm1_sep", "cor1_sep"):
        rows[did] = _pair_task("flexible_link", "c", did, {}, None, 0.01)["row"]
        lo, hi = rows[did]["admissible_lo"], rows[did]["failing_hi"]
        assert rows[did]["kind"] == "bracketed" and hi / lo - 1 <= 0.01 + 1e-12
        below = evaluate("flexible_link", "c", 0.999 * lo, did)
        above = evaluate("flexible_link", "c", 1.001 * hi, did)
        assert below["ok"] and below["feasible"] and below["certified"]
        assert not above["ok"]
        assert lo > 0.333  # feasible at the paper's c (REPORT.md)
    # gamma = 0 and beta = alpha^2: the x-side LMIs of Theorem 1 and Corollary 1 coincide, so do the brackets
    assert rows["thm1_sep"]["admissible_lo"] == rows["cor1_sep"]["admissible_lo"]
    assert "x-side" in rows["thm1_sep"]["fail_reason"]


@pytest.mark.slow
def test_theorem1_admits_more_than_corollary1_on_an_osl_plant():
    from bench.studies.admissible import _pair_task

    thm = _pair_task("random_osl_v1", "c", "thm1", {}, None, 0.01)["row"]
    cor = _pair_task("random_osl_v1", "c", "cor1", {}, None, 0.01)["row"]
    assert thm["admissible_lo"] > 2 * cor["admissible_lo"]


def test_bisection_on_a_known_threshold():
    calls = []

    def check(v):
        calls.append(v)
        return {"ok": v <= math.pi, "status": "x"}

    out = bisect_largest(check, 1.0, rtol=0.01)
    assert out["lo"] <= math.pi < out["hi"] and out["hi"] / out["lo"] <= 1.01
    out = bisect_largest(check, 100.0, rtol=0.001)
    assert out["lo"] <= math.pi < out["hi"] and out["hi"] / out["lo"] <= 1.001
    assert bisect_largest(check, 1.0, bounds=(4.0, 5.0))["kind"] == "below_range"
    assert bisect_largest(check, 1.0, bounds=(1.0, 2.0))["kind"] == "above_range"
    with pytest.raises(StudyError, match="bounds"):
        bisect_largest(check, 1.0, bounds=(2.0, 1.0))


# -- noise --------------------------------------------------------------------------------------
def test_noise_study_equals_the_harness_and_scales_with_sigma():
    from bench.constants import compute_constants
    from bench.pipeline import RunOptions, evaluate_pair
    from bench.studies.noise import run_noise

    res = run_noise(["flexible_link"], ["lqr+lqe"], levels=(1e-3, 1e-2), seed=3, jobs=1)
    by = {r["noise"]: r for r in res.rows}
    plant = PLANTS.create("flexible_link")
    rec = evaluate_pair(plant, "lqr+lqe", compute_constants(plant, seed=0, n_samples=2000),
                   RunOptions(noise=1e-2, seed=3)).record
    assert by[1e-2]["rms_e"] == pytest.approx(rec["rms_e"], rel=1e-9)
    assert by[1e-2]["final_x"] == pytest.approx(rec["final_x"], rel=1e-9)
    # a stable loop, noise-dominated steady state: RMS error proportional to sigma (same seeded sequence)
    assert by[1e-2]["rms_e"] / by[1e-3]["rms_e"] == pytest.approx(10, rel=0.05)


# -- argument checks, CLI, files ----------------------------------------------------------------
def test_argument_checks_name_the_parameter():
    for bad in (-1.0, 0.0, math.nan, math.inf):
        with pytest.raises(StudyError, match="^box:"):
            check_box("box", bad)
    with pytest.raises(StudyError, match="^levels:"):
        check_levels("levels", [1e-3, -1e-3])
    with pytest.raises(StudyError, match="^levels:"):
        check_levels("levels", [math.nan])
    with pytest.raises(StudyError, match="wrong order"):
        check_range("h_range", (0.1, 0.01))
    from bench.studies.montecarlo import run_montecarlo

    with pytest.raises(StudyError, match="^n:"):
        run_montecarlo(["flexible_link"], ["paper_gains"], n=0)


@pytest.mark.parametrize("argv, option", [
    (["montecarlo", "--box", "-1"], "--box"),
    (["montecarlo", "--box", "nan"], "--box"),
    (["montecarlo", "--n", "0"], "--n"),
    (["noise", "--levels", "1e-3,-1"], "--levels"),
    (["noise", "--levels", "inf"], "--levels"),
    (["admissible", "--range", "2", "1"], "--range"),
    (["sampling", "--h-range", "0.1", "0.01"], "--h-range"),
    (["sampling", "--box", "0"], "--box"),
    (["admissible", "--plant", "chua_v1"], "--plant"),
    (["sampling", "--plant", "flexible_link", "--design", "lqr+ekf"], "--design"),
])
def test_cli_bad_input_exits_2_naming_the_option(argv, option, tmp_path, capsys):
    assert main(["study", *argv, "--out", str(tmp_path), "-j", "1", "-q"]) == 2
    err = capsys.readouterr().err
    assert option in err
    assert not list(tmp_path.glob("STUDY_*"))


def test_cli_montecarlo_writes_its_own_files_only(tmp_path):
    argv = ["study", "montecarlo", "--plant", "flexible_link", "--design", "paper_gains", "--design", "lqr+ekf",
            "--n", "40", "--t-final", "10", "--seed", "7", "--out", str(tmp_path), "-j", "1", "-q"]
    assert main(argv) == 0
    import pandas as pd

    df = pd.read_csv(tmp_path / "study_montecarlo.csv")
    row = df[df.design == "paper_gains"].iloc[0]
    assert row.frac_converged == 1.0 and row.N == 40 and row.seed == 7
    assert df[df.design == "lqr+ekf"].iloc[0].status == "no fixed gains"
    md = (tmp_path / "STUDY_montecarlo.md").read_text()
    assert "seed = 7" in md and "paper_gains" in md
    assert (tmp_path / "figures" / "study_montecarlo_flexible_link.png").exists()
    assert not (tmp_path / "REPORT.md").exists()
    assert not list(tmp_path.glob(".tmp-*"))
    first = (tmp_path / "study_montecarlo.csv").read_text()
    assert main(argv) == 0  # seeded: the same numbers again (timings aside)
    again = pd.read_csv(tmp_path / "study_montecarlo.csv")
    cols = ["frac_converged", "worst_final_x", "settling_median"]
    pd.testing.assert_frame_equal(df[cols], again[cols])
    assert first.splitlines()[0] == (tmp_path / "study_montecarlo.csv").read_text().splitlines()[0]


def test_study_files_are_written_whole_or_not_at_all(tmp_path):
    import pandas as pd

    write_study(tmp_path, "x", "# first\n", {"study_x": pd.DataFrame({"a": [1]})}, {})
    before = (tmp_path / "STUDY_x.md").read_text()

    def broken(path):
        raise RuntimeError("figure failed")

    with pytest.raises(RuntimeError):
        write_study(tmp_path, "x", "# second\n", {"study_x": pd.DataFrame({"a": [2]})}, {"study_x": broken})
    assert (tmp_path / "STUDY_x.md").read_text() == before
    assert pd.read_csv(tmp_path / "study_x.csv").a.tolist() == [1]
    assert not list(tmp_path.glob(".tmp-*"))


def test_bisection_of_an_inapplicable_design_stops_at_once():
    from bench.studies._common import bisect_largest

    calls = []

    def check(v):
        calls.append(v)
        return {"value": v, "ok": False, "status": "inapplicable", "reason": "no channels"}

    out = bisect_largest(check, 10.0)
    assert out["kind"] == "inapplicable" and calls == [10.0] and len(out["evals"]) == 1


def test_bisection_checks_each_value_once():
    from bench.studies._common import bisect_largest

    calls = []

    def check(v):
        calls.append(v)
        return {"value": v, "ok": v <= 3.0, "status": "feasible" if v <= 3.0 else "infeasible", "reason": ""}

    out = bisect_largest(check, 1.0, rtol=0.01)
    assert out["lo"] <= 3.0 < out["hi"] and out["hi"] / out["lo"] - 1 <= 0.01
    assert len(calls) == len(set(calls))


def test_study_functions_show_their_options_and_refuse_unknown_ones():
    """A notebook sees each study's options in its signature (tab completion), and a misspelt one is refused."""
    import inspect

    from bench.studies.noise import run_noise
    from bench.studies.sampling import run_sampling

    params = inspect.signature(run_noise).parameters
    assert list(params)[:4] == ["plant_ids", "design_ids", "jobs", "progress"]
    assert {"levels", "seed", "matched_ekf", "noise_dt", "t_final"} <= set(params)
    assert "options" not in params and "rtol" in inspect.signature(run_sampling).parameters
    with pytest.raises(TypeError, match="levelz"):
        run_noise(["pendulum_v1"], ["lqr+lqe"], levelz=(0.1,))
