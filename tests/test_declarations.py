"""Declarations (channels, slope bounds, constants, Jacobian) are checked where certificates use them,
and a certified pair that contradicts its certificate is reported as such."""

import math
import threading
import time

import numpy as np
import pytest

from bench import api
from bench.constants import compute_constants
from bench.findings import findings
from bench.pipeline import RunOptions, evaluate_pair
from bench.verdicts import convergence_note
from plants import Channels, Plant, PlantError
from tests._plugin_helpers import clean_registries  # noqa: F401

G2, H2 = np.array([[0.0], [1.0]]), np.array([[1.0, 0.0]])
DOUBLE_INTEGRATOR = dict(A=[[0.0, 1.0], [0.0, 0.0]], B=[[0.0], [1.0]], C=[[1.0, 0.0]])


def _sine_f(c):
    def f(x):
        x = np.asarray(x, dtype=float)
        out = np.zeros_like(x)
        out[1] = -c * np.sin(x[0])
        return out
    return f


def test_a_design_certificate_on_disproved_slopes_is_refused():
    # f2 = -2 sin(x1) has slopes in [-2, 2]; the plugin declares [-1, 1]: the structured design's own
    # joint certificate uses those slopes, so it must not certify (the plugin)
    ch = Channels(G=G2, H=H2, phi=lambda z: -2 * np.sin(z), lo=-1, hi=1)
    plant = Plant(id="liar", A=[[0.0, 1.0], [0.0, -1.0]], B=[[0.0], [1.0]], C=[[1.0, 0.0]], f=_sine_f(2.0),
                  x0=[1.0, 0.0], x_hat0=[0.0, 0.0], channels=ch)
    res = api.run([plant], ["structured"], jobs=1, progress=False)
    row = res.table.iloc[0]
    assert row["status"] == "feasible"  # the gains exist ...
    assert not row["certified"] and row["cert_level"] == ""  # ... but nothing is certified
    assert row["cert_structured"] == "not certified"
    assert "refused" in row["details"] and "channel 0" in row["details"] and "slope bound = 1" in row["details"]
    assert res.findings["plants"]["liar"]["best"] is None


def test_a_channel_identity_broken_along_the_simulation_uncertifies_every_pair():
    # f = G phi(Hx) holds for |x2| <= 3.5 only (where the plant's own probes look); from x0 the
    # uncontrolled start pushes x2 beyond 3.5, where a destabilising term takes over
    def f(x):
        x = np.asarray(x, dtype=float)
        out = np.zeros_like(x)
        out[1] = -np.sin(x[0]) + np.where(np.abs(x[1]) > 3.5, 50.0 * (np.abs(x[1]) - 3.5) * x[1], 0.0)
        return out

    ch = Channels(G=G2, H=H2, phi=lambda z: -np.sin(z), lo=-1, hi=1)
    plant = Plant(id="hidden", **DOUBLE_INTEGRATOR, f=f, x0=[-3.0, 3.4], x_hat0=[0.0, 0.0], channels=ch)
    res = api.run([plant], ["structured", "lqr+lqe"], jobs=1, progress=False)
    t = res.table.set_index("design")
    for d in ("structured", "lqr+lqe"):
        assert not t.loc[d, "certified"], (d, t.loc[d, "details"])
        assert "differs from f" in t.loc[d, "details"]
    assert any(v["constant"] == "channels" for v in res.findings["disproved"])
    assert "x_hat" in t.loc["lqr+lqe", "sim_witness"]


def test_a_slope_bound_broken_beyond_the_sampled_range_is_found_from_the_reach():
    # slope within [-0.3, 0.3] for |z| <= 35, 3 beyond: the pre-simulation sampler (|z| <= 31.6 here)
    # cannot see it; the simulation (non-normal A: from ||x0|| = 3, x1 overshoots to ~4.4) is checked
    # out to 10 times its reach
    def phi(z):
        z = np.asarray(z, dtype=float)
        return -0.3 * np.sin(z) - 3.0 * np.sign(z) * np.maximum(np.abs(z) - 35.0, 0.0)

    def f(x):
        x = np.asarray(x, dtype=float)
        out = np.zeros_like(x)
        out[1] = phi(x[0])
        return out

    ch = Channels(G=G2, H=H2, phi=phi, lo=-0.3, hi=0.3)
    plant = Plant(id="far", A=[[-1.0, 4.0], [0.0, -1.0]], B=[[0.0], [1.0]], C=[[1.0, 0.0]], f=f, x0=[0.0, 3.0],
                  x_hat0=[0.0, 0.0], channels=ch)
    rep = compute_constants(plant, n_samples=500)
    assert rep.channel_violations == [] and math.isclose(rep.checked_on, 10**1.5)
    rec = evaluate_pair(plant, "lqr+lqe", rep, RunOptions(n_samples=500)).record
    assert rec["max_norm"] > 3.5
    assert not rec["certified"] and "slope bound" in rec["disproved"], rec["reason"]
    assert f"sampled on ||x|| <= {10 * rec['max_norm']:.3g}" in rec["checked_on"]
    # the same plant with the declaration true everywhere stays certified (the check is not what fails)
    ok = Plant(id="near", A=plant.A, B=plant.B, C=plant.C, f=_sine_f(0.3), x0=plant.x0, x_hat0=plant.x_hat0,
               channels=Channels(G=G2, H=H2, phi=lambda z: -0.3 * np.sin(z), lo=-0.3, hi=0.3))
    rec = evaluate_pair(ok, "lqr+lqe", compute_constants(ok, n_samples=500), RunOptions(n_samples=500)).record
    assert rec["certified"] and rec["disproved"] == "", rec["reason"]


