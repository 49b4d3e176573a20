"""Plant.scaled(c) and the study of the largest admissible scale of a plant's class (``study scale``).

Near the exact limit a certificate's margin tends to zero, so the ladder's last probes there are "marginal"
(within its verification tolerance: undecided); the test allows the bracket to stop short of the closed form by
those probes only, by at most two grid steps, and never to certify beyond it.

The scaled plant's constants are checked on independent samples (their own seed, plus the pairs where each
constant is tight), and the study's bracket is checked against a factor known in closed form: for one state,
x' = a x + u + c g sin(x), y = x, with fixed gains the closed loop (x, e) has the linear members
x' = (a + F + d1) x - F e, e' = (a - K + d2) e for every |d1|, |d2| <= c g (slopes of c g sin), so it is
stable for the whole class iff c g < min(-(a + F), -(a - K)), and below that a quadratic certificate exists
(diagonal V = x^2 + t e^2 with t large: the cascade). The largest certified factor is that minimum over g.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import pytest

from bench.errors import PlantError
from bench.registry import DESIGNS, PLANTS
from designs import Design, DesignResult
from plants import Channels, Constants, Plant
from plants._core import sine_slopes


# -- the scaled plant --------------------------------------------------------------------------
def _pairs(plant: Plant, rng, n: int = 4000) -> tuple[np.ndarray, np.ndarray]:
    """Independent sample pairs (x1, x2) inside the plant's region: random, near its boundary along rays (where
    the moving object's constants are tight), and close pairs."""
    r = (plant.bounds.radius if plant.bounds is not None and plant.bounds.radius is not None else 4.0)
    X1 = rng.standard_normal((plant.n, n))
    X1 *= r * rng.uniform(0, 1, n) ** (1 / plant.n) / np.linalg.norm(X1, axis=0)
    X2 = X1 + rng.standard_normal((plant.n, n)) * rng.choice([1e-3, 0.1, 1.0], n)
    U = rng.standard_normal((plant.n, n // 4))
    U /= np.linalg.norm(U, axis=0)
    s = rng.uniform(0.9, 1.0, n // 4) * r
    ray1, ray2 = U * r, U * s  # two points on one ray, near the boundary
    X1, X2 = np.hstack([X1, ray1]), np.hstack([X2, ray2])
    norms = np.maximum(np.linalg.norm(X1, axis=0), np.linalg.norm(X2, axis=0))
    keep = norms <= r * (1 - 1e-12)  # inside the region (closed ball minus rounding)
    return X1[:, keep], X2[:, keep]


def _ratios(plant: Plant, X1, X2) -> dict:
    """The largest ratio of each constant's inequality over the pairs (<= 1 where the constant holds)."""
    dX = X1 - X2
    dF = np.asarray(plant.f(X1)) - np.asarray(plant.f(X2))
    nx2, nf2, ip = (dX * dX).sum(0), (dF * dF).sum(0), (dX * dF).sum(0)
    b = plant.bounds
    out = {"alpha": np.max(np.sqrt(nf2 / nx2)) / b.alpha if b.alpha else np.max(nf2)}
    out["rho"] = np.max(ip / nx2) - b.rho  # <= 0 where rho holds
    out["qib"] = np.max(nf2 - b.beta * nx2 - b.gamma * ip) / max(1e-300, np.max(nf2))  # <= 0 where QIB holds
    return out


@pytest.mark.parametrize("pid", ["flexible_link", "moving_object_v1", "chua_v1", "random_osl_v1"])
@pytest.mark.parametrize("c", [0.3, 2.5])
def test_the_scaled_class_constants_hold_on_independent_samples(pid, c):
    base = PLANTS.create(pid)
    p = base.scaled(c)
    X1, X2 = _pairs(p, np.random.default_rng([2024, int(10 * c), len(pid)]))
    got = _ratios(p, X1, X2)
    tol = 1e-9
    assert got["alpha"] <= 1 + tol, f"alpha = {p.bounds.alpha} does not hold for {c} f"
    assert got["rho"] <= tol * max(1.0, p.bounds.alpha)
    assert got["qib"] <= 1e-9
    # ... and not looser by a power of c (c^2 alpha would be attained only to within c = 0.3 or 1 / c = 0.4)
    assert got["alpha"] > 0.6
    b0 = base.bounds
    assert (p.bounds.alpha, p.bounds.rho, p.bounds.beta, p.bounds.gamma) == pytest.approx(
        (c * b0.alpha, c * b0.rho, c * c * b0.beta, c * b0.gamma), rel=1e-12, abs=0)
    assert p.bounds.radius == b0.radius


def test_the_moving_object_qib_pair_is_tight_after_scaling():
    """On a ray at the region's edge the scaled QIB pair (0, c gamma) holds with equality in the limit: a gamma
    scaled by c^2 (for c < 1) would fail there, one scaled by 1 (for c > 1) too."""
    for c in (0.3, 2.5):
        p = PLANTS.create("moving_object_v1").scaled(c)
        r = p.bounds.radius
        u = np.array([0.6, 0.8])
        x1, x2 = r * u, (r - 1e-6) * u
        df, dx = p.f(x1) - p.f(x2), x1 - x2
        lhs, rhs = df @ df, p.bounds.beta * (dx @ dx) + p.bounds.gamma * (dx @ df)
        assert lhs <= rhs * (1 + 1e-9) and lhs >= rhs * (1 - 1e-5)
        wrong = c * c * PLANTS.create("moving_object_v1").bounds.gamma if c < 1 else \
            PLANTS.create("moving_object_v1").bounds.gamma
        assert lhs > p.bounds.beta * (dx @ dx) + wrong * (dx @ df)


def test_the_scaled_plant_keeps_the_linear_part_and_multiplies_f():
    base = PLANTS.create("flexible_link_d10ms_v1")
    c = 1.7
    p = base.scaled(c)
    for name in ("A", "B", "C", "x0", "x_hat0"):
        assert np.array_equal(getattr(p, name), getattr(base, name))
    assert (p.dt, p.t_final, p.family) == (base.dt, base.t_final, base.family)
    assert p.id == "flexible_link_d10ms_v1_scaled1.7" and p.params["scale"] == c and p.params["c"] == base.params["c"]
    X = np.random.default_rng(7).standard_normal((4, 5))
    assert np.allclose(p.f(X), c * base.f(X), rtol=1e-14, atol=0)
    assert np.allclose(p.jacobian_at(X[:, 0]), c * base.jacobian_at(X[:, 0]), rtol=1e-12, atol=1e-15)
    assert np.allclose(p.channels.apply(X), p.f(X), rtol=1e-12, atol=1e-15)
    assert np.array_equal(p.channels.lo, c * base.channels.lo) and np.array_equal(p.channels.hi, c * base.channels.hi)
    lo_r, hi_r = p.channels.slopes_on(0.5)
    lo0, hi0 = base.channels.slopes_on(0.5)
    assert np.allclose(lo_r, c * lo0) and np.allclose(hi_r, c * hi0)
    # the claimed constants scale like the trusted ones (a claim stays right or wrong)
    fl = PLANTS.create("flexible_link")
    assert fl.scaled(c).claimed.rho == pytest.approx(c * fl.claimed.rho)
    assert fl.scaled(c).claimed.beta == pytest.approx(c * c * fl.claimed.beta)
    # twice: the factors multiply
    assert p.scaled(2.0).params["scale"] == pytest.approx(2 * c)


def test_scaling_by_zero_is_the_linear_plant_and_a_negative_factor_is_refused():
    z = PLANTS.create("pendulum_v1").scaled(0.0)
    assert np.all(z.f(np.ones((2, 3))) == 0)
    assert (z.bounds.alpha, z.bounds.rho, z.bounds.beta, z.bounds.gamma) == (0, 0, 0, 0)
    with pytest.raises(PlantError, match="c: must be finite and >= 0"):
        PLANTS.create("pendulum_v1").scaled(-0.5)
    with pytest.raises(PlantError, match="c: "):
        PLANTS.create("pendulum_v1").scaled(float("nan"))


# -- the study's bracket against the closed form ------------------------------------------------
A_SCALAR, G_SCALAR = 1.0, 0.5


def _scalar_plant() -> Plant:
    """x' = a x + u + g sin(x), y = x: one channel G = g, H = 1, phi = sin with slopes [-1, 1]."""
    g = G_SCALAR
    return Plant(id="_scalar_sine", A=[[A_SCALAR]], B=[[1.0]], C=[[1.0]],
                 f=lambda x: g * np.sin(np.asarray(x, dtype=float)),
                 jacobian=lambda x: np.atleast_2d(g * np.cos(np.asarray(x, dtype=float).reshape(-1)[0])),
                 x0=[0.5], x_hat0=[0.0],
                 channels=Channels(G=[[g]], H=[[1.0]], phi=np.sin, lo=-1.0, hi=1.0, narrow=sine_slopes(1.0)),
                 bounds=Constants(alpha=g, rho=g, beta=g * g, gamma=0.0), t_final=10.0)


@dataclass(frozen=True, kw_only=True)
class _Given(Design):
    """Fixed scalar gains (like paper_gains: nothing solved)."""

    K: float = 0.0
    F: float = 0.0

    def design(self, plant, constants):
        return DesignResult(status="given", route="given", K=np.array([[self.K]]), F=np.array([[self.F]]))


@pytest.fixture
def scalar_registry():
    PLANTS.register("_scalar_sine", lambda: _scalar_plant())
    # x-side limited: a + F = -1.5, a - K = -3; e-side limited: a + F = -3, a - K = -1.2
    DESIGNS.register("_given_x_limited", lambda: _Given(K=4.0, F=-2.5))
    DESIGNS.register("_given_e_limited", lambda: _Given(K=2.2, F=-4.0))
    yield
    for i in ("_scalar_sine",):
        PLANTS.unregister(i)
    for i in ("_given_x_limited", "_given_e_limited"):
        DESIGNS.unregister(i)


def test_the_certified_bracket_contains_the_closed_form_factor(scalar_registry):
    from bench.studies.scale import run_scale

    # LQR and LQE with unit weights on x' = a x + u, y = x: both poles at -sqrt(a^2 + 1) (the scalar Riccati
    # equations 2 a s - s^2 + 1 = 0), so the factor is sqrt(a^2 + 1) / g
    expected = {"lqr+lqe": math.sqrt(A_SCALAR**2 + 1) / G_SCALAR,
                "_given_x_limited": 1.5 / G_SCALAR, "_given_e_limited": 1.2 / G_SCALAR}
    res = run_scale(["_scalar_sine"], list(expected), jobs=1, rtol=0.01)
    rows = {r["design"]: r for r in res.rows}
    for did, c_star in expected.items():
        r = rows[did]
        assert r["designed_kind"] == "above_range"  # the gains do not depend on the class
        assert r["certified_kind"] == "bracketed", (did, r["certified_reason"])
        lo, hi = r["certified_lo"], r["certified_hi"]
        assert lo <= c_star, f"{did}: certified at {lo}, beyond the closed form {c_star} (unsound)"
        assert hi / lo - 1 <= 0.0101
        # the bracket contains the closed form, or stops short of it only where the certificate's margin is within
        # the ladder's tolerance of zero ("marginal": undecided, not failed), within two grid steps
        if hi < c_star:
            assert r["certified_fails_by"] == "marginal certificate", (did, r["certified_reason"])
            assert c_star / lo - 1 <= 0.0201, f"{did}: [{lo}, {hi}) stops too far below {c_star}"
        assert r["circle_bound"] == pytest.approx(c_star, rel=1e-6)  # python-control's norm agrees
    # the ranking: the largest certified factor first
    assert [rows[d]["certified_rank"] for d in ("_given_x_limited", "lqr+lqe", "_given_e_limited")] == [1, 2, 3]


def test_a_design_without_fixed_gains_or_time_domain_is_not_applicable(scalar_registry):
    from bench.studies.scale import run_scale

    disc = dataclasses.replace(_scalar_plant(), id="_scalar_sine_d", A=[[1.001]], B=[[0.001]],
                               f=lambda x: 0.0005 * np.sin(np.asarray(x, dtype=float)), jacobian=None,
                               channels=None, bounds=Constants(alpha=5e-4, rho=5e-4, beta=2.5e-7, gamma=0.0),
                               dt=0.001)
    PLANTS.register("_scalar_sine_d", lambda: disc)
    try:
        res = run_scale(["_scalar_sine", "_scalar_sine_d"], ["lqr+ekf", "lqr+rajamani", "lqr+lqe"], jobs=1)
    finally:
        PLANTS.unregister("_scalar_sine_d")
    rows = {(r["plant"], r["design"]): r for r in res.rows}
    ekf = rows[("_scalar_sine", "lqr+ekf")]
    assert ekf["designed_kind"] == ekf["certified_kind"] == "inapplicable"
    assert "no fixed gains" in ekf["designed_reason"]
    raj = rows[("_scalar_sine_d", "lqr+rajamani")]
    assert raj["designed_kind"] == "inapplicable" and "no discrete-time form" in raj["designed_reason"]
    lqe = rows[("_scalar_sine_d", "lqr+lqe")]  # designed at every factor; the discrete ladder judges it
    assert lqe["designed_kind"] == "above_range"
    assert lqe["certified_kind"] != "inapplicable"


def test_the_study_writes_its_report_table_and_figure(scalar_registry, tmp_path):
    from bench.cli import main

    rc = main(["study", "scale", "-q", "-j", "1", "--plant", "_scalar_sine", "--design", "_given_*",
               "--rtol", "0.05", "--out", str(tmp_path)])
    assert rc == 0
    md = (tmp_path / "STUDY_scale.md").read_text()
    assert "## (b) Certified" in md and "_given_e_limited" in md and "Q, R << 1e3 I" in md
    assert (tmp_path / "figures" / "study_scale.png").stat().st_size > 5000
    import pandas as pd

    df = pd.read_csv(tmp_path / "study_scale.csv")
    assert set(df["design"]) == {"_given_x_limited", "_given_e_limited"}
    assert main(["study", "scale", "-q", "--plant", "_scalar_sine", "--rtol", "2", "--out", str(tmp_path)]) == 2


def test_a_pair_that_fails_is_a_row_with_its_error(scalar_registry, tmp_path):
    from bench.studies.scale import run_scale, write_scale

    def broken():
        raise RuntimeError("cannot build")

    PLANTS.register("_broken_plant", broken)
    try:
        res = run_scale(["_broken_plant", "_scalar_sine"], ["_given_e_limited"], jobs=1, rtol=0.05)
    finally:
        PLANTS.unregister("_broken_plant")
    rows = {r["plant"]: r for r in res.rows}
    assert rows["_broken_plant"]["certified_kind"] == "error" and "cannot build" in rows["_broken_plant"][
        "certified_reason"]
    assert rows["_scalar_sine"]["certified_kind"] == "bracketed"
    md = write_scale(res, tmp_path, "test", figures=False).read_text()
    assert "| _broken_plant | error |" in md and not (tmp_path / "figures" / "study_scale.png").exists()
