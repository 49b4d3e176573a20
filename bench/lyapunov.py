"""One level of the certificate ladder as an LMI: its matrix, the coordinates it is solved in, its solve and its
rate search (:mod:`bench.certify` builds the ladder from these).

The matrix. With ``z = (x, e)``, ``xi = (z, w_x, w_e)``, the closed loop ``z' = Acl z + Gb w`` and the
quadratic constraints ``xi' Pi_k xi >= 0`` that f meets (:func:`level_data`), a level's matrix is ::

    M(P, tau; lam) = [[Acl' P + P Acl + 2 lam P, P Gb], [Gb' P, 0]] + sum_k tau_k Pi_k

(:func:`matrix`, the one place it is written, for numpy and cvxpy alike). The measure ``lam`` enters
affinely; :func:`matrix` is also where the level's other time axis (discrete time) and other measure (the L2 gain)
change it, below.

Coordinates. A level is solved in balanced coordinates ``z = T z~`` (:class:`Level`), T the diagonal similarity
that balances ``Acl`` (:func:`scipy.linalg.matrix_balance`, powers of 2, so the change is exact in floating
point): the congruence ``S = blkdiag(T, I)`` maps M to ``S' M S``, which is the same matrix built from
``Acl~ = T^-1 Acl T``, ``Gb~ = T^-1 Gb``, ``Pi_k~ = S' Pi_k S`` and ``P~ = T' P T`` (the multipliers unchanged).
A congruence keeps the inertia, so the class of certificates is unchanged (a diagonal T keeps a block-diagonal
P so); the margins and the normalisation are written in the original coordinates (``M~ << -slack S'S`` is
``M << -slack I``), so the program is the original one, its numbers balanced for the solver. Every verdict is
taken in the original coordinates: the solver's ``P~`` is mapped back to ``P = T^-T P~ T^-1`` and the matrix
rebuilt with numpy from the plant's own numbers (:attr:`bench.lmi.Program.original`, :func:`bench.lmi.classify`).

Normalisation. ``trace(P) = 1`` by default; a level whose best point is within the tolerance (or that no solver
solved) is solved again normalised by ``|M_ij|, |P_ij| <= 1`` (:attr:`Spec.norm`): its margin is then exactly
the one :func:`bench.lmi.classify` judges, which high gains (entries of ``P B F`` far above the margin) need.

Discrete time (:attr:`Spec.discrete`, a plant with ``dt > 0``: ``z_{k+1} = Acl z_k + Gb w_k``). A level proves
``V(z_{k+1}) <= r^2 V(z_k)`` over the class; with ``c = (1 - r^2) / dt`` the condition
``[Acl, Gb]' P [Acl, Gb] - diag(r^2 P, 0) + sum_k tau_k Pi_k <= 0`` is written in its *delta form*: with
``Acl = I + dt Ad``, ``w = W w^`` (``W = dt`` for a level whose inputs are f itself, ``Gw = I``: a step's
increment; ``W = 1`` for channel outputs, whose ``G`` carries the step), ``Gd = Gb W / dt`` and ``P^ = dt P``,
it is exactly (a congruence, then a Schur complement on ``P^``, which keeps it linear in P: DPP) ::

    [ Ad' P^ + P^ Ad + c P^    P^ Gd    sqrt(dt) Ad' P^ ]
    [ Gd' P^                   0        sqrt(dt) Gd' P^ ]  +  sum_k tau_k Pi^_k  <  0,
    [ sqrt(dt) P^ Ad           sqrt(dt) P^ Gd    -P^    ]

``Pi^_k = diag(I, W)' Pi_k diag(I, W)`` scaled to a unit largest entry (a positive factor: the multipliers absorb
it). As ``dt -> 0`` this is the continuous matrix with ``2 lam`` for ``c`` (``r = exp(-lam dt)``: ``c -> 2 lam``),
so a fine sample time keeps the continuous scaling and margins; it verifies where the plain form's differences
``Acl' P Acl - P`` of nearly equal numbers do not. :class:`Data` holds the delta form's matrices (``Acl`` is
``Ad``, ``Gb`` is ``Gd``, ``Pi`` the ``Pi^_k``). The program's parameter ``lam`` is then ``c / 2`` (:func:`measure`):
the matrix is affine in it as in continuous time, and the searches convert at their ends.

The L2 gain (:attr:`Spec.measure` ``"l2"``): with the disturbance ``w_d`` entering as ``Bd w_d`` and the output
``zeta = Cz z`` (``Qz = Cz' Cz``), the bounded real lemma with the same S-procedure terms ::

    [ Acl' P + P Acl + Qz    P Gb    P Bd   ]
    [ Gb' P                  0       0      ]  +  sum_k tau_k Pi_k (zero in the w_d rows)  <=  0
    [ Bd' P                  0       -g2 I  ]

proves ``V' + |zeta|^2 - g2 |w_d|^2 <= 0``, so ``||zeta||_L2^2 <= g2 ||w_d||_L2^2 + V(z(0))``; it is linear in
``(P, tau, g2)``: g2 is minimised directly (:func:`_build_l2`). In discrete time the same delta form, with
``Bd^ = Bd / dt`` and the Schur row ``sqrt(dt) Bd^' P^`` (``P^ = dt P``: the plain
``V(z_{k+1}) - V(z_k) + |zeta_k|^2 - g2 |w_k|^2 <= 0`` in ``P``).

The rate a point proves. For a verified point ``(P, tau)`` the matrix is affine in lam,
``M(lam) = M(lam0) + (lam - lam0) D``; the largest lam with ``M(lam) < 0`` is
``lam0 + 1 / lambda_max(D, -M(lam0))`` (a generalised eigenvalue, :func:`reach`), and every grid point
below it at which the rebuilt matrix verifies is a certified rate of the same certificate, without a solve.
The searches (:meth:`Level.search`) use it to move their lower end.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
import scipy.linalg as sla

from bench import lmi
from bench.search import RATE_RTOL, grid_floor, largest_passing, secant_estimate

__all__ = ["Level", "Spec", "level_data", "matrix", "measure", "rate_of", "values"]


@dataclass(frozen=True)
class Spec:
    """The structure of a level's LMI (it keys the compiled program).

    Attributes
    ----------
    level : str
    n, nw : int
        States, and nonlinearity inputs per side (``w = (w_x, w_e)``).
    full_p : bool
        A full ``2n x 2n`` P (else ``blkdiag(P1, P2)``).
    scalars : tuple of str
        Scalar constraints used, of ``("osl", "qib", "lip")``.
    channels : bool
        One slope constraint per channel and side.
    region : tuple of int
        Rows of each block of the region that must hold the level set through ``z0``
        (``|R_j z| <= r``, :func:`level_data`); empty: no region (normalisation ``trace(P) = 1``).
    measure : str
        The quantity searched: ``"rate"``, the decay rate lam of ``V' <= -2 lam V`` (discrete time:
        ``V(z_{k+1}) <= r^2 V(z_k)``, ``r = exp(-lam dt)``), or ``"l2"``, the least ``g2`` of the bounded real
        lemma (module docstring).
    norm : str
        The normalisation of a level without a region: ``"trace"`` (``trace(P) = 1``) or ``"relative"``
        (``|M_ij|, |P_ij| <= 1``: the margin maximised is the one the verification judges), :func:`_build`.
    side : str
        ``""``: the level's matrix in ``(x, e, w_x, w_e)``; ``"x"`` or ``"e"``: one side of it alone, in
        ``(x, w_x)`` or ``(e, w_e)`` with that side's multipliers (:func:`side`, :func:`cascade`).
    discrete : bool
        The delta form of the discrete-time condition (module docstring): ``zdim`` more rows, a Schur complement.
    nd : int
        Disturbance inputs (measure ``"l2"``; 0 otherwise).
    """

    level: str
    n: int
    nw: int
    full_p: bool
    scalars: tuple[str, ...]
    channels: bool
    region: tuple[int, ...] = ()
    measure: str = "rate"
    norm: str = "trace"
    side: str = ""
    discrete: bool = False
    nd: int = 0

    @property
    def multipliers(self) -> tuple[str, ...]:
        """The multipliers' names, in the order of ``tau`` and of :attr:`Data.Pi`."""
        own = (*self.scalars, *(f"ch{i}" for i in range(self.nw) if self.channels))
        return tuple(f"{k}_{side}" for side in (("x", "e") if not self.side else (self.side,)) for k in own)

    @property
    def zdim(self) -> int:
        """The state's dimension: ``2 n`` for ``z = (x, e)``, n for one side."""
        return self.n if self.side else 2 * self.n

    @property
    def size(self) -> int:
        """The size of the matrix's ``(z, w)`` part, ``2 n + 2 nw`` (``n + nw`` for one side); :attr:`dim` adds the
        disturbance and Schur rows."""
        return self.zdim + (self.nw if self.side else 2 * self.nw)

    @property
    def dim(self) -> int:
        """The whole matrix's size: :attr:`size`, the disturbance rows (``"l2"``) and the Schur rows (discrete)."""
        return self.size + (self.nd if self.measure == "l2" else 0) + (self.zdim if self.discrete else 0)

    @property
    def decision(self) -> tuple[str, ...]:
        """The positive definite decision matrices."""
        return ("P",) if self.full_p or self.side else ("P1", "P2")


