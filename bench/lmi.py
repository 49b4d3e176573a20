"""The LMI toolkit shared by the designs and the certificate: build, compile once, solve, verify.

Strict inequalities carry a margin ``slack`` (``M << -slack I``, ``Q >> slack I``), maximised under a
normalisation. A solver status is never trusted alone: the LMI is rebuilt with numpy at the solution
and classified by :func:`classify` with one tolerance, :data:`VERIFY_TOL`. Programs keep every
plant-dependent number as a cvxpy Parameter and are fetched from :func:`cached_program`, so cvxpy
compiles once per structure. A solve cut short by the time limit raises
:class:`bench.limits.DeadlineExceeded`, never a status.

One solve path (:meth:`Program.solve`): a solve already made at the same parameter values (same program,
solver and options) is not repeated (its point is restored: solvers are deterministic on the same data);
with ``fallback``, a solve that failed (a solver error, a status other than optimal, or a point claiming a
margin its recomputed matrix does not have) is repeated with the second installed solver
(:data:`SECOND_SOLVER`), and the better point is kept (:meth:`Program.verdict` decides). A program may solve in
other coordinates than its verdict: :attr:`Program.original` maps the solver's values back, and every
verdict is taken on the matrix rebuilt in the original coordinates. Below the programs, a solve whose problem data
(arrays, cones, solver and options) went to the solver before takes that answer again (:func:`_solve_problem`):
two programs that compile to the same data (the x-side of Theorem 1 and of Corollary 1 when their Schur weights
agree) cost one solve.
"""

from __future__ import annotations

import math
import threading
import time
import warnings
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Callable, NamedTuple

import numpy as np

from bench.limits import DeadlineExceeded, check_deadline, remaining_time

__all__ = ["SECOND_SOLVER", "VERIFY_TOL", "Program", "cached_program", "classify", "conclude", "margin_program"]

#: The verification tolerance of :func:`classify`, relative to ``max(1, max |M_ij|)`` (:func:`verify_tol`).
VERIFY_TOL = 1e-7


def sym(M):
    """Symmetric part of a cvxpy expression or array (so ``<<`` sees a symmetric matrix)."""
    return 0.5 * (M + M.T)  # not "/ 2": cvxpy's COO backend rejects it on some parameter-affine terms


def diag(v):
    """``diag(v)`` of a cvxpy vector or of a numpy array."""
    if isinstance(v, np.ndarray):
        return np.diag(v)
    import cvxpy as cp

    return cp.diag(v)


def _sym_eig(M: np.ndarray, k: int) -> float:
    M = np.asarray(M, dtype=float)
    return float(np.linalg.eigvalsh((M + M.T) / 2)[k]) if np.all(np.isfinite(M)) else float("nan")


def max_eig(M: np.ndarray) -> float:
    """Largest eigenvalue of the symmetric part of ``M`` (NaN if ``M`` is not finite)."""
    return _sym_eig(M, -1)


def min_eig(M: np.ndarray) -> float:
    """Smallest eigenvalue of the symmetric part of ``M`` (NaN if ``M`` is not finite)."""
    return _sym_eig(M, 0)


def verify_tol(M: np.ndarray) -> float:
    """The tolerance :func:`classify` applies to a margin of ``M``: ``VERIFY_TOL * max(1, max |M_ij|)``."""
    M = np.asarray(M, dtype=float)
    return VERIFY_TOL * max(1.0, float(np.max(np.abs(M)))) if M.size and np.all(np.isfinite(M)) else VERIFY_TOL


def classify(margin: float, M: np.ndarray) -> str:
    """``"verified"`` (``margin < -tol``), ``"marginal"`` (``|margin| <= tol``) or ``"violated"``
    (otherwise, NaN too) for the largest eigenvalue ``margin`` of ``M``, ``tol = verify_tol(M)``."""
    if not math.isfinite(margin):
        return "violated"
    tol = verify_tol(M)
    if margin < -tol:
        return "verified"
    return "marginal" if margin <= tol else "violated"


def is_positive_definite(X: np.ndarray) -> bool:
    """True when the symmetric matrix ``X`` is verified positive definite (:func:`classify` of ``-X``)."""
    X = np.asarray(X, dtype=float)
    return classify(max_eig(-X), X) == "verified"


