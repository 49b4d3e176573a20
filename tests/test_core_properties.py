"""Properties of the core whose failure a plausible bug (a flipped sign, the wrong constant, or for and)
would cause, each against an expectation derived independently of the code."""

import math

import numpy as np
import pytest

from bench.certify import certify
from bench.constants import Knowledge, compute_constants
from bench.pipeline import DesignResult, RunOptions, Scenario, evaluate_pair
from designs import Design
from plants import Channels, Constants, Plant

SCALAR = dict(A=[[0.0]], B=[[1.0]], C=[[1.0]])


def test_the_osl_constraint_keeps_its_sign_in_the_certificate():
    # f = -x: rho = -1 (<df, dx> = -|dx|^2) and |df|^2 <= 1 |dx|^2 (beta = 1, gamma = 0). Together they
    # admit only df = -dx, so the certificate sees the linear loop x' = -x + u: with F = -1, K = 1 both
    # A - 1 + BF and A - 1 - KC are -2, the loop's exact rate. A certificate rate is at most 2, and a
    # full P certifies (the loop is stable); an OSL term of the wrong sign would describe f = +x
    # (A + 1 + BF = 0: not exponentially stable), and certify nothing
    plant = Plant(id="minus_x", **SCALAR, f=lambda x: -np.asarray(x, dtype=float), x0=[1.0], x_hat0=[0.0])
    know = Knowledge(Constants(rho=-1.0, beta=1.0, gamma=0.0))
    cert = certify(plant, [[1.0]], [[-1.0]], know, levels=("paper", "full"))
    for lv in ("paper", "full"):
        r = cert.levels[lv]
        assert r.certified, (lv, r.reason)
        assert 0.5 < r.decay_rate <= 2.0 * (1 + 1e-6), (lv, r.decay_rate)


def test_a_claimed_qib_pair_is_checked_at_its_own_gamma():
    # f = -x/2 (scalar): (|df|^2 - g <dx, df>) / |dx|^2 = 1/4 + g/2. Analytic (beta, gamma) = (1/4, 0);
    # the source claims (beta, gamma) = (0.6, 1), true only at gamma = 0: at gamma = 1 the supremum is
    # 3/4 > 0.6. Checked at the analytic gamma the claim would pass (1/4 <= 0.6)
    plant = Plant(id="half", **SCALAR, f=lambda x: -0.5 * np.asarray(x, dtype=float), x0=[1.0], x_hat0=[0.0],
                  bounds=Constants(alpha=0.5, rho=-0.5, beta=0.25, gamma=0.0),
                  claimed=Constants(beta=0.6, gamma=1.0))
    rep = compute_constants(plant, n_samples=500)
    v = rep.violated("beta")
    assert v is not None and v.sampled == pytest.approx(0.75, rel=1e-6)


def _Fixed(K, F):
    """A test design returning the given gains K, F."""

    class Given(Design):
        def applicable(self, plant, constants):
            return None

        def design(self, plant, constants):
            return DesignResult(status="given", K=np.asarray(K, dtype=float), F=np.asarray(F, dtype=float))

    return Given()


@pytest.mark.parametrize("K, F, x_stable, e_stable", [([[3.0]], [[-2.0]], True, True), ([[3.0]], [[0.5]], False, True),
                                                      ([[-1.0]], [[-2.0]], True, False)])
def test_stabilizing_needs_both_closed_loops_hurwitz(K, F, x_stable, e_stable):
    # A = 0, B = C = 1: A + BF = F, A - KC = -K (eigenvalues by hand)
    plant = Plant(id="lin", **SCALAR, f=lambda x: 0 * np.asarray(x, dtype=float), x0=[1.0], x_hat0=[0.0])
    rep = compute_constants(plant, n_samples=100)
    rec = evaluate_pair(plant, _Fixed(K, F), rep, RunOptions(n_samples=100, simulate=False,
                                                             certificate="none")).record
    assert rec["stabilizing"] is (x_stable and e_stable)