@dataclass
class Data:
    """A level's numbers in the original coordinates (:func:`level_data`).

    Attributes
    ----------
    Acl : ndarray (2n, 2n)
    Gb : ndarray (2n, 2nw)
    Pi : ndarray (K, N, N)
        The constraints ``xi' Pi_k xi >= 0``, in the order of :attr:`Spec.multipliers`.
    rows : tuple of ndarray
        Region blocks ``R_j`` (k_j x 2n): the region is ``|R_j z| <= r`` for every j.
    r : float or None
    z0 : ndarray (2n,) or None
        The initial condition whose level set must lie in the region.
    masks : dict
        Where ``Acl``, ``Gb`` and ``Pi`` (and ``Bd``, ``Qz``) may be nonzero whatever the gains, constants and slopes
        (the structure of the compiled program; :func:`bench.lmi.matrices`).
    dt : float
        The sample time of a discrete level (0: continuous). ``Acl``, ``Gb``, ``Pi``, ``Bd`` are then the delta
        form's ``Ad``, ``Gd``, ``Pi^_k``, ``Bd^`` (module docstring).
    Bd : ndarray (2n, nd) or None
        Where the disturbance enters (measure ``"l2"``).
    Qz : ndarray (2n, 2n) or None
        ``Cz' Cz`` of the performance output (measure ``"l2"``).
    """

    Acl: np.ndarray
    Gb: np.ndarray
    Pi: np.ndarray
    rows: tuple = ()
    r: float | None = None
    z0: np.ndarray | None = None
    masks: dict = field(default_factory=dict, repr=False)
    dt: float = 0.0
    Bd: np.ndarray | None = None
    Qz: np.ndarray | None = None


def _scalar_pieces(k: str, Gw: np.ndarray, c) -> tuple:
    """``(zz, zw, ww)`` of a scalar constraint on ``(dx, w)`` with ``df = Gw w``."""
    n = Gw.shape[0]
    GtG = Gw.T @ Gw
    if k == "lip":
        return (c.alpha or 0.0) ** 2 * np.eye(n), np.zeros_like(Gw), -GtG
    if k == "osl":
        return (c.rho or 0.0) * np.eye(n), -0.5 * Gw, np.zeros_like(GtG)
    if k == "qib":
        return (c.beta or 0.0) * np.eye(n), 0.5 * (c.gamma or 0.0) * Gw, -GtG
    raise ValueError(f"unknown scalar constraint {k!r}")