@dataclass
class SolveOutcome:
    """The outcome of one cvxpy solve (``solver_s``: the solver's own time, part of ``solve_s``)."""

    status: str
    compile_s: float
    solve_s: float
    error: str = ""
    value: float = float("nan")
    solver_s: float = 0.0

    @property
    def solved(self) -> bool:
        return self.status in ("optimal", "optimal_inaccurate")


#: The solvers' own wall-clock limit options (seconds).
_TIME_LIMIT_OPTION = {"CLARABEL": "time_limit", "SCS": "time_limit_secs"}


def solve_timed(problem, solver: str = "CLARABEL", **opts) -> SolveOutcome:
    """Solve ``problem`` cold, timed, given the time left (module docstring); a solver failure: ``"solver_error"``."""
    import cvxpy as cp

    check_deadline("before an SDP solve")
    granted = remaining_time()
    if granted is not None and solver.upper() in _TIME_LIMIT_OPTION:
        granted = max(granted, 1e-3)
        opts.setdefault(_TIME_LIMIT_OPTION[solver.upper()], granted)
    t0 = time.perf_counter()
    opts = {k: v for k, v in opts.items() if k != "warm_start"}
    reused = False
    try:
        with warnings.catch_warnings():  # the status carries "inaccurate"; no stray warnings
            warnings.simplefilter("ignore", UserWarning)
            if getattr(getattr(problem.solve, "__func__", None), "__module__", "") == "cvxpy.problems.problem":
                reused = _solve_problem(problem, solver, opts)
            else:  # cvxpy's solve replaced, on the class or the instance (an injected fault): called as it is
                problem.solve(solver=solver, warm_start=False, **opts)
        status = str(problem.status)
        err = ""
    except cp.error.SolverError as exc:
        status, err = "solver_error", str(exc).splitlines()[0] if str(exc) else "solver failed"
    wall = time.perf_counter() - t0
    if granted is not None and wall >= 0.9 * granted:
        raise DeadlineExceeded(f"an SDP solve ({solver}, {wall:.3g} s of the {granted:.3g} s left)")
    check_deadline(f"an SDP solve ({solver}, {wall:.3g} s)")
    comp = min(float(getattr(problem, "compilation_time", None) or 0.0), wall)
    val = problem.value if status in ("optimal", "optimal_inaccurate") else float("nan")
    stats = getattr(problem, "solver_stats", None) if status != "solver_error" else None
    own = 0.0 if reused else min(float(getattr(stats, "solve_time", None) or 0.0), wall - comp)
    out = SolveOutcome(status, comp, wall - comp, err, float(val) if val is not None else float("nan"), own)
    _tally["reused" if reused else "n"] += 1
    for k in ("compile_s", "solve_s", "solver_s"):
        _tally[k] += getattr(out, k)
    return out


#: Solver answers kept per thread by their problem data (least recently used dropped first): :func:`_solve_problem`;
#: :func:`clear_program_cache` drops them too.
DATA_MEMO_SIZE = 512


def _answers() -> OrderedDict:
    return _LOCAL.__dict__.setdefault("answers", OrderedDict())


def _detached(raw):
    """A solver's raw answer that no unpacked value shares memory with (SCS: a dict of arrays, copied; CLARABEL:
    lists, which cvxpy copies into new arrays when it unpacks them)."""
    import copy

    return copy.deepcopy(raw) if isinstance(raw, dict) else raw


def _data_key(solver: str, data: dict, opts: dict) -> bytes:
    """A digest of what a solver is given: its name and options, every array and sparse matrix of ``data``
    (values, pattern, shape, type) and the cones (``dims``)."""
    import hashlib

    import scipy.sparse as sp

    h = hashlib.blake2b(repr((solver.upper(), sorted((k, repr(v)) for k, v in opts.items()))).encode(),
                        digest_size=20)
    for k in sorted(data):
        v = data[k]
        h.update(k.encode())
        if sp.issparse(v):
            v = v.tocsc()
            parts = (v.data, v.indices, v.indptr)
            h.update(repr(("sparse", v.shape, *(a.dtype.str for a in parts))).encode())
            for a in parts:
                h.update(np.ascontiguousarray(a).tobytes())
        elif isinstance(v, np.ndarray):
            h.update(repr(("array", v.shape, v.dtype.str)).encode())
            h.update(np.ascontiguousarray(v).tobytes())
        elif k == "dims" or v is None or isinstance(v, (int, float, str, bool)):
            h.update(repr(v).encode())
        else:  # the parametrised program cvxpy keeps beside the data: what it gives the solver is above
            h.update(type(v).__name__.encode())
    return h.digest()


