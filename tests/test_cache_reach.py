"""The cache sees f (and phi, the narrowing, the Jacobian) wherever the run's own checks look.

- issue #31's case: f changes only where |x1| > 12 (beyond the old probe, ||x|| <= 10, inside the
  constants sampler's reach): the second run takes nothing from the cache and reports what a run
  without the cache reports;
- f changing only beyond the samplers' reach but within a pair's own reach (REACH_FACTOR times the
  largest state of its simulation) makes that pair a miss on load, not an error;
- the channels' phi and narrowing enter the key by what they compute, not by their names.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

import bench
from bench.cache import Cache, _pair_states
from bench.constants import REACH_FACTOR, sampled_range
from bench.harness import RunOptions, run
from bench.registry import DESIGNS, PLANTS
from plants import Channels, Constants, Plant
from tests._plugin_helpers import clean_registries  # noqa: F401 - autouse: registries restored after each test

C = 0.5


def _phi(k: float, edge: float):
    """-c sin(z), plus a slope k beyond |z| > edge (k = 0: the first run's phi)."""

    def phi(z):
        z = np.asarray(z, dtype=float)
        return -C * np.sin(z) + k * np.sign(z) * np.maximum(np.abs(z) - edge, 0.0)

    return phi


def _plant(k: float = 0.0, edge: float = 12.0, narrow_far: float = 1.0) -> Plant:
    """Issue #31's plant: a damped oscillator, f = (0, phi(x1)), declared with valid constants and channels."""
    phi = _phi(k, edge)

    def narrow(r):  # slopes of -c sin on |z| <= r (a value far out may be changed)
        return -C * (narrow_far if r > 12.0 else 1.0), -C * np.cos(min(r, np.pi))

    return Plant(id="far_change", A=[[0.0, 1.0], [-1.0, -0.5]], B=[[0.0], [1.0]], C=[[1.0, 0.0]],
                 f=lambda x: np.stack([0.0 * np.asarray(x, dtype=float)[0], phi(np.asarray(x, dtype=float)[0])]),
                 x0=[1.0, 0.0], x_hat0=[0.0, 0.0], bounds=Constants(alpha=C, rho=C / 2, beta=C**2, gamma=0.0),
                 channels=Channels(G=[[0.0], [1.0]], H=[[1.0, 0.0]], phi=phi, lo=-C, hi=C, narrow=narrow),
                 params={"c": C})


VERDICTS = ["status", "certified", "cert_level", "decay_rate", "cert_scope", "constants", "disproved", "reason"]


def _api_run(plant, cache):
    PLANTS.unregister(plant.id)  # another object under the same id: a new run of an edited plugin
    res = bench.run([plant], ["lqr+lqe"], cache=cache, progress=False, jobs=1)
    return res.table[VERDICTS], res.run_result


def test_f_changed_only_beyond_the_old_probe_is_recomputed(tmp_path):
    first, _ = _api_run(_plant(), tmp_path)
    assert first.loc[0, "certified"]
    again, r = _api_run(_plant(), tmp_path)  # the same f: served from the cache
    assert r.cache_hits == 1
    changed, r = _api_run(_plant(k=5.0), tmp_path)
    assert r.cache_hits == 0
    fresh, _ = _api_run(_plant(k=5.0), None)
    # the change matters to the run's checks: the sampler disproves the declarations, nothing is certified
    assert "DISPROVED" in fresh.loc[0, "constants"] and not fresh.loc[0, "certified"]
    pd.testing.assert_frame_equal(changed, fresh)


def test_the_probe_reaches_the_samplers_range():
    plant = _plant()
    X = Cache._probe_points(plant)
    reach = np.linalg.norm(X, axis=0).max()
    assert reach == pytest.approx(sampled_range(plant)) and sampled_range(plant) > 30


def test_a_pair_is_a_miss_when_f_changed_only_where_its_own_checks_looked(tmp_path):
    """The key cannot know how far a simulation goes; the entry's digest out to its reach does."""
    near = _plant()
    PLANTS.register("far_change", lambda: _plant())
    (o,) = run(["far_change"], ["lqr+lqe"], RunOptions(n_samples=500)).outcomes  # a finished pair
    # the stored simulation went out to ||x|| = 6 sqrt(2), so the pair's checks sampled out to 10 times that
    big = dataclasses.replace(o, trajectory=dataclasses.replace(o.trajectory, x=np.full_like(o.trajectory.x, 6.0),
                                                                x_hat=np.full_like(o.trajectory.x, 6.0)))
    reach, _ = _pair_states(near, big)
    assert reach == pytest.approx(REACH_FACTOR * np.hypot(6.0, 6.0))
    edge = 1.1 * sampled_range(near) * np.sqrt(2)  # beyond every probe of the key, inside the pair's reach
    far = _plant(k=5.0, edge=edge)
    cor = DESIGNS.create("lqr+lqe")
    store = Cache(tmp_path)
    key = store.pair_key(near, "far_change", cor, "lqr+lqe", RunOptions())
    assert store.store_pair(key, big) and store.errors == []
    seen = Cache(tmp_path)
    assert seen.pair_key(far, "far_change", cor, "lqr+lqe", RunOptions()) == key  # the key cannot see it
    assert seen.load_pair(key) is None and seen.misses == 1 and seen.errors == []  # a miss, not an error
    same = Cache(tmp_path)
    assert same.pair_key(_plant(), "far_change", cor, "lqr+lqe", RunOptions()) == key
    assert same.load_pair(key) is not None and same.hits == 1


def test_phi_and_the_narrowing_enter_the_key_by_what_they_compute(tmp_path):
    cor = DESIGNS.create("lqr+lqe")

    def key(plant):
        return Cache(tmp_path).pair_key(plant, "far_change", cor, "lqr+lqe", RunOptions())

    base = key(_plant())
    assert base == key(_plant())
    assert key(_plant(narrow_far=2.0)) != base  # narrow(r) differs only for r > 12
    phi_only = _plant()
    channels = dataclasses.replace(phi_only.channels, phi=_phi(5.0, 20.0))  # phi alone differs, beyond |z| = 20
    assert key(dataclasses.replace(phi_only, channels=channels)) != base