def level_data(spec: Spec, A: np.ndarray, B: np.ndarray, C: np.ndarray, K: np.ndarray, F: np.ndarray, know, *,
               box: tuple | None = None, rows: tuple = (), r: float | None = None,
               z0: np.ndarray | None = None, dt: float = 0.0, Bw: np.ndarray | None = None,
               Dw: np.ndarray | None = None, zeta: str | None = None) -> Data:
    """The level's numbers for the gains K, F (:class:`Data`; a discrete level's in the delta form).

    Parameters
    ----------
    spec : Spec
    A, B, C, K, F : ndarray
    know : bench.constants.Knowledge
        The trusted constants (``spec.scalars``) and channels (``spec.channels``; ``Gw = G`` for a level with
        channels, else ``I``).
    box : (lo, hi), optional
        Channel slopes instead of the declared ones (a narrowed box on a region).
    rows, r, z0
        The region and the initial condition of a level with ``spec.region``.
    dt : float
        The sample time of a discrete level (``spec.discrete``).
    Bw, Dw : ndarray, optional
        The plant's disturbance inputs (measure ``"l2"``): ``Bd = [Bw; Bw - K Dw]``.
    zeta : {"e", "x"}, optional
        The performance output of measure ``"l2"``: ``Cz = [0 I]`` (e) or ``[I 0]`` (x).

    Returns
    -------
    Data
    """
    n, nw = spec.n, spec.nw
    BF = B @ F
    Acl = np.block([[A + BF, -BF], [np.zeros((n, n)), A - K @ C]])
    ch = know.channels if spec.channels else None
    Gw = ch.G if ch is not None else np.eye(n)
    Gb = sla.block_diag(Gw, Gw)
    slopes = box if box is not None else (ch.lo, ch.hi) if ch is not None else None
    Pi = _constraints(spec, Gw, ch, know.constants, slopes)
    generic = SimpleNamespace(alpha=1.0, rho=1.0, beta=1.0, gamma=1.0)  # every entry that can be nonzero
    masks = {"Acl": np.block([[np.ones((n, n)), np.ones((n, n))], [np.zeros((n, n)), np.ones((n, n))]]),
             "Gb": (Gb != 0).astype(float),
             "Pi": (_constraints(spec, Gw, ch, generic, None if ch is None else (-np.ones(nw), 2 * np.ones(nw))) != 0)
             .astype(float)}
    Bd = Qz = None
    if spec.measure == "l2":
        if Bw is None or zeta not in ("e", "x"):
            raise ValueError("level_data: an L2 level needs the disturbance inputs Bw, Dw and zeta 'e' or 'x'")
        Bw = np.asarray(Bw, dtype=float)
        Dw = np.zeros((C.shape[0], Bw.shape[1])) if Dw is None else np.asarray(Dw, dtype=float)
        Bd = np.vstack([Bw, Bw - K @ Dw])
        Cz = np.hstack([np.zeros((n, n)), np.eye(n)] if zeta == "e" else [np.eye(n), np.zeros((n, n))])
        Qz = Cz.T @ Cz
        masks.update(Bd=np.ones_like(Bd), Qz=(Qz != 0).astype(float))
    if spec.discrete:
        if not dt > 0:
            raise ValueError(f"level_data: a discrete level needs a sample time dt > 0, got {dt!r}")
        W = 1.0 if spec.channels else dt  # w^ = w / W (module docstring)
        Acl = (Acl - np.eye(2 * n)) / dt
        Gb = Gb * (W / dt)
        Bd = None if Bd is None else Bd / dt
        sw = np.concatenate([np.ones(2 * n), W * np.ones(spec.size - 2 * n)])
        Pi = Pi * sw[None, :, None] * sw[None, None, :]
        top = np.abs(Pi).reshape(len(Pi), -1).max(axis=1, initial=0.0)
        Pi = Pi / np.where(top > 0, top, 1.0)[:, None, None]
    return Data(Acl, Gb, Pi, tuple(np.atleast_2d(R) for R in rows), r, z0, masks, dt=float(dt) if spec.discrete
                else 0.0, Bd=Bd, Qz=Qz)


def measure(lam: float, dt: float) -> float:
    """The program's parameter ``lam`` for a decay rate ``lam`` per second: ``lam`` itself in continuous time, and
    ``c / 2 = (1 - r^2) / (2 dt)`` with ``r = exp(-lam dt)`` in discrete time (module docstring; it tends to lam as
    ``dt -> 0`` and is at most ``1 / (2 dt)``, a deadbeat loop)."""
    if not dt > 0:
        return lam
    return -math.expm1(-2.0 * lam * dt) / (2.0 * dt)


def rate_of(m: float, dt: float) -> float:
    """The decay rate per second whose :func:`measure` is ``m`` (``inf`` at or beyond ``1 / (2 dt)``)."""
    if not dt > 0:
        return m
    x = 2.0 * dt * m
    return math.inf if x >= 1.0 else -math.log1p(-x) / (2.0 * dt)


def values(spec: Spec, data: Data, T: np.ndarray | None = None) -> dict:
    """The matrices :func:`matrix` reads, from ``data`` in the coordinates ``z = T z~`` (T diagonal; None: the
    original ones): ``Acl``, ``Gb``, ``Pi`` (columns, ``(N * N, K)``), ``Bd``, ``Qz`` for measure ``"l2"``, and for a
    discrete level the Schur rows' ``Ah = sqrt(dt) Acl``, ``Gh``, ``Bh``."""
    t = np.ones(spec.zdim) if T is None else np.diag(T).copy()
    Ti = np.diag(1 / t)
    sd = np.concatenate([t, np.ones(spec.size - spec.zdim)])
    Pi = data.Pi * sd[None, :, None] * sd[None, None, :]
    out = {"Acl": Ti @ data.Acl @ np.diag(t), "Gb": Ti @ data.Gb, "Pi": Pi.reshape(len(Pi), -1).T}
    if spec.measure == "l2":
        out.update(Bd=Ti @ data.Bd, Qz=data.Qz * t[:, None] * t[None, :])
    if spec.discrete:
        rt = math.sqrt(data.dt)
        out.update(Ah=rt * out["Acl"], Gh=rt * out["Gb"])
        if spec.measure == "l2":
            out["Bh"] = rt * out["Bd"]
    return out


def scaling(spec: Spec, T: np.ndarray) -> np.ndarray:
    """The diagonal of the congruence ``S`` that maps the level's matrix to the coordinates ``z = T z~``:
    T on z, 1 on the nonlinearity and disturbance inputs, T on the Schur rows of a discrete level."""
    t = np.diag(T)
    rest = spec.dim - spec.zdim - (spec.zdim if spec.discrete else 0)
    return np.concatenate([t, np.ones(rest), t if spec.discrete else np.empty(0)])


def _constraints(spec: Spec, Gw: np.ndarray, ch, constants, slopes) -> np.ndarray:
    """The matrices ``Pi_k`` (K, N, N) of a level's constraints, in the order of :attr:`Spec.multipliers`."""
    n, nw, N = spec.n, spec.nw, spec.size
    Pi = []
    for iz, iw in ((0, 2 * n), (n, 2 * n + nw)):  # the x side (x, 0), the e side (x, x_hat)
        pieces = [_scalar_pieces(k, Gw, constants) for k in spec.scalars]
        if ch is not None:
            lo, hi = (np.asarray(b, dtype=float) for b in slopes)
            for i in range(nw):
                h, ei = ch.H[i], np.eye(nw)[i]
                pieces.append((-lo[i] * hi[i] * np.outer(h, h), 0.5 * (lo[i] + hi[i]) * np.outer(h, ei),
                               -np.outer(ei, ei)))
        for zz, zw, ww in pieces:
            Q = np.zeros((N, N))
            Q[iz:iz + n, iz:iz + n] = zz
            Q[iz:iz + n, iw:iw + nw] = zw
            Q[iw:iw + nw, iz:iz + n] = zw.T
            Q[iw:iw + nw, iw:iw + nw] = ww
            Pi.append(Q)
    return np.array(Pi)