def test_a_batch_converges_only_when_every_member_does():
    # x' = u + f(x), f(x) = 2 sign(x) max(|x| - 1, 0), with x_hat0 = x0 (e = 0 for good) and u = -x_hat:
    # x' = -x for |x| <= 1 and x' = x - 2 sign(x) beyond, so x = +-2 are unstable equilibria: from
    # |x0| < 2 the state converges, from |x0| > 2 it grows like e^t
    def f(x):
        x = np.asarray(x, dtype=float)
        return 2.0 * np.sign(x) * np.maximum(np.abs(x) - 1.0, 0.0)

    plant = Plant(id="dead_zone", **SCALAR, f=f, x0=[0.5], x_hat0=[0.5], t_final=30.0)
    rep = compute_constants(plant, n_samples=100)
    opts = RunOptions(n_samples=100, certificate="none")
    design = _Fixed([[2.0]], [[-1.0]])
    good = Scenario(x0=np.array([[0.5, -1.5]]), x_hat0=np.array([[0.5, -1.5]]))
    both = Scenario(x0=np.array([[0.5, 3.0]]), x_hat0=np.array([[0.5, 3.0]]))
    assert evaluate_pair(plant, design, rep, opts, scenario=good).record["converged"] is True
    out = evaluate_pair(plant, design, rep, opts, scenario=both)
    assert out.metrics["converged"].tolist() == [True, False]
    assert out.record["converged"] is False


def test_a_failing_joint_certificate_leaves_the_structured_design_undecided(monkeypatch):
    import designs.structured as st

    # the pendulum-like plant the structured design solves; then its joint check is made to fail
    plant = Plant(id="pend", A=[[0.0, 1.0], [0.0, -1.0]], B=[[0.0], [1.0]], C=[[1.0, 0.0]],
                  f=lambda x: np.stack([0 * np.asarray(x)[0], -0.5 * np.sin(np.asarray(x)[0])]),
                  x0=[1.0, 0.0], x_hat0=[0.0, 0.0],
                  channels=Channels(G=[[0.0], [1.0]], H=[[1.0, 0.0]], phi=lambda z: -0.5 * np.sin(z), lo=-0.5,
                                    hi=0.5))
    ok = st.Structured().design(plant, Constants())
    assert ok.status == "feasible" and ok.certificate is not None
    monkeypatch.setattr(st.joint, "verdict", lambda M, **kw: "violated")  # the joint matrix is not negative definite
    res = st.Structured().design(plant, Constants())
    assert res.status == "undecided" and res.certificate is None


def test_theorem_1_uses_beta_in_its_e_side():
    # rho = 0.5 > sqrt(beta) = 0 (f = x/2 has (|df|^2 - gamma <dx, df>) / |dx|^2 = 1/4 - gamma/2 = 0 at
    # gamma = 1/2), so alpha^2 = 1/4 != beta = 0 and rho^2 != beta: the paper's e-side block
    # S22 = A'R + RA - C'Kh - Kh'C + 2 (eps3 rho + eps4 beta) I and the Schur weight
    # kappa / (beta + gamma rho) are computed by hand
    from designs.thm1 import Thm1

    A = np.array([[0.0, 1.0], [-2.0, -3.0]])
    C = np.array([[1.0, 0.0]])
    plant = Plant(id="half_up", A=A, B=[[0.0], [1.0]], C=C, f=lambda x: 0.5 * np.asarray(x, dtype=float),
                  x0=[1.0, 0.0], x_hat0=[0.0, 0.0])
    c = Constants(alpha=0.5, rho=0.5, beta=0.0, gamma=0.5)
    form = Thm1().form(plant, c)
    R = np.array([[2.0, 0.3], [0.3, 1.0]])
    Kh = np.array([[0.7, 0.2]])  # (p, n)
    d = {**form.constants, "A": A, "B": plant.B, "C": C, "R": R, "Kh": Kh, "eps3": 0.4, "eps4": 1.3,
         "Q": np.eye(2), "Fh": np.zeros((2, 1)), "kappa": 0.9, "phi": 1.0, "iphi": 1.0}
    (E11, E12), _ = form.blocks[2](d)
    want = A.T @ R + R @ A - C.T @ Kh - Kh.T @ C + 2 * (0.4 * 0.5 + 1.3 * 0.0) * np.eye(2)
    np.testing.assert_allclose(np.asarray(E11), want, atol=1e-12)
    np.testing.assert_allclose(np.asarray(E12), R + (1.3 * 0.5 - 0.4) * np.eye(2), atol=1e-12)
    x_blocks = form.blocks[1](d)
    np.testing.assert_allclose(np.asarray(x_blocks[1][1]), -0.9 / (0.0 + 0.5 * 0.5) * np.eye(2), atol=1e-12)
