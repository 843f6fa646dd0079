"""Seeded synthetic networks shared by the adjustment tests (built once per session)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mercury_dem.adjust.bundle import bundle_adjust
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.validate.synthetic_network import make_synthetic_network

BAL_DIR = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "bal"


def bal_file(name: str) -> Path:
    path = BAL_DIR / name
    if not path.exists():
        pytest.skip(f"BAL file {path} not present (../shared/data/bal is only on the development machine)")
    return path


@pytest.fixture(scope="session")
def accuracy_network():
    """~30k measures, 1 % gross outliers (5-50 px), 0.25 px noise, 450 urad a-priori pointing error.

    Points are tie points seen in 3-5 images (as in Preusker et al. 2011): on
    2-ray points an outlier along the epipolar line cannot be detected at all.
    """
    return make_synthetic_network(30_000, rng=np.random.default_rng(20261122), min_views=3, noise_px=0.25,
                                  outlier_fraction=0.01)


@pytest.fixture(scope="session")
def accuracy_config():
    # the a-priori pointing sigma is the problem's: make_synthetic_network's injected 450 urad (Preusker et al. 2011)
    return AdjustConfig()


@pytest.fixture(scope="session")
def accuracy_result(accuracy_network, accuracy_config):
    return bundle_adjust(accuracy_network.problem, accuracy_config)


@pytest.fixture(scope="session")
def small_network():
    """A small clean network (no outliers) for exactness and diagnosis tests."""
    return make_synthetic_network(3000, rng=np.random.default_rng(7), min_views=3, outlier_fraction=0.0,
                                  noise_px=0.0, measures_per_image=150)


@pytest.fixture(scope="session")
def bal_path():
    """Path of a BAL file under ../shared/data/bal (skips when absent)."""
    return bal_file