def _p(spec: Spec, d: dict):
    """The full ``2n x 2n`` P of values ``d`` (numpy or cvxpy)."""
    if spec.full_p or spec.side:
        return d["P"]
    Z = np.zeros((spec.n, spec.n))
    if isinstance(d["P1"], np.ndarray):
        return np.block([[d["P1"], Z], [Z, d["P2"]]])
    import cvxpy as cp

    return cp.bmat([[d["P1"], Z], [Z, d["P2"]]])


def matrix(spec: Spec, d: dict) -> list[list]:
    """The level's matrix (module docstring) as one block, from values ``d`` (numpy arrays: numeric; cvxpy
    expressions: the program's). ``d["Pi"]`` holds the constraints as columns, ``(N * N, K)``; measure ``"rate"``
    reads ``d["lam"]``, ``"l2"`` reads ``d["g2"]``, ``d["Bd"]``, ``d["Qz"]``; a discrete level the Schur rows'
    ``d["Ah"]``, ``d["Gh"]`` (and ``d["Bh"]``). The rows are ``(z, w, [w_d], [Schur])``."""
    P, Acl, Gb = _p(spec, d), d["Acl"], d["Gb"]
    N, n2 = spec.size, spec.zdim
    nwf, l2 = N - n2, spec.measure == "l2"
    numeric = isinstance(d["tau"], np.ndarray) and isinstance(P, np.ndarray)
    if numeric:
        bmat, Pt = np.block, (d["Pi"] @ d["tau"]).reshape(N, N, order="F")
    else:
        import cvxpy as cp

        bmat, Pt = cp.bmat, cp.reshape(d["Pi"] @ d["tau"], (N, N), order="F")
    Z = np.zeros
    zz = Acl.T @ P + P @ Acl + (d["Qz"] if l2 else 2 * d["lam"] * P)
    PG = P @ Gb
    if not (l2 or spec.discrete):
        return [[bmat([[zz, PG], [PG.T, Z((nwf, nwf))]]) + Pt]]
    blocks = [[zz, PG], [PG.T, Z((nwf, nwf))]]
    if l2:
        nd = spec.nd
        PB = P @ d["Bd"]
        blocks[0].append(PB)
        blocks[1].append(Z((nwf, nd)))
        blocks.append([PB.T, Z((nd, nwf)), -d["g2"] * np.eye(nd)])
    if spec.discrete:
        cols = [d["Ah"].T @ P, d["Gh"].T @ P] + ([d["Bh"].T @ P] if l2 else [])
        for row, c in zip(blocks, cols):
            row.append(c)
        blocks.append([c.T for c in cols] + [-P])
    k = spec.dim - N
    return [[bmat(blocks) + bmat([[Pt, Z((N, k))], [Z((k, N)), Z((k, k))]])]]


def _build(spec: Spec, mats: lmi.Matrices) -> lmi.Program:
    """The margin program of a level (module docstring), in the variables of diagonal coordinates ``z = T z~``
    (:class:`Level`) with every margin and normalisation measured in the original ones: ``M << -slack I``,
    decision matrices ``>> slack I``, ``tau >= 0``; normalised by ``trace(P) = 1`` (``spec.norm == "trace"``),
    by ``|M_ij| <= 1`` and ``|P_ij| <= 1`` (``"relative"``: the margin is then the one :func:`bench.lmi.classify`
    judges), or with a region by ``V(z0) <= 1``, ``slack <= 1``, the level set ``{V <= V(z0)}`` inside
    ``|R_j z| <= r`` (Schur complements ``[[P, R_j'], [R_j, r^2 I]] >> 0``).
    With ``S = blkdiag(T, I)``, ``M = S^-T M~ S^-1`` and ``P = T^-1 P~ T^-1``: the parameters ``s2``, ``t2`` are
    the squared diagonals of S and T, ``Mb``, ``Pb`` their outer products. ``mats`` (:func:`bench.lmi.matrices` of
    ``Acl``, ``Gb`` and ``Pi``) fixes which of their entries are structurally zero (Patterns)."""
    import cvxpy as cp

    if spec.measure == "l2":
        return _build_l2(spec, mats)
    t0 = time.perf_counter()
    n, n2, N, K = spec.n, spec.zdim, spec.dim, len(spec.multipliers)
    size = n2 if spec.full_p or spec.side else n
    v = {"slack": cp.Variable(name="slack"), "tau": cp.Variable(K, name="tau")}
    v.update({k: cp.Variable((size, size), symmetric=True, name=k) for k in spec.decision})
    prm = {"lam": cp.Parameter(nonneg=True, name="lam"), **mats.parameters(),
           "s2": cp.Parameter(N, pos=True, name="s2"), "t2": cp.Parameter(n2, pos=True, name="t2")}
    exprs = {k: (p.expr if isinstance(p, lmi.Pattern) else p) for k, p in prm.items()}
    M = matrix(spec, {**v, **exprs})[0][0]  # cvxpy constrains its symmetric part (sym() fails in its COO backend)
    slack = v["slack"]
    blocks = {"P": slice(0, n2)} if spec.full_p or spec.side else {"P1": slice(0, n), "P2": slice(n, n2)}
    cons = [M << -slack * cp.diag(prm["s2"]), v["tau"] >= 0]
    cons += [v[k] >> slack * cp.diag(prm["t2"][sl]) for k, sl in blocks.items()]
    if spec.region:
        P = _p(spec, v)
        prm["Z0"] = cp.Parameter((n2, n2), PSD=True, name="Z0")
        prm["r2"] = cp.Parameter(nonneg=True, name="r2")
        cons += [cp.trace(prm["Z0"] @ P) <= 1, slack <= 1]
        for j, k in enumerate(spec.region):
            R = prm[f"R{j}"] = cp.Parameter((k, n2), name=f"R{j}")
            cons.append(lmi.sym(cp.bmat([[P, R.T], [R, prm["r2"] * np.eye(k)]])) >> 0)
    elif spec.norm == "relative":
        prm["Mb"] = cp.Parameter((N, N), pos=True, name="Mb")
        prm["Pb"] = cp.Parameter((n2, n2), pos=True, name="Pb")
        cons += [cp.abs(M) <= prm["Mb"], slack <= 1]
        cons += [cp.abs(v[k]) <= prm["Pb"][sl, sl] for k, sl in blocks.items()]
    else:
        prm["it2"] = cp.Parameter(n2, pos=True, name="it2")
        cons.append(sum(cp.sum(cp.multiply(cp.diag(v[k]), prm["it2"][sl])) for k, sl in blocks.items()) == 1)
    prob = cp.Problem(cp.Maximize(slack), cons)
    from functools import partial

    return lmi.Program(prob, v, prm, partial(matrix, spec), spec.decision, build_s=time.perf_counter() - t0)


