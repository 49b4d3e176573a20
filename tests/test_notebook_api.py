"""bench.run from a notebook (issue 35): objects need no registration (named by their class's id and the
hyperparameters that differ from the defaults, run from a per-call overlay, so a cell runs again), and every
argument is checked with an error naming it."""

from __future__ import annotations

import dataclasses
import json
import re
from dataclasses import dataclass

import control
import numpy as np
import pytest

from bench.pipeline import COST_COLUMNS

import bench
from bench.errors import ExecutorError, RegistryError, UnknownIdError
from bench.registry import DESIGNS, ID_MAX_CHARS, PLANTS, check_object_id, object_id
from designs import Design, DesignResult
from designs.thm1 import Thm1
from plants import Constants, Plant


@dataclass(frozen=True, kw_only=True)
class Placed(Design):
    """Both gains by pole placement (an unregistered class, as a notebook cell defines one)."""

    rate: float = 2.0
    speed: float = 3.0

    def design(self, plant, constants):
        poles = -self.rate * (1.0 + 0.5 * np.arange(plant.n))
        F = -control.place(plant.A, plant.B, poles)
        K = control.place(plant.A.T, plant.C.T, self.speed * poles).T
        return DesignResult(status="computed", route="formula", K=K, F=F)


def _notebook_plant(c: float = 0.5) -> Plant:
    """A plant built in a cell from a python-control system, its f a lambda (rebuilt each time the cell runs)."""
    sys = control.ss([[0.0, 1.0], [-1.0, -0.4]], [[0.0], [1.0]], [[1.0, 0.0]], 0)
    return Plant.from_statespace(sys, f=lambda x: np.stack([0.0 * x[0], -c * np.sin(x[0])]), x0=[1.0, 0.0],
                                 bounds=Constants(alpha=c, rho=c / 2, beta=c**2, gamma=0.0), id="nb_plant")


def _run(**kw):
    return bench.run(jobs=1, progress=False, **kw)


# -- ids of objects ------------------------------------------------------------------------------------
def test_a_design_object_is_named_by_its_class_id_and_changed_hyperparameters():
    assert object_id(Thm1(), "design") == ("thm1", True)  # the registered design itself
    assert object_id(Thm1(phi1=0.05), "design") == ("thm1[phi1=0.05]", False)
    # thm1_sep is Thm1 registered with method="separated": the registration leaving the fewest differences
    assert object_id(Thm1(method="separated"), "design") == ("thm1_sep", True)
    # several: sorted by name, tuples written without blanks
    i, _ = object_id(Thm1(phi1_range=(0.001, 1.0), phi1=0.01, method="separated"), "design")
    assert i == "thm1_sep[phi1=0.01,phi1_range=(0.001,1.0)]"
    # an unregistered class: its name in lower case; a default is not written, a changed value is
    assert object_id(Placed(), "design") == ("placed", False)
    assert object_id(Placed(speed=4), "design") == ("placed[speed=4]", False)
    assert object_id(Placed(rate=2), "design") == ("placed", False)  # 2 == 2.0: the default
    # a pairing of parts: feedback+estimator, the parts' hyperparameters by role
    lqr = DESIGNS.create("lqr+lqe")
    assert object_id(lqr, "design") == ("lqr+lqe", True)
    changed = dataclasses.replace(lqr, feedback=dataclasses.replace(lqr.feedback, R=2.0))
    assert object_id(changed, "design")[0] == "lqr+lqe[feedback.R=2.0]"


def test_object_ids_are_stable_short_and_name_files():
    big = Placed(rate=1.0 + 1e-15 * 3, speed=float(np.pi))
    a, b = object_id(big, "design")[0], object_id(Placed(rate=1.0 + 1e-15 * 3, speed=float(np.pi)), "design")[0]
    assert a == b  # the same hyperparameters, the same id
    assert a == f"placed[rate={1.0 + 3e-15!r},speed={np.pi!r}]"  # repr: distinct floats, distinct ids
    # a matrix is named by a digest of its bytes; equal matrices give equal ids, other matrices others
    lqr = DESIGNS.create("lqr+lqe")
    Q1 = dataclasses.replace(lqr, feedback=dataclasses.replace(lqr.feedback, Q=np.diag([1.0, 2, 3, 4])))
    Q2 = dataclasses.replace(lqr, feedback=dataclasses.replace(lqr.feedback, Q=np.diag([1.0, 2, 3, 4])))
    Q3 = dataclasses.replace(lqr, feedback=dataclasses.replace(lqr.feedback, Q=np.diag([1.0, 2, 3, 5])))
    ids = [object_id(d, "design")[0] for d in (Q1, Q2, Q3)]
    assert ids[0] == ids[1] != ids[2]
    assert re.fullmatch(r"lqr\+lqe\[feedback\.Q=~[0-9a-f]{8}\]", ids[0])
    for i in [a, *ids]:
        assert len(i) <= ID_MAX_CHARS and check_object_id(i) == i and "/" not in i and " " not in i


def test_a_plant_object_keeps_its_id_and_cannot_pose_as_a_catalog_plant():
    assert object_id(_notebook_plant(), "plant") == ("nb_plant", False)
    assert object_id(PLANTS.create("flexible_link"), "plant") == ("flexible_link", True)  # the catalog's, rebuilt
    other = dataclasses.replace(PLANTS.create("pendulum_v1"), id="flexible_link")
    with pytest.raises(RegistryError, match="'flexible_link' is the id of the registered plant .* not that plant"):
        _run(plants=[other], designs=["paper_gains"])
    changed = PLANTS.create("flexible_link", c=0.5)  # same id, another constant
    with pytest.raises(RegistryError, match="not that plant"):
        object_id(changed, "plant")


