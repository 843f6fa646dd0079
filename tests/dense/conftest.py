"""Session fixtures of the dense tests: the rendered pairs of :mod:`dense_scene`."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from dense_scene import RenderedPair, render_pair  # noqa: E402


@pytest.fixture(scope="session")
def lambert_pair() -> RenderedPair:
    from mercury_dem.synth.render import RenderSettings

    return render_pair(RenderSettings(lambert_weight=1.0))


@pytest.fixture(scope="session")
def default_pair() -> RenderedPair:
    from mercury_dem.synth.render import RenderSettings

    return render_pair(RenderSettings())


@pytest.fixture(scope="session")
def low_sun_pair() -> RenderedPair:
    """Sun 78 deg from the zenith: the craters' western walls and floors are in cast shadow."""
    from mercury_dem.synth.render import RenderSettings

    return render_pair(RenderSettings(lambert_weight=1.0), incidence_deg=78.0)


@pytest.fixture(scope="session")
def coarse_east_pair() -> RenderedPair:
    """Nadir at 200 m/px and a view tilted 30 deg west at 300 m/px: the epipolar lines run along the samples
    (not the lines as in the other pairs) and the right image is 1.6x coarser in the rectified frame.
    """
    from mercury_dem.synth.render import RenderSettings

    return render_pair(RenderSettings(lambert_weight=1.0), right_view={"gsd_m": 300.0, "tilt_east_deg": -30.0,
                                                                        "tilt_north_deg": 0.0})
