"""Session-scoped rendered pairs for the matching tests.

The pairs are :func:`mercury_dem.validate.matching.standard_pairs` (every class of
issue 4, section 4). They are rendered with the mission renderer
(``mercury_dem.synth.render.render_image`` on the truth ``Surface``) when it is
available, else with the small Lambert world of ``tests/match/world.py``. The
a-priori geometry has the synthetic missions' default errors (450 urad pointing,
100 m position per axis).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest

from mercury_dem.geometry.body import DATUM_RADIUS_M
from mercury_dem.geometry.camera import mdis_wac
from mercury_dem.geometry.pose import rotation_from_angles
from mercury_dem.match import ImageGeometry
from mercury_dem.validate.matching import ScenePair, TruePose, standard_pairs

sys.path.insert(0, str(Path(__file__).resolve().parent))

POINTING_SIGMA_RAD = 450e-6
POSITION_SIGMA_M = 100.0


@dataclass
class PairWorld:
    """Rendered standard pairs: images, a-priori and true geometry per view id, and the pair list."""

    renderer: str
    height: Callable[..., Any]
    images: dict[str, Any]
    geometry: dict[str, ImageGeometry]
    truth: dict[str, TruePose]
    pairs: list[tuple[str, str]]
    names: list[str]


def _renderer() -> tuple[str, Callable[..., Any], Callable[..., Any], float | None]:
    try:
        from mercury_dem.synth.render import render_image
        from mercury_dem.synth.terrain import Surface, SurfaceParams
    except ImportError:
        from world import ToySurface, View, render

        toy = ToySurface(lat0=5.0, lon0=3.0)

        def draw(cam: Any, c: Any, r: Any, sun: Any, rng: np.random.Generator) -> Any:
            return render(toy, View(cam, c, r, sun), rng)

        return "toy Lambert world (tests/match/world.py)", toy.height, draw, 28e3
    surface = Surface(SurfaceParams(seed=42))

    def draw(cam: Any, c: Any, r: Any, sun: Any, rng: np.random.Generator) -> Any:
        return render_image(surface, cam, c, r, sun, rng)

    return "mercury_dem.synth.render", surface.height, draw, None


@pytest.fixture(scope="session")
def pair_world() -> PairWorld:
    name, height, draw, altitude = _renderer()
    cam = mdis_wac(256)
    scene: list[ScenePair] = standard_pairs(cam, altitude_m=altitude)
    rng = np.random.default_rng(2024)
    ids: dict[int, str] = {}
    images: dict[str, Any] = {}
    geometry: dict[str, ImageGeometry] = {}
    truth: dict[str, TruePose] = {}
    pairs: list[tuple[str, str]] = []
    for sp in scene:
        pair_ids = []
        for v in (sp.ref, sp.match):
            if id(v) not in ids:
                vid = f"v{len(ids):02d}"
                ids[id(v)] = vid
                images[vid] = draw(v.camera, v.position, v.rotation, v.sun, rng)
                c_ap = v.position + rng.normal(0.0, POSITION_SIGMA_M, 3)
                r_ap = rotation_from_angles(rng.normal(0.0, POINTING_SIGMA_RAD, 3)) @ v.rotation
                geometry[vid] = ImageGeometry.of(v.camera, c_ap, r_ap, v.sun, datum_radius_m=DATUM_RADIUS_M)
                truth[vid] = TruePose(v.camera, v.position, v.rotation)
            pair_ids.append(ids[id(v)])
        pairs.append((pair_ids[0], pair_ids[1]))
    return PairWorld(name, height, images, geometry, truth, pairs, [sp.name for sp in scene])
