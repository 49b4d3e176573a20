import re

import numpy as np
import pytest

from bench.registry import PLANTS
from plants import Constants, Plant, PlantError

A = np.array([[0.0, 1.0], [-1.0, -1.0]])
B = np.array([[0.0], [1.0]])
C = np.array([[1.0, 0.0]])


def good(**over):
    kw = dict(id="toy", A=A, B=B, C=C, f=lambda x: np.zeros_like(np.asarray(x, dtype=float)),
              x0=[1.0, 0.0], x_hat0=[0.0, 0.0])
    kw.update(over)
    return Plant(**kw)


def test_valid_plant_builds():
    p = good()
    assert (p.n, p.m, p.p) == (2, 1, 1)


@pytest.mark.parametrize(
    "over, words",
    [
        (dict(A=np.ones((2, 3))), ["A", "square"]),
        (dict(B=np.ones((3, 1))), ["B", "rows", "(3, 1)"]),
        (dict(C=np.ones((1, 3))), ["C", "columns", "(1, 3)"]),
        (dict(A=np.array([[0.0, np.nan], [0.0, 0.0]])), ["A", "finite"]),
        (dict(B=np.array([[np.inf], [1.0]])), ["B", "finite"]),
        (dict(x0=[1.0, 2.0, 3.0]), ["x0", "(2,)"]),
        (dict(x_hat0=[np.nan, 0.0]), ["x_hat0", "finite"]),
        (dict(f=lambda x: np.ones_like(np.asarray(x, dtype=float))), ["f(0)", "0"]),
        (dict(f=lambda x: np.zeros(3)), ["f", "shape"]),
        (dict(f=lambda x: 1 / 0), ["f", "ZeroDivisionError"]),
        (dict(f="not callable"), ["f", "callable"]),
        (dict(t_final=-1.0), ["t_final", "> 0"]),
        (dict(id=""), ["id"]),
        (dict(A=[1.0, 2.0]), ["A", "2-D"]),
        (dict(A=[["a", "b"], ["c", "d"]]), ["A", "numeric"]),
    ],
)
def test_bad_plants_rejected_naming_the_field(over, words):
    with pytest.raises(PlantError, match=re.escape(words[0])) as info:
        good(**over)
    msg = str(info.value)
    for w in words:
        assert w in msg, msg


def test_constants_validation():
    with pytest.raises(PlantError, match="alpha"):
        Constants(alpha=float("nan"))
    with pytest.raises(PlantError, match="radius"):
        Constants(radius=0.0)
    with pytest.raises(PlantError, match="beta/gamma"):
        Constants(beta=1.0)


def test_flexible_link_matches_paper():
    p = PLANTS.create("flexible_link")
    assert p.A[1, 1] == -1.26 and p.A[2, 3] == 10 and p.B[1, 0] == 21.6
    np.testing.assert_array_equal(p.C, np.hstack([np.eye(2), np.zeros((2, 2))]))
    x = np.array([0.3, -0.2, 0.7, 0.1])
    np.testing.assert_allclose(p.f(x), [0, 0, 0, -0.333 * np.sin(0.7)])
    q = PLANTS.create("flexible_link_printed")
    np.testing.assert_allclose(q.f(x), [0, 0, 0, -0.333 * np.sin(0.3)])
    # the paper's claims are kept as claimed
    assert p.claimed.rho == 0.1109 and p.claimed.beta == 0.1109 and p.claimed.gamma == 0.0


def test_flexible_link_jacobian_matches_finite_differences():
    p = PLANTS.create("flexible_link")
    x = np.array([0.3, -0.2, 0.7, 0.1])
    h = 1e-6
    J = np.column_stack([(p.f(x + h * e) - p.f(x - h * e)) / (2 * h) for e in np.eye(4)])
    np.testing.assert_allclose(p.jacobian(x), J, atol=1e-8)


def test_factory_is_keyword_only():
    with pytest.raises(TypeError, match="positional"):
        PLANTS["flexible_link"].factory(0.5)


def _float_kwargs():
    import inspect

    for pid in PLANTS.ids():
        sig = inspect.signature(PLANTS[pid].factory)
        for name, prm in sig.parameters.items():
            if prm.kind is inspect.Parameter.KEYWORD_ONLY and isinstance(prm.default, float):
                yield pid, name


@pytest.mark.parametrize("pid, name", list(_float_kwargs()))
@pytest.mark.parametrize("bad", ["abc", float("nan"), float("inf")])
def test_every_factory_names_a_bad_scalar(pid, name, bad):
    with pytest.raises(PlantError, match=f"{name}|t_final") as info:
        PLANTS.create(pid, **{name: bad})
    assert name in str(info.value) or "t_final" in str(info.value)


@pytest.mark.parametrize("pid", ["random_lipschitz_v1", "random_osl_v1"])
def test_random_family_refuses_absurd_n(pid):
    with pytest.raises(PlantError, match="^n:"):
        PLANTS.create(pid, n=10**9)
