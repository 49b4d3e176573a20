"""The on-disk cache (bench.cache): keys follow what a result depends on, a damaged entry is a miss.

- editing only a helper module that a plugin imports (``import mylib``) is a miss;
- f is probed at many points and the Jacobian is probed too (changes hidden in closures);
- a plugin that changes a suite setting does not poison the catalog pairs of its run (the plugin
  files of a run are in every key of the run);
- every source file of the project is in the key;
- a cache problem (a key that cannot be computed, an entry that cannot be stored) never fails a run;
- the module docstring names every part of the key.
"""

from __future__ import annotations

import dataclasses
import json
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import bench.cache as cache_mod
import bench.metrics
from bench.cache import Cache, default_cache_dir
from bench.cli import main
from bench.harness import RunOptions, run
from bench.registry import DESIGNS, PLANTS
from plants import Constants, Plant
from tests._plugin_helpers import clean_registries  # noqa: F401 - autouse: registries restored after each test

ROOT = Path(__file__).resolve().parents[1]
FAST = RunOptions(n_samples=500)


def _cache_counts(out: Path) -> tuple[int, int]:
    info = json.loads((out / "run.json").read_text())
    return info["cache"]["hits"], info["cache"]["misses"]


# -- item 1: a helper module beside the plugin ---------------------------------------------------
MYLIB = '''
import numpy as np


def f(x, c):
    return np.stack([0.0 * x[0], -c * np.sin(x[0])])


def jac(x, c):
    return np.array([[0.0, 0.0], [-c * np.cos(x[0]), 0.0]])
'''

HELPER_PLUGIN = '''
import mylib
from bench.registry import register_plant
from plants import Constants, Plant


@register_plant("helper_plant")
def helper_plant(*, c: float = 0.5) -> Plant:
    """Oscillator whose f and Jacobian live in mylib.py, beside this file."""
    return Plant(id="helper_plant", A=[[0.0, 1.0], [-1.0, -0.5]], B=[[0.0], [1.0]], C=[[1.0, 0.0]],
                 f=lambda x: mylib.f(x, c), jacobian=lambda x: mylib.jac(x, c),
                 x0=[1.0, 0.0], x_hat0=[0.0, 0.0], bounds=Constants(alpha=c, rho=c / 2, beta=c**2, gamma=0.0),
                 params={"c": c})
'''


def test_editing_a_helper_module_of_a_plugin_is_a_miss(tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "dont_write_bytecode", True)  # an edit within the same second is never a stale .pyc
    (tmp_path / "mylib.py").write_text(MYLIB)
    plugin = tmp_path / "helper_plugin.py"
    plugin.write_text(HELPER_PLUGIN)
    out = tmp_path / "rep"
    args = ["run", "-q", "-j", "1", "--no-figures", "--plugin", str(plugin), "--plant", "helper_plant",
            "--design", "lqr+ekf", "--out", str(out)]

    def fresh_run() -> tuple[int, int]:
        """A run as from a new process: the plugin and mylib imported again."""
        PLANTS.unregister("helper_plant")
        for name in [m for m in sys.modules if m == "mylib" or m.startswith("oslbench_plugin_helper_plugin")]:
            del sys.modules[name]  # else the plugin gets another module name (part of the key: f's name)
        assert main(args) == 0
        return _cache_counts(out)

    try:
        assert fresh_run() == (0, 1)
        assert fresh_run() == (1, 0)  # unchanged: served from the cache
        # only the Jacobian's code in mylib.py changes, to the same values up to round-off (the EKF uses
        # it; f is the same everywhere; a Jacobian that is not f's derivative is refused)
        (tmp_path / "mylib.py").write_text(MYLIB.replace("-c * np.cos(x[0])", "-c * np.sin(x[0] + np.pi / 2)"))
        assert fresh_run() == (0, 1)
        # an edit of mylib.py that changes no value (the source is part of the key)
        (tmp_path / "mylib.py").write_text(MYLIB + "\n# edited\n")
        assert fresh_run() == (0, 1)
    finally:
        sys.modules.pop("mylib", None)


def _plant(f, jacobian=None, **kw) -> Plant:
    c = 0.5
    return Plant(id="probe_plant", A=[[0.0, 1.0], [-1.0, -0.5]], B=[[0.0], [1.0]], C=[[1.0, 0.0]], f=f,
                 jacobian=jacobian, x0=[1.0, 0.0], x_hat0=[0.0, 0.0],
                 bounds=Constants(alpha=c, rho=c / 2, beta=c**2, gamma=0.0), **kw)


