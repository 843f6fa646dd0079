"""Synthetic worlds for the network tests: cameras over a patch of Mercury, ground points, true pixels."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from mercury_dem.geometry.body import DATUM_RADIUS_M, latlon_to_xyz
from mercury_dem.geometry.camera import FramingCamera, mdis_nac
from mercury_dem.geometry.pose import look_at_rotation, project
from mercury_dem.network import ControlNetwork, PairMatches

SHARED = Path(__file__).resolve().parents[2] / ".." / "shared"
ISIS_DIR = SHARED / "data" / "isis_cnet"


@dataclass(frozen=True)
class World:
    image_ids: np.ndarray  # (K,) str
    camera: FramingCamera
    positions: np.ndarray  # (K, 3)
    rotations: np.ndarray  # (K, 3, 3)
    truth: np.ndarray  # (N, 3) ground points
    pixels: np.ndarray  # (K, N, 2) true pixels (NaN when not visible)
    observed: np.ndarray  # (K, N, 2) pixels with noise (fixed per image and point)
    visible: np.ndarray  # (K, N) bool
    gsd_m: float  # ground sample distance, m per pixel
    sigma_px: float


def make_world(lat0: float, lon0: float, n_points: int = 300, n_images: int = 6, sigma_px: float = 0.1,
               seed: int = 0) -> World:
    """``n_images`` NAC images (512^2) from 200 km, spread +-60 km, all looking at (lat0, lon0).

    Ground points lie within +-2 km of the target with heights +-2 km.
    """
    rng = np.random.default_rng(seed)
    cam = mdis_nac(512)
    target = latlon_to_xyz(lat0, lon0, 0.0, datum_radius_m=DATUM_RADIUS_M)
    up = target / np.linalg.norm(target)
    east = np.cross([0.0, 0.0, 1.0], up)
    if np.linalg.norm(east) < 1e-6:
        east = np.array([0.0, 1.0, 0.0])
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    ang = np.linspace(0, 2 * np.pi, n_images, endpoint=False)
    offsets = 60e3 * (np.cos(ang)[:, None] * east + np.sin(ang)[:, None] * north)
    positions = target + 200e3 * up + offsets
    rotations = np.stack([look_at_rotation(c, target, north) for c in positions])
    # ground points in the local tangent plane, then put at a height above the datum
    xy = rng.uniform(-2000, 2000, size=(n_points, 2))
    p = target + xy[:, :1] * east + xy[:, 1:] * north
    h = rng.uniform(-2000, 2000, n_points)
    truth = p / np.linalg.norm(p, axis=1, keepdims=True) * (DATUM_RADIUS_M + h)[:, None]
    pixels = np.stack([project(cam, positions[k], rotations[k], truth)[0] for k in range(n_images)])
    visible = np.all(np.isfinite(pixels), axis=2) & cam.in_image(pixels, margin=1.0)
    # keep features apart (>= 3 px in every image): coincident features are a real ambiguity,
    # tested on purpose elsewhere, not by chance
    crowded = np.zeros(n_points, bool)
    for k in range(n_images):
        vis = np.flatnonzero(visible[k])
        pairs = cKDTree(pixels[k, vis]).query_pairs(3.0, output_type="ndarray")
        crowded[vis[pairs.ravel()]] = True
    truth, pixels, visible = truth[~crowded], pixels[:, ~crowded], visible[:, ~crowded]
    pixels[~visible] = np.nan
    observed = pixels + rng.normal(0.0, sigma_px, pixels.shape)
    gsd = 200e3 * cam.ifov_rad
    ids = np.array([f"IMG{k:03d}" for k in range(n_images)])
    return World(ids, cam, positions, rotations, truth, pixels, observed, visible, gsd, sigma_px)


def make_matches(world: World, pairs: list[tuple[int, int]], known_features: bool = True,
                 points: np.ndarray | None = None) -> tuple[PairMatches, np.ndarray]:
    """Matches of every truth point seen in both images of each pair; returns (matches, truth point of each row)."""
    rows = []
    for a, b in pairs:
        n = np.flatnonzero(world.visible[a] & world.visible[b])
        if points is not None:
            n = np.intersect1d(n, points)
        rows.append((np.full(n.size, a), np.full(n.size, b), n))
    ia = np.concatenate([r[0] for r in rows]).astype(np.int64)
    ib = np.concatenate([r[1] for r in rows]).astype(np.int64)
    pt = np.concatenate([r[2] for r in rows]).astype(np.int64)
    fa = pt if known_features else np.full(pt.size, -1)
    fb = pt if known_features else np.full(pt.size, -1)
    m = PairMatches(ia, ib, world.observed[ia, pt, 0], world.observed[ia, pt, 1],
                    world.observed[ib, pt, 0], world.observed[ib, pt, 1], fa, fb)
    return m, pt


def all_pairs(k: int) -> list[tuple[int, int]]:
    return [(a, b) for a in range(k) for b in range(a + 1, k)]


def measure_sets(net: ControlNetwork, truth_of_measure: np.ndarray | None = None) -> set[frozenset]:
    """The network as a set of points, each a frozenset of (image id, rounded sample, rounded line)."""
    key = [(str(i), round(float(s), 6), round(float(l), 6)) for i, s, l in
           zip(net.image_ids[net.measure_image], net.sample, net.line)]
    groups: dict[int, set] = {}
    for p, k in zip(net.measure_point.tolist(), key):
        groups.setdefault(p, set()).add(k)
    return {frozenset(g) for g in groups.values()}




def truth_of_measures(world: World, net: ControlNetwork) -> np.ndarray:
    """Truth point of each measure, found by its exact observed pixel (-1 when none matches)."""
    lookup = {}
    for k in range(world.observed.shape[0]):
        for n in np.flatnonzero(world.visible[k]):
            lookup[(str(world.image_ids[k]), float(world.observed[k, n, 0]), float(world.observed[k, n, 1]))] = n
    ids = net.image_ids[net.measure_image]
    return np.array([lookup.get((str(i), float(s), float(l)), -1) for i, s, l in zip(ids, net.sample, net.line)])


def require_isis() -> Path:
    if not ISIS_DIR.is_dir():
        pytest.skip(f"real ISIS networks not found at {ISIS_DIR} (../shared is absent in a fresh clone)")
    return ISIS_DIR
