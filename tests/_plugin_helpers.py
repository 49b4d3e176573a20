"""Shared by the tests that load plugins: an autouse fixture that leaves the registries as it found them.

Import it into a test module (``from tests._plugin_helpers import clean_registries``) to apply it to
every test of that module.
"""

import pytest

from bench.registry import DESIGNS, PLANTS


@pytest.fixture(autouse=True)
def clean_registries():
    """Remove whatever a test's plugins registered."""
    plants, designs = set(PLANTS.ids()), set(DESIGNS.ids())
    yield
    for i in set(PLANTS.ids()) - plants:
        PLANTS.unregister(i)
    for i in set(DESIGNS.ids()) - designs:
        DESIGNS.unregister(i)
