"""Every simulated certified pair is checked along its trajectory: a certificate V = z'Pz of rate lam
proves V(z(t)) <= V(z0) exp(-2 lam t) inside its region (bench.verdicts.lyapunov_note, called in the
pipeline's simulation step). Closed forms for the rule; a false certificate let through makes it fire;
the flexible link's certified pairs all pass."""

from __future__ import annotations

import math

import numpy as np

from bench import certify as certify_mod
from bench.certify import LevelResult
from bench.findings import findings
from bench.harness import run
from bench.pipeline import RunOptions, evaluate_pair
from bench.registry import DESIGNS, PLANTS
from bench.verdicts import lyapunov_note
from designs import Design, DesignResult


def _decaying(rate: float, T: float = 4.0, k: int = 401):
    """x(t) = x_hat(t) = e^(-rate t) (1, 2): e = 0 and V = z'z = 5 e^(-2 rate t)."""
    t = np.linspace(0.0, T, k)
    x = np.array([[1.0], [2.0]]) * np.exp(-rate * t)[None, :]
    return t, x, x.copy()


def test_the_bound_holds_at_the_true_rate_and_fails_above_it_with_its_factor():
    t, x, xh = _decaying(1.0)
    P = np.eye(4)
    assert lyapunov_note(t, x, xh, P, 1.0, inside=None, atol=1e-12, rtol=1e-8) == ""
    assert lyapunov_note(t, x, xh, P, 0.5, inside=None, atol=1e-12, rtol=1e-8) == ""
    note = lyapunov_note(t, x, xh, P, 1.5, inside=None, atol=1e-12, rtol=1e-8)
    # V / (V0 e^(-3 t)) = e^(t): largest at the last sample, e^4
    assert note.startswith("INCONSISTENT with the certificate: V(z(t)) exceeds V(z0) e^(-2 lam t)")
    factor = float(note.split("by a factor ")[1].split()[0])
    assert math.isclose(factor, math.exp(4.0), rel_tol=1e-3) and "t = 4 s" in note


def test_only_samples_before_the_first_exit_from_the_region_are_judged():
    t, x, xh = _decaying(1.0)
    x[:, 200:] *= 10.0  # a jump after t = 2: V exceeds the bound from there on
    inside = np.ones(t.size, dtype=bool)
    assert lyapunov_note(t, x, xh, np.eye(4), 1.0, inside=None, atol=1e-12, rtol=1e-8)
    inside[150] = False  # left the region before the jump (and came back): nothing after the exit is judged
    assert lyapunov_note(t, x, xh, np.eye(4), 1.0, inside=inside, atol=1e-12, rtol=1e-8) == ""


def test_a_batch_names_its_member():
    t, x, xh = _decaying(1.0)
    X = np.stack([x, 3 * x], axis=1)  # (n, N, T)
    X[:, 1, -1] *= 2.0
    note = lyapunov_note(t, X, np.stack([xh, 3 * xh], axis=1), np.eye(4), 1.0, inside=None, atol=1e-12, rtol=1e-8)
    assert "(member 1)" in note


class _FalseCertificate(Design):
    """LQR/LQE gains with V = |z|^2 claimed to decay at rate 1 (false on the flexible link)."""

    def applicable(self, plant, constants):
        return None

    def design(self, plant, constants):
        res = DESIGNS.create("lqr+lqe").design(plant, constants)
        return DesignResult(status="computed", K=res.K, F=res.F, certificate={
            "level": "structured", "P": np.eye(2 * plant.n), "decay_rate": 1.0, "how": "a false certificate"})


def test_a_false_certificate_let_through_is_inconsistent_along_the_simulation(monkeypatch, catalog_constants):
    # the suite's verification would refuse it: let it through, as a bug there would
    monkeypatch.setattr(certify_mod, "verify_certificate", lambda c, plant, loop, know: (LevelResult(
        c["level"], "certified", decay_rate=c["decay_rate"], P=c["P"]), ""))
    plant = PLANTS.create("flexible_link")
    rep = catalog_constants("flexible_link", n_samples=2000)
    rec = evaluate_pair(plant, _FalseCertificate(), rep, RunOptions(n_samples=2000, certificate="own")).record
    assert rec["certified"] and rec["decay_rate"] == 1.0
    assert "INCONSISTENT with the certificate: V(z(t)) exceeds V(z0) e^(-2 lam t) by a factor" in rec["reason"]
    import pandas as pd

    assert findings(pd.DataFrame([rec]), {})["counts"]["inconsistent"] == 1


def test_every_certified_pair_of_the_flexible_link_keeps_its_decay():
    res = run(["flexible_link"], DESIGNS.ids(), RunOptions(n_samples=2000), jobs=2)
    df = res.frame()
    cert = df[df["certified"]]
    assert len(cert) >= 10
    assert not df["reason"].str.contains("INCONSISTENT").any(), df.loc[df["reason"].str.contains("INCONSISTENT"),
                                                                       "reason"].tolist()
    assert cert["cert_horizon_s"].notna().all()  # the check applies to each of them (fixed gains, no noise)
