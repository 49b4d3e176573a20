"""gains.json holds every certificate results.csv reports, so an outside script checks each claim from the
files alone; what the API returns cannot change what it writes; one pair's unwritable value costs that pair only.

The checks below use numpy only, on the files and the plant's definition (A, B, C, f, phi): P symmetric
positive definite; the certificate's inequality ``Acl' P + P Acl + 2 lam P <= 0`` at the loop linearised at
the origin (the linear map ``Df(0)`` meets every constraint a certificate may use near the origin, so a true
certificate of rate lam must satisfy it, and lam cannot exceed the linearisation's decay rate); in discrete time
``Acl' P Acl - r^2 P <= 0`` with the contraction factor ``r = exp(-lam dt)`` written beside it; for a
certificate from x0, ``V(z0)`` inside the largest level set in ``|Hx|, |Hx_hat| <= r`` and phi's sampled
slopes on ``|z| <= r`` inside the narrowed slopes written beside it. An L2 claim ``g`` with its P: the bounded real
matrix ``[[Acl' P + P Acl + Cz' Cz, P Bd], [Bd' P, -g^2 I]] <= 0`` (discrete: ``[Acl, Bd]' P [Acl, Bd] -
diag(P - Cz' Cz, g^2 I) <= 0``) at the same linear member, and ``g`` at least the H-infinity norm of that linear
loop from w to zeta (a dense frequency sweep).
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
import pytest

import bench
from bench.registry import DESIGNS, PLANTS
from designs import Design
from tests._plugin_helpers import clean_registries  # noqa: F401 - autouse: registries restored after each test

PAIRS = (["flexible_link", "flexible_joint_v1", "moving_object_v1", "flexible_link_d10ms_v1",
          "nguyen2018_ex2_moving_object_v1"], ["lqr+lqe", "thm1"])


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("gains")
    res = bench.run(*PAIRS, progress=False, jobs=1)
    res.write(out, figures=False)
    return res, out


def _jacobian_at_zero(f, n: int, h: float = 1e-6) -> np.ndarray:
    """Df(0) by central differences (independent of the plant's declared Jacobian)."""
    return np.stack([(f(h * e) - f(-h * e)) / (2 * h) for e in np.eye(n)], axis=1)


def _linearised_loop(plant, K, F) -> np.ndarray:
    """The loop in z = (x, e) with f replaced by its linearisation at 0."""
    J = _jacobian_at_zero(plant.f, plant.n)
    return np.block([[plant.A + J + plant.B @ F, -plant.B @ F], [np.zeros_like(plant.A), plant.A + J - K @ plant.C]])


def _check_claim(c: dict, plant, K, F) -> None:
    """Re-check one certified claim of gains.json with numpy."""
    P, lam = np.array(c["P"]), c["decay_rate"]
    assert P.shape == (2 * plant.n, 2 * plant.n)
    assert np.allclose(P, P.T, rtol=0, atol=1e-12 * np.abs(P).max())
    assert np.linalg.eigvalsh(P)[0] > 0
    Acl = _linearised_loop(plant, K, F)
    if plant.dt > 0:  # a contraction factor per step, and its rate per second
        r = c["contraction"]
        assert c["dt"] == plant.dt and r == pytest.approx(math.exp(-lam * plant.dt), rel=1e-12)
        assert r >= np.abs(np.linalg.eigvals(Acl)).max() * (1 - 1e-9)  # no certificate beats the spectral radius
        M = Acl.T @ P @ Acl - r**2 * P
        assert np.linalg.eigvalsh((M + M.T) / 2)[-1] <= 1e-9 * np.linalg.norm(P, 2) * max(1.0, np.linalg.norm(Acl, 2))**2
    else:
        assert c["contraction"] is None
        rate = -np.linalg.eigvals(Acl).real.max()
        assert lam <= rate * (1 + 1e-9) + 1e-12  # no certificate beats the linearisation
        M = Acl.T @ P + P @ Acl + 2 * lam * P
        assert np.linalg.eigvalsh((M + M.T) / 2)[-1] <= 1e-7 * np.linalg.norm(P, 2) * max(1.0, np.linalg.norm(Acl, 2))
    if c["scope"] == "global":
        assert c["radius"] is None and c["region"] == "everywhere"
    if c["scope"] == "from x0" and c["region_H"] is not None:
        H, r = np.array(c["region_H"]), c["radius"]
        rows = np.vstack([np.hstack([H, 0 * H]), np.hstack([H, -H])])  # (Hx, H x_hat) = rows @ (x, e)
        z0 = np.concatenate([plant.x0, plant.x0 - plant.x_hat0])
        v0 = z0 @ P @ z0
        widest = np.sqrt(v0 * np.einsum("ij,jk,ik->i", rows, np.linalg.inv(P), rows)).max()
        assert widest <= r * (1 + 1e-9)  # {V <= V(z0)} lies in the region
        lo, hi = (np.array(c["slopes"][k]) for k in ("lo", "hi"))
        ch = plant.channels
        rng = np.random.default_rng(0)
        for i in range(ch.q):
            a, b = rng.uniform(-r, r, (2, 4000))
            Z1, Z2 = np.zeros((ch.q, a.size)), np.zeros((ch.q, a.size))
            Z1[i], Z2[i] = a, b
            s = (ch.phi(Z1)[i] - ch.phi(Z2)[i]) / (a - b)
            assert lo[i] - 1e-9 <= s.min() and s.max() <= hi[i] + 1e-9


def _loop_from_w(plant, K, F, zeta: str):
    """(Acl, Bd, Cz) of the loop linearised at the origin, from w to zeta = e or x."""
    n = plant.n
    Acl = _linearised_loop(plant, K, F)
    Bd = np.vstack([plant.Bw, plant.Bw - K @ plant.Dw])
    Cz = np.hstack([np.zeros((n, n)), np.eye(n)] if zeta == "e" else [np.eye(n), np.zeros((n, n))])
    return Acl, Bd, Cz


def _sweep_norm(Acl, Bd, Cz, dt: float) -> float:
    """max over a dense frequency grid of the largest singular value of Cz (s I - Acl)^-1 Bd (s = e^{j w dt})."""
    top = math.pi / dt if dt > 0 else 1e3
    best = 0.0
    for w in np.concatenate([[0.0], np.geomspace(1e-4, top, 6000)]):
        s = np.exp(1j * w * dt) if dt > 0 else 1j * w
        G = Cz @ np.linalg.solve(s * np.eye(len(Acl)) - Acl, Bd)
        best = max(best, float(np.linalg.svd(G, compute_uv=False)[0]))
    return best


def _check_gain(c: dict, plant, K, F) -> None:
    """Re-check one certified L2 claim with numpy: the bounded real matrix of the loop linearised at the origin (a
    member of every class a certificate uses near it) at the claim's P and gain, and the gain against its norm."""
    P, g = np.array(c["P"]), c["gain"]
    assert P.shape == (2 * plant.n, 2 * plant.n) and np.linalg.eigvalsh((P + P.T) / 2)[0] > 0
    Acl, Bd, Cz = _loop_from_w(plant, K, F, c["zeta"])
    q = Bd.shape[1]
    if plant.dt > 0:
        T = np.hstack([Acl, Bd])
        M = T.T @ P @ T
        M[:len(P), :len(P)] += Cz.T @ Cz - P
        M[len(P):, len(P):] -= g**2 * np.eye(q)
    else:
        M = np.block([[Acl.T @ P + P @ Acl + Cz.T @ Cz, P @ Bd], [Bd.T @ P, -g**2 * np.eye(q)]])
    assert np.linalg.eigvalsh((M + M.T) / 2)[-1] <= 1e-7 * max(1.0, np.abs(M).max())
    assert g >= _sweep_norm(Acl, Bd, Cz, plant.dt) * (1 - 1e-6)


def test_every_certified_claim_is_in_gains_json_and_checks_out(small_run):
    res, out = small_run
    table = pd.read_csv(out / "results.csv")
    entries = {(g["plant"], g["design"]): g for g in json.loads((out / "gains.json").read_text())}
    certified = table[table["certified"]]
    assert len(certified) >= 3 and "from x0" in set(certified["cert_scope"])  # the run has both kinds
    checked = gains = 0
    for row in table.itertuples():
        if row.status in ("error", "timeout") or (row.plant, row.design) not in entries:
            continue
        g = entries[row.plant, row.design]
        plant, K, F = PLANTS.create(row.plant), np.array(g["K"]), np.array(g["F"])
        for lv in ("paper", "full", "structured"):  # each level results.csv shows has its certificate
            assert g["certificate"][lv]["status"] == getattr(row, f"cert_{lv}")
        claims = [c for c in [*g["certificate"].values(), g["from_x0"]] if c is not None and c["status"] == "certified"]
        for c in claims:
            _check_claim(c, plant, K, F)
            checked += 1
            for gain in c["l2"].values():
                if gain["status"] == "certified":
                    _check_gain(gain, plant, K, F)
                    gains += 1
        for z in ("e", "x"):  # the row's gain is the strongest certified level's
            strongest = [c for c in g["certificate"].values() if c["status"] == "certified"]
            want = strongest[-1]["l2"].get(z, {}).get("gain") if strongest else None
            assert (want is None and math.isnan(getattr(row, f"l2_gain_{z}"))) or \
                want == pytest.approx(getattr(row, f"l2_gain_{z}"), rel=1e-12)
        if row.certified:  # the headline is one of them, with the rate, level and scope of the row
            head = g["from_x0"] if g["best"] == "from_x0" else g["certificate"][g["best"]]
            assert head["level"] == row.cert_level and head["scope"] == row.cert_scope
            assert head["decay_rate"] == pytest.approx(row.decay_rate, rel=1e-12)
            assert head["P"] is not None
    assert checked >= len(certified)
    assert gains >= 4 and (table["contraction"] > 0).sum() >= 2  # L2 claims and discrete rows were checked


def test_a_false_claim_fails_the_outside_check(small_run):
    """The outside check is not vacuous: a rate above the linearisation's or a P not positive fails it."""
    _, out = small_run
    g = next(g for g in json.loads((out / "gains.json").read_text()) if g["best"] == "from_x0")
    plant, K, F = PLANTS.create(g["plant"]), np.array(g["K"]), np.array(g["F"])
    claim = g["from_x0"]
    _check_claim(claim, plant, K, F)
    for bad in ({"decay_rate": 10 * claim["decay_rate"] + 1}, {"P": (-np.array(claim["P"])).tolist()},
                {"radius": claim["radius"] / 10}):
        with pytest.raises(AssertionError):
            _check_claim({**claim, **bad}, plant, K, F)
    # an L2 claim below the linear loop's norm, or a discrete claim with a smaller contraction, fails too
    entries = json.loads((out / "gains.json").read_text())
    g = next(g for g in entries if g["certified"] and g["l2_gain_x"] is not None)
    plant, K, F = PLANTS.create(g["plant"]), np.array(g["K"]), np.array(g["F"])
    gain = g["certificate"][g["cert_level"]]["l2"]["x"]
    _check_gain(gain, plant, K, F)
    with pytest.raises(AssertionError):
        _check_gain({**gain, "gain": 0.9 * _sweep_norm(*_loop_from_w(plant, K, F, "x"), plant.dt)}, plant, K, F)
    g = next(g for g in entries if g["certified"] and g["contraction"] is not None)
    plant, K, F = PLANTS.create(g["plant"]), np.array(g["K"]), np.array(g["F"])
    claim = g["certificate"][g["cert_level"]]
    _check_claim(claim, plant, K, F)
    with pytest.raises(AssertionError):
        _check_claim({**claim, "decay_rate": 2 * claim["decay_rate"],
                      "contraction": math.exp(-2 * claim["decay_rate"] * plant.dt)}, plant, K, F)


def test_the_api_returns_read_only_arrays_and_write_writes_what_was_computed(small_run, tmp_path):
    res, out = small_run
    g = res.gains["flexible_link", "lqr+lqe"]
    K0 = np.array(g["K"])
    with pytest.raises(ValueError, match="read-only"):
        g["K"][0, 0] = 1e6
    level = g["certificate"].levels["structured"]
    for arr in (g["F"], level.P, g["trajectory"].x, g["result"].K, res.run_result.outcomes[0].loop.K):
        with pytest.raises(ValueError, match="read-only"):
            arr[0, 0] = 1e6
    res.table.loc[0, "decay_rate"] = 99.0  # a copy: nothing written changes
    res.findings.clear()
    res.write(tmp_path, figures=False)
    again = {(e["plant"], e["design"]): e for e in json.loads((tmp_path / "gains.json").read_text())}
    np.testing.assert_array_equal(np.array(again["flexible_link", "lqr+lqe"]["K"]), K0)
    assert (tmp_path / "results.csv").read_bytes() == (out / "results.csv").read_bytes()
    assert "## What the suite found" in (tmp_path / "REPORT.md").read_text()
    assert (tmp_path / "gains.json").read_bytes() == (out / "gains.json").read_bytes()


@dataclass(frozen=True, kw_only=True)
class OddRoute(Design):
    """LQR + LQE gains whose result carries a route JSON cannot hold (a set)."""

    def design(self, plant, constants):
        return dataclasses.replace(DESIGNS.create("lqr+lqe").design(plant, constants), route={"lqr", "lqe"})


@dataclass(frozen=True, kw_only=True)
class ComplexK(Design):
    """LQR + LQE gains with a complex observer gain."""

    def design(self, plant, constants):
        res = DESIGNS.create("lqr+lqe").design(plant, constants)
        return dataclasses.replace(res, K=res.K + 1e-3j)


def test_an_unwritable_value_is_that_pairs_note_and_an_error_row_carries_no_certificate(tmp_path):
    res = bench.run(["flexible_link"], [OddRoute(), ComplexK(), "lqr+lqe"], progress=False, jobs=1)
    res.write(tmp_path, figures=False)
    table = pd.read_csv(tmp_path / "results.csv", keep_default_na=False).set_index("design")
    entries = {g["design"]: g for g in json.loads((tmp_path / "gains.json").read_text())}
    # the set is blanked in both files, the pair's reason says so, and its verdicts stand
    assert table.loc["oddroute", "route"] == "" and "route held a set" in table.loc["oddroute", "details"]
    assert entries["oddroute"]["route"] == "" and entries["oddroute"]["certified"]
    assert bool(table.loc["oddroute", "certified"])
    # complex gains: refused by name, an error row with no certificate and no gains in gains.json
    assert table.loc["complexk", "status"] == "error"
    assert "K: complex entries" in table.loc["complexk", "details"]
    assert "the gains must be real" in table.loc["complexk", "details"]
    assert "complexk" not in entries  # an error row keeps neither gains nor a certificate: no entry at all
    # the other pairs are whole
    assert entries["lqr+lqe"]["certified"] and entries["lqr+lqe"]["certificate"]["structured"]["P"] is not None


def test_a_pair_whose_entry_cannot_be_written_is_noted_and_the_rest_written(small_run, tmp_path, monkeypatch):
    """A value that reaches gains.json unchecked (here an estimator whose repr raises) costs its pair only."""
    import bench.report as report_mod

    res, _ = small_run

    class Hostile:
        def __repr__(self):
            raise RuntimeError("no repr")

    o = res.run_result.outcomes[0]
    monkeypatch.setattr(o, "result", dataclasses.replace(o.result, estimator=Hostile()))
    entries = report_mod._gains(res.run_result)
    assert entries[0] == {"plant": o.record["plant"], "design": o.record["design"], "status": o.record["status"],
                          "error": "this pair's gains and certificates cannot be written to JSON: RuntimeError: no "
                                   "repr"}
    assert all("error" not in e and e["K"] is not None for e in entries[1:])
    assert math.isfinite(entries[1]["decay_rate"])