def _solve_problem(problem, solver: str, opts: dict) -> bool:
    """``problem.solve(solver=solver, **opts)`` cold, as cvxpy does it (compile, solve the data, unpack), the solver's
    answer taken from this thread's memo (:data:`DATA_MEMO_SIZE` answers) when the same data went to the same solver
    with the same options before (another program that compiles to the same data, e.g. the x-side of Theorem 1 and
    of Corollary 1 when their Schur weights agree): a solver is deterministic on the same data. Returns whether the
    answer was reused."""
    import cvxpy as cp

    for parameter in problem.parameters():  # as cvxpy's own solve: an unset one fails loudly
        if parameter.value is None:
            raise cp.error.ParameterError(
                f"A Parameter (whose name is '{parameter.name()}') does not have a value associated with it; all "
                "Parameter objects must have values before solving a problem.")
    data, chain, inverse = problem.get_problem_data(solver, solver_opts=opts)
    key = _data_key(solver, data, opts)
    memo = _answers()
    raw = memo.get(key)
    reused = raw is not None
    if reused:
        memo.move_to_end(key)
        raw = _detached(raw)
    else:
        raw = chain.solve_via_data(problem, data, False, False, dict(opts))
        memo[key] = _detached(raw)
        while len(memo) > DATA_MEMO_SIZE:
            memo.popitem(last=False)
    problem.unpack_results(raw, chain, inverse)
    return reused


_tally = {"n": 0, "compile_s": 0.0, "solve_s": 0.0, "solver_s": 0.0, "reused": 0}


def solve_tally() -> dict:
    """This process's SDP solves since :func:`reset_solve_tally`: ``n`` and the seconds of :class:`SolveOutcome`;
    ``reused``: solves answered from a program's memo instead (:meth:`Program.solve`) or from the solver answers kept by
    problem data (:func:`_solve_problem`)."""
    return dict(_tally)


def reset_solve_tally() -> None:
    """Zero :func:`solve_tally`."""
    _tally.update(n=0, compile_s=0.0, solve_s=0.0, solver_s=0.0, reused=0)


#: The solver tried when the first fails (:meth:`Program.solve` with ``fallback``): both are installed.
SECOND_SOLVER = {"CLARABEL": "SCS", "SCS": "CLARABEL"}

#: Solutions a program keeps by parameter values (least recently used dropped first).
MEMO_SIZE = 256


def log_search(
    objective: Callable[[float], float],
    lo: float,
    hi: float,
    *,
    n_grid: int = 9,
    n_refine: int = 5,
) -> tuple[float, float]:
    """The best ``(x, objective(x))`` tried on a log grid of ``[lo, hi]``, golden-section refined (NaN: ``-inf``)."""
    points: list[tuple[float, float]] = []

    def ev(x: float) -> float:
        v = objective(x)
        v = -math.inf if v is None or not math.isfinite(v) else float(v)
        points.append((x, v))
        return v

    grid = np.logspace(math.log10(lo), math.log10(hi), n_grid)
    vals = [ev(float(x)) for x in grid]
    k = int(np.argmax(vals))
    if n_refine > 0 and math.isfinite(vals[k]):
        a = math.log10(grid[max(k - 1, 0)])
        b = math.log10(grid[min(k + 1, n_grid - 1)])
        g = (math.sqrt(5) - 1) / 2
        c, d = b - g * (b - a), a + g * (b - a)
        fc, fd = ev(10**c), ev(10**d)
        for _ in range(max(n_refine - 2, 0)):
            if fc >= fd:
                b, d, fd = d, c, fc
                c = b - g * (b - a)
                fc = ev(10**c)
            else:
                a, c, fc = c, d, fd
                d = a + g * (b - a)
                fd = ev(10**d)
    return max(points, key=lambda p: p[1])


def assemble(blocks_fn: Callable[[dict], list], values: dict, *, numeric: bool):
    """Build a block matrix from ``blocks_fn(values)`` with cvxpy (``numeric=False``) or numpy."""
    rows = blocks_fn(values)
    if numeric:
        return np.block([[np.asarray(b, dtype=float) for b in row] for row in rows])
    import cvxpy as cp

    return cp.bmat(rows)


class BestPoint(NamedTuple):
    """A solution of a :class:`Program`: objective, variable and parameter values by name, status, error."""

    value: float
    values: dict
    status: str
    error: str = ""