def _build_l2(spec: Spec, mats: lmi.Matrices) -> lmi.Program:
    """The L2 program of a level (module docstring): minimise ``g2`` subject to ``M << -eps diag(d)`` and the
    decision matrices ``>> eps I`` (both measured in the original coordinates, as :func:`_build`), ``tau >= 0``;
    ``eps`` and the row weights ``d`` are parameters (``w2``: ``d`` in the solve's coordinates; :meth:`Level.minimise`
    chooses them until the point verifies)."""
    import cvxpy as cp

    t0 = time.perf_counter()
    n, n2, K = spec.n, spec.zdim, len(spec.multipliers)
    size = n2 if spec.full_p or spec.side else n
    v = {"g2": cp.Variable(name="g2"), "tau": cp.Variable(K, name="tau")}
    v.update({k: cp.Variable((size, size), symmetric=True, name=k) for k in spec.decision})
    prm = {**mats.parameters(), "w2": cp.Parameter(spec.dim, pos=True, name="w2"),
           "t2": cp.Parameter(n2, pos=True, name="t2"), "eps": cp.Parameter(nonneg=True, name="eps")}
    exprs = {k: (p.expr if isinstance(p, lmi.Pattern) else p) for k, p in prm.items()}
    M = matrix(spec, {**v, **exprs})[0][0]
    blocks = {"P": slice(0, n2)} if spec.full_p or spec.side else {"P1": slice(0, n), "P2": slice(n, n2)}
    cons = [M << -prm["eps"] * cp.diag(prm["w2"]), v["tau"] >= 0]
    cons += [v[k] >> prm["eps"] * cp.diag(prm["t2"][sl]) for k, sl in blocks.items()]
    prob = cp.Problem(cp.Minimize(v["g2"]), cons)
    from functools import partial

    return lmi.Program(prob, v, prm, partial(matrix, spec), spec.decision, build_s=time.perf_counter() - t0)


def program(spec: Spec, mats: lmi.Matrices) -> lmi.Program:
    """The compiled program of ``spec`` for matrices shaped as ``mats`` (:func:`bench.lmi.cached_program`), reset."""
    return lmi.cached_program(("ladder", spec, mats.key), lambda: _build(spec, mats))


def balancing(Acl: np.ndarray, spec: Spec) -> np.ndarray:
    """The diagonal similarity ``T`` that balances ``Acl`` (:func:`scipy.linalg.matrix_balance`, powers of 2, so
    the change of coordinates is exact in floating point)."""
    _, (scale, _) = sla.matrix_balance(Acl, permute=False, separate=True)
    return np.diag(scale)


def reach(M0: np.ndarray, D: np.ndarray) -> float:
    """``sup {t >= 0 : M0 + t D < 0}`` for ``M0 < 0`` (``inf`` when D is negative semidefinite; 0 when M0 is not
    negative definite), as ``1 / lambda_max(D, -M0)``."""
    try:
        w = sla.eigh(lmi.sym(D), -lmi.sym(M0), eigvals_only=True)
    except (np.linalg.LinAlgError, ValueError):
        return 0.0
    top = float(w[-1])
    return math.inf if top <= 0 else 1.0 / top


def _extrapolate(pts: list[tuple[float, float]]) -> float | None:
    """Where the margins of verified points (``(lam, m)``, m in units of the tolerance, rising to -1 at the threshold)
    reach -2: the margin near a threshold r behaves as ``-c (r - lam)^p``, so the last two points' values of
    ``(-m)^(1/p)`` are extrapolated linearly; p is fitted to the last three points (within [1, 2]; 1.5 with two)."""
    if len(pts) < 2:
        return None
    (a, ma), (b, mb) = pts[-2:]
    if not (b > a and ma < mb < 0):
        return None
    p = 1.5
    if len(pts) >= 3 and pts[-3][0] < a and pts[-3][1] < ma:
        lo, hi = 1.0, 2.0  # p with the three points on one line in (lam, (-m)^(1/p)): bisect the curvature's sign

        def bend(q: float) -> float:
            (x0, m0), (x1, m1), (x2, m2) = pts[-3:]
            y0, y1, y2 = ((-m) ** (1 / q) for m in (m0, m1, m2))
            return (y1 - y0) / (x1 - x0) - (y2 - y1) / (x2 - x1)

        if bend(lo) * bend(hi) < 0:
            for _ in range(20):
                mid = (lo + hi) / 2
                lo, hi = (mid, hi) if bend(lo) * bend(mid) > 0 else (lo, mid)
            p = (lo + hi) / 2
        else:
            p = lo if abs(bend(lo)) < abs(bend(hi)) else hi
    ya, yb, y2 = (-ma) ** (1 / p), (-mb) ** (1 / p), 2.0 ** (1 / p)
    if not ya > yb:
        return None
    return b + (yb - y2) * (b - a) / (ya - yb)


