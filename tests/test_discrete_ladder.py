"""The certificate ladder in discrete time (a plant with dt > 0): V(z_{k+1}) <= r^2 V(z_k) over the class, written
in the delta form (bench.lyapunov), reported as the contraction factor r per step and the rate -ln(r)/dt per second.

Independent expectations:

- the delta form is exact: its Schur complement is the plain condition ``[Acl, Gb]' P [Acl, Gb] - diag(r^2 P, 0)
  + sum tau Pi`` (congruence by ``diag(I, W)`` and division by dt), checked entry by entry with numpy;
- a linear loop (constants 0) has quadratic certificates for every r above its spectral radius and none below,
  so the certified contraction lies on the grid just above the spectral radius (numpy's eigenvalues);
- the witnesses are those of the map: a linear member of the class whose loop has spectral radius >= 1, a fixed
  point ``z = Phi(z)`` besides the origin (checked by evaluating the map), and the determinant test proves there is
  none when the slopes cannot make ``M - I`` singular (for a one-state loop: by hand);
- a false certificate (a rate above the true one, a contraction that is not exp(-lam dt)) is refused, and the
  decay along the steps ``V(z_k) <= r^(2k) V(z_0)`` fails for a false rate;
- agreement in the limit: with the same gains, the zoh-discretised flexible link's loop is ``I + h Acl + O(h^2)``,
  and its certified rate tends to the continuous one (within 1 % at h = 1 ms, measured equal on the grid; 2 % at
  h = 10 ms); the discrete structured design's certified rate tends to the continuous design's (within 1 % at
  h = 0.1 ms, measured equal on the grid; +5 % at 1 ms).
"""

import dataclasses
import math

import control
import numpy as np
import pytest
from scipy.linalg import expm

from bench import certify, checks, lyapunov, witness
from bench.constants import Knowledge, compute_constants, resolve_constants
from bench.pipeline import RunOptions, _lyapunov, evaluate_pair
from bench.registry import DESIGNS, PLANTS
from bench.simulate import SimOptions, simulate_controller
from designs import Design, DesignResult
from plants import Channels, Constants, Plant


def oscillator(dt):
    """x'' = -4 x - 0.4 x' + u (f = 0, every constant 0), zoh-discretised."""
    A = np.array([[0.0, 1.0], [-4.0, -0.4]])
    B = np.array([[0.0], [1.0]])
    p = Plant(id="osc", A=A, B=B, C=np.array([[1.0, 0.0]]), f=lambda x: np.zeros_like(np.asarray(x, dtype=float)),
              x0=np.array([1.0, 0.0]), x_hat0=np.zeros(2), t_final=20.0,
              bounds=Constants(alpha=0.0, rho=0.0, beta=0.0, gamma=0.0))
    return p.discretise(dt, "zoh")


def dlqg(p):
    G, _, _ = control.dlqr(p.A, p.B, 0.1 * np.eye(p.n), np.eye(p.m))
    L, _, _ = control.dlqe(p.A, np.eye(p.n), p.C, 1e-3 * np.eye(p.n), np.eye(p.p))
    return p.A @ L, -G


def radius(p, K, F):
    """The spectral radius of the linear loop (block triangular: of A + B F and A - K C)."""
    return max(np.abs(np.linalg.eigvals(p.A + p.B @ F)).max(), np.abs(np.linalg.eigvals(p.A - K @ p.C)).max())


def certify_pair(p, K, F, know=None):
    know = Knowledge.trusting(p) if know is None else know
    return certify.certify(p, K, F, know, loop=checks.closed_loop(p, K, F))