@dataclass
class Program:
    """A margin-maximisation LMI program with parameters (compiled once, solved many times).

    Attributes
    ----------
    problem : cvxpy.Problem
    variables, parameters : dict
        cvxpy variables (``slack`` the margin) and parameters by name; an ndarray among the
        parameters moves to ``constants`` (baked in), a :class:`Pattern` to ``patterns``.
    blocks : callable
        ``blocks(values) -> list of lists``, the LMI matrix from a dict of values.
    positive : tuple of str
        Decision matrices that must be positive definite.
    compile_s, solve_s, n_solves
        cvxpy's compile (with the expression tree's ``build_s``), the other solve seconds, and the
        solves since :meth:`reset` (those answered from :attr:`memo` included, so that a result never depends
        on what this process solved before).
    last_status, last_error, solver : str
        The last solve's status, error message and solver.
    best : BestPoint or None
        The best solution since :meth:`reset`.
    reused : bool
        Whether :func:`cached_program` returned it from its cache (under ``cache_key``).
    problems : dict
        One cvxpy problem per solver (sharing variables and parameters).
    original : callable or None
        ``original(values) -> values`` maps the solver's values to the coordinates the LMI is verified in
        (None: the same); set by the caller for each use, cleared by :meth:`reset`.
    n_reused : int
        Solves since :meth:`reset` answered from :attr:`memo` (no solver called; :func:`solve_tally` counts those
        called).
    tried : str
        The solvers the last :meth:`solve` tried, e.g. ``"CLARABEL:solver_error -> SCS:optimal"``.
    """

    problem: object
    variables: dict
    parameters: dict
    blocks: Callable[[dict], list]
    positive: tuple[str, ...]
    compile_s: float = 0.0
    solve_s: float = 0.0
    n_solves: int = 0
    last_status: str = ""
    last_error: str = ""
    best: BestPoint | None = None
    solver: str = "CLARABEL"
    build_s: float = 0.0
    reused: bool = False
    constants: dict = field(default_factory=dict)
    cache_key: tuple | None = None
    problems: dict = field(default_factory=dict, repr=False)
    patterns: dict = field(default_factory=dict, repr=False)
    original: Callable[[dict], dict] | None = field(default=None, repr=False)
    n_reused: int = 0
    tried: str = ""
    memo: OrderedDict = field(default_factory=OrderedDict, repr=False)

    def __post_init__(self) -> None:
        arrays = {k: v for k, v in self.parameters.items() if isinstance(v, np.ndarray)}
        self.constants = {**self.constants, **arrays}
        self.patterns = {k: v for k, v in self.parameters.items() if isinstance(v, Pattern)}
        self.parameters = {k: v for k, v in self.parameters.items() if k not in arrays and k not in self.patterns}
        self.parameters.update({pat.param.name(): pat.param for pat in self.patterns.values()})

    def set(self, **params) -> None:
        """Set parameter values (scalars or arrays of the parameter's shape)."""
        for k, v in params.items():
            if k in self.patterns:
                self.patterns[k].set(v)
            else:
                self.parameters[k].value = v

    def _problem_for(self, solver: str):
        """The problem for ``solver`` (cvxpy drops its compiled form when the solver changes)."""
        import cvxpy as cp

        key = solver.upper()
        prob = self.problems.get(key)
        if prob is None:
            prob = self.problem if not self.problems else cp.Problem(self.problem.objective, self.problem.constraints)
            self.problems[key] = prob
        return prob

    def reset(self) -> None:
        """Forget counters, the best point and every parameter value (an unset one fails the solve)."""
        self.compile_s = self.solve_s = 0.0
        self.n_solves = self.n_reused = 0
        self.last_status = self.last_error = self.tried = ""
        self.best = None
        self.solver = "CLARABEL"
        self.original = None
        for p in self.parameters.values():
            p.value = None

    def solve(self, *, solver: str = "CLARABEL", solver_opts: dict | None = None, fallback: bool | str = False,
              **params: float) -> float:
        """Solve at the given parameter values; return the objective, the margin ``slack`` (NaN if not solved).

        With ``fallback``, a solve that failed (:meth:`failed`; ``fallback="errors"``: only a solve without a
        point) is repeated with the second solver (:data:`SECOND_SOLVER`); its point is kept when it verifies or
        when the first solve has none, else the first is restored. :attr:`tried` names the solvers and statuses.
        """
        self.set(**params)
        value = self._solve_once(solver, solver_opts)
        self.tried = f"{solver.upper()}:{self.last_status}"
        return self.settle(value, claims=fallback != "errors") if fallback else value

    def settle(self, value: float = float("nan"), *, claims: bool = True) -> float:
        """After a solve (the parameters as they were): when it failed (:meth:`failed`), solve again with the
        second solver (:data:`SECOND_SOLVER`) and keep its point when it verifies or when the first has none,
        else restore the first. Returns the objective of the point kept (``value``: the first's)."""
        if not self.failed(claims):
            return value
        first = self._snapshot(value)
        used = self.solver
        alt = SECOND_SOLVER.get(used, "CLARABEL")
        value = self._solve_once(alt, FALLBACK_SCS_OPTS if alt == "SCS" else None)
        self.tried = f"{self.tried or used + ':' + first.status} -> {alt}:{self.last_status}"
        if first.status in ("optimal", "optimal_inaccurate") and not self.verified():
            value = self._restore(first)
            self.solver = used
            self.tried += f" (kept {used})"
        return value

    def failed(self, claims: bool = True) -> bool:
        """True when the last solve needs a second solver: no point (an error, an inaccurate infeasibility, an
        iteration limit; a certificate of infeasibility is an answer), or (``claims``) a point whose margin
        ``slack`` claims more than its recomputed matrix verifies (:meth:`verdict`)."""
        if self.last_status in ("infeasible", "unbounded"):
            return False
        if self.last_status not in ("optimal", "optimal_inaccurate"):
            return True
        if not claims:
            return False
        slack = self.values().get("slack")
        if slack is None or not math.isfinite(float(slack)):
            return False
        M = self.numeric_matrix()
        return M is not None and float(slack) > verify_tol(M) and not self.verified()

    def _memo_key(self, solver: str, opts: dict | None) -> bytes:
        import hashlib

        import cvxpy as cp

        # the solve path's identity too: a solver swapped (a test's injected fault) never answers from another's memory
        path = (id(solve_timed), id(cp.Problem.solve))
        h = hashlib.blake2b(repr((solver.upper(), sorted((opts or {}).items()), path)).encode(), digest_size=20)
        for k in sorted(self.parameters):
            v = self.parameters[k].value
            h.update(k.encode())
            h.update(b"unset" if v is None else np.ascontiguousarray(np.asarray(v, dtype=float)).tobytes())
        return h.digest()

    def _solve_once(self, solver: str, opts: dict | None) -> float:
        """One solve, or its memo (:attr:`memo`): the same program at the same parameter values gives the same point."""
        key = self._memo_key(solver, opts)
        hit = self.memo.get(key)
        if hit is not None:
            self.memo.move_to_end(key)
            self.n_solves += 1
            self.n_reused += 1
            _tally["reused"] += 1
            value = self._restore(hit)
        else:
            try:
                out = solve_timed(self._problem_for(solver), solver, **(opts or {}))
            except BaseException as exc:
                if not isinstance(exc, Exception) and self.cache_key is not None:  # cut short: never reuse
                    _cache().pop(self.cache_key, None)
                raise
            if not self.reused and self.n_solves == self.n_reused:
                self.compile_s += self.build_s
            self.compile_s += out.compile_s
            self.solve_s += out.solve_s
            self.n_solves += 1
            self.last_status, self.last_error = out.status, out.error
            value = out.value if out.solved else float("nan")
            self.memo[key] = self._snapshot(value)
            while len(self.memo) > MEMO_SIZE:
                self.memo.popitem(last=False)
        self.solver = solver.upper()
        if self.last_status in ("optimal", "optimal_inaccurate") and (self.best is None or value > self.best.value):
            self.best = self._snapshot(value)
        return value

    def _snapshot(self, value: float) -> BestPoint:
        held = {**self.variables, **self.parameters}
        snap = {k: (None if v.value is None else np.array(v.value)) for k, v in held.items()}
        return BestPoint(value, snap, self.last_status, self.last_error)

    def _restore(self, point: BestPoint) -> float:
        held = {**self.variables, **self.parameters}
        for k, v in point.values.items():
            held[k].value = v
        self.last_status, self.last_error = point.status, point.error
        return point.value

    def restore_best(self) -> bool:
        """Put the best solution back into the variables and parameters (False: there is none)."""
        if self.best is None:
            return False
        self._restore(self.best)
        self.last_error = ""
        return True

    def values(self) -> dict:
        """Numeric values of all variables and parameters at the last solve."""
        vals = dict(self.constants)
        vals.update({k: (None if v.value is None else np.array(v.value, dtype=float)) for k, v in self.variables.items()})
        for k, p in self.parameters.items():
            vals[k] = None if p.value is None else (float(p.value) if p.size == 1 and not p.shape
                                                     else np.array(p.value, dtype=float))
        vals.update({k: pat.value() for k, pat in self.patterns.items()})
        return vals

    def checked_values(self) -> dict:
        """:meth:`values` in the coordinates the LMI is verified in (:attr:`original`)."""
        vals = self.values()
        return self.original(vals) if self.original is not None and all(v is not None for v in vals.values()) \
            else vals

    def verdict(self) -> tuple[str, float]:
        """The last solution checked: :func:`classify` of the rebuilt LMI (``"violated"`` when a decision
        matrix is not positive definite; the solver status when unsolved) and its largest eigenvalue, in the
        original coordinates (:meth:`checked_values`)."""
        M = self.numeric_matrix() if self.last_status in ("optimal", "optimal_inaccurate") else None
        if M is None:
            return self.last_status, float("nan")
        margin = max_eig(M)
        verdict = classify(margin, M)
        vals = self.checked_values()
        if verdict == "verified" and not all(is_positive_definite(vals[k]) for k in self.positive):
            verdict = "violated"
        return verdict, margin

    def verified(self) -> bool:
        """True when :func:`classify` verifies the last solution's LMI and decision matrices."""
        return self.verdict()[0] == "verified"

    def numeric_matrix(self, **at) -> np.ndarray | None:
        """The LMI matrix rebuilt with numpy from the last solution, in the original coordinates (None if
        unsolved); ``at`` overrides values (e.g. ``lam=0.3``: the same point at another rate)."""
        vals = self.values()
        if any(v is None for v in vals.values()):
            return None
        vals = self.checked_values()
        return assemble(self.blocks, {**vals, **at}, numeric=True)