def test_the_samplers_reach_ten_times_the_initial_state():
    plant = Plant(id="big_x0", **DOUBLE_INTEGRATOR, f=_sine_f(1.0), x0=[40.0, 0.0], x_hat0=[0.0, 0.0])
    rep = compute_constants(plant, n_samples=200)
    assert rep.checked_on == pytest.approx(400.0)
    assert "sampled on ||x|| <= 400" in rep.region


def test_a_wrong_jacobian_is_a_plant_error_naming_the_entry():
    def jac(x):
        J = np.zeros((2, 2))
        J[1, 0] = 20.0 * np.cos(x[0])  # 20 times too large and sign-flipped
        return J

    with pytest.raises(PlantError, match=r"jacobian: entry \[1, 0\]"):
        Plant(id="badjac", **DOUBLE_INTEGRATOR, f=_sine_f(1.0), jacobian=jac, x0=[1.0, 0.0], x_hat0=[0.0, 0.0])


def test_a_jacobian_wrong_only_far_out_is_found_along_the_simulation():
    from bench.constants import check_trajectory

    def jac(x):
        J = np.zeros((2, 2))
        J[1, 0] = -np.cos(x[0]) * (1.0 if abs(x[1]) < 3.2 else 2.0)
        return J

    plant = Plant(id="farjac", **DOUBLE_INTEGRATOR, f=_sine_f(1.0), jacobian=jac, x0=[1.0, 0.0], x_hat0=[0.0, 0.0])
    rep = compute_constants(plant, n_samples=200)
    X = np.array([[0.0, 1.0, 2.0], [0.0, 3.0, 4.0]])
    with pytest.raises(PlantError, match=r"entry \[1, 0\].*along the simulation"):
        check_trajectory(plant, rep.knowledge(plant), X, X)


def test_a_random_f_is_refused_as_not_deterministic():
    rng = np.random.default_rng(0)

    def f(x):
        x = np.asarray(x, dtype=float)
        return -0.5 * np.sin(x) * (1.0 + 0.01 * rng.random())

    with pytest.raises(PlantError, match="f is not deterministic: at the state x ="):
        Plant(id="noisy_f", **DOUBLE_INTEGRATOR, f=f, x0=[1.0, 0.0], x_hat0=[0.0, 0.0])


# -- the convergence verdict of a certified pair ----------------------------------------------
def _rec(**kw):
    rec = {"converged": False, "sim_status": "ok", "certified": True, "cert_scope": "global", "cert_horizon_s": 10.0,
           "in_region": None, "horizon_rule": "certified rate", "horizon_s": 10.0, "tail_rate": math.nan,
           "decay_rate": 0.7, "sim_witness": "t = 3 s, x = (1e7, 0), x_hat = (0, 0)"}
    rec.update(kw)
    return rec


@pytest.mark.parametrize("kw", [dict(sim_status="diverged"), dict(cert_scope="from x0", in_region=False),
                                dict(horizon_s=10.0), dict(horizon_rule="fixed", horizon_s=12.0)])
def test_a_certified_pair_that_fails_is_inconsistent_with_a_witness(kw):
    note = convergence_note(_rec(**kw))
    assert "INCONSISTENT" in note and "t = 3 s, x = (1e7, 0)" in note


def test_a_horizon_too_short_for_the_certified_rate_is_not_inconsistent():
    note = convergence_note(_rec(horizon_rule="fixed", horizon_s=1e-9))
    assert "INCONSISTENT" not in note and "horizon too short" in note


@pytest.mark.parametrize("kw", [dict(certified=False, sim_status="diverged"), dict(cert_scope="local"),
                                dict(cert_horizon_s=math.nan, sim_status="diverged"), dict(sim_status="budget")])
def test_what_the_certificate_does_not_cover_is_not_inconsistent(kw):
    assert "INCONSISTENT" not in convergence_note(_rec(**kw))


def test_an_inconsistent_pair_is_counted_in_the_findings():
    import pandas as pd

    from bench.pipeline import blank_record

    rec = blank_record("p", "d")
    rec.update(certified=True, decay_rate=0.5, reason="not converged (INCONSISTENT with the certificate: ...)",
               sim_witness="t = 1 s")
    found = findings(pd.DataFrame([rec]), {})
    assert found["counts"]["inconsistent"] == 1 and found["inconsistent"][0]["witness"] == "t = 1 s"


