"""Fuzzing with hypothesis: plant construction, design hyperparameters and CLI arguments.

Property: only the project's documented exceptions escape (``PlantError``, ``DesignError``,
both ``ValueError`` subclasses), each naming the field or parameter in the first words of its
message; never a bare numpy / scipy / cvxpy / Python error. The CLI returns an exit code and
never raises.

Every property counts the inputs it tried and the ones that escaped; the totals are printed
at the end of the module (``fuzz: N inputs tried, M escaped``). The default budget keeps the
module well under a minute; ``-m slow`` runs a larger one.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import fields

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from bench.registry import DESIGNS
from designs import GAIN_STATUSES, STATUSES, Design, DesignError
from designs._parts import ESTIMATORS, FEEDBACKS, Part
from plants._core import Constants, Plant, PlantError

#: inputs tried and escapes, per property family
STATS: dict[str, list[int]] = {"plant": [0, 0], "constants": [0, 0], "design": [0, 0], "part_run": [0, 0],
                               "cli": [0, 0]}

FAST = settings(max_examples=100, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
BIG = settings(max_examples=2000, deadline=None, database=None,
               suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@pytest.fixture(scope="module", autouse=True)
def _summary(request):
    yield
    tried = sum(v[0] for v in STATS.values())
    escaped = sum(v[1] for v in STATS.values())
    detail = ", ".join(f"{k} {v[0]}/{v[1]}" for k, v in STATS.items())
    rep = request.config.pluginmanager.get_plugin("terminalreporter")
    capman = request.config.pluginmanager.get_plugin("capturemanager")
    if rep is not None and capman is not None:
        with capman.global_and_fixture_disabled():
            rep.write_line(f"\nfuzz: {tried} inputs tried, {escaped} escaped (tried/escaped: {detail})")


def _check(kind: str, fn, documented: tuple[type[BaseException], ...], names_field) -> object:
    """Run ``fn``; count it; fail on an undocumented exception or a message that names no field."""
    STATS[kind][0] += 1
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # overflow in a fuzzed f is expected
            return fn()
    except documented as exc:
        if not names_field(str(exc)):
            STATS[kind][1] += 1
            raise AssertionError(f"{type(exc).__name__} does not name the field: {exc}") from exc
    except Exception as exc:
        STATS[kind][1] += 1
        raise AssertionError(f"undocumented exception escaped: {type(exc).__name__}: {exc}") from exc
    return None


# -- values -----------------------------------------------------------------------------------
SPECIAL = [math.nan, math.inf, -math.inf, 1e308, -1e308, 1e-308, 5e-324, 0.0, -0.0, 1e300, -1e-300]
_OBJ = object()
GARBAGE = st.sampled_from([None, "abc", "1.5", "", [], [[1, 2], [3]], {"a": 1}, 1 + 2j, True, b"x", 10**400, _OBJ,
                           (1, 2, 3)]) | st.builds(lambda: np.array([[1j]]))
SCALARS = st.one_of(st.floats(-10, 10), st.sampled_from(SPECIAL), st.floats(allow_nan=True, allow_infinity=True),
                    st.integers(-(10**6), 10**6))


def _any_array(draw, max_dim: int = 4):
    shape = draw(st.lists(st.integers(0, max_dim), min_size=0, max_size=3).map(tuple))
    return draw(arrays(np.float64, shape, elements=SCALARS.filter(lambda v: isinstance(v, float))))


# -- plants -----------------------------------------------------------------------------------
def _f_catalog(n: int) -> dict:
    def batch_fail(x):
        if np.ndim(x) == 2:
            raise IndexError("only states, no batches")
        return np.zeros(n)

    def raiser(x):
        raise ZeroDivisionError("fuzzed f")

    return {
        "zero": lambda x: np.zeros_like(np.asarray(x, dtype=float)),
        "tanh": lambda x: 0.5 * np.tanh(x),
        "cube": lambda x: -np.asarray(x) ** 3,
        "drop": lambda x: np.asarray(x)[:-1],
        "transpose": lambda x: np.asarray(x).T,
        "scalar": lambda x: 0.0,
        "nan": lambda x: np.asarray(x) * math.nan,
        "inf_off_origin": lambda x: np.where(np.asarray(x) != 0, math.inf, 0.0),
        "raise": raiser,
        "none": lambda x: None,
        "string": lambda x: "abc",
        "object": lambda x: object(),
        "complex": lambda x: np.asarray(x) * 1j,
        "offset": lambda x: np.asarray(x) + 1.0,
        "list": lambda x: list(x),
        "batch_fail": batch_fail,
        "huge": lambda x: np.asarray(x) * 1e308 * 10,
        "generator": lambda x: (v for v in x),
        "dict": lambda x: {},
        "not_callable": 42,
    }


def _jac_catalog(n: int) -> dict:
    def raiser(x):
        raise KeyError("fuzzed jacobian")

    return {
        "none": None,
        "good": lambda x: np.zeros((n, n)),
        "wrong_shape": lambda x: np.zeros((n, n + 1)),
        "raise": raiser,
        "string": lambda x: "J",
        "nan": lambda x: np.full((n, n), math.nan),
        "complex": lambda x: np.eye(n) * 1j,
        "not_callable": "jacobian",
    }


PLANT_FIELDS = ("id", "A", "B", "C", "x0", "x_hat0", "t_final", "claimed", "bounds", "params", "f", "jacobian")


@st.composite
def plant_kwargs(draw):
    n, m, p = draw(st.integers(1, 4)), draw(st.integers(1, 3)), draw(st.integers(1, 3))
    scale = 10.0 ** draw(st.sampled_from([-300, -8, 0, 8, 150, 300]))

    def good(shape):
        return draw(arrays(np.float64, shape, elements=st.floats(-1, 1))) * scale

    kw = dict(id="fuzz", A=good((n, n)), B=good((n, m)), C=good((p, n)), x0=good((n,)), x_hat0=good((n,)),
              t_final=draw(st.sampled_from([20.0, 1e-9, 1e300])))
    kw["f"] = _f_catalog(n)[draw(st.sampled_from(sorted(_f_catalog(n))))]
    kw["jacobian"] = _jac_catalog(n)[draw(st.sampled_from(sorted(_jac_catalog(n))))]
    for name in draw(st.lists(st.sampled_from(PLANT_FIELDS[:10]), max_size=3, unique=True)):
        if name in ("A", "B", "C", "x0", "x_hat0"):
            how = draw(st.sampled_from(["garbage", "shape", "entry"]))
            if how == "garbage":
                bad = draw(GARBAGE)
            elif how == "shape":
                bad = _any_array(draw)
            else:  # the right shape with one special entry (NaN, inf, 1e308, denormal, ...)
                bad = kw[name].copy()
                bad.flat[draw(st.integers(0, bad.size - 1))] = draw(st.sampled_from(SPECIAL))
        elif name == "t_final":
            bad = draw(st.one_of(SCALARS, GARBAGE))
        elif name == "params":
            bad = draw(st.one_of(GARBAGE, st.dictionaries(st.text(max_size=3), st.one_of(SCALARS, GARBAGE),
                                                          max_size=2)))
        else:
            bad = draw(GARBAGE)
        kw[name] = bad
    return kw


def _names_plant_field(msg: str) -> bool:
    head = msg.split(":", 1)[0]
    return head in PLANT_FIELDS or head.startswith("params[") or head.startswith("constants.")


def _build_plant(kw):
    plant = Plant(**kw)
    # accepted: the invariants the rest of the suite relies on hold
    n = plant.n
    assert plant.A.shape == (n, n) and plant.B.shape[0] == n and plant.C.shape[1] == n
    assert all(np.all(np.isfinite(M)) for M in (plant.A, plant.B, plant.C, plant.x0, plant.x_hat0))
    out = np.asarray(plant.f(plant.x0), dtype=float)
    assert out.shape == (n,) and np.all(np.isfinite(out))
    assert math.isfinite(plant.t_final) and plant.t_final > 0
    return plant


def _plant_property(kw):
    _check("plant", lambda: _build_plant(kw), (PlantError,), _names_plant_field)


@FAST
@given(plant_kwargs())
def test_fuzz_plant_construction(kw):
    _plant_property(kw)


@pytest.mark.slow
@BIG
@given(plant_kwargs())
def test_fuzz_plant_construction_big(kw):
    _plant_property(kw)


CONSTANT_FIELDS = ("alpha", "rho", "beta", "gamma", "radius")


@FAST
@given(st.dictionaries(st.sampled_from(CONSTANT_FIELDS), st.one_of(SCALARS, GARBAGE), max_size=4))
@example({"alpha": 10**400})  # float() of a huge int raises OverflowError
@example({"radius": "1e-3"})
def test_fuzz_constants(kw):
    def names(msg):
        return msg.split(":", 1)[0].startswith("constants.")

    c = _check("constants", lambda: Constants(**kw), (PlantError,), names)
    if c is not None:
        for k in CONSTANT_FIELDS:
            v = getattr(c, k)
            assert v is None or (isinstance(v, float) and math.isfinite(v))


# -- design hyperparameters -------------------------------------------------------------------
def _targets() -> list[tuple[str, list[str], object]]:
    """(label, known parameter names, make(**params)) for every design and part."""
    out = []
    for did in DESIGNS.ids():
        if did.startswith("_"):
            continue
        obj = DESIGNS.create(did)
        if "+" in did:  # a pairing: parameters go to its parts
            for key, part in (("feedback_params", obj.feedback), ("estimator_params", obj.estimator)):
                names = [f.name for f in fields(part)]
                out.append((f"{did}:{key}", names, lambda kw, did=did, key=key: DESIGNS.create(did, **{key: kw})))
            out.append((did, ["feedback_params", "estimator_params"], lambda kw, did=did: DESIGNS.create(did, **kw)))
        else:
            out.append((did, [f.name for f in fields(obj)], lambda kw, did=did: DESIGNS.create(did, **kw)))
    for reg in (FEEDBACKS, ESTIMATORS):
        for pid in reg.ids():
            names = [f.name for f in fields(reg.create(pid))]
            out.append((f"part {pid}", names, lambda kw, reg=reg, pid=pid: reg.create(pid, **kw)))
    return out


TARGETS = _targets()
VALUES = st.one_of(
    SCALARS, GARBAGE, st.booleans(), st.text(max_size=6),
    st.sampled_from(["auto", "CLARABEL", "SCS", "joint", "separated"]),
    st.lists(SCALARS, max_size=3).map(tuple), st.lists(SCALARS, max_size=3),
    st.integers(1, 3).flatmap(lambda k: arrays(np.float64, (k, k), elements=st.floats(-3, 3))),
    st.dictionaries(st.text(max_size=3), SCALARS, max_size=2),
)


@st.composite
def design_params(draw):
    label, names, make = draw(st.sampled_from(TARGETS))
    name = st.one_of(st.sampled_from(names), st.text(max_size=6)) if names else st.text(max_size=6)
    keys = draw(st.lists(name, min_size=1, max_size=3, unique=True))
    return label, make, {k: draw(VALUES) for k in keys}


def _design_property(label, make, kw):
    def names(msg):
        named = [k if k.isidentifier() else repr(k) for k in kw]
        if ":" in label:  # parameters of a pairing's part: "feedback_params: Q: ..."
            named = [label.split(":")[1]]
        return any(msg.startswith(f"{k}:") for k in named)

    obj = _check("design", lambda: make(kw), (DesignError,), names)
    if obj is not None:
        assert isinstance(obj, (Design, Part))


@FAST
@given(design_params())
def test_fuzz_design_hyperparameters(args):
    _design_property(*args)


@pytest.mark.slow
@BIG
@given(design_params())
def test_fuzz_design_hyperparameters_big(args):
    _design_property(*args)


def test_unknown_hyperparameter_is_a_design_error_with_a_suggestion():
    with pytest.raises(DesignError, match=r"^phi: unknown hyperparameter of Thm1 .*did you mean 'phi1'"):
        DESIGNS.create("thm1", phi=0.1)
    with pytest.raises(DesignError, match=r"^estimator_params: Q: unknown hyperparameter of LQEObserver"):
        DESIGNS.create("lqr+lqe", estimator_params={"Q": 1.0})
    with pytest.raises(DesignError, match=r"^n_grid: expected an integer"):
        DESIGNS.create("cor1", n_grid=2.5)


# accepted hyperparameters of the cheap parts are usable: compute() returns a result (or a
# DesignError naming the parameter, e.g. a weight of the wrong size for this plant)
def _small_plant() -> Plant:
    return Plant(id="fuzz2", A=[[0.0, 1.0], [-1.0, -0.5]], B=[[0.0], [1.0]], C=[[1.0, 0.0]],
                 f=lambda x: np.stack([np.zeros_like(np.asarray(x)[0]), 0.1 * np.sin(np.asarray(x)[0])]),
                 x0=[1.0, 0.0], x_hat0=[0.0, 0.0], t_final=2.0)


SMALL = _small_plant()
SMALL_C = Constants(alpha=0.1, rho=0.1, beta=0.01, gamma=0.0)
WEIGHTS = st.one_of(st.none(), st.floats(-2, 5), arrays(np.float64, st.sampled_from([(1, 1), (2, 2), (3, 3), (2, 1)]),
                                                        elements=st.floats(-3, 3)))
CHEAP = {
    "lqr": {"Q": WEIGHTS, "R": WEIGHTS},
    "lqe": {"QN": WEIGHTS, "RN": WEIGHTS},
    "ekf": {k: st.sampled_from([0.01, 0.3, 0.0, -1.0, 1e-9, 2.0, 1e6]) for k in ("dt", "q", "r", "p0")},
    "rh_riccati": {"eps": st.one_of(st.none(), st.floats(1e-6, 1e3)), "n_grid": st.integers(-1, 40),
                   "eps_range": st.tuples(st.floats(1e-6, 1e3), st.floats(1e-6, 1e3)),
                   "residual_tol": st.floats(-1, 1)},
}


@st.composite
def cheap_parts(draw):
    pid = draw(st.sampled_from(sorted(CHEAP)))
    spec = CHEAP[pid]
    keys = draw(st.lists(st.sampled_from(sorted(spec)), min_size=1, max_size=len(spec), unique=True))
    return pid, {k: draw(spec[k]) for k in keys}


@settings(max_examples=60, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(cheap_parts())
def test_fuzz_accepted_part_parameters_are_usable(args):
    pid, kw = args
    reg = FEEDBACKS if pid in FEEDBACKS else ESTIMATORS

    def names(msg):
        return any(msg.startswith(f"{k}:") for k in kw)

    def build_and_compute():
        part = reg.create(pid, **kw)
        res = part.compute(SMALL, SMALL_C)
        assert res.status in STATUSES
        # a part returns a DesignResult holding its half: F (feedback) or K / a run-time estimator;
        # gains may be "feasible", "computed" (LQR, LQE) or "given" (the EKF's settings), and only
        # a result without gains must say why
        if res.status in GAIN_STATUSES:
            half = res.F if reg is FEEDBACKS else (res.K if res.K is not None else res.estimator)
            assert half is not None
        else:
            assert res.reason
        return res

    _check("part_run", build_and_compute, (DesignError,), names)


# -- CLI ----------------------------------------------------------------------------------------
@pytest.fixture
def cli_sandbox(tmp_path, monkeypatch):
    """A temporary cwd, with the expensive work (pairs, perf) stubbed so each argv costs milliseconds."""
    import bench.harness as harness
    from bench import cli

    monkeypatch.syspath_prepend(str(cli._BENCHMARKS_DIR))  # the perf report is a script of the checkout
    import perf_report as perf
    from bench.pipeline import blank_record

    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("not a folder")
    (tmp_path / "bad_plugin.py").write_text("def broken(:\n")
    (tmp_path / "empty_plugin.py").write_text("x = 1\n")
    (tmp_path / "adir").mkdir()

    def fake_run(plant_ids, design_ids, options, **kw):
        outs = []
        for pid in plant_ids:
            for did in design_ids:
                rec = blank_record(pid, did)
                rec.update(status="inapplicable", reason="stubbed by the fuzz test")
                outs.append(harness.PairOutcome(rec))
        return harness.RunResult(outs, {}, {}, options, 0.0)

    monkeypatch.setattr(harness, "run", fake_run)
    monkeypatch.setattr(perf, "perf_main", lambda out, *a, **k: str(out) + "/PERF.md")
    return tmp_path


NUMBERS = st.sampled_from(["0", "1", "-1", "2.5", "1e999", "nan", "inf", "-inf", "abc", "", "0x10", "10" * 30, "1e-300",
                           " 3 ", "1_000"])
OUT_DIRS = st.sampled_from(["out", "a/b/c", "afile", "afile/sub", "adir", ".", "", "bad\x00name", "-x"])
PLUGINS = st.sampled_from(["missing.py", "adir", "bad_plugin.py", "empty_plugin.py", "afile", ""])
IDS = st.sampled_from(["flexible_link", "flex*", "*", "thm1", "thm2", "cor1_sep", "lqr+*", "", "[", "nope",
                       "paper_gains"])
OPTION = st.one_of(
    st.tuples(st.sampled_from(["--plant", "--design"]), IDS),
    st.tuples(st.just("--out"), OUT_DIRS),
    st.tuples(st.sampled_from(["--seed", "--t-final", "--noise", "--timeout", "-j", "--jobs", "--sizes",
                               "--max-joint-n"]), NUMBERS),
    st.tuples(st.just("--plugin"), PLUGINS),
    st.tuples(st.just("--scheduler"), st.sampled_from(["garbage", "", "tcp://", "tcp://host:x", "::", "a b:1"])),
    st.tuples(st.sampled_from(["--claimed-constants", "--no-figures", "--fail-fast", "-q", "--quiet", "--no-cache",
                               "--no-run", "--help", "--bogus", "-"])),
    st.tuples(st.text(max_size=5)),
)


@st.composite
def argvs(draw):
    cmd = draw(st.sampled_from(["run", "run", "run", "list", "perf", "bogus", "", "--help", "-h"]))
    argv = [cmd] if cmd else []
    for opt in draw(st.lists(OPTION, max_size=5)):
        argv.extend(opt)
    return argv


def _cli_property(argv, capsys):
    from bench.cli import main

    STATS["cli"][0] += 1
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rc = main(list(argv))
    except BaseException as exc:  # noqa: BLE001 - SystemExit included: main must return
        STATS["cli"][1] += 1
        raise AssertionError(f"main({argv!r}) raised {type(exc).__name__}: {exc}") from exc
    err = capsys.readouterr().err
    if not (isinstance(rc, int) and rc in (0, 1, 2, 130)):
        STATS["cli"][1] += 1
        raise AssertionError(f"main({argv!r}) returned {rc!r}")
    if rc != 0:
        assert err.strip(), f"exit {rc} without a message for {argv!r}"
        assert "Traceback" not in err


@settings(max_examples=80, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(argv=argvs())
def test_fuzz_cli_returns_an_exit_code(cli_sandbox, argv, capsys):
    _cli_property(argv, capsys)


@pytest.mark.slow
@settings(max_examples=1000, deadline=None, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(argv=argvs())
def test_fuzz_cli_returns_an_exit_code_big(cli_sandbox, argv, capsys):
    _cli_property(argv, capsys)
