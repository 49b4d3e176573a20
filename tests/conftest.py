import bench._env  # noqa: F401  (BLAS and Rayon threads before numpy and Clarabel; see bench/_env.py)
import numpy as np
import pytest

from bench.constants import compute_constants
from bench.registry import PLANTS


@pytest.fixture(scope="session")
def catalog_constants():
    """``get(pid, seed=0, n_samples=20000, **plant_kw)``: ``compute_constants(PLANTS.create(pid, **plant_kw),
    seed=seed, n_samples=n_samples)``, computed once per session for each argument set (the sampler is
    seeded, so a second computation gives the same report). For tests whose subject is not the constants."""
    reports = {}

    def get(pid, *, seed=0, n_samples=20000, **plant_kw):
        key = (pid, seed, n_samples, tuple(sorted(plant_kw.items())))
        if key not in reports:
            reports[key] = compute_constants(PLANTS.create(pid, **plant_kw), seed=seed, n_samples=n_samples)
        return reports[key]

    return get


@pytest.fixture(scope="session")
def paper_gains_report(tmp_path_factory):
    """``copy_to(folder)``: the report of ``python -m bench run -q -j 1 --no-figures --plant flexible_link
    --design paper_gains``, run once per session, copied into ``folder/rep`` with its cache beside it
    (``folder/.bench-cache``); returns ``folder/rep``. For tests that start from a finished run (its report
    names the folder it was written to, so a test comparing report bytes across runs makes its own)."""
    import shutil

    from bench.cli import main

    made = []

    def copy_to(folder):
        if not made:
            base = tmp_path_factory.mktemp("paper_gains_report")
            assert main(["run", "-q", "-j", "1", "--no-figures", "--plant", "flexible_link", "--design",
                         "paper_gains", "--out", str(base / "rep")]) == 0
            made.append(base)
        shutil.copytree(made[0], folder, dirs_exist_ok=True)
        return folder / "rep"

    return copy_to


@pytest.fixture(scope="session")
def flex():
    return PLANTS.create("flexible_link")


@pytest.fixture(scope="session")
def flex_constants(catalog_constants):
    return catalog_constants("flexible_link")


@pytest.fixture(scope="session")
def flex_knowledge(flex, flex_constants):
    """What the certificate may trust about the flexible link (analytic constants, channels)."""
    return flex_constants.knowledge(flex)


@pytest.fixture(scope="session")
def designed(flex, flex_constants):
    """Results of the LMI designs on the flexible link, computed once."""
    from bench.registry import DESIGNS

    return {d: DESIGNS.create(d).design(flex, flex_constants.used) for d in ("thm1", "cor1", "thm1_printed",
                                                                               "cor1_printed")}


def hurwitz(M):
    return float(np.linalg.eigvals(M).real.max()) < 0


# -- independent rebuilds of the paper's matrices (numpy and cvxpy, written from the paper and docs/paper.md) ----
# Nothing below imports the suite's LMI code: these are the tests' own readings of the formulas.

def _stack(blocks, numeric):
    if numeric:
        return np.block(blocks)
    import cvxpy as cp

    return cp.bmat(blocks)


def equilibrated_max_eig(M):
    """Largest eigenvalue of ``D M D``, ``D = diag(|M_ii|^-1/2)`` (same inertia as M by Sylvester's law;
    +inf when a diagonal entry is >= 0, since M is then not negative definite)."""
    M = (np.asarray(M, dtype=float) + np.asarray(M, dtype=float).T) / 2
    d = np.diag(M)
    if np.any(d >= 0):
        return float("inf")
    s = 1 / np.sqrt(-d)
    return float(np.linalg.eigvalsh(M * s[:, None] * s[None, :])[-1])


