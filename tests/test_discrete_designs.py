"""The designs on a discrete plant: the flexible link discretised in the test itself.

Discretisation (the test's own): the linear part by python-control's zero-order hold (``control.c2d``), the
nonlinearity by Euler, ``f_d = h f``: ``f_d(x) = (0, 0, 0, -c h sin x3)``, so the class's constants are
``h alpha``, ``h rho``, ``(h^2 beta, h gamma)`` and the channel is ``G = h e4``, ``H = e3'``, slopes in ``[-c, c]``.
Expectations are independent of the designs' code: python-control's dlqr / dlqe, scipy's DARE, spectral
radii, and each LMI design's returned certificate re-checked with numpy on linear members ``f = L x`` of the
class (``V(z+) <= r^2 V(z)`` is the matrix inequality ``Acl' P Acl - r^2 P <= 0`` for them).
"""

import math

import control
import numpy as np
import pytest
import scipy.linalg as sla

import plants.flexible_link as fl
from bench.registry import DESIGNS, PLANTS
from designs._parts import ESTIMATORS, FEEDBACKS
from plants import Plant
from plants._core import sine_terms

C_GRAV = 0.333


def discretised_link(h, c=C_GRAV):
    sysd = control.c2d(control.ss(fl.A, fl.B, fl.C, 0), h)
    terms = sine_terms(4, acts=[3], reads=[2], coef=-c, scale=1.0 / h)  # f_d = h f
    plant = Plant(id=f"flexible_link_h{h:g}", A=np.asarray(sysd.A), B=np.asarray(sysd.B), C=fl.C, x0=fl.X0,
                  x_hat0=fl.X_HAT0, dt=h, t_final=20.0, **terms)
    return plant, terms["bounds"]


@pytest.fixture(scope="module")
def link3():
    return discretised_link(1e-3)


def radius(M):
    return float(np.abs(np.linalg.eigvals(M)).max())


def class_members(plant, c, kind, rng, count=6):
    """Linear members ``L`` of the class: the channel's slopes ``s G H`` (s in [-c h, c h] as ``G = h e4``), and
    random ``L`` meeting the constants (OSL/QIB: ``t U`` and ``sqrt(beta) S``; Lipschitz: ``alpha U``)."""
    ch = plant.channels
    out = [s * ch.G @ ch.H for s in np.linspace(ch.lo[0], ch.hi[0], 5)]
    n = plant.n
    for _ in range(count):
        U, _ = np.linalg.qr(rng.standard_normal((n, n)))
        Sk = rng.standard_normal((n, n))
        Sk = (Sk - Sk.T) / 2
        Sk /= np.linalg.norm(Sk, 2)
        if kind == "osl_qib":  # gamma = 0 here: ||L||^2 <= beta and sym(L) <= rho
            assert c.gamma == 0
            out += [min(math.sqrt(c.beta), c.rho) * U, math.sqrt(c.beta) * Sk]
        else:
            out += [c.alpha * U]
    return out


def certificate_holds(plant, res, members):
    """The test's own check of the returned certificate: ``Acl' P Acl - r^2 P <= 0`` (to rounding) for every member,
    and ``Acl' P Acl - P < 0``."""
    cert = res.certificate
    P, r = cert["P"], cert["contraction"]
    A, B, C, F, K = plant.A, plant.B, plant.C, res.F, res.K
    n = plant.n
    for L in members:
        Acl = np.block([[A + B @ F + L, -B @ F], [np.zeros((n, n)), A - K @ C + L]])
        M = Acl.T @ P @ Acl
        scale = np.linalg.norm(P, 2)
        if np.linalg.eigvalsh(M - r**2 * P).max() > 1e-9 * scale:
            return False
        if np.linalg.eigvalsh(M - P).max() >= 0:
            return False
    return True


def test_the_discretised_constants_are_the_scaled_continuous_ones(link3):
    plant, c = link3
    h = plant.dt
    assert plant.discrete and h == 1e-3
    assert c.alpha == pytest.approx(h * C_GRAV) and c.rho == pytest.approx(h * C_GRAV / 2)
    assert c.beta == pytest.approx((h * C_GRAV) ** 2) and c.gamma == 0


def test_time_domains_declared():
    assert set(DESIGNS.create("lqr+lqe").time_domains) == {"continuous", "discrete"}
    assert set(DESIGNS.create("lqr+ekf").time_domains) == {"continuous", "discrete"}
    assert DESIGNS.create("lqr+rajamani").time_domains == ("continuous",)
    for did in ("thm1", "thm1_sep", "cor1", "cor1_sep", "structured"):
        assert "discrete" in DESIGNS.create(did).time_domains, did
    for did in ("thm1_printed", "cor1_printed", "paper_gains", "hinf_osl", "lqr+hinf_lipschitz"):
        assert "discrete" not in DESIGNS.create(did).time_domains, did
    assert "discrete" in FEEDBACKS.create("lqr").time_domains and "discrete" in ESTIMATORS.create("lqe").time_domains