def _f(scale_far: float, nan_far: bool = False):
    def f(x):
        x = np.asarray(x, dtype=float)
        far = np.abs(x[0]) > 4.0  # beyond every point the old 3-point probe used, and beyond the plant's checks
        g = np.where(far, scale_far, 1.0) * -0.5 * np.sin(x[0])
        if nan_far:
            g = np.where(far, np.nan, g)
        return np.stack([0.0 * x[0], g])

    return f


def _jac(gain: float, raise_far: bool = False):
    def jac(x):
        x = np.asarray(x, dtype=float)
        if raise_far and abs(x[0]) > 4.0:
            raise ValueError("outside the model")
        # the gain acts where f's scale does, far out (a declared Jacobian must be f's derivative near 0)
        return np.array([[0.0, 0.0], [-0.5 * (gain if abs(x[0]) > 4.0 else 1.0) * np.cos(x[0]), 0.0]])

    return jac


def test_f_is_probed_at_many_scales_and_the_jacobian_too(tmp_path):
    cor1 = DESIGNS.create("cor1")

    def key(plant):
        return Cache(tmp_path).pair_key(plant, "probe_plant", cor1, "cor1", FAST)

    base = key(_plant(_f(1.0), _jac(1.0)))
    assert base is not None and base == key(_plant(_f(1.0), _jac(1.0)))
    # same names, same source, a value that differs only far from the origin
    assert key(_plant(_f(3.0), _jac(1.0))) != base
    # the Jacobian differs only by a closure value
    assert key(_plant(_f(1.0), _jac(2.0))) != base
    # non-finite values and exceptions at some probe points: a key still, the same every time, and its own
    odd = _plant(_f(1.0, nan_far=True), _jac(1.0, raise_far=True))
    assert key(odd) is not None and key(odd) == key(_plant(_f(1.0, nan_far=True), _jac(1.0, raise_far=True)))
    assert key(odd) not in (base, key(_plant(_f(1.0, nan_far=True), _jac(1.0))))


def test_the_probe_stays_inside_the_constants_radius():
    plant = _plant(_f(1.0), _jac(1.0))
    local = dataclasses.replace(plant, bounds=dataclasses.replace(plant.bounds, radius=0.3))
    X = Cache._probe_points(local)[:, : cache_mod.PROBE_POINTS]
    assert X.shape == (2, cache_mod.PROBE_POINTS)
    assert np.linalg.norm(X, axis=0).max() <= 0.3 * 0.95 + 1e-12
    assert np.linalg.norm(Cache._probe_points(plant), axis=0).max() > 5.0  # several scales, up to 10