# -- the matrix -----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("level,channels", [("full", False), ("structured", True)])
def test_the_delta_form_is_the_plain_discrete_condition(level, channels):
    p = PLANTS.create("flexible_link").discretise(0.01, "zoh")
    res = DESIGNS.create("lqr+lqe").design(p, p.bounds)
    know = Knowledge.trusting(p)
    spec, _ = certify._spec(level, p.n, know)
    spec = dataclasses.replace(spec, discrete=True)
    data = lyapunov.level_data(spec, p.A, p.B, p.C, res.K, res.F, know, dt=p.dt)
    plain = lyapunov.level_data(dataclasses.replace(spec, discrete=False), p.A, p.B, p.C, res.K, res.F, know)
    rng = np.random.default_rng(3)
    X = rng.standard_normal((2 * p.n, 2 * p.n))
    P = X @ X.T + np.eye(2 * p.n)
    tau = rng.uniform(0.1, 2.0, len(spec.multipliers))
    lam, h = 0.7, p.dt
    r2 = math.exp(-2 * lam * h)
    M = lyapunov.matrix(spec, {**lyapunov.values(spec, data), "P": h * P, "tau": tau,
                               "lam": lyapunov.measure(lam, h)})[0][0]
    N, k = spec.size, 2 * p.n
    Schur = M[:N, :N] - M[:N, N:] @ np.linalg.solve(M[N:, N:], M[N:, :N])
    # the plain condition in (z, w), with the delta form's constraints taken back to w
    W = 1.0 if channels else h
    Pi_hat = plain.Pi * np.concatenate([np.ones(k), W * np.ones(N - k)])[None, :, None] \
        * np.concatenate([np.ones(k), W * np.ones(N - k)])[None, None, :]
    scale = np.abs(Pi_hat).reshape(len(Pi_hat), -1).max(axis=1)
    T = np.hstack([plain.Acl, plain.Gb])
    Q = T.T @ P @ T
    Q[:k, :k] -= r2 * P
    Q += np.einsum("k,kij->ij", tau / scale, plain.Pi)
    S = np.diag(np.concatenate([np.ones(k), W * np.ones(N - k)]))
    np.testing.assert_allclose(Schur, S @ Q @ S, rtol=1e-8, atol=1e-8 * np.abs(Schur).max())
    assert M.shape == (spec.dim, spec.dim) and np.allclose(M[N:, N:], -h * P)


def test_the_measure_is_the_rate_per_second():
    h = 0.01
    for lam in (0.0, 0.3, 5.0):
        m = lyapunov.measure(lam, h)
        assert m == pytest.approx((1 - math.exp(-2 * lam * h)) / (2 * h), rel=1e-12)
        assert lyapunov.rate_of(m, h) == pytest.approx(lam, rel=1e-9, abs=1e-15)
    assert lyapunov.measure(0.3, 1e-9) == pytest.approx(0.3, rel=1e-6)  # the continuous limit
    assert lyapunov.rate_of(1 / (2 * h), h) == math.inf  # a deadbeat loop


# -- certified rates --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("dt", [0.01, 0.001])
def test_a_linear_loops_certified_contraction_is_its_spectral_radius(dt):
    p = oscillator(dt)
    K, F = dlqg(p)
    rho = radius(p, K, F)
    cert = certify_pair(p, K, F)
    best = cert.best
    assert best.level == "full" and best.dt == dt
    r = best.contraction
    assert r == pytest.approx(math.exp(-best.decay_rate * dt), rel=1e-12)
    lin = -math.log(rho) / dt
    assert lin / 1.01 <= best.decay_rate <= lin  # the grid point just below the spectral radius's rate
    assert rho <= r


def test_a_discrete_loop_is_certified_from_x0_where_no_global_certificate_exists():
    """The flexible-joint robot sampled at 10 ms with discrete LQR + Kalman gains: a linear member of the class is
    unstable (spectral radius > 1), and the narrowed slopes give a certificate whose level set through z0 stays in
    its region, as in continuous time."""
    p = PLANTS.create("flexible_joint_v1").discretise(0.01, "zoh")
    K, F = dlqg(p)
    rep = compute_constants(p, n_samples=2000, n_refine=0)
    know = rep.knowledge(p)
    loop = checks.closed_loop(p, K, F)
    cert = certify.explain(certify.certify(p, K, F, know, loop=loop), p, K, F, know, loop=loop)
    lin = [w for w in cert.witnesses if w.kind == "linear member"]
    assert lin and "spectral radius" in lin[0].text
    L = lin[0].L
    worst = max(np.abs(np.linalg.eigvals(p.A + L + p.B @ F)).max(), np.abs(np.linalg.eigvals(p.A + L - K @ p.C)).max())
    assert worst > 1
    assert cert.local is not None and cert.local.from_x0 and cert.local.dt == p.dt
    assert 0 < cert.local.contraction < 1


