"""Generation on Dask gives the same mission as the plain loop (the large preset's code path)."""

from __future__ import annotations

import numpy as np
import pytest

from mercury_dem.config.synth import SynthConfig
from mercury_dem.exceptions import StoreError
from mercury_dem.mission import open_mission
from mercury_dem.synth.generate import generate_mission
from mercury_dem.synth.presets import MissionDesign
from mercury_dem.synth.terrain import SurfaceParams

MINI = MissionDesign(
    name="mini", area_deg=(-4.0, 4.0, -4.0, 4.0), samples=64, pixel_scale_m=(3000.0, 4500.0), passes=2,
    spacing_factor=1.0, truth_dem_ppd=2.0, surface=SurfaceParams(crater_d_min_m=10e3, n_basins=1),
)


def test_dask_generation_equals_the_plain_loop(tmp_path):
    distributed = pytest.importorskip("distributed")
    cfg = SynthConfig(seed=9)
    serial = generate_mission(tmp_path / "serial", cfg, design=MINI)
    with distributed.Client(processes=False, n_workers=1, threads_per_worker=2, dashboard_address="127.0.0.1:0") as client:
        par = generate_mission(tmp_path / "dask", cfg, design=MINI, client=client)
    assert serial["images"] == par["images"] >= 2
    a, b = open_mission(tmp_path / "serial"), open_mission(tmp_path / "dask")
    assert a.image_ids == b.image_ids
    for image_id in a.image_ids:
        assert np.array_equal(a.read_image(image_id), b.read_image(image_id))
    assert np.array_equal(a.truth.dem().values, b.truth.dem().values)


def test_a_failed_generation_leaves_nothing_behind(tmp_path, monkeypatch):
    import mercury_dem.synth.generate as gen

    def boom(*args, **kwargs):
        raise RuntimeError("renderer died")

    monkeypatch.setattr(gen, "render_all", boom)
    with pytest.raises(RuntimeError):
        generate_mission(tmp_path / "m", SynthConfig(seed=1), design=MINI)
    assert not (tmp_path / "m").exists()
    assert not list(tmp_path.iterdir())  # no temporary directory left either
    with pytest.raises(StoreError, match="does not exist"):
        open_mission(tmp_path / "m")


def test_a_partial_mission_is_the_same_images_and_is_marked(tmp_path):
    """--images A:B renders those images of the design exactly as the full mission does, and says it is partial."""
    from mercury_dem.exceptions import ConfigError

    cfg = SynthConfig(seed=9)
    full = generate_mission(tmp_path / "full", cfg, design=MINI)
    part = generate_mission(tmp_path / "part", cfg, design=MINI, images="1:3")
    assert part["partial"] and not full["partial"] and part["images"] == 2 and part["images_design"] == full["images"]
    a, b = open_mission(tmp_path / "full"), open_mission(tmp_path / "part")
    assert b.meta["partial"]["images"] == [1, 3] and b.meta["n_images"] == 2
    assert b.meta["n_images_design"] == a.meta["n_images_design"] == full["images"]
    assert "partial" not in a.meta
    assert b.image_ids == a.image_ids[1:3]
    for image_id in b.image_ids:
        assert np.array_equal(a.read_image(image_id), b.read_image(image_id))
        assert np.allclose(a.a_priori_pose(image_id)[1], b.a_priori_pose(image_id)[1], rtol=0, atol=0)
    assert len(b.truth.poses) == 2
    with pytest.raises(ConfigError, match="selects none"):
        generate_mission(tmp_path / "none", cfg, design=MINI, images="50:60")