def test_key_is_the_same_in_another_process(tmp_path):
    """Settings and code are read the same way everywhere: no per-process value enters the key."""
    script = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(ROOT)!r})
        from bench.cache import Cache
        from bench.harness import RunOptions
        from bench.registry import DESIGNS, PLANTS
        c = Cache({str(tmp_path)!r})
        print(c.pair_key(PLANTS.create("flexible_link"), "flexible_link", DESIGNS.create("thm1"), "thm1",
                         RunOptions(n_samples=500)))
    """)
    other = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert other.returncode == 0, other.stderr
    here = Cache(tmp_path).pair_key(PLANTS.create("flexible_link"), "flexible_link", DESIGNS.create("thm1"), "thm1",
                                    FAST)
    assert other.stdout.strip() == here


# -- item 2: a plugin that changes a suite setting -----------------------------------------------
TWEAK_PLUGIN = '''
import numpy as np

import bench.metrics
from bench.registry import register_plant
from plants import Constants, Plant

bench.metrics.CONVERGED_RATIO = 0.1  # a "setting" changed by a plugin, for the whole run


@register_plant("tweak_plant")
def tweak_plant(*, c: float = 0.5) -> Plant:
    """Damped oscillator."""
    return Plant(id="tweak_plant", A=[[0.0, 1.0], [-1.0, -0.5]], B=[[0.0], [1.0]], C=[[1.0, 0.0]],
                 f=lambda x: np.stack([0.0 * x[0], -c * np.sin(x[0])]), x0=[1.0, 0.0], x_hat0=[0.0, 0.0],
                 bounds=Constants(alpha=c, rho=c / 2, beta=c**2, gamma=0.0), params={"c": c})
'''


def test_a_plugin_changing_a_setting_does_not_poison_the_catalog_pairs(tmp_path, monkeypatch):
    original = bench.metrics.CONVERGED_RATIO
    monkeypatch.setattr(bench.metrics, "CONVERGED_RATIO", original)  # restored after the test, whatever happens
    plugin = tmp_path / "tweak.py"
    plugin.write_text(TWEAK_PLUGIN)
    out = tmp_path / "rep"
    args = ["run", "-q", "-j", "1", "--no-figures", "--plant", "flexible_link", "--design", "paper_gains",
            "--out", str(out)]
    assert main([*args, "--plugin", str(plugin)]) == 0
    assert bench.metrics.CONVERGED_RATIO == 0.1 and _cache_counts(out) == (0, 1)
    # a later plain run: the setting is back, so the rows computed under the plugin's setting are not served
    bench.metrics.CONVERGED_RATIO = original
    PLANTS.unregister("tweak_plant")
    assert main(args) == 0
    assert _cache_counts(out) == (0, 1)
    assert main(args) == 0
    assert _cache_counts(out) == (1, 0)


def test_every_project_source_file_is_in_the_key(tmp_path, monkeypatch):
    """Editing any file of the project is a miss: cor1's helpers live in designs/_separated.py, and the
    constants do not depend on the designs at all, yet a change of either file changes both keys."""
    flex, cor1 = PLANTS.create("flexible_link"), DESIGNS.create("cor1")

    def keys():
        c = Cache(tmp_path)
        return c.pair_key(flex, "flexible_link", cor1, "cor1", FAST), c.constants_key(flex, "flexible_link", FAST)

    before = keys()
    assert None not in before
    real = cache_mod._sha_file
    for edited in ("designs/_separated.py", "bench/metrics.py"):
        monkeypatch.setattr(cache_mod, "_sha_file", lambda p, e=edited: "edited" if p.endswith(e) else real(p))
        after = keys()
        assert after[0] != before[0] and after[1] != before[1], edited
    monkeypatch.undo()
    assert keys() == before


# -- item 5: a cache problem never fails a run ---------------------------------------------------
def test_a_key_that_cannot_be_computed_is_a_miss_not_a_failure(tmp_path, monkeypatch):
    def broken(self, plant, plant_id):
        raise RuntimeError("fingerprint exploded")

    monkeypatch.setattr(Cache, "plant_fingerprint", broken)
    cache = Cache(tmp_path / "c")
    res = run(["flexible_link"], ["paper_gains"], FAST, cache=cache)
    assert res.frame()["converged"].all()
    assert cache.stored == 0 and any("fingerprint exploded" in e for e in cache.errors)


def test_an_entry_that_cannot_be_stored_is_not_a_failure(tmp_path, monkeypatch):
    def broken(path, write):
        raise ValueError("cannot serialise this")  # not an OSError: a value the writer chokes on

    monkeypatch.setattr(cache_mod, "_atomic_write", broken)
    cache = Cache(tmp_path / "c")
    res = run(["flexible_link"], ["paper_gains"], FAST, cache=cache)
    assert res.frame()["converged"].all() and cache.stored == 0
    assert any("cannot serialise this" in e for e in cache.errors)


def test_the_docstring_names_every_part_of_the_key(tmp_path, monkeypatch):
    docs: list[dict] = []
    real = Cache._key

    def capture(self, doc):
        docs.append(doc)
        return real(self, doc)

    monkeypatch.setattr(Cache, "_key", capture)
    cache = Cache(tmp_path)
    flex = PLANTS.create("flexible_link")
    cache.pair_key(flex, "flexible_link", DESIGNS.create("thm1"), "thm1", FAST)
    cache.constants_key(flex, "flexible_link", FAST)
    text = cache_mod.__doc__
    named = set(re.findall(r"``(\w+)``", text))
    for doc in docs:
        assert set(doc) <= named, f"parts of the key the docstring does not name: {set(doc) - named}"
    assert {"pair", "constants"} <= {d["kind"] for d in docs}
    plant_doc = docs[0]["plant"]
    assert set(plant_doc) == {"id", "plant", "probe"}
    assert str(cache_mod.PROBE_POINTS) == "64" and "PROBE_POINTS" in text


# -- a damaged entry is a miss with a warning naming it ------------------------------------------
def _edit_pair_entries(cache_dir: Path, edit, *, reseal: bool) -> list[Path]:
    """Apply ``edit(record)`` to every pair entry's record; ``reseal``: recompute the checksum too (an edit
    made with knowledge of the format), else leave the old one."""
    entries = sorted((cache_dir / "pairs").glob("*.npz"))
    for path in entries:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        doc = json.loads(str(arrays.pop("meta")))
        old_sha = str(arrays.pop("sha256"))
        edit(doc["value"]["fields"]["record"]["__dict__"])
        meta = json.dumps(doc)
        sha = cache_mod._checksum(meta, arrays) if reseal else old_sha
        np.savez_compressed(path, **arrays, meta=np.array(meta), sha256=np.array(sha))
    return entries


@pytest.mark.parametrize("edit, reseal", [
    (lambda r: r.update(decay_rate="fast"), False),
    (lambda r: r.update(decay_rate="fast"), True),  # the checksum matches: the column's kind is checked
    (lambda r: r.update(certified=not r["certified"], cert_level="none"), False),  # an edited verdict
])
def test_a_damaged_entry_is_a_miss_with_a_warning_and_the_row_is_recomputed(tmp_path, capsys, edit, reseal,
                                                                          paper_gains_report):
    out = paper_gains_report(tmp_path)  # a first run's report and, beside it, its cache
    args = ["run", "-j", "1", "--no-figures", "--plant", "flexible_link", "--design", "paper_gains", "--out", str(out)]
    assert _cache_counts(out) == (0, 1)  # the copied run computed the pair
    first = pd.read_csv(out / "results.csv")
    assert first.loc[0, "certified"] and np.isfinite(first.loc[0, "decay_rate"])
    capsys.readouterr()
    (entry,) = _edit_pair_entries(default_cache_dir(out), edit, reseal=reseal)
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "warning" in err and str(entry) in err and "damaged cache entry" in err and "Traceback" not in err
    assert _cache_counts(out) == (0, 1)
    again = pd.read_csv(out / "results.csv")
    verdicts = ["status", "certified", "cert_level", "decay_rate", "converged"]
    pd.testing.assert_frame_equal(again[verdicts], first[verdicts])
    # the recomputed row replaced the damaged entry: the next run takes it from the cache, silently
    assert main(args) == 0
    assert _cache_counts(out) == (1, 0) and "damaged cache entry" not in capsys.readouterr().err


def test_entries_round_trip_whole(tmp_path):
    """A stored pair reads back equal, field by field (arrays exactly), and carries a checksum of its content."""
    cache = Cache(tmp_path)
    res = run(["flexible_link"], ["lqr+lqe"], FAST, cache=cache)
    (o,) = res.outcomes
    key = cache.pair_key(o.plant, "flexible_link", DESIGNS.create("lqr+lqe"), "lqr+lqe", FAST)
    back = Cache(tmp_path).load_pair(key)
    assert back is not None and back.plant is None
    assert json.dumps(back.record, default=str) == json.dumps(o.record, default=str)
    np.testing.assert_array_equal(back.result.K, o.result.K)
    np.testing.assert_array_equal(back.trajectory.x, o.trajectory.x)
    assert back.certificate.levels.keys() == o.certificate.levels.keys()
    for lv, r in o.certificate.levels.items():
        assert back.certificate.levels[lv].status == r.status
    with np.load(tmp_path / "pairs" / f"{key}.npz", allow_pickle=False) as z:
        assert len(str(z["sha256"])) == 64


def test_a_pair_with_witnesses_is_stored_and_reads_back(tmp_path):
    # the loop linearised at the origin has an unstable eigenvalue (a complex scalar in the witness):
    # the entry is stored, not skipped with a warning, and the witness reads back equal
    cache = Cache(tmp_path)
    res = run(["pendulum_v1"], ["lqr+lqe"], FAST, cache=cache)
    (o,) = res.outcomes
    key = cache.pair_key(o.plant, "pendulum_v1", DESIGNS.create("lqr+lqe"), "lqr+lqe", FAST)
    assert cache.errors == [] and (tmp_path / "pairs" / f"{key}.npz").is_file()
    back = Cache(tmp_path).load_pair(key)
    assert o.certificate.witnesses and back is not None
    for w, b in zip(o.certificate.witnesses, back.certificate.witnesses):
        assert isinstance(b.eig, complex) and (b.eig == w.eig or (np.isnan(b.eig) and np.isnan(w.eig)))