def test_the_cascade_rung_works_in_discrete_time():
    """V = x'Px x + mu e'Pe e from the two sides, each a discrete level with its own Schur rows: the joint P and
    multipliers are a point of the level's own (delta-form) matrix, which verifies, at a rate no larger than the
    level's own and than each side's."""
    from bench import lmi

    p = PLANTS.create("flexible_link_d10ms_v1")
    K, F = suite_lqg(p)
    know = Knowledge.trusting(p)
    spec, _ = certify._spec("structured", p.n, know)
    lv = certify._level(spec, p, K, F, know, 0.01)
    got = lyapunov.cascade(lv.spec, lv.data, checks.closed_loop(p, K, F).linearised_rate)
    assert got["P"] is not None and got["rate"] > 0
    Pi = lv.data.Pi.reshape(len(lv.data.Pi), -1).T
    M = lyapunov.matrix(lv.spec, lyapunov._values(lv.spec, got["P"], got["tau"], lv.data, Pi, got["rate"]))[0][0]
    assert M.shape == (lv.spec.dim, lv.spec.dim) and lmi.classify(lmi.max_eig(M), M) == "verified"
    assert got["rate"] <= min(got["side_rates"].values()) and got["rate"] <= certify_pair(p, K, F).decay_rate
    n = p.n
    assert np.allclose(got["P"][:n, n:], 0)  # block diagonal: a cascade


# -- witnesses ------------------------------------------------------------------------------------------------
def cubic_plant(c):
    """x_{k+1} = x_k + u_k + c x^3 / (1 + x^2), y = x (one state): phi(s) = c s^3 / (1 + s^2), slopes in
    [0, 9 c / 8] (the derivative c (s^4 + 3 s^2) / (1 + s^2)^2 peaks at s^2 = 3)."""
    phi = lambda z: c * np.asarray(z, float) ** 3 / (1 + np.asarray(z, float) ** 2)  # noqa: E731
    ch = Channels(G=np.eye(1), H=np.eye(1), phi=phi, lo=0.0, hi=9 * c / 8)
    return Plant(id="cubic", A=[[1.0]], B=[[1.0]], C=[[1.0]], f=lambda x: phi(x), x0=[0.5], x_hat0=[0.0], dt=1.0,
                 channels=ch, t_final=50.0)


def closed_map(p, K, F, z):
    x, e = z[:1], z[1:]
    xh = x - e
    return np.concatenate([(p.A + p.B @ F) @ x - p.B @ F @ e + p.f(x), (p.A - K @ p.C) @ e + p.f(x) - p.f(xh)])


GAINS = np.array([[1.0]]), np.array([[-0.5]])  # A - K C = 0, A + B F = 0.5


def test_a_fixed_point_of_the_map_and_an_unstable_member_are_witnesses():
    """With A + B F = 0.5, A - K C = 0 and c = 0.8: the member with slope 0.9 gives 1.4 (spectral radius > 1), and
    x = 0.5 x + 0.8 x^3 / (1 + x^2) at x^2 = 5/3 (e = 0) is a fixed point besides the origin."""
    p = cubic_plant(0.8)
    K, F = GAINS
    know = Knowledge.trusting(p)
    w = witness.linear_witness(p, K, F, know, channels=True, scalars=())
    assert w is not None and abs(w.eig) == pytest.approx(1.4, rel=1e-9)
    assert not witness.no_equilibrium(p, K, F, know)
    eq = witness.equilibrium_witness(p, K, F, know)
    assert eq is not None
    np.testing.assert_allclose(closed_map(p, K, F, eq.z), eq.z, atol=1e-9)
    assert np.linalg.norm(eq.z) > 0.1
    assert "fixed point of its map" in eq.text
    cert = certify_pair(p, K, F, know)
    assert not cert.certified and cert.levels["structured"].reason.startswith(certify.RULED_OUT)


