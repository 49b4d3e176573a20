"""Plugin code cannot change what the suite reports about other pairs, nor end a run: a design works on a
copy of the plant and a change is that pair's error; SystemExit from a design or from f is an error row
and the report is written; an error row claims nothing; a plugin's "feasible" reads "unverified"."""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass

import numpy as np
import pytest

from bench.cli import main
from bench.harness import run
from bench.pipeline import CERT_COLUMNS, RunOptions, evaluate_pair
from bench.registry import DESIGNS, PLANTS
from designs import Design, DesignResult
from tests._plugin_helpers import clean_registries  # noqa: F401 - autouse: registries restored after each test

OPTS = RunOptions(n_samples=1000)


class _Hostile(Design):
    """The issue's design: A -> A - 3I and f -> 0 on the plant it is given, then K = F = 0."""

    def applicable(self, plant, constants):
        return None

    def design(self, plant, constants):
        object.__setattr__(plant, "A", plant.A - 3 * np.eye(plant.n))
        object.__setattr__(plant, "f", lambda x: 0 * np.asarray(x))
        return DesignResult(status="given", K=np.zeros((plant.n, plant.C.shape[0])),
                            F=np.zeros((plant.B.shape[1], plant.n)))


_SCALE = [1.0]


class _ChangesWhatFComputes(Design):
    """Leaves every field alone, but changes the number f reads."""

    def applicable(self, plant, constants):
        return None

    def design(self, plant, constants):
        _SCALE[0] = 3.0
        return DesignResult(status="given", K=np.ones((plant.n, 1)), F=-np.ones((1, plant.n)))


@dataclass(frozen=True, kw_only=True)
class _SaysFeasible(Design):
    """LQR/LQE gains reported as "feasible", an LMI the suite never saw."""

    params_value: object = 1.0

    def applicable(self, plant, constants):
        return None

    def design(self, plant, constants):
        res = DESIGNS.create("lqr+lqe").design(plant, constants)
        return DesignResult(status="feasible", K=res.K, F=res.F, params={"x": self.params_value})


def test_a_design_that_changes_the_plant_is_an_error_and_touches_no_other_row():
    plant = PLANTS.create("flexible_link")
    A, f = plant.A.copy(), plant.f
    DESIGNS.register("_hostile_test", _Hostile)
    alone = run(["flexible_link"], ["lqr+lqe"], OPTS).frame().iloc[0]
    both = run(["flexible_link"], ["_hostile_test", "lqr+lqe"], OPTS).frame().set_index("design")
    bad = both.loc["_hostile_test"]
    assert bad["status"] == "error" and "the design changed the plant: A, f differ" in bad["reason"]
    assert not bad["certified"] and not bad["converged"] and bad["sim_status"] == ""
    other = both.loc["lqr+lqe"]
    assert other["reason"] == alone["reason"] and "DISPROVED" not in other["reason"]
    assert other["certified"] and other["decay_rate"] == alone["decay_rate"] and other["converged"]
    # the plant object handed to the pipeline is not the one the design changed
    rep = run(["flexible_link"], ["lqr+lqe"], OPTS).constants["flexible_link"]
    evaluate_pair(plant, _Hostile(), rep, OPTS)
    assert np.array_equal(plant.A, A) and plant.f is f


def test_a_design_that_changes_what_f_computes_is_an_error():
    from plants import Plant

    plant = Plant(id="scaled_sine", A=[[0.0, 1.0], [-1.0, -1.0]], B=[[0.0], [1.0]], C=[[1.0, 0.0]],
                  f=lambda x: np.stack([0 * np.asarray(x)[0], -0.1 * _SCALE[0] * np.sin(np.asarray(x)[0])]),
                  x0=[1.0, 0.0], x_hat0=[0.0, 0.0])
    from bench.constants import compute_constants

    rep = compute_constants(plant, n_samples=200)
    try:
        rec = evaluate_pair(plant, _ChangesWhatFComputes(), rep, RunOptions(n_samples=200)).record
    finally:
        _SCALE[0] = 1.0
    assert rec["status"] == "error" and "what f or its Jacobian computes" in rec["reason"]