def paper20_blocks(v, lam, numeric):
    """The paper's (20) with a decay rate: ``V = x'Px + e'Re``, multipliers eps1..eps4 of (16)-(19),
    ``V' + 2 lam V <= xi' M xi`` for ``xi = (x, e, f, f - f_hat)``; the pair is certified at rate
    ``lam`` when M < 0 with P, R > 0 and eps >= 0."""
    A, B, C, K, F = v["A"], v["B"], v["C"], v["K"], v["F"]
    P, R = v["P1"], v["P2"]
    rho, beta, gamma = v["rho"], v["beta"], v["gamma"]
    e1, e2, e3, e4 = v["eps1"], v["eps2"], v["eps3"], v["eps4"]
    n = A.shape[0]
    I, Z = np.eye(n), np.zeros((n, n))
    Ax, Ae = A + B @ F, A - K @ C
    eta1, eta2, eta3 = 2 * (e1 * rho + e2 * beta), e2 * gamma - e1, e4 * gamma - e3
    S11 = Ax.T @ P + P @ Ax + eta1 * I + 2 * lam * P
    S22 = Ae.T @ R + R @ Ae + 2 * (e3 * rho + e4 * beta) * I + 2 * lam * R
    S12 = -P @ B @ F
    S13 = P + eta2 * I
    S24 = R + eta3 * I
    blocks = [[S11, S12, S13, Z],
              [S12.T, S22, Z, S24],
              [S13.T, Z, -2 * e2 * I, Z],
              [Z, S24.T, Z, -2 * e4 * I]]
    return _stack(blocks, numeric)


def paper20_certificate(plant, K, F, constants, lam):
    """Search P, R, eps1..eps4 for the paper's (20) at rate ``lam`` (cvxpy + Clarabel, trace(P) + trace(R) = 1)
    and return ``(equilibrated max eig of the numpy-rebuilt matrix, min eig P, min eig R)``."""
    import cvxpy as cp

    n = plant.n
    v = {"A": plant.A, "B": plant.B, "C": plant.C, "K": np.asarray(K, float), "F": np.asarray(F, float),
         "rho": constants.rho, "beta": constants.beta, "gamma": constants.gamma}
    var = {"P1": cp.Variable((n, n), symmetric=True), "P2": cp.Variable((n, n), symmetric=True),
           **{f"eps{i}": cp.Variable(nonneg=True) for i in range(1, 5)}}
    t = cp.Variable()
    M = paper20_blocks({**v, **var}, lam, numeric=False)
    M = (M + M.T) / 2
    cons = [M << -t * np.eye(4 * n), var["P1"] >> t * np.eye(n), var["P2"] >> t * np.eye(n),
            cp.trace(var["P1"]) + cp.trace(var["P2"]) == 1]
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "solution may be inaccurate": the numpy check decides
        cp.Problem(cp.Maximize(t), cons).solve(solver=cp.CLARABEL)
    if any(x.value is None for x in var.values()):
        return float("inf"), float("nan"), float("nan")
    num = {k: (np.array(x.value, dtype=float) if np.ndim(x.value) else float(x.value)) for k, x in var.items()}
    Mn = paper20_blocks({**v, **num}, lam, numeric=True)
    return (equilibrated_max_eig(Mn), float(np.linalg.eigvalsh(num["P1"])[0]),
            float(np.linalg.eigvalsh(num["P2"])[0]))


def thm1_joint_blocks(v, numeric):
    """docs/paper.md's corrected Theorem 1 (gamma >= 0), 6n x 6n, as printed there::

        [ S11+kappa I  0        0        B Fh'    0        Q                   ]
        [ 0            S22      R+eta3 I 0        I        0                   ]
        [ 0            *        -2eps4 I 0        0        0                   ]
        [ Fh B'        0        0        -Q/phi1  0        0                   ]
        [ 0            I        0        0        -phi1 Q  0                   ]
        [ Q            0        0        0        0        -(kappa/beta_eff) I ]

    S11 = AQ + QA' + B Fh' + Fh B', S22 = A'R + RA - C'Kh - Kh'C + 2(eps3 rho + eps4 beta) I,
    eta3 = eps4 gamma - eps3, beta_eff = beta + gamma rho.
    """
    A, B, C = v["A"], v["B"], v["C"]
    Q, R, Fh, Kh = v["Q"], v["R"], v["Fh"], v["Kh"]
    kappa, e3, e4, phi = v["kappa"], v["eps3"], v["eps4"], v["phi"]
    rho, beta, gamma = v["rho"], v["beta"], v["gamma"]
    n = A.shape[0]
    I, Z = np.eye(n), np.zeros((n, n))
    beff = beta + gamma * rho
    S11 = A @ Q + Q @ A.T + B @ Fh.T + Fh @ B.T
    S22 = A.T @ R + R @ A - C.T @ Kh - Kh.T @ C + 2 * (e3 * rho + e4 * beta) * I
    X = R + (e4 * gamma - e3) * I
    BF = B @ Fh.T
    blocks = [[S11 + kappa * I, Z, Z, BF, Z, Q],
              [Z, S22, X, Z, I, Z],
              [Z, X.T, -2 * e4 * I, Z, Z, Z],
              [BF.T, Z, Z, -Q / phi, Z, Z],
              [Z, I, Z, Z, -phi * Q, Z],
              [Q, Z, Z, Z, Z, -(kappa / beff) * I]]
    return _stack(blocks, numeric)


