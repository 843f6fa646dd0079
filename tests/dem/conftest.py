"""Fixtures of the DEM tests: seeded synthetic point clouds."""

from __future__ import annotations

import numpy as np
import pytest
from dem_synthetic import sample_cloud


@pytest.fixture(scope="session")
def regional_cloud():
    """~3 points per pixel over lat -35..35, lon 95..165 at 4 pixel/deg; 1 % outliers of +-3 km."""
    return sample_cloud(np.random.default_rng(7), 150_000, (-35, 35), (95, 165), outlier_fraction=0.01)


@pytest.fixture(scope="session")
def global_cloud():
    """A sparse global cloud (20k points) for chunking and store tests at 1 pixel/deg."""
    return sample_cloud(np.random.default_rng(11), 20_000)