def margin_program(blocks_fn, variables: dict, parameters: dict, positive: tuple[str, ...],
                   extra: Callable[[dict], list] | None = None, *, cap: float = 1e3) -> Program:
    """Build ``max slack s.t. M(v) << -slack I, X >> slack I (X in positive), X << cap I, slack <= 1``.

    Parameters
    ----------
    blocks_fn : callable
        Builds the blocks of M from a dict of values (cvxpy or numpy).
    variables, parameters : dict
        As :class:`Program`'s (``slack`` among the variables).
    positive : tuple of str
        Decision matrices constrained ``>> slack I`` and ``<< cap I``.
    extra : callable, optional
        ``extra(vars_and_params) -> list of constraints``.
    cap : float

    Returns
    -------
    Program
    """
    import cvxpy as cp

    t_build = time.perf_counter()
    allv = {**variables, **{k: (v.expr if isinstance(v, Pattern) else v) for k, v in parameters.items()}}
    M = sym(assemble(blocks_fn, allv, numeric=False))
    slack = variables["slack"]
    cons = [M << -slack * np.eye(M.shape[0]), slack <= 1]
    for name in positive:
        X = variables[name]
        k = X.shape[0]
        cons += [X >> slack * np.eye(k), X << cap * np.eye(k)]
    if extra is not None:
        cons += extra(allv)
    problem = cp.Problem(cp.Maximize(slack), cons)
    return Program(problem, variables, parameters, blocks_fn, positive, build_s=time.perf_counter() - t_build)


