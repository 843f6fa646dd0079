"""Opt-in real long wavelengths: a surface built with GTMES_150V05 carries the shape model's expansion
on top of its craters and roughness; without the option (every preset) nothing changes."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mercury_dem.exceptions import ReferenceDataError
from mercury_dem.geometry.body import latlon_to_unit
from mercury_dem.reference import sha
from mercury_dem.reference.sha import evaluate, read_shadr, resolve_shape_path
from mercury_dem.synth.presets import PRESETS
from mercury_dem.synth.terrain import GTMES_PACKAGED, Surface, SurfaceParams, surface_from_dict, with_shape_harmonics

SHA_TAB = resolve_shape_path(GTMES_PACKAGED)  # the table the package ships
R = 2_439_400.0


def test_shape_harmonics_add_the_real_long_wavelengths() -> None:
    base = replace(SurfaceParams(seed=5, crater_d_min_m=20e3, rough_shortest_m=20e3),
                   longwave_amplitude_m=0.0, polar_drop_m=0.0)
    plain = Surface(base, R)
    real = Surface(with_shape_harmonics(base, str(SHA_TAB), lmax=30), R)
    rng = np.random.default_rng(11)
    lat, lon = np.degrees(np.arcsin(rng.uniform(-1, 1, 400))), rng.uniform(0, 360, 400)
    diff = real.height(lat, lon) - plain.height(lat, lon)
    want = evaluate(read_shadr(SHA_TAB), lat, lon, lmax=30) - R
    # bilinear on a 0.25 deg (10.6 km) grid of a degree-30 field (wavelengths >= 500 km, ~1 km amplitude):
    # error <= A k^2 dx^2 / 8 ~ 2.2 m at worst, ~0.1 m typically
    err = np.abs(diff - want)
    assert np.max(err) < 2.5 and np.median(err) < 0.3 and np.std(want) > 300.0
    assert real.shape_height(latlon_to_unit(np.array([90.0]), np.array([0.0]))).shape == (1,)


def test_only_the_demo_preset_uses_it_and_bad_paths_are_named(tmp_path: Path) -> None:
    # tiny (the tests' mission) and large are unchanged; the demo takes GTMES's long wavelengths by
    # default, from the packaged table (portable: truth/surface.json keeps the package name)
    assert all(p.surface.shape_harmonics == "" for name, p in PRESETS.items() if name != "demo")
    demo = PRESETS["demo"].surface
    assert demo.shape_harmonics == GTMES_PACKAGED == sha.GTMES_PACKAGED and demo.shape_lmax == 148
    assert demo.longwave_amplitude_m == 0.0 and demo.polar_drop_m == 0.0
    with pytest.raises(ReferenceDataError, match="nope.tab"):
        Surface(with_shape_harmonics(SurfaceParams(), str(tmp_path / "nope.tab")), R)


def test_packaged_shape_builds_the_same_surface_as_the_file() -> None:
    """The demo's surface from the packaged table equals one from the shared file, and survives the
    truth/surface.json round trip by name (no path of this machine in it)."""
    base = replace(SurfaceParams(seed=5, crater_d_min_m=20e3, rough_shortest_m=20e3),
                   longwave_amplitude_m=0.0, polar_drop_m=0.0)
    packaged = with_shape_harmonics(base, GTMES_PACKAGED, lmax=30)
    assert packaged.shape_harmonics == GTMES_PACKAGED
    from_file = Surface(with_shape_harmonics(base, str(SHA_TAB), lmax=30), R)
    again = surface_from_dict({"params": packaged.to_dict(), "radius_m": R})
    rng = np.random.default_rng(3)
    lat, lon = np.degrees(np.arcsin(rng.uniform(-1, 1, 200))), rng.uniform(0, 360, 200)
    np.testing.assert_array_equal(again.height(lat, lon), from_file.height(lat, lon))
