"""bench.errors: one base class for what the suite raises, bad inputs are ValueErrors, the messages
name the input, and the errors are public names of ``bench``."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

import bench
import bench.errors as errors
from bench.registry import PLANTS

BAD_INPUT = {"PlantError", "DesignError", "PluginError", "RegistryError", "StudyError", "OutDirError"}
CONTROL_FLOW = {"SimulationStopped", "DeadlineExceeded", "HardStop"}


def _classes() -> dict[str, type]:
    return {k: v for k, v in vars(errors).items()
            if inspect.isclass(v) and issubclass(v, BaseException) and v.__module__ == errors.__name__}


def test_every_public_error_derives_from_the_base():
    classes = _classes()
    assert set(errors.__all__) == set(classes) - CONTROL_FLOW
    for name in errors.__all__:
        assert issubclass(classes[name], errors.OslbenchError), name
    assert BAD_INPUT <= set(errors.__all__)
    for name in BAD_INPUT:
        assert issubclass(classes[name], ValueError), name
    assert issubclass(errors.UnknownIdError, KeyError) and issubclass(errors.ExecutorError, RuntimeError)


def test_a_time_limit_escapes_except_exception():
    # a timeout must not be swallowed by a design's ``except Exception`` and turned into a verdict
    assert not issubclass(errors.DeadlineExceeded, Exception)
    assert issubclass(errors.HardStop, errors.DeadlineExceeded)


def test_errors_are_public_names_of_bench_and_internal_ones_are_not():
    names = set(dir(bench))
    assert set(errors.__all__) <= names and set(errors.__all__) <= set(bench.__all__)
    assert not CONTROL_FLOW & set(bench.__all__)
    for name in errors.__all__:
        assert getattr(bench, name) is getattr(errors, name)
    from designs import DesignError
    from plants import PlantError

    assert PlantError is bench.PlantError and DesignError is bench.DesignError


@pytest.mark.parametrize("bad, matrix", [("B", "B"), ("C", "C")])
def test_a_wrong_matrix_shape_raises_the_base_error_naming_the_matrix(bad, matrix):
    n = 2
    shapes = {"B": (n, 1), "C": (1, n)}
    shapes[bad] = (n + 1, 1) if bad == "B" else (1, n + 1)
    with pytest.raises(errors.OslbenchError, match=rf"^{matrix}\b") as info:
        bench.Plant(id="p", A=np.eye(n), B=np.ones(shapes["B"]), C=np.ones(shapes["C"]), f=lambda x: 0 * x,
                    x0=np.ones(n), x_hat0=np.zeros(n))
    assert isinstance(info.value, ValueError)


def test_an_unknown_id_is_a_key_error_and_the_base_error():
    with pytest.raises(errors.OslbenchError) as info:
        PLANTS.select(["no_such_plant_anywhere"])
    assert isinstance(info.value, KeyError) and "no_such_plant_anywhere" in str(info.value)