#: A matrix with this fraction of nonzeros or more enters a program as a Parameter, a sparser one as a Pattern.
DENSE_FRACTION = 0.75


def digest(raw) -> str:
    """SHA-256 of an array's shape and values, exact (every NaN alike); a non-numeric value by its type."""
    import hashlib
    import json

    try:
        a = np.asarray(raw)
    except Exception as exc:  # noqa: BLE001 - an array-like that fails to convert
        return f"not an array: {type(exc).__name__}"
    if a.dtype.kind not in "biufc":
        return f"not numeric: {type(raw).__name__} {a.dtype}"
    a = a.astype(np.complex128 if a.dtype.kind == "c" else np.float64)
    a = np.where(np.isnan(a), np.nan, a)
    return hashlib.sha256(json.dumps([list(a.shape), str(a.dtype)]).encode() + np.ascontiguousarray(a).tobytes()).hexdigest()


class Pattern:
    """A matrix of sparsity pattern ``mask`` in a program: ``expr``, its nonzeros' Parameter placed (DPP)."""

    def __init__(self, name: str, mask: np.ndarray) -> None:
        import cvxpy as cp
        import scipy.sparse as sp

        mask = np.asarray(mask, dtype=bool)
        self.name, self.shape, self.mask = name, mask.shape, mask
        self.rows, self.cols = np.nonzero(mask)
        nnz = self.rows.size
        r = mask.shape[0]
        place = sp.csc_matrix((np.ones(nnz), (self.cols * r + self.rows, np.arange(nnz))), shape=(mask.size, nnz))
        self.param = cp.Parameter(nnz, name=name + ".nz")
        self.expr = cp.reshape(place @ self.param, mask.shape, order="F")

    def set(self, M: np.ndarray) -> None:
        """Set the nonzeros from a whole matrix (its entries outside the pattern must be zero)."""
        M = np.asarray(M, dtype=float)
        if M.shape != self.shape:
            raise ValueError(f"{self.name}: expected shape {self.shape}, got {M.shape}")
        if np.any(M[~self.mask] != 0.0):
            raise ValueError(f"{self.name}: nonzero entries outside the sparsity pattern the program was built for")
        self.param.value = M[self.rows, self.cols]

    def value(self) -> np.ndarray | None:
        """The whole matrix (None when unset)."""
        if self.param.value is None:
            return None
        M = np.zeros(self.shape)
        M[self.rows, self.cols] = self.param.value
        return M