# -- the same cell twice ------------------------------------------------------------------------------------
def test_the_same_call_runs_twice_in_one_process():
    before = (PLANTS.ids(), DESIGNS.ids())
    tables = []
    for _ in range(2):  # a notebook cell run again: the plant rebuilt, the design object built again
        r = _run(plants=[_notebook_plant()], designs=[Placed(rate=1.0), "lqr+lqe"])
        tables.append(r.table)
        assert list(r.table["design"]) == ["placed[rate=1.0]", "lqr+lqe"]
        assert list(r.table["plant"]) == ["nb_plant", "nb_plant"]
        assert (PLANTS.ids(), DESIGNS.ids()) == before  # nothing registered
    a, b = tables
    # rate 1 places eig(A + BF) at -1, -1.5: the linearised loop's slowest rate is 1 (independent of the code)
    row = a.set_index("design").loc["placed[rate=1.0]"]
    assert row["status"] == "computed" and abs(row["max_re_eig_x"] + 1.0) < 1e-9
    cols = [c for c in a.columns if c not in COST_COLUMNS]  # timings and solver calls (a memo) differ
    assert a[cols].equals(b[cols])


def test_sweeping_a_builtin_design_by_objects():
    r = _run(plants="flexible_link", designs=[Thm1(phi1=0.01), Thm1(phi1=0.05)])
    assert list(r.table["design"]) == ["thm1[phi1=0.01]", "thm1[phi1=0.05]"]
    assert set(r.table["status"]) == {"feasible"}
    used = [json.loads(p)["phi1"] for p in r.table["params"]]
    assert used == [0.01, 0.05]  # each design ran with its own fixed Young weight, not the default search
    assert r.gains["flexible_link", "thm1[phi1=0.05]"]["result"].params["phi1"] == 0.05
    assert "thm1[phi1=0.01]" not in DESIGNS


def test_a_plant_object_given_twice_as_one_id():
    p = _notebook_plant()
    r = _run(plants=[p, p, "flexible_link"], designs="paper_gains")
    assert list(r.table["plant"]) == ["nb_plant", "flexible_link"]
    with pytest.raises(RegistryError, match="two different Plant objects have the id 'nb_plant'"):
        _run(plants=[_notebook_plant(c=0.5), _notebook_plant(c=0.9)], designs="paper_gains")


# -- arguments ------------------------------------------------------------------------------------------------
def test_a_string_is_one_id_or_glob():
    r = _run(plants="flexible_link", designs="paper_gains")
    assert list(r.table["plant"]) == ["flexible_link"] and list(r.table["design"]) == ["paper_gains"]
    with pytest.raises(UnknownIdError) as err:
        _run(plants="my_plant", designs="paper_gains")
    assert "'my_plant'" in str(err.value) and "'m'" not in str(err.value)
    r = _run(plants="flexible_link", designs="thm1_printe?")  # a glob
    assert list(r.table["design"]) == ["thm1_printed"]


@pytest.mark.parametrize("kw, message", [
    (dict(designs=[]), "designs: an empty list selects nothing; pass None for every design"),
    (dict(plants=()), "plants: an empty list selects nothing; pass None for every plant"),
    (dict(jobs="2"), "jobs: expected an integer, got '2'"),
    (dict(jobs=0), "jobs: must be >= 1"),
    (dict(jobs=2.0), "jobs: expected an integer"),
    (dict(seed="1"), "seed: expected an integer"),
    (dict(seed=-1), "seed: must be >= 0"),
    (dict(noise="0.1"), "noise: expected a real number"),
    (dict(noise=-1.0), "noise: must be finite and >= 0"),
    (dict(disturbance=float("nan")), "disturbance: must be finite"),
    (dict(t_final=0), "t_final: must be finite and > 0"),
    (dict(timeout="5"), "timeout: expected a real number"),
    (dict(claimed_constants="yes"), "claimed_constants: expected True or False"),
    (dict(fail_fast=1), "fail_fast: expected True or False"),
    (dict(progress="bar"), "progress: expected True, False or a callable"),
    (dict(cache=1), "cache: expected a folder path"),
    (dict(scheduler=8786), "scheduler: expected an address"),
    (dict(command=None), "command: expected a str"),
    (dict(start_method="thread"), "start_method: expected one of fork, forkserver, spawn"),
    (dict(plants=3), "plants: expected None (every plant), an id or glob, a Plant object, or a list of them"),
    (dict(designs={"thm1": 1}), "designs: expected None"),
    (dict(designs=["thm1", 3]), r"designs\[1\]: expected an id or glob \(a str\) or a Design object, got 3"),
    (dict(plants=[Thm1()]), r"plants\[0\]: expected an id or glob \(a str\) or a Plant object"),
])
def test_every_option_is_checked_by_name(kw, message):
    args = {"plants": "flexible_link", "designs": "paper_gains", **kw}
    with pytest.raises((ValueError, ExecutorError), match=message if "\\" in message else re.escape(message)):
        bench.run(**args)  # before anything is computed


def test_the_progress_bar_counts_constants_and_pairs(monkeypatch):
    import bench.progress

    made = []

    class Recording(bench.progress.Progress):
        def __init__(self, *a, **kw):
            made.append(kw.get("desc"))
            super().__init__(*a, disable=True, **{k: v for k, v in kw.items() if k != "disable"})

    monkeypatch.setattr(bench.progress, "Progress", Recording)
    bench.run(plants=["flexible_link"], designs=["paper_gains", "thm1_printed"], jobs=1, progress=True)
    assert made == ["constants of 1 plant + 2 pairs"]
    assert bench.api.progress_label(3, 1) == "constants of 3 plants + 1 pair"
