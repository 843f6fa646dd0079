"""Fixtures of the network tests (helpers in network_world.py)."""

from __future__ import annotations

import pytest
from network_world import World, make_world


@pytest.fixture(scope="session")
def seam_world() -> World:
    return make_world(0.0, 0.0, seed=1)


@pytest.fixture(scope="session")
def pole_world() -> World:
    return make_world(89.99, 123.0, seed=2)