def cor1_joint_blocks(v, numeric):
    """docs/paper.md's corrected Corollary 1, 6n x 6n, as printed there::

        [ S11+kappa I  0     0      Q                  B Fh'    0        ]
        [ 0            W22   R      0                  0        I        ]
        [ 0            R     -mu2 I 0                  0        0        ]
        [ Q            0     0      -(kappa/alpha^2) I 0        0        ]
        [ Fh B'        0     0      0                  -Q/phi2  0        ]
        [ 0            I     0      0                  0        -phi2 Q  ]

    W22 = A'R + RA - C'Kh - Kh'C + mu2 alpha^2 I.
    """
    A, B, C = v["A"], v["B"], v["C"]
    Q, R, Fh, Kh = v["Q"], v["R"], v["Fh"], v["Kh"]
    kappa, mu2, phi, a2 = v["kappa"], v["mu2"], v["phi"], v["alpha"] ** 2
    n = A.shape[0]
    I, Z = np.eye(n), np.zeros((n, n))
    S11 = A @ Q + Q @ A.T + B @ Fh.T + Fh @ B.T
    W22 = A.T @ R + R @ A - C.T @ Kh - Kh.T @ C + mu2 * a2 * I
    BF = B @ Fh.T
    blocks = [[S11 + kappa * I, Z, Z, Q, BF, Z],
              [Z, W22, R, Z, Z, I],
              [Z, R, -mu2 * I, Z, Z, Z],
              [Q, Z, Z, -(kappa / a2) * I, Z, Z],
              [BF.T, Z, Z, Z, -Q / phi, Z],
              [Z, I, Z, Z, Z, -phi * Q]]
    return _stack(blocks, numeric)


def joint_holds_for_gains(kind, plant, K, F, constants, phi, cap=1e3):
    """Do the gains (K, F) satisfy docs/paper.md's corrected Theorem 1 (``kind="thm1"``, gamma >= 0,
    beta_eff > 0) or Corollary 1 (``"cor1"``, alpha > 0) at Young weight ``phi``?

    With K, F fixed, ``Fh = Q F'`` and ``Kh = K' R`` make the 6n matrix linear in Q, R and the
    multipliers: search them (cvxpy + Clarabel, ``Q, R << cap I``), rebuild the matrix with numpy
    at the solution and return ``(equilibrated max eig, min eig Q, min eig R)``.
    """
    import cvxpy as cp

    n = plant.n
    K, F = np.asarray(K, float), np.asarray(F, float)
    Q, R = cp.Variable((n, n), symmetric=True), cp.Variable((n, n), symmetric=True)
    if kind == "thm1":
        assert constants.beta + constants.gamma * constants.rho > 0 and constants.gamma >= 0
        names, blocks = ("kappa", "eps3", "eps4"), thm1_joint_blocks
        base = {"rho": constants.rho, "beta": constants.beta, "gamma": constants.gamma}
    else:
        assert constants.alpha > 0
        names, blocks = ("kappa", "mu2"), cor1_joint_blocks
        base = {"alpha": constants.alpha}
    base.update(A=plant.A, B=plant.B, C=plant.C, phi=phi)
    sc = {k: cp.Variable(nonneg=True) for k in names}
    t = cp.Variable()
    M = blocks({**base, "Q": Q, "R": R, "Fh": Q @ F.T, "Kh": K.T @ R, **sc}, numeric=False)
    M = (M + M.T) / 2
    cons = [M << -t * np.eye(6 * n), Q >> t * np.eye(n), R >> t * np.eye(n), Q << cap * np.eye(n),
            R << cap * np.eye(n), t <= 1]
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "solution may be inaccurate": the numpy check decides
        cp.Problem(cp.Maximize(t), cons).solve(solver=cp.CLARABEL)
    if Q.value is None or R.value is None:
        return float("inf"), float("nan"), float("nan")
    Qn, Rn = np.array(Q.value), np.array(R.value)
    num = {**base, "Q": Qn, "R": Rn, "Fh": Qn @ F.T, "Kh": K.T @ Rn, **{k: float(x.value) for k, x in sc.items()}}
    Mn = blocks(num, numeric=True)
    return equilibrated_max_eig(Mn), float(np.linalg.eigvalsh(Qn)[0]), float(np.linalg.eigvalsh(Rn)[0])


