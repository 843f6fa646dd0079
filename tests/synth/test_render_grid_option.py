"""The renderer's surface grid and band limit (issue 31: two views of the same surface should agree).

The grid spacing and the surface's band limit are separate settings: ``surface_resolution_px`` 1 on the
1-pixel grid is the renderer of sessions <= 19 bit for bit; ``mercury-dem synth --render-grid-px 0.5``
draws the same surface from a twice finer grid, and the mission says how it was rendered. The agreement
itself (the dense matcher's disparity error between two noise-free views) is measured by
``workflows/benchmarks/render_agreement.py`` (docs/design/dense.md).
"""

from __future__ import annotations

import numpy as np
import pytest

from mercury_dem.config.synth import SynthConfig
from mercury_dem.exceptions import GeometryError
from mercury_dem.geometry.body import DATUM_RADIUS_M, latlon_to_unit
from mercury_dem.geometry.camera import mdis_wac
from mercury_dem.geometry.pose import look_at_rotation
from mercury_dem.mission import open_mission
from mercury_dem.synth.generate import generate_mission
from mercury_dem.synth.presets import MissionDesign
from mercury_dem.synth.render import RenderSettings, footprint_grid, render_reflectance
from mercury_dem.synth.terrain import Surface, SurfaceParams

MINI = MissionDesign(
    name="mini", area_deg=(-4.0, 4.0, -4.0, 4.0), samples=64, pixel_scale_m=(3000.0, 4500.0), passes=2,
    spacing_factor=1.0, truth_dem_ppd=2.0, surface=SurfaceParams(crater_d_min_m=10e3, n_basins=1),
)


def _scene(scale_m: float = 2000.0):
    cam = mdis_wac(64)
    up = latlon_to_unit(5.0, 3.0)
    centre = up * DATUM_RADIUS_M
    c = centre + up * scale_m / cam.ifov_rad
    east = np.cross([0.0, 0.0, 1.0], up)
    sun = centre + 5.8e10 * (np.cos(np.radians(45.0)) * up + np.sin(np.radians(45.0)) * east / np.linalg.norm(east))
    return cam, c, look_at_rotation(c, centre), sun


def test_the_band_limit_at_one_pixel_is_the_old_renderer_bit_for_bit() -> None:
    """surface_resolution_px 1 on the 1-px grid is the default renderer; the half-pixel grid draws nearly the same scene."""
    surf = Surface(SurfaceParams(seed=3, crater_d_min_m=5000.0))
    cam, c, r, sun = _scene()
    old = render_reflectance(surf, cam, c, r, sun, RenderSettings())
    same = render_reflectance(surf, cam, c, r, sun, RenderSettings(surface_resolution_px=1.0))
    assert np.array_equal(old, same)
    grid = footprint_grid(cam, c, r, sun, surf.radius_m, RenderSettings())
    assert RenderSettings().surface_resolution(grid.spacing_m) == grid.spacing_m
    half = RenderSettings(grid_spacing_px=0.5, surface_resolution_px=1.0)
    assert half.surface_resolution(grid.spacing_m / 2) == pytest.approx(grid.spacing_m)
    assert RenderSettings(surface_resolution_m=900.0).surface_resolution(grid.spacing_m) == 900.0
    fine = render_reflectance(surf, cam, c, r, sun, half)
    # the same scene drawn from a finer grid of the same surface: close, not equal
    lit = old > 0
    assert 0 < np.mean(np.abs(fine - old)[lit]) < 0.1 * np.mean(old[lit])


def test_negative_band_limits_are_refused() -> None:
    """A negative band limit is the renderer's own error naming the setting."""
    with pytest.raises(GeometryError, match="surface_resolution"):
        RenderSettings(surface_resolution_px=-1.0)
    with pytest.raises(GeometryError, match="surface_resolution"):
        RenderSettings(surface_resolution_m=-1.0)


def test_a_mission_records_its_render_grid(tmp_path) -> None:
    """synth.render_grid_px reaches the renderer and mission.json says how the images were drawn."""
    generate_mission(tmp_path / "default", SynthConfig(seed=9), design=MINI, images="0:1")
    generate_mission(tmp_path / "fine", SynthConfig(seed=9, render_grid_px=0.5), design=MINI, images="0:1")
    a, b = open_mission(tmp_path / "default"), open_mission(tmp_path / "fine")
    assert a.meta["render"]["grid_spacing_px"] == 1.0 and a.meta["render"]["surface_resolution_px"] == 0.0
    assert b.meta["render"]["grid_spacing_px"] == 0.5 and b.meta["render"]["surface_resolution_px"] == 1.0
    ia, ib = (m.read_image(m.image_ids[0]).astype(float) for m in (a, b))
    assert not np.array_equal(ia, ib) and np.corrcoef(ia.ravel(), ib.ravel())[0, 1] > 0.9