def test_a_user_fixed_short_horizon_is_not_flagged():
    plant = Plant(id="lin_sine", A=[[0.0, 1.0], [-1.0, -1.0]], B=[[0.0], [1.0]], C=[[1.0, 0.0]], f=_sine_f(0.1),
                  x0=[1.0, 0.0], x_hat0=[0.0, 0.0],
                  channels=Channels(G=G2, H=H2, phi=lambda z: -0.1 * np.sin(z), lo=-0.1, hi=0.1))
    rep = compute_constants(plant, n_samples=500)
    rec = evaluate_pair(plant, "lqr+lqe", rep, RunOptions(n_samples=500, t_final=1e-3)).record
    assert rec["certified"] and not rec["converged"]
    assert "horizon too short" in rec["reason"] and "INCONSISTENT" not in rec["reason"]


# -- limits in a thread -------------------------------------------------------------------------
def test_the_constants_limit_holds_when_run_is_called_from_a_thread():
    def slow_f(x):
        x = np.asarray(x, dtype=float)
        t_end = time.perf_counter() + 0.002
        while time.perf_counter() < t_end:  # Python code that checks no limit
            pass
        return -0.5 * np.sin(x)

    plant = Plant(id="slow_f", **DOUBLE_INTEGRATOR, f=slow_f, x0=[1.0, 0.0], x_hat0=[0.0, 0.0])
    box = {}

    def work():
        t0 = time.perf_counter()
        box["res"] = api.run([plant], ["lqr+lqe"], jobs=1, progress=False, timeout=0.1)  # constants: 10 x 0.1 s
        box["wall"] = time.perf_counter() - t0

    th = threading.Thread(target=work)
    th.start()
    th.join(60)
    assert not th.is_alive()
    assert box["wall"] < 8.0, box["wall"]
    assert "timeout" in str(box["res"].run_result.constants_errors.get("slow_f", "")) or \
        box["res"].table.iloc[0]["status"] == "timeout"


def test_a_declaration_disproved_by_one_pair_is_dropped_for_every_pair_of_the_plant():
    from bench.pipeline import rejudge

    ch = Channels(G=G2, H=H2, phi=lambda z: -0.1 * np.sin(z), lo=-0.1, hi=0.1)
    plant = Plant(id="shared", A=[[0.0, 1.0], [-1.0, -1.0]], B=[[0.0], [1.0]], C=[[1.0, 0.0]], f=_sine_f(0.1),
                  x0=[1.0, 0.0], x_hat0=[0.0, 0.0], channels=ch)
    rep = compute_constants(plant, n_samples=500)
    opts = RunOptions(n_samples=500)
    outs = [evaluate_pair(plant, d, rep, opts, design_id=d) for d in ("lqr+lqe", "structured")]
    assert all(o.record["cert_level"] == "structured" for o in outs)
    # as if the structured pair's simulation had disproved the channels
    outs[1].record["disproved"] = '{"channels": "the declared channels: (a test witness)"}'
    rejudge(outs, {"shared": rep}, opts)
    rec = outs[0].record
    assert rec["cert_structured"] != "certified" or "inherits" in rec["reason"]
    assert rec["cert_level"] != "structured" and "another pair's simulation" in rec["reason"]
    # in_region speaks of the new certificate's region: unknown (None) where it has no finite radius
    for o in outs:
        assert (o.record["in_region"] is None) == (not np.isfinite(o.record["cert_radius"])), o.record


def test_a_narrowing_a_sample_disproves_is_not_used_by_certificates():
    # -sin(z) on |z| <= r has secant slopes in [-1, -cos(r)]; a declared narrowing of [-1, -0.9] is
    # false for r > acos(0.9) = 0.451 (the secant from 0 to r = 1 is -sin(1)/1 = -0.841 > -0.9)
    def f(x):
        return _sine_f(1.0)(x)

    wrong = Channels(G=G2, H=H2, phi=lambda z: -np.sin(z), lo=-1, hi=1, narrow=lambda r: (-1.0, -0.9))
    plant = Plant(id="narrow_liar", **DOUBLE_INTEGRATOR, f=f, x0=[1.0, 0.0], x_hat0=[0.0, 0.0], channels=wrong)
    rep = compute_constants(plant)
    assert any("narrowed" in v.name for v in rep.channel_violations)
    know = rep.knowledge(plant)
    assert know.channels is not None and know.channels.narrow is None  # the global slopes [-1, 1] still hold
    assert "channels.narrow" in know.untrusted and "channels" not in know.untrusted

    # the true narrowing (-cos(min(r, pi)), ..) passes, and the channels keep it
    from plants._core import sine_slopes

    right = Channels(G=G2, H=H2, phi=lambda z: -np.sin(z), lo=-1, hi=1, narrow=sine_slopes(-1.0))
    plant = Plant(id="narrow_true", **DOUBLE_INTEGRATOR, f=f, x0=[1.0, 0.0], x_hat0=[0.0, 0.0], channels=right)
    rep = compute_constants(plant)
    assert rep.channel_violations == []
    assert rep.knowledge(plant).channels.narrow is not None