def gains_satisfy_joint_lmi(kind, plant, K, F, constants, phis=(1e-3, 1e-2, 1e-1)):
    """True when, at some Young weight of ``phis``, :func:`joint_holds_for_gains` verifies with numpy:
    the joint matrix is negative definite and Q, R are positive definite."""
    for phi in phis:
        margin, qmin, rmin = joint_holds_for_gains(kind, plant, K, F, constants, phi)
        if margin < -1e-7 and qmin > 0 and rmin > 0:
            return True
    return False


def thm1_synthesis_margin(plant, constants, phi, cap=1e3):
    """The test's own solve of docs/paper.md's corrected Theorem 1 (gamma >= 0) as a synthesis LMI at a fixed
    Young weight: max t s.t. M(Q, R, Fh, Kh, kappa, eps3, eps4) << -t I, Q, R >> t I, Q, R << cap I,
    t <= 1. Returns t (> 0: strictly feasible under this normalisation; < 0: not)."""
    import warnings

    import cvxpy as cp

    n, m, p = plant.n, plant.m, plant.p
    v = {"Q": cp.Variable((n, n), symmetric=True), "R": cp.Variable((n, n), symmetric=True),
         "Fh": cp.Variable((n, m)), "Kh": cp.Variable((p, n)),
         **{k: cp.Variable(nonneg=True) for k in ("kappa", "eps3", "eps4")}}
    t = cp.Variable()
    M = thm1_joint_blocks({**v, "A": plant.A, "B": plant.B, "C": plant.C, "phi": phi, "rho": constants.rho,
                           "beta": constants.beta, "gamma": constants.gamma}, numeric=False)
    M = (M + M.T) / 2
    cons = [M << -t * np.eye(6 * n), t <= 1]
    for X in (v["Q"], v["R"]):
        cons += [X >> t * np.eye(n), X << cap * np.eye(n)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        cp.Problem(cp.Maximize(t), cons).solve(solver=cp.CLARABEL)
    return float(t.value)


# -- the closed loop, written here from (1) and (6) --------------------------------------------------------
def jacobian_at_zero(f, n, h=1e-6):
    """Central differences of f at 0 (the test's own, not the plant's jacobian)."""
    J = np.zeros((n, n))
    for j in range(n):
        e = np.zeros(n)
        e[j] = h
        J[:, j] = (f(e) - f(-e)) / (2 * h)
    return J


def linearised_rate(plant, K, F):
    """-max Re eig of A + Df(0) + BF and A + Df(0) - KC (the loop in (x, e) linearised at 0)."""
    A = plant.A + jacobian_at_zero(plant.f, plant.n)
    eig = np.concatenate([np.linalg.eigvals(A + plant.B @ F), np.linalg.eigvals(A - K @ plant.C)])
    return float(-eig.real.max())


def closed_loop(plant, K, F):
    """The closed loop (1) + (6) in (x, x_hat), for scipy's integrator."""
    n = plant.n

    def rhs(_, z):
        x, xh = z[:n], z[n:]
        u = F @ xh
        dx = plant.A @ x + plant.B @ u + plant.f(x)
        dxh = plant.A @ xh + plant.B @ u + plant.f(xh) + K @ (plant.C @ (x - xh))
        return np.concatenate([dx, dxh])

    return rhs