@dataclass
class Level:
    """One level's program bound to a gain pair's numbers (:class:`Data`), solved in chosen coordinates.

    Attributes
    ----------
    spec : Spec
    data : Data
        The original coordinates' numbers (every verdict is taken on them).
    prog : bench.lmi.Program
    T : ndarray
        The coordinates of the next solve, ``z = T z~``.
    rtol : float
        The rate grid (:mod:`bench.search`).
    found : dict
        Verified certificates by grid rate: ``lam -> P`` (original coordinates).
    lam0_margin : float
        The largest eigenvalue at ``lam = 0`` of the first verified point (NaN before one).
    solver_errors : int
        Probes at which the first solver failed outright (``"solver_error"``).
    taus : dict
        The multipliers of :attr:`found`'s certificates, by the same rates.
    failed_at : float
        The least rate at which a probe outside :meth:`search` failed (inf: none).
    verdicts : dict
        Every probe's verdict by rate (:meth:`solve`).
    curve : dict
        The re-optimised points' margins by rate, ``lam -> (verified, max eig, tolerance)``, for the probes that
        verified or failed by their margin beyond the tolerance (not marginal: a margin that stays near zero over a
        range of rates says nothing of the distance; not by a decision matrix; not unsolved): what searches aim with.
    """

    spec: Spec
    data: Data
    prog: lmi.Program = None
    T: np.ndarray = None
    rtol: float = RATE_RTOL
    found: dict = field(default_factory=dict)
    lam0_margin: float = math.nan
    solver_errors: int = 0
    taus: dict = field(default_factory=dict)
    failed_at: float = math.inf
    verdicts: dict = field(default_factory=dict)
    curve: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.T is None:
            self.T = balancing(self.data.Acl, self.spec)
        self._vals = self._coordinates()
        if self.prog is None:
            m = self.data.masks
            keys = [k for k in ("Acl", "Gb", "Pi", "Bd", "Qz", "Ah", "Gh", "Bh") if k in self._vals]
            if m:
                base = {"Ah": "Acl", "Gh": "Gb", "Bh": "Bd"}
                shapes = {k: m[base.get(k, k)] for k in keys}
                shapes["Pi"] = m["Pi"].reshape(len(m["Pi"]), -1).T
            else:
                shapes = {k: self._vals[k] for k in keys}
            self.prog = program(self.spec, lmi.matrices(**shapes))

    # -- coordinates ---------------------------------------------------------------------------
    def m(self, lam: float) -> float:
        """The program's parameter for the rate ``lam`` per second (:func:`measure`)."""
        return measure(lam, self.data.dt)

    def _coordinates(self) -> dict:
        """The program's parameter values: the data in the coordinates ``T``."""
        T, d, spec = self.T, self.data, self.spec
        t = np.diag(T).copy()
        Ti = np.diag(1 / t)
        sd = scaling(spec, T)
        vals = {**values(spec, d, T), "s2": sd ** 2, "t2": t ** 2}
        if spec.measure == "l2":
            return vals
        if not spec.region and spec.norm == "relative":
            vals.update(Mb=np.outer(sd, sd), Pb=np.outer(t, t))
        elif not spec.region:
            vals["it2"] = 1 / t ** 2
        if spec.region:
            z = Ti @ d.z0
            rows = {f"R{j}": R @ T for j, R in enumerate(d.rows)}
            vals.update(Z0=np.outer(z, z), r2=d.r ** 2, **rows)
        return vals

    def _set(self) -> None:
        """Put the data, in the coordinates ``T``, into the program; map its values back for verdicts."""
        T, d, spec = self.T, self.data, self.spec
        Ti = np.diag(1 / np.diag(T))
        self.prog.set(**{k: v for k, v in self._vals.items() if k in self.prog.parameters or k in self.prog.patterns})
        orig = values(spec, d)
        n = spec.n

        def original(v: dict) -> dict:
            out = {**v, **orig}
            if spec.full_p or spec.side:
                out["P"] = Ti.T @ v["P"] @ Ti
            else:
                out["P1"] = Ti[:n, :n].T @ v["P1"] @ Ti[:n, :n]
                out["P2"] = Ti[n:, n:].T @ v["P2"] @ Ti[n:, n:]
            return out

        self.prog.original = original

    def matrix_at(self, lam: float) -> np.ndarray | None:
        """The last point's matrix at the rate ``lam`` per second, in the original coordinates."""
        return self.prog.numeric_matrix(lam=self.m(lam))

    # -- one probe -----------------------------------------------------------------------------
    def solve(self, lam: float, *, probe: bool = False) -> tuple[str, float]:
        """Solve at rate ``lam`` and verify in the original coordinates (:meth:`bench.lmi.Program.verdict`). The
        second solver is tried when the first fails (``probe``, a probe of a rate search: only when it has no
        point; a point near the threshold that does not verify is that probe's answer)."""
        self._set()
        self.prog.solve(lam=self.m(lam), fallback="errors" if probe else True)
        self.solver_errors += "solver_error" in self.prog.tried
        verdict, margin = self.prog.verdict()
        self.verdicts[lam] = verdict
        if verdict == "verified" or (verdict == "violated" and margin > 0):
            self.curve[lam] = (verdict == "verified", margin, lmi.verify_tol(self.prog.numeric_matrix()))
        if verdict == "verified":
            self.found[lam], self.taus[lam] = self.point()
            if math.isnan(self.lam0_margin):
                self.lam0_margin = lmi.max_eig(self.prog.numeric_matrix(lam=0.0))
        return verdict, margin

    def point(self) -> tuple[np.ndarray, np.ndarray]:
        """The last point's full P, in the original coordinates, and its multipliers, scaled to ``trace(P) = 1``, or
        for a region's program to ``V(z0) = 1`` (the LMI is homogeneous in ``(P, tau)``)."""
        vals = self.prog.checked_values()
        P = _p(self.spec, vals)
        z0 = self.data.z0
        scale = float(z0 @ P @ z0) if self.spec.region else float(np.trace(P))
        return P / scale, np.array(vals["tau"], dtype=float) / scale

    def minimise(self, eps: float, weights: np.ndarray | None = None) -> tuple[str, float]:
        """Solve the L2 program (measure ``"l2"``) with the margin ``M << -eps diag(weights)`` in the original
        coordinates (:func:`_build_l2`; default weights 1), verify it there; returns the verdict and the largest
        eigenvalue of the rebuilt matrix (at the point's own ``g2``)."""
        d = np.ones(self.spec.dim) if weights is None else np.asarray(weights, dtype=float)
        self._vals["w2"] = d * scaling(self.spec, self.T) ** 2
        self._set()
        self.prog.solve(eps=eps, fallback=True)
        self.solver_errors += "solver_error" in self.prog.tried
        return self.prog.verdict()

    def gain_point(self) -> tuple[float, np.ndarray, np.ndarray]:
        """The last L2 point: ``g2``, its P in the plain form's scale (``V = z' P z``; a discrete level's
        ``P^ / dt``) and its multipliers."""
        vals = self.prog.checked_values()
        P = _p(self.spec, vals)
        if self.data.dt > 0:
            P = P / self.data.dt
        return float(vals["g2"]), P, np.array(vals["tau"], dtype=float)

    def reach_grid(self, lam: float, hi: float) -> float | None:
        """The largest grid rate in ``(lam, hi)`` at which the last (verified) point's matrix verifies too, or None."""
        m0 = self.m(lam)
        M0 = self.prog.numeric_matrix(lam=m0)
        D = self.prog.numeric_matrix(lam=m0 + 1.0) - M0
        top = rate_of(m0 + reach(M0, D), self.data.dt)
        if not top > lam:
            return None
        k = grid_floor(min(top, hi) * (1 - 1e-9), self.rtol)
        for _ in range(3):  # the first grid point below the reach that verifies (rounding may spoil the very first)
            if k <= lam * (1 + 1e-12):
                return None
            if k < hi * (1 - 1e-12):
                M = self.matrix_at(k)
                if lmi.classify(lmi.max_eig(M), M) == "verified":
                    self.found[k], self.taus[k] = self.point()
                    return k
            k = grid_floor(k / (1 + self.rtol) * (1 + 1e-12), self.rtol)
        return None

    # -- the search ----------------------------------------------------------------------------
    def secant(self) -> float | None:
        """The threshold rate the probes' margins point to (:func:`bench.search.secant_estimate` of :attr:`curve`), or
        None."""
        return secant_estimate(self.curve)

    def margin(self, lam: float) -> float:
        """The largest eigenvalue of the last point's matrix at ``lam``, in units of its verification tolerance."""
        M = self.matrix_at(lam)
        return lmi.max_eig(M) / lmi.verify_tol(M)

    def aim(self, lam: float) -> float:
        """Where the last (verified) point's own matrix reaches twice the verification tolerance, by a Newton step
        on its largest eigenvalue m: ``lam + (-m - 2 tol) / (u' D u)`` (u the eigenvector, D the matrix's
        derivative in lam). A first estimate of the level's threshold (the point is re-optimised at the next
        probe, so its own line is a cautious one)."""
        m = self.m(lam)
        M = lmi.sym(self.prog.numeric_matrix(lam=m))
        D = lmi.sym(self.prog.numeric_matrix(lam=m + 1.0)) - M
        w, U = np.linalg.eigh(M)
        u = U[:, -1]
        slope, gap = float(u @ D @ u), -float(w[-1]) - 2 * lmi.verify_tol(M)
        out = rate_of(m + gap / slope, self.data.dt) if slope > 0 and gap > 0 else lam
        return out if math.isfinite(out) else lam

    def search(self, lo: float, hi: float, *, top_first: bool = False,
               seen: tuple[float, float] | None = None, above_lo: bool = True) -> float:
        """The largest grid rate in ``[lo, hi)`` whose LMI verifies (``lo`` verified already, ``hi`` an upper
        bound no certificate reaches), on the grid of :mod:`bench.search`: a grid rate that verified whose next
        grid rate failed (or is ``hi``). Which grid rates are probed depends on the margins found, but the answer
        only on the outcomes at the threshold (as a bisection's).

        The probes: the grid rate just above ``lo`` (a level often certifies no more than the level below); with
        ``top_first`` (``hi`` a tight ceiling) 1, 2, 4, ... grid steps below ``hi`` until one verifies; then where
        the margins of the last verified points (:meth:`margin`) extrapolate to twice the tolerance
        (:func:`_extrapolate`; with one point, where it aims, :meth:`aim`; a region's program too: the probes only
        choose where to look, the answer rests on the outcomes); bisection when that lands beyond a failed probe or after two failures in a row. Every
        verified point is carried up by :meth:`reach_grid`. ``seen``: an earlier verified ``(lam, margin)``;
        ``above_lo=False``: no first probe just above ``lo`` (``lo`` is not a lower level's rate).
        """
        from bench.search import _index, _point

        rt = self.rtol
        k0 = kl = _index(lo, rt, up=False)
        kh = _index(hi, rt, up=True)
        pts = [seen] if seen is not None else []
        plan = [kl + 1] if above_lo else []
        fails, aimed, down = 0, None, 1 if top_first else 0
        while kh - kl > 1:
            plan = [k for k in plan if kl < k < kh]
            galloping = False
            if plan:
                k = plan.pop(0)
            elif down and kh - down > kl:  # down from a tight ceiling: 1, 2, 4, ... grid steps below it
                k, galloping = kh - down, True
                down = 2 * down if kh - 2 * down > kl + 2 else 0
                est = self.secant()  # unless the failed probes' margins say the threshold lies further down
                ke = _index(est, rt, up=False) if est is not None and est > 0 else None
                if ke is not None and kl < ke < k:
                    k = ke  # still galloping: on a failure the steps below go on doubling from here
            else:
                est = None
                if fails < 2:  # the further of the two estimates that leave the passing end's next grid rate
                    ests = [e for e in (self.secant(), _extrapolate(pts))
                            if e is not None and e > 0 and kl + 1 < _index(e, rt, up=False) < kh]
                    est = max(ests, default=None)
                if est is None and fails < 2:
                    est = aimed
                ke = _index(est, rt, up=False) if est is not None and est > 0 else None
                if ke is None or ke >= kh or (fails and ke >= kh - 1):
                    k = (kl + kh) // 2
                else:
                    k = max(ke, kl + 1)
            lam = _point(k, rt)
            if self.solve(lam, probe=True)[0] == "verified":
                pts.append((lam, self.margin(lam)))
                aimed = self.aim(lam)
                up = self.reach_grid(lam, _point(kh, rt))
                kl = max(k, _index(up, rt, up=False)) if up is not None else k
                fails, down = 0, 0 if galloping else down
            else:
                fails = 0 if galloping else fails + 1
                kh = k
        return lo if kl == k0 else _point(kl, rt)

    @property
    def n_solves(self) -> int:
        return self.prog.n_solves

    @property
    def solve_s(self) -> float:
        return self.prog.compile_s + self.prog.solve_s