def test_error_rows_claim_nothing(catalog_constants):
    # the gains are fine and certify; the failure comes after the certificate (in the simulation)
    class _Broken(Design):
        def applicable(self, plant, constants):
            return None

        def design(self, plant, constants):
            res = DESIGNS.create("lqr+lqe").design(plant, constants)
            return DesignResult(status="computed", K=res.K, F=res.F, estimator=object())

    plant = PLANTS.create("flexible_link")
    rep = catalog_constants("flexible_link", n_samples=2000)
    out = evaluate_pair(plant, _Broken(), rep, RunOptions(n_samples=2000))
    rec = out.record
    assert rec["status"] == "error"
    for c in CERT_COLUMNS:
        v = rec[c]
        assert v in (False, "", None) or (isinstance(v, float) and math.isnan(v)), (c, v)
    assert out.certificate is None and out.result is None


def test_a_plugins_feasible_is_unverified_and_unserialisable_params_are_its_own_error(catalog_constants):
    plant = PLANTS.create("flexible_link")
    rep = catalog_constants("flexible_link", n_samples=2000)
    rec = evaluate_pair(plant, _SaysFeasible(), rep, RunOptions(n_samples=2000, simulate=False)).record
    assert rec["status"] == "unverified" and rec["feasible"] is False
    assert "did not verify" in rec["reason"] and rec["certified"]  # certified by the ladder, like "computed"
    assert evaluate_pair(plant, "thm1", rep, RunOptions(n_samples=2000, simulate=False)).record["feasible"]
    bad = evaluate_pair(plant, _SaysFeasible(params_value=1j), rep, RunOptions(n_samples=2000)).record
    assert bad["status"] == "error" and "params" in bad["reason"] and not bad["certified"]


PLUGIN = '''
import sys
import numpy as np
from bench.registry import register_design, register_plant
from designs import Design
from plants import Plant


def f(x):
    x = np.asarray(x, dtype=float)
    if x.ndim == 2 and x.shape[1] == 2:  # the simulation's call (x and x_hat together): the plugin exits
        sys.exit(0)
    return np.stack([0 * x[0], -0.2 * np.sin(x[0])])


@register_plant("exits_in_f")
def exits_in_f():
    return Plant(id="exits_in_f", A=[[0.0, 1.0], [-1.0, -1.0]], B=[[0.0], [1.0]], C=[[1.0, 0.0]], f=f,
                 x0=[0.5, 0.0], x_hat0=[0.0, 0.0])


def g(x):
    x = np.asarray(x, dtype=float)
    if x.ndim == 2 and x.shape[1] > 100:  # the constants sampler's batches: the plugin exits
        sys.exit(0)
    return np.stack([0 * x[0], -0.2 * np.sin(x[0])])


@register_plant("exits_in_sampler")
def exits_in_sampler():
    return Plant(id="exits_in_sampler", A=[[0.0, 1.0], [-1.0, -1.0]], B=[[0.0], [1.0]], C=[[1.0, 0.0]], f=g,
                 x0=[0.5, 0.0], x_hat0=[0.0, 0.0])


@register_design("exits_in_design")
class ExitsInDesign(Design):
    def design(self, plant, constants):
        raise SystemExit(3)
'''


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_system_exit_in_f_or_in_a_design_is_an_error_row_and_the_report_is_written(tmp_path, jobs):
    """sys.exit(0) in f during a pair's simulation, in f during the plant's constants, SystemExit(3) in a design."""
    plugin = tmp_path / "exits.py"
    plugin.write_text(PLUGIN, encoding="utf-8")
    out = tmp_path / "rep"
    rc = main(["run", "--plugin", str(plugin), "--plant", "exits_in_f", "--plant", "flexible_link", "--plant",
               "exits_in_sampler", "--design",
               "lqr+lqe", "--design", "exits_in_design", "--out", str(out), "--no-figures", "--no-cache", "-q",
               "--jobs", jobs])
    assert rc == 0
    assert (out / "REPORT.md").is_file()
    rows = {(r["plant"], r["design"]): r for r in csv.DictReader((out / "results.csv").open())}
    assert len(rows) == 6
    for did in ("lqr+lqe", "exits_in_design"):  # the plant's constants failed: each of its pairs says so
        r = rows["exits_in_sampler", did]
        assert r["status"] == "error" and "SystemExit" in r["reason"] and "exits_in_sampler" in r["reason"]
    in_f = rows["exits_in_f", "lqr+lqe"]
    assert in_f["status"] == "error" and "SystemExit" in in_f["reason"] and "simulation" in in_f["reason"]
    for pid in ("exits_in_f", "flexible_link"):
        r = rows[pid, "exits_in_design"]
        assert r["status"] == "error" and r["reason"].startswith("SystemExit: 3")
    assert rows["flexible_link", "lqr+lqe"]["converged"] == "True"