def test_slopes_that_cannot_close_a_fixed_point_prove_there_is_none():
    """c = 0.2: slopes in [0, 0.225]; by hand the loop's map minus I with the secants d1 (at x), d2 (at x_hat) is
    [[-0.5 + d1, 0.5], [d1 - d2, -1 + d2]], determinant (0.5 - d1)(1 - d2) - 0.5 (d1 - d2): 0.5, 0.1625, 0.5 and
    0.213 at the vertices, one sign: no fixed point besides the origin."""
    p = cubic_plant(0.2)
    K, F = GAINS
    know = Knowledge.trusting(p)
    assert witness.no_equilibrium(p, K, F, know)
    assert witness.linear_witness(p, K, F, know, channels=True, scalars=()) is None
    cert = certify_pair(p, K, F, know)
    assert cert.levels["structured"].certified
    ceiling, _ = witness.rate_ceiling(p, K, F, know, channels=True, scalars=())
    assert ceiling == pytest.approx(-math.log(0.5 + 9 * 0.2 / 8), rel=1e-6)  # the member with the largest slope
    assert cert.levels["structured"].decay_rate <= ceiling


# -- false certificates ---------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, kw_only=True)
class Claims(Design):
    """The suite's discrete lqr+lqe gains with a certificate of the test's choosing."""

    cert: dict = None
    time_domains = ("discrete",)

    def design(self, plant, constants):
        res = DESIGNS.create("lqr+lqe").design(plant, constants)
        return dataclasses.replace(res, certificate=self.cert)


def suite_lqg(p):
    res = DESIGNS.create("lqr+lqe").design(p, p.bounds)
    return res.K, res.F


def test_a_false_discrete_certificate_is_refused():
    p = PLANTS.create("flexible_link_d10ms_v1")
    K, F = suite_lqg(p)
    know = Knowledge.trusting(p)
    loop = checks.closed_loop(p, K, F)
    true = certify_pair(p, K, F, know).levels["structured"]
    assert true.certified
    good = {"level": "structured", "P": true.P, "decay_rate": true.decay_rate, "contraction": true.contraction}
    got, why = certify.verify_certificate(good, p, loop, know)
    assert got is not None and got.contraction == pytest.approx(true.contraction) and why == ""
    lam = loop.linearised_rate
    for bad, says in (({"decay_rate": 1.5 * lam, "contraction": math.exp(-1.5 * lam * p.dt)}, "exceeds the rate"),
                      ({"contraction": true.contraction ** 2}, "is not exp(-decay_rate dt)"),
                      ({"P": -true.P}, "not positive definite"),
                      ({"decay_rate": 0.999 * lam, "contraction": math.exp(-0.999 * lam * p.dt)}, "")):
        got, why = certify.verify_certificate({**good, **bad}, p, loop, know)
        assert got is None and says in why
    # through the pipeline: the design's rate above the linearisation is refused, the row says so
    rep = compute_constants(p, n_samples=500, n_refine=0)
    claim = {**good, "decay_rate": 1.5 * lam, "contraction": math.exp(-1.5 * lam * p.dt)}
    rec = evaluate_pair(p, Claims(cert=claim), rep, RunOptions(n_samples=500), design_id="claims").record
    assert "the design's certificate is refused" in rec["reason"] and rec["decay_rate"] < lam