@dataclass(frozen=True)
class Matrices:
    """How a design's matrices (classified by :func:`matrices`) enter a program; ``key`` is part of its cache key."""

    values: dict
    dense: frozenset

    @property
    def key(self) -> tuple:
        return tuple((k, "parameter", M.shape) if k in self.dense else (k, "pattern", M.shape, digest(M != 0))
                     for k, M in self.values.items())

    def parameters(self) -> dict:
        """A Parameter, :class:`Pattern` or (all zero) the array itself, by name."""
        import cvxpy as cp

        return {k: cp.Parameter(M.shape, name=k) if k in self.dense else Pattern(k, M != 0) if np.any(M != 0) else M
                for k, M in self.values.items()}

    def settable(self) -> dict:
        """Values for :meth:`Program.set` (every matrix that is not all zero)."""
        return {k: M for k, M in self.values.items() if k in self.dense or np.any(M != 0)}


def matrices(*, all_parameters: bool = False, **mats: np.ndarray) -> Matrices:
    """:class:`Matrices` by the names the blocks read, dense by :data:`DENSE_FRACTION` (all with ``all_parameters``)."""
    vals = {k: np.asarray(M, dtype=float) for k, M in mats.items()}
    dense = frozenset(k for k, M in vals.items()
                      if all_parameters or (M.size and np.count_nonzero(M) >= DENSE_FRACTION * M.size))
    return Matrices(vals, dense)


def plant_matrices(plant) -> Matrices:
    """:func:`matrices` of the plant's ``A``, ``B``, ``C``."""
    return matrices(A=plant.A, B=plant.B, C=plant.C)


def scalar_parameters(*names: str) -> dict:
    """Scalar cvxpy Parameters by name (constants such as rho, beta, gamma; any sign)."""
    import cvxpy as cp

    return {k: cp.Parameter(name=k) for k in names}


#: Compiled programs kept per thread (least recently used dropped first).
PROGRAM_CACHE_SIZE = 24
_LOCAL = threading.local()


def _cache() -> OrderedDict:
    return _LOCAL.__dict__.setdefault("programs", OrderedDict())


def cached_program(key: tuple, build: Callable[[], Program]) -> Program:
    """The compiled :class:`Program` for ``key``, built by ``build()`` on first use, then reused.

    The program comes back :meth:`Program.reset`, from this thread's cache (:data:`PROGRAM_CACHE_SIZE`).

    Parameters
    ----------
    key : tuple
        Everything that fixes the problem's structure (design, hyperparameters, shapes, flags).
    build : callable
        Builds the program.

    Returns
    -------
    Program
    """
    cache = _cache()
    prog = cache.get(key)
    if prog is None:
        prog = build()
        prog.cache_key = key
        cache[key] = prog
        while len(cache) > PROGRAM_CACHE_SIZE:
            cache.popitem(last=False)
    else:
        cache.move_to_end(key)
        prog.reused = True
    prog.reset()
    return prog