def test_dlqr_and_dlqe_are_python_controls_and_the_kalman_predictor(link3):
    plant, c = link3
    res = DESIGNS.create("lqr+lqe").design(plant, c)
    assert res.status == "computed"
    G, _, _ = control.dlqr(plant.A, plant.B, np.eye(4), np.eye(1))
    np.testing.assert_allclose(res.F, -G, rtol=1e-9, atol=1e-12)  # u = -G x: F = -G
    # the one-step predictor's gain from scipy's DARE (textbook: Anderson & Moore 1979, ch. 3)
    A, C = plant.A, plant.C
    P = sla.solve_discrete_are(A.T, C.T, np.eye(4), np.eye(2))
    Kp = A @ P @ C.T @ np.linalg.inv(C @ P @ C.T + np.eye(2))
    np.testing.assert_allclose(res.K, Kp, rtol=1e-7, atol=1e-10)
    Kf = P @ C.T @ np.linalg.inv(C @ P @ C.T + np.eye(2))  # the filter gain is not it (A != I)
    assert not np.allclose(res.K, Kf, rtol=1e-3)
    _, _, E = control.dlqe(A, np.eye(4), C, np.eye(4), np.eye(2))
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(A - res.K @ C)), np.sort_complex(E), rtol=1e-8)
    assert radius(A + plant.B @ res.F) < 1 and radius(A - res.K @ C) < 1


def test_discrete_ekf_reaches_the_steady_kalman_predictor_and_tracks_the_link():
    from bench.estimators import DiscreteEKF, runtime_estimator

    # linear (c = 0): the a priori covariance converges to the DARE's solution with Q = q dt I, R = r I
    plant, c = discretised_link(1e-2, c=0.0)
    res = DESIGNS.create("lqr+ekf").design(plant, c)
    spec = res.estimator
    assert spec.dt == plant.dt
    ekf = runtime_estimator(spec, plant, plant.x_hat0, t_final=plant.t_final)
    assert isinstance(ekf, DiscreteEKF) and ekf.dt == plant.dt and not ekf.predicts_with_model
    for _ in range(3000):
        ekf.update(np.zeros(2))
        ekf.predict(np.zeros(1))
    Pss = sla.solve_discrete_are(plant.A.T, plant.C.T, spec.q * plant.dt * np.eye(4), spec.r * np.eye(2))
    np.testing.assert_allclose(ekf.P, Pss, rtol=1e-6, atol=1e-12)
    # nonlinear, noise-free, the loop closed with dlqr: the estimate converges to the state
    plant, c = discretised_link(1e-2)
    res = DESIGNS.create("lqr+ekf").design(plant, c)
    ekf = runtime_estimator(res.estimator, plant, plant.x_hat0, t_final=plant.t_final)
    x = plant.x0.copy()
    e0 = np.linalg.norm(x - ekf.x)
    for _ in range(1000):
        ekf.update(plant.C @ x)
        u = res.F @ ekf.x
        ekf.predict(u)
        x = plant.A @ x + plant.B @ u + plant.f(x)
    assert np.linalg.norm(x - ekf.x) < 1e-4 * e0 and np.linalg.norm(x) < 1e-2


@pytest.mark.parametrize("did", ["thm1", "thm1_sep", "cor1", "cor1_sep"])
def test_discrete_theorem1_and_corollary1_verified_and_certified(link3, did):
    plant, c = link3
    res = DESIGNS.create(did).design(plant, c)
    assert res.status == "feasible", res.reason
    assert radius(plant.A + plant.B @ res.F) < 1 and radius(plant.A - res.K @ plant.C) < 1
    cert = res.certificate
    assert cert["level"] == ("paper" if did.startswith("thm1") else "full")
    r = cert["contraction"]
    assert 0 < r < 1 and cert["decay_rate"] == pytest.approx(-math.log(r) / plant.dt)
    kind = "osl_qib" if did.startswith("thm1") else "lipschitz"
    assert certificate_holds(plant, res, class_members(plant, c, kind, np.random.default_rng(1)))
    # a flipped sign of the feedback is not certified by the same P (the check can fail)
    bad = type(res)(status="feasible", K=res.K, F=-res.F, certificate=cert)
    assert not certificate_holds(plant, bad, [np.zeros((4, 4))])


def test_discrete_theorem1_on_a_coarser_step(catalog_constants):
    plant, c = discretised_link(1e-2)
    res = DESIGNS.create("thm1").design(plant, c)
    assert res.status == "feasible", res.reason
    assert certificate_holds(plant, res, class_members(plant, c, "osl_qib", np.random.default_rng(2)))


def test_discrete_structured_certified_and_its_rate_tends_to_the_continuous_one(link3):
    plant, c = link3
    res = DESIGNS.create("structured", rtol=0.01).design(plant, c)
    assert res.status == "feasible", res.reason
    assert radius(plant.A + plant.B @ res.F) < 1 and radius(plant.A - res.K @ plant.C) < 1
    members = [s * plant.channels.G @ plant.channels.H for s in np.linspace(-C_GRAV, C_GRAV, 9)]
    assert certificate_holds(plant, res, members)
    # the gain bound: ||F|| and the Euler-equivalent ||K|| / dt within max_gain = 20
    assert np.linalg.norm(res.F, 2) <= 20 * (1 + 1e-6) and np.linalg.norm(res.K, 2) / plant.dt <= 20 * (1 + 1e-6)
    cont = DESIGNS.create("structured", rtol=0.01).design(PLANTS.create("flexible_link"), None)
    lam_c, lam_d = cont.params["decay_target"], res.params["decay_target"]
    assert abs(lam_d - lam_c) <= 0.10 * lam_c, (lam_d, lam_c)
    # the certificate proves the target's rate per second (to the bisection's resolution)
    assert res.certificate["decay_rate"] >= 0.99 * lam_d


def test_structured_riccati_route_has_no_discrete_form(link3):
    plant, c = link3
    res = DESIGNS.create("structured", route="riccati").design(plant, c)
    assert res.status == "inapplicable" and "discrete" in res.reason