# -- the cascade certificate ---------------------------------------------------------------------
def side(spec: Spec, data: Data, which: str) -> tuple[Spec, Data]:
    """One side of a level: ``"x"``, the rows and columns of ``(x, w_x)`` with ``A + B F`` and the x multipliers,
    or ``"e"``, those of ``(e, w_e)`` with ``A - K C`` (its matrix is a principal submatrix of the level's when
    the other side's P block and multipliers are 0), normalised as the verification judges (``norm="relative"``)."""
    n, nw = spec.n, spec.nw
    iz = np.arange(n) + (0 if which == "x" else n)
    iw = np.arange(nw) + (2 * n if which == "x" else 2 * n + nw)
    idx = np.concatenate([iz, iw])
    keep = [k for k, name in enumerate(spec.multipliers) if name.endswith(f"_{which}")]
    sub = Spec(spec.level, n, nw, True, spec.scalars, spec.channels, side=which, norm="relative",
               discrete=spec.discrete)
    cut = {"Acl": lambda M: M[np.ix_(iz, iz)], "Gb": lambda M: M[np.ix_(iz, iw - 2 * n)],
           "Pi": lambda M: M[keep][:, idx][:, :, idx]}
    return sub, Data(*(cut[k](getattr(data, k)) for k in ("Acl", "Gb", "Pi")),
                     masks={k: cut[k](m) for k, m in data.masks.items() if k in cut}, dt=data.dt)


