import bench._env  # noqa: F401  (BLAS threads before numpy; see bench/_env.py)
import numpy as np
import pytest

from bench.constants import compute_constants
from bench.registry import PLANTS


@pytest.fixture(scope="session")
def flex():
    return PLANTS.create("flexible_link")


@pytest.fixture(scope="session")
def flex_constants(flex):
    return compute_constants(flex, seed=0)


@pytest.fixture(scope="session")
def designed(flex, flex_constants):
    """Results of the LMI designs on the flexible link, computed once."""
    from bench.registry import DESIGNS

    return {d: DESIGNS.create(d).design(flex, flex_constants.valid) for d in ("thm1", "cor1", "thm1_printed",
                                                                               "cor1_printed")}


def hurwitz(M):
    return float(np.linalg.eigvals(M).real.max()) < 0