@pytest.mark.xfail(strict=True, reason=(
    "known gap: the suite's multiplier search at a fixed P (certify._find_multipliers, delta form) does not find "
    "multipliers for the discrete structured design's own joint certificate above about 0.1 of its rate; the "
    "ladder certifies the same gains on its own (refusing is the safe direction)"))
def test_the_discrete_structured_designs_own_certificate_is_verified():
    p = PLANTS.create("flexible_link_d10ms_v1")
    own = DESIGNS.create("structured").design(p, p.bounds)
    assert own.status == "feasible" and own.certificate["contraction"] < 1
    got, why = certify.verify_certificate(own.certificate, p, checks.closed_loop(p, own.K, own.F),
                                          Knowledge.trusting(p))
    assert got is not None and why == "" and got.contraction == pytest.approx(own.certificate["contraction"])


def test_the_decay_along_the_steps_catches_a_false_discrete_rate():
    p = PLANTS.create("flexible_link_d10ms_v1", t_final=5.0)
    K, F = suite_lqg(p)
    best = certify_pair(p, K, F).best
    tr = simulate_controller(p, F, K=K, t_final=5.0)
    assert np.allclose(np.diff(tr.t), p.dt)  # the steps
    assert _lyapunov(tr, best, SimOptions()) == ""
    false = dataclasses.replace(best, decay_rate=3 * best.decay_rate)
    note = _lyapunov(tr, false, SimOptions())
    assert note.startswith("INCONSISTENT with the certificate: V(z(t)) exceeds")
    # the bound itself, by hand: V(z_k) <= r^(2k) V(z_0) at every step for the true certificate
    z = np.vstack([tr.x, tr.x - tr.x_hat])
    V = np.einsum("ik,ij,jk->k", z, best.P, z)
    k = np.arange(V.size)
    assert np.all(V <= best.contraction ** (2 * k) * V[0] * (1 + 1e-9))


# -- agreement in the limit -----------------------------------------------------------------------------------
def zoh_gamma(A, h):
    n = A.shape[0]
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n], M[:n, n:] = A, np.eye(n)
    return expm(h * M)[:n, n:]


def test_the_discrete_rate_of_the_same_gains_tends_to_the_continuous_one():
    """Continuous LQR + LQE gains on the flexible link, the same F and the observer injection K held over the
    step (``Gamma K``) on the zoh-discretised plant: the loop is ``I + h Acl + O(h^2)``. Measured: continuous
    0.8114 /s (structured level); discrete 0.7954 at h = 10 ms (-2.0 %), 0.8034 at 3 ms (-1.0 %), 0.8114 at
    1 ms (the same grid point)."""
    pc = PLANTS.create("flexible_link")
    res = DESIGNS.create("lqr+lqe").design(pc, pc.bounds)
    cont = certify_pair(pc, res.K, res.F).decay_rate
    for h, rtol in ((1e-3, 0.01), (1e-2, 0.03)):
        pd = pc.discretise(h, "zoh")
        disc = certify_pair(pd, zoh_gamma(pc.A, h) @ res.K, res.F).decay_rate
        assert abs(disc - cont) <= rtol * cont * (1 + 1e-9), (h, disc, cont)


def test_the_discrete_structured_design_tends_to_the_continuous_one():
    """The structured design itself, discrete (delta form) against continuous, each certified by the ladder.
    Measured: continuous 2.088 /s; discrete 2.523 (h = 10 ms), 2.195 (1 ms), 2.088 (0.1 ms: the same grid point)."""
    pc = PLANTS.create("flexible_link")
    rates = {}
    for h in (0.0, 1e-4):
        p = pc if h == 0 else pc.discretise(h, "zoh")
        rep = compute_constants(p, n_samples=500, n_refine=0)
        res = DESIGNS.create("structured").design(p, resolve_constants(rep))
        assert res.status == "feasible"
        rates[h] = certify_pair(p, res.K, res.F, rep.knowledge(p)).decay_rate
    assert abs(rates[1e-4] - rates[0.0]) <= 0.01 * rates[0.0] * (1 + 1e-9), rates