def _side_rows(spec: Spec, which: str) -> np.ndarray:
    """The rows of the level's matrix that belong to one side: its z block, its w block and (discrete) its Schur
    rows."""
    n, nw, N = spec.n, spec.nw, spec.size
    off = 0 if which == "x" else n
    rows = [off + np.arange(n), 2 * n + (0 if which == "x" else nw) + np.arange(nw)]
    if spec.discrete:
        rows.append(N + off + np.arange(n))
    return np.concatenate(rows)


#: The weight mu of :func:`cascade` is searched on ``MU_GRID`` points from its least value up to ``MU_SPAN`` times it.
MU_GRID, MU_SPAN = 25, 1e6


def joint_of_sides(spec: Spec, data: Data, lam: float, Px, tx, Pe, te) -> tuple[float, np.ndarray, np.ndarray, float]:
    """The cascade ``V = x' Px x + mu e' Pe e`` at ``lam`` from verified sides: the weight mu that makes the level's
    matrix (multipliers ``(tx, mu te)``) most clearly negative definite relative to its entries, as
    :func:`bench.lmi.classify` and :func:`bench.lmi.is_positive_definite` judge, and that matrix's largest eigenvalue
    in units of its tolerance. Returns ``(mu, P, tau, score)``; score < -1: verified."""
    n = spec.n
    Pi = data.Pi.reshape(len(data.Pi), -1).T

    def build(mu: float):
        P = sla.block_diag(Px, mu * Pe)
        tau = np.concatenate([tx, mu * te])
        return P, tau, matrix(spec, _values(spec, P, tau, data, Pi, lam))[0][0]

    # the least mu: Schur complement of the x side (its block and the coupling -Px B F in the (x, e) block)
    _, _, M1 = build(1.0)
    xs, es = _side_rows(spec, "x"), _side_rows(spec, "e")
    _, _, M0 = build(0.0)
    Mx, C = lmi.sym(M0)[np.ix_(xs, xs)], M0[np.ix_(xs, es)]
    Me = lmi.sym(M1 - M0)[np.ix_(es, es)]
    try:
        W = C.T @ sla.solve(-Mx, C, assume_a="pos")
        low = max(float(sla.eigh(lmi.sym(W), -Me, eigvals_only=True)[-1]), 1e-300)
    except (np.linalg.LinAlgError, ValueError):
        return math.nan, None, None, math.inf
    best = (math.nan, None, None, math.inf)
    for mu in low * np.logspace(0.0, math.log10(MU_SPAN), MU_GRID)[1:]:
        P, tau, M = build(float(mu))
        score = max(lmi.max_eig(M) / lmi.verify_tol(M), lmi.max_eig(-P) / lmi.verify_tol(P))
        if score < best[3]:
            best = (float(mu), P, tau, score)
    return best


def _values(spec: Spec, P: np.ndarray, tau: np.ndarray, data: Data, Pi: np.ndarray, lam: float) -> dict:
    n = spec.n
    d = {**values(spec, data), "tau": tau, "Pi": Pi, "lam": measure(lam, data.dt)}
    if spec.full_p:
        d["P"] = P
    else:
        d["P1"], d["P2"] = P[:n, :n], P[n:, n:]
    return d


def cascade(spec: Spec, data: Data, hi: float, rtol: float = RATE_RTOL) -> dict | None:
    """A cascade certificate of a level: ``V = x' Px x + mu e' Pe e`` from the e side alone and the x side with the
    coupling ``B F e`` as a bounded input. Each side is a level of its own (:func:`side`, size ``n + nw``; the e side
    does not see F), solved and its rate searched in its balanced coordinates; the joint weight mu is chosen by
    :func:`joint_of_sides`, at the smaller of the two rates or the grid rates below it. ``P = blkdiag(Px, mu Pe)``
    with the multipliers ``(tau_x, mu tau_e)`` is a point of the level's own LMI (block diagonal), verified by
    the level's matrix in the original coordinates.

    Returns
    -------
    dict
        ``P``, ``tau``, ``rate``, ``mu``, ``margin`` (at rate 0), ``side_rates``, ``n_solves``, ``solve_s``;
        ``P`` None when a side does not verify at rate 0 or no mu verifies.
    """
    from bench.search import grid_floor as floor

    levels = {w: Level(*side(spec, data, w), rtol=rtol) for w in ("x", "e")}
    cost = lambda: (sum(lv.n_solves for lv in levels.values()), sum(lv.solve_s for lv in levels.values()))  # noqa: E731
    rates = {}
    none = lambda: dict(zip(("n_solves", "solve_s"), cost()), P=None, side_rates=rates)  # noqa: E731
    for w, lv in levels.items():
        if lv.solve(0.0)[0] != "verified":
            return none()
        up = lv.reach_grid(0.0, hi) if hi > 0 else None
        rates[w] = lv.search(up, hi, seen=(0.0, lv.margin(0.0)), above_lo=False) if up is not None else 0.0
    lam = min(rates.values())
    tried = [lam] + ([floor(lam / (1 + rtol) ** k * (1 + 1e-12), rtol) for k in range(1, 4)] if lam > 0 else [])
    for r in [*tried, 0.0]:
        pts = {w: max((k for k in lv.found if k >= r), default=None) for w, lv in levels.items()}
        if any(k is None for k in pts.values()):
            continue
        mu, P, tau, score = joint_of_sides(spec, data, r, levels["x"].found[pts["x"]], levels["x"].taus[pts["x"]],
                                           levels["e"].found[pts["e"]], levels["e"].taus[pts["e"]])
        if score < -1:
            Pi = data.Pi.reshape(len(data.Pi), -1).T
            M0 = matrix(spec, _values(spec, P, tau, data, Pi, 0.0))[0][0]
            n_solves, solve_s = cost()
            scale = float(np.trace(P))
            return {"P": P / scale, "tau": tau / scale, "rate": r, "mu": mu, "margin": lmi.max_eig(M0),
                    "side_rates": rates, "n_solves": n_solves, "solve_s": solve_s}
    return none()