def clear_program_cache() -> None:
    """Drop this thread's compiled programs and the solver answers kept by problem data (:func:`_solve_problem`)."""
    _cache().clear()
    _answers().clear()


def conclude(prog: Program, *, what: str, normalisation: str, searched: str, fallback: bool = True) -> dict:
    """Turn the last solve of ``prog`` into status, reason and evidence.

    With ``fallback``, a last solve that failed (:meth:`Program.failed`) is first repeated with the second
    solver (:meth:`Program.settle`; the cost is in ``prog``'s counters).

    ``feasible``: the rebuilt LMI verified (:func:`classify`), decision matrices positive definite;
    ``marginal``: its largest eigenvalue within the tolerance of zero; ``infeasible`` under the
    normalisation (named in the reason): the best slack is not positive; ``undecided``: the
    solver failed, or claimed a margin its point does not have.

    Returns
    -------
    dict
        ``status``, ``reason``, ``margin``, ``min_eig``, ``lmi_size``, ``solver_status``, ``slack``.
    """
    if fallback and prog.last_status:
        prog.settle()
    out: dict = {"solver_status": prog.last_status, "min_eig": {}, "margin": float("nan"), "lmi_size": 0}
    if prog.last_status not in ("optimal", "optimal_inaccurate"):
        msg = f": {prog.last_error}" if prog.last_error else ""
        out.update(status="undecided", reason=f"solver status {prog.last_status!r}{msg} ({searched})")
        return out
    M = prog.numeric_matrix()
    vals = prog.values()
    slack = float(vals["slack"])
    verdict, out["margin"] = prog.verdict()
    out.update(slack=slack, lmi_size=int(M.shape[0]), min_eig={k: min_eig(vals[k]) for k in prog.positive})
    if verdict == "verified":
        out.update(status="feasible", reason="")
    elif verdict == "marginal" and slack <= verify_tol(M):
        out.update(status="marginal", reason=(
            f"{what}: the best margin is within the verification tolerance of zero (max eig of the LMI "
            f"{out['margin']:.3g}, tolerance {verify_tol(M):.2g}) {searched}, under {normalisation}: "
            "not strictly feasible there, and not proven infeasible"))
    elif slack <= 0:
        out.update(
            status="infeasible",
            reason=(
                f"{what}: infeasible under {normalisation}: no strictly feasible point; best slack = {slack:.3g} "
                f"(max eig of the LMI = {out['margin']:.3g}) {searched}"
            ),
        )
    else:
        out.update(
            status="undecided",
            reason=(
                f"{what}: solver reported slack = {slack:.3g} > 0 but the recomputed LMI has max eig "
                f"{out['margin']:.3g} and min eig of decision matrices {out['min_eig']}"
            ),
        )
    return out


SCS_OPTS = {"eps_abs": 1e-6, "eps_rel": 1e-6, "max_iters": 100_000}

#: SCS as the second solver of :meth:`Program.settle`: the same accuracy, a bounded effort (a few tenths of a second
#: on the ladder's programs; a point it leaves inaccurate is still verified like any other).
FALLBACK_SCS_OPTS = {**SCS_OPTS, "max_iters": 2_500}

SCS_FROM_N = 8


def solve_side(prog: Program, solver: str = "auto", n: int | None = None) -> str:
    """Solve ``prog``; ``"auto"``: Clarabel when ``n < SCS_FROM_N``, else SCS (:data:`SCS_OPTS`), then Clarabel
    if SCS's point does not verify; one named solver falls back to the other when it fails (:meth:`Program.settle`).
    Returns the solvers tried: ``"SCS:optimal (not verified) -> CLARABEL:optimal"``."""
    if solver == "auto" and n is not None and n < SCS_FROM_N:
        solver = "CLARABEL"
    if solver == "auto":
        prog.solve(solver="SCS", solver_opts=SCS_OPTS)
        if prog.verified():
            return f"SCS:{prog.last_status}"
        first = f"SCS:{prog.last_status} (not verified)"
        prog.solve(solver="CLARABEL")
        return f"{first} -> CLARABEL:{prog.last_status}"
    prog.solve(solver=solver, solver_opts=SCS_OPTS if solver == "SCS" else None, fallback=True)
    return prog.tried
