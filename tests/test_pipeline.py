"""The pipeline's records: certified pairs converge or say why, local certificates, the EKF row, agreement of
studies and the main table, a pair re-used with a prior (the rules themselves: tests/test_verdicts.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.harness import run
from bench.pipeline import RunOptions, evaluate_pair
from bench.registry import PLANTS


@pytest.fixture(scope="module")
def small_run():
    plants = ["flexible_link", "random_osl_v1", "moving_object_v1"]
    designs = ["thm1_sep", "lqr+lqe", "lqr+zhang_osl", "lqr+ekf"]
    return run(plants, designs, RunOptions(n_samples=2000), jobs=1)


def test_a_certified_pair_converges_unless_the_row_says_why(small_run):
    df = small_run.frame()
    for r in df.itertuples():
        if r.certified and r.cert_scope in ("global", "from x0") and not str(r.horizon_rule).startswith("cut"):
            assert r.converged, (r.plant, r.design, r.reason)
        if r.certified and not r.converged:
            assert "not converged" in r.reason


def test_local_certificates_say_what_they_prove(small_run):
    """random_osl_v1 (constants on ||x|| <= 1): 'from x0' only when the level set through (x0, e0) stays in the
    region; checked here by sampling the boundary of that level set."""
    for o in small_run.outcomes:
        rec = o.record
        if rec["plant"] != "random_osl_v1" or not rec["certified"]:
            continue
        P = o.certificate.best.P
        plant = o.plant
        z0 = np.concatenate([plant.x0, plant.x0 - plant.x_hat0])
        v0 = float(z0 @ P @ z0)
        rng = np.random.default_rng(0)
        Z = rng.standard_normal((P.shape[0], 4000))
        Z *= np.sqrt(v0 / np.einsum("ij,ij->j", Z, P @ Z))  # points on {V = V(z0)}
        n = plant.n
        reach = max(np.linalg.norm(Z[:n], axis=0).max(), np.linalg.norm(Z[:n] - Z[n:], axis=0).max())
        if reach > 1.0 + 1e-9:  # the level set leaves the region: the certificate is not a proof from x0
            assert rec["cert_scope"] == "local"
            assert "certified locally" in rec["reason"]
        assert rec["in_region"] == bool(rec["max_norm"] <= 1.0)


def test_the_ekf_row_is_an_estimator_the_simulator_runs(small_run):
    df = small_run.frame().set_index(["plant", "design"])
    r = df.loc[("flexible_link", "lqr+ekf")]
    assert r["status"] == "computed" and r["stabilizing"] is None
    assert not r["certified"] and r["cert_paper"] == "inapplicable"
    assert "no fixed observer gain" in r["reason"]
    assert r["converged"] and r["sim_status"] == "ok"


def test_studies_and_the_main_table_agree_on_shared_pairs(small_run):
    """The admissible study at the default knob, the Monte Carlo study and the main table judge a pair alike."""
    from bench.studies.admissible import evaluate_at
    from bench.studies.montecarlo import run_montecarlo

    df = small_run.frame().set_index(["plant", "design"])
    for did in ("thm1_sep", "lqr+lqe"):
        main = df.loc[("flexible_link", did)]
        adm = evaluate_at("flexible_link", "c", 0.333, did)
        assert adm["certified"] == bool(main["certified"]) and adm["status"] == main["status"]
    mc = run_montecarlo(["flexible_link"], ["thm1_sep", "lqr+lqe"], n=20, jobs=1)
    for row in mc.rows:
        main = df.loc[("flexible_link", row["design"])]
        assert row["certified"] == bool(main["certified"])
        assert row["decay_rate"] == pytest.approx(main["decay_rate"], rel=1e-9)
        assert row["horizon_s"] == main["horizon_s"]


def test_a_pair_reused_with_prior_keeps_its_design_and_certificate(catalog_constants):
    plant = PLANTS.create("flexible_link")
    rep = catalog_constants("flexible_link", n_samples=1000)
    first = evaluate_pair(plant, "thm1_sep", rep, RunOptions(simulate=False))
    again = evaluate_pair(plant, "thm1_sep", rep, RunOptions(noise=1e-3, certificate="none"), prior=first)
    assert again.result is first.result and again.certificate is first.certificate
    assert again.record["decay_rate"] == first.record["decay_rate"]
    assert again.record["sim_status"] == "ok" and again.record["noise"] == 1e-3


def test_in_region_is_one_rule_for_the_first_judgement_and_the_rejudgement():
    """A certificate from x0 holds on |Hx|, |Hx_hat| <= r, not on a ball: a trajectory with a large state
    but small Hx is in its region; without region_H the ball ||(x, x_hat)|| <= r decides."""
    from types import SimpleNamespace

    from bench.pipeline import _in_region

    tr = SimpleNamespace(x=np.array([[10.0, 0.0], [0.0, 0.0]]), x_hat=np.array([[9.0, 0.0], [0.5, 0.0]]))
    H = np.array([[0.0, 1.0]])  # reads the second state only: |Hx| <= 0.5 along the trajectory
    assert _in_region(max_norm=10.0, radius=1.0, H=H, tr=tr) is True
    assert _in_region(max_norm=10.0, radius=0.4, H=H, tr=tr) is False
    assert _in_region(max_norm=10.0, radius=1.0, H=None, tr=tr) is False  # the ball: 10 > 1
    assert _in_region(max_norm=0.5, radius=1.0, H=None, tr=None) is True
    assert _in_region(max_norm=0.5, radius=float("inf"), H=H, tr=tr) is None
    assert _in_region(max_norm=0.5, radius=1.0, H=H, tr=None) is None  # a region but no trajectory: unknown
