"""The truth surface of the synthetic Mercury: height and albedo anywhere, from a seed.

``Surface(SurfaceParams(seed=...))`` draws a crater population, a few multi-ring
basins, smooth-plains units and long-wavelength relief, then evaluates

    height = polar depression + sum of crater profiles (softly limited at -4.5 km)
             + fractal noise from long-wave relief down to roughness (damped on the plains)
    albedo = mean * (1 + mottling) * (1 + halo/ray boost of fresh craters)

at any latitude/longitude without a global array (craters are bucketed in a
lat/lon index, noise is procedural). The albedo field is independent of the
height (separate seeds, no height term). Everything is deterministic from
``params``: a :class:`Surface` is rebuilt from its parameters, which is what the
mission store keeps under ``truth/``.

Heights are metres above the datum sphere (:data:`DATUM_RADIUS_M`), latitudes
planetocentric and longitudes east, degrees.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from mercury_dem.exceptions import ConfigError
from mercury_dem.geometry.body import DATUM_RADIUS_M, latlon_to_unit
from mercury_dem.synth import craters as cr
from mercury_dem.synth.noise import fbm, octaves


@dataclass(frozen=True)
class SurfaceParams:
    """Everything that defines a synthetic surface (stored as JSON with a mission).

    Crater density: ``N(>D) = crater_k_per_km2 * (D / 1 km) ** -crater_slope`` per km^2.
    """

    seed: int = 42
    crater_k_per_km2: float = 0.05
    crater_slope: float = 2.0
    crater_d_min_m: float = 2000.0
    crater_d_max_m: float = 300e3
    transition_m: float = 12e3
    n_basins: int = 5
    basin_d_min_m: float = 500e3
    basin_d_max_m: float = 1550e3
    n_plains: int = 7
    plains_age: float = 0.6
    fresh_age: float = 0.985
    ray_length: float = 10.0
    longwave_amplitude_m: float = 900.0
    polar_drop_m: float = 1500.0
    rough_longest_m: float = 200e3
    rough_amplitude_m: float = 500.0
    rough_hurst: float = 0.6
    rough_shortest_m: float = 30.0
    albedo_mean: float = 0.14
    albedo_variation: float = 0.3
    index_cell_deg: float = 0.5
    #: Opt-in real long wavelengths: a PDS SHADR shape table (MLA's GTMES_150V05_SHA.TAB) whose
    #: expansion to ``shape_lmax`` (radius - datum) is added to the height; "" (default): none.
    #: Set ``longwave_amplitude_m`` and ``polar_drop_m`` to 0 with it (``with_shape_harmonics``).
    shape_harmonics: str = ""
    shape_lmax: int = 148
    shape_grid_deg: float = 0.25

    def __post_init__(self) -> None:
        positive = ("crater_d_min_m", "crater_d_max_m", "transition_m", "rough_longest_m", "rough_shortest_m",
                    "albedo_mean", "index_cell_deg", "crater_slope")
        for name in positive:
            if not getattr(self, name) > 0:
                raise ConfigError(f"surface parameter '{name}' must be > 0, got {getattr(self, name)!r}")
        if self.crater_d_min_m >= self.crater_d_max_m:
            raise ConfigError("surface parameters: crater_d_min_m must be below crater_d_max_m")
        if self.seed < 0:
            raise ConfigError(f"surface parameter 'seed' must be >= 0, got {self.seed}")
        if self.shape_lmax < 0 or not 0 < self.shape_grid_deg <= 5.0:
            raise ConfigError("surface parameters: shape_lmax must be >= 0 and 0 < shape_grid_deg <= 5")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SurfaceParams:
        known = {f.name for f in fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise ConfigError(f"unknown surface parameters {sorted(unknown)}; known: {sorted(known)}")
        return cls(**data)


@numba.njit(cache=True, nogil=True)
def _plains_mask(units: NDArray[np.float64], plains: NDArray[np.float64]) -> NDArray[np.float64]:
    """Smooth-plains mask in [0, 1] at unit vectors (N, 3).

    ``plains`` rows: centre unit vector (3), radius (rad), edge width (rad),
    cosine of (radius + width/2) for the early rejection.
    """
    n = units.shape[0]
    out = np.zeros(n)
    for i in range(n):
        px, py, pz = units[i, 0], units[i, 1], units[i, 2]
        m = 0.0
        for k in range(plains.shape[0]):
            dot = px * plains[k, 0] + py * plains[k, 1] + pz * plains[k, 2]
            if dot <= plains[k, 5]:
                continue
            dx = px - plains[k, 0]
            dy = py - plains[k, 1]
            dz = pz - plains[k, 2]
            ang = 2.0 * np.arcsin(min(1.0, 0.5 * np.sqrt(dx * dx + dy * dy + dz * dz)))
            x = (plains[k, 3] - ang) / plains[k, 4] + 0.5
            if x > 0.0:
                v = 1.0 if x >= 1.0 else x * x * (3.0 - 2.0 * x)
                m = max(m, v)
        out[i] = m
    return out


class Surface:
    """The truth height and albedo fields. Build with ``Surface(SurfaceParams(seed=...))``.

    Attributes
    ----------
    params : SurfaceParams
    radius_m : datum radius (m)
    craters : ndarray (n, N_COLS) — the crater table (see :mod:`mercury_dem.synth.craters`)
    """

    def __init__(self, params: SurfaceParams | None = None, radius_m: float = DATUM_RADIUS_M) -> None:
        self.params = params or SurfaceParams()
        self.radius_m = float(radius_m)
        p = self.params
        rng = np.random.default_rng([p.seed, 0x5EED])
        area_km2 = 4.0 * np.pi * (self.radius_m / 1e3) ** 2
        n_craters = int(rng.poisson(p.crater_k_per_km2 * (p.crater_d_min_m / 1e3) ** -p.crater_slope * area_km2))
        d = cr.sample_diameters(rng, n_craters, p.crater_d_min_m, p.crater_d_max_m, p.crater_slope)
        centres = cr.random_unit_vectors(rng, n_craters)
        ages = rng.random(n_craters)
        kinds = np.where(d < p.transition_m, cr.KIND_SIMPLE, cr.KIND_COMPLEX).astype(np.int64)
        bd = np.exp(rng.uniform(np.log(p.basin_d_min_m), np.log(p.basin_d_max_m), p.n_basins))
        bc = cr.random_unit_vectors(rng, p.n_basins)
        ba = rng.uniform(0.2, 0.5, p.n_basins)
        # Smooth-plains units: caps with soft edges.
        plains = np.zeros((p.n_plains, 6))
        plains[:, 0:3] = cr.random_unit_vectors(rng, p.n_plains)
        plains[:, 3] = rng.uniform(np.radians(8.0), np.radians(25.0), p.n_plains)
        plains[:, 4] = np.radians(3.0)
        plains[:, 5] = np.cos(plains[:, 3] + 0.5 * plains[:, 4])
        self._plains = np.ascontiguousarray(plains)
        table = cr.build_crater_table(
            np.concatenate([centres, bc]),
            np.concatenate([d, bd]),
            np.concatenate([ages, ba]),
            np.concatenate([kinds, np.full(p.n_basins, cr.KIND_BASIN, np.int64)]),
            rng,
            p.transition_m,
            p.fresh_age,
            p.ray_length,
        )
        # Craters older than the plains are erased where the plains are.
        m_centre = _plains_mask(np.ascontiguousarray(table[:, 0:3]), self._plains)
        old = (table[:, cr.C_AGE] < p.plains_age) & (table[:, cr.C_KIND] != cr.KIND_BASIN)
        table[:, cr.C_AMP] *= np.where(old, 1.0 - m_centre, 1.0)
        # Fresh craters on the plains keep their rays; fully erased craters are dropped.
        keep = table[:, cr.C_AMP] > 0.02
        self.craters = np.ascontiguousarray(table[keep])
        self._height_index = cr.build_index(self.craters, self.craters[:, cr.C_REACH], self.radius_m, p.index_cell_deg)
        rays = np.flatnonzero(self.craters[:, cr.C_RAYLEN] > 0)
        self._ray_table = np.ascontiguousarray(self.craters[rays])
        self._ray_index = cr.build_index(self._ray_table, self._ray_table[:, cr.C_RAYLEN], self.radius_m, p.index_cell_deg)
        self._seed_rough = np.uint64(rng.integers(0, 2**62))
        self._seed_albedo = np.uint64(rng.integers(0, 2**62))
        self._seed_longwave = np.uint64(rng.integers(0, 2**62))
        # Long-wave relief: three octaves of noise with wavelengths of thousands of km.
        self._longwave = (np.array([4000e3, 2000e3, 1000e3]), p.longwave_amplitude_m * np.array([1.0, 0.6, 0.35]))
        self._shape = self._shape_grid() if p.shape_harmonics else None

    def _shape_grid(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """(height above the datum (H, W), pixel-centre lats, lons) of the shape model's expansion, on a
        global grid of ``shape_grid_deg`` (evaluated once: scattered evaluation costs O(N L^2)).
        """
        from mercury_dem.reference.sha import evaluate_grid, read_shadr

        p = self.params
        shape = read_shadr(p.shape_harmonics)
        step = p.shape_grid_deg
        lats = 90.0 - (np.arange(int(round(180.0 / step))) + 0.5) * step
        lons = (np.arange(int(round(360.0 / step))) + 0.5) * step
        return evaluate_grid(shape, lats, lons, lmax=p.shape_lmax) - self.radius_m, lats, lons

    def shape_height(self, flat: NDArray[np.float64]) -> NDArray[np.float64]:
        """The shape model's height (m above the datum) at unit vectors (N, 3); zeros without one."""
        if self._shape is None:
            return np.zeros(flat.shape[0])
        from mercury_dem.reference.sampling import sample_grid

        grid, lats, lons = self._shape
        lat = np.degrees(np.arcsin(np.clip(flat[:, 2], -1.0, 1.0)))
        lon = np.mod(np.degrees(np.arctan2(flat[:, 1], flat[:, 0])), 360.0)
        return sample_grid(grid, lats, lons, lat, lon)

    # -- evaluation on unit vectors -----------------------------------------
    def _rough_octaves(self, resolution_m: float | None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        p = self.params
        shortest = p.rough_shortest_m if resolution_m is None else max(p.rough_shortest_m, 2.0 * resolution_m)
        shortest = min(shortest, p.rough_longest_m)
        return octaves(p.rough_longest_m, shortest, p.rough_amplitude_m, p.rough_hurst)

    def height_unit(self, units: ArrayLike, resolution_m: float | None = None) -> NDArray[np.float64]:
        """Height (m above the datum) at unit vectors (..., 3).

        ``resolution_m`` drops roughness octaves shorter than twice that scale
        (they would alias on a grid of that spacing); None keeps them all.
        """
        u = np.asarray(units, dtype=np.float64)
        shape = u.shape[:-1]
        flat = np.ascontiguousarray(u.reshape(-1, 3))
        ix = self._height_index
        h = cr.crater_sum(
            flat, self.craters, ix.cell_deg, ix.n_lat, ix.n_lon, ix.starts, ix.members, ix.cand, self.radius_m, False
        )
        return self._compose_height(flat, h, resolution_m).reshape(shape)

    def _compose_height(
        self, flat: NDArray[np.float64], h: NDArray[np.float64], resolution_m: float | None
    ) -> NDArray[np.float64]:
        """Height (N,) at unit vectors ``flat`` (N, 3) from their summed crater relief ``h`` (N,)."""
        plains = _plains_mask(flat, self._plains)
        # Stacked craters (a crater in a crater in a basin) would add their depths; real
        # excavation does not go that deep, so the crater relief is softly limited at -4.5 km (C1).
        knee, span = -2500.0, 2000.0
        h = np.where(h > knee, h, knee - span * np.tanh((knee - h) / span))
        lam, amp = self._rough_octaves(resolution_m)
        lam = np.concatenate([self._longwave[0], lam])
        amp = np.concatenate([self._longwave[1], amp])
        # One fbm call for the long-wave relief and the roughness (different octaves, one seed).
        rough = fbm(flat * self.radius_m, lam, amp, self._seed_rough)
        z = flat[:, 2]
        polar = -self.params.polar_drop_m * (z * z - 1.0 / 3.0)
        out = polar + h + rough * (1.0 - 0.6 * plains)
        return out if self._shape is None else out + self.shape_height(flat)

    def albedo_unit(self, units: ArrayLike, resolution_m: float | None = None) -> NDArray[np.float64]:
        """Normal albedo (dimensionless, ~0.05-0.4) at unit vectors (..., 3); independent of the height."""
        u = np.asarray(units, dtype=np.float64)
        shape = u.shape[:-1]
        flat = np.ascontiguousarray(u.reshape(-1, 3))
        ix = self._ray_index
        boost = cr.crater_sum(
            flat, self._ray_table, ix.cell_deg, ix.n_lat, ix.n_lon, ix.starts, ix.members, ix.cand, self.radius_m, True
        )
        return self._compose_albedo(flat, boost, resolution_m).reshape(shape)

    def _compose_albedo(
        self, flat: NDArray[np.float64], boost: NDArray[np.float64], resolution_m: float | None
    ) -> NDArray[np.float64]:
        """Albedo (N,) at unit vectors ``flat`` (N, 3) from the ray/halo boost (N,)."""
        p = self.params
        shortest = 2.0 * resolution_m if resolution_m else 500.0
        lam, amp = octaves(800e3, max(shortest, 500.0), 1.0, 0.5, lacunarity=3.0)
        amp = amp / np.sqrt(np.sum(amp**2)) * 1.6
        mottle = fbm(flat * self.radius_m, lam, amp, self._seed_albedo)
        a = p.albedo_mean * np.exp(p.albedo_variation * mottle) * (1.0 + boost)
        return np.clip(a, 0.01, 0.9)

    def sample_grid(
        self, grid: Any, units: NDArray[np.float64], resolution_m: float | None = None
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Height (m) and albedo, each (ny, nx), at the nodes of a renderer's local grid.

        ``grid`` : a :class:`mercury_dem.synth.render.LocalGrid` (plane tangent at
        ``grid.centre``, spacing ``grid.spacing_m``), ``units`` (ny, nx, 3) its node
        directions. The same fields as :meth:`height_unit` / :meth:`albedo_unit` at
        ``resolution_m = grid.spacing_m`` (up to the order of the crater sums, ~1e-12 m),
        but the craters are visited crater by crater over the grid (each touches only
        the nodes it reaches) instead of point by point through the lat/lon index:
        ~3x faster on a renderer's grid. ``resolution_m`` (default: the grid spacing) is the
        resolution the fields are band-limited to.
        """
        res = float(grid.spacing_m) if resolution_m is None else float(resolution_m)
        u = np.ascontiguousarray(units, dtype=np.float64)
        shape = u.shape[:-1]
        flat = u.reshape(-1, 3)
        frame = np.ascontiguousarray(np.stack([grid.centre, grid.east, grid.north]), dtype=np.float64)
        geo = (frame, float(grid.radius_m), float(grid.x0), float(grid.y0), float(grid.spacing_m), self.radius_m)
        ix = self._height_index
        ids = cr.grid_candidates(ix, u, self.craters.shape[0])
        h = cr.crater_heights_grid(u, self.craters, ids, ix.reach_rad, *geo)
        height = self._compose_height(flat, h.ravel(), res).reshape(shape)
        ix = self._ray_index
        ids = cr.grid_candidates(ix, u, self._ray_table.shape[0])
        boost = cr.ray_albedo_grid(u, self._ray_table, ids, ix.reach_rad, *geo)
        albedo = self._compose_albedo(flat, boost.ravel(), res).reshape(shape)
        return height, albedo

    # -- evaluation on latitude/longitude ------------------------------------
    def height(self, lat_deg: ArrayLike, lon_deg: ArrayLike, resolution_m: float | None = None) -> NDArray[np.float64]:
        """Height (m above the datum) at planetocentric latitude / east longitude (degrees), any shape."""
        lat, lon = np.broadcast_arrays(np.asarray(lat_deg, float), np.asarray(lon_deg, float))
        return self.height_unit(latlon_to_unit(lat, lon), resolution_m)

    def albedo(self, lat_deg: ArrayLike, lon_deg: ArrayLike, resolution_m: float | None = None) -> NDArray[np.float64]:
        """Normal albedo at latitude/longitude (degrees), any shape."""
        lat, lon = np.broadcast_arrays(np.asarray(lat_deg, float), np.asarray(lon_deg, float))
        return self.albedo_unit(latlon_to_unit(lat, lon), resolution_m)

    def normal(self, lat_deg: ArrayLike, lon_deg: ArrayLike, step_m: float = 50.0) -> NDArray[np.float64]:
        """Outward unit surface normals (..., 3), body-fixed, by central differences over ``step_m``."""
        lat, lon = np.broadcast_arrays(np.asarray(lat_deg, float), np.asarray(lon_deg, float))
        u = latlon_to_unit(lat, lon)
        east = np.stack([-np.sin(np.radians(lon)), np.cos(np.radians(lon)), np.zeros_like(lon)], -1)
        north = np.cross(u, east)
        e = step_m / self.radius_m

        def point(v: NDArray[np.float64]) -> NDArray[np.float64]:
            v = v / np.linalg.norm(v, axis=-1, keepdims=True)
            return v * (self.radius_m + self.height_unit(v, step_m / 2))[..., None]

        de = point(u + e * east) - point(u - e * east)
        dn = point(u + e * north) - point(u - e * north)
        nrm = np.cross(de, dn)
        return nrm / np.linalg.norm(nrm, axis=-1, keepdims=True)

    def crater_catalog(self) -> dict[str, NDArray[np.float64]]:
        """Centres (lat, lon deg), diameters (m), kinds, ages and ray flags of the craters (for tests and docs)."""
        t = self.craters
        lat = np.degrees(np.arcsin(np.clip(t[:, cr.C_Z], -1, 1)))
        lon = np.mod(np.degrees(np.arctan2(t[:, cr.C_Y], t[:, cr.C_X])), 360.0)
        return {
            "lat": lat,
            "lon": lon,
            "diameter_m": 2.0 * t[:, cr.C_RADIUS],
            "depth_m": t[:, cr.C_DEPTH] * t[:, cr.C_AMP],
            "kind": t[:, cr.C_KIND].astype(np.int64),
            "age": t[:, cr.C_AGE],
            "rays": t[:, cr.C_RAYLEN] > 0,
        }


#: MLA's GTMES_150V05 shape of Mercury as shipped with the package (the same name as
#: ``mercury_dem.reference.sha.GTMES_PACKAGED``; spelled here so the presets need not import the reference package).
GTMES_PACKAGED = "package:GTMES_150V05_SHA.TAB"


def with_shape_harmonics(params: SurfaceParams, path: str, lmax: int = 148) -> SurfaceParams:
    """``params`` with a real shape model's long wavelengths in place of the synthetic ones (the
    long-wave noise and the polar depression set to 0; craters, basins, plains and roughness kept).
    """
    from dataclasses import replace
    from pathlib import Path

    # a packaged table keeps its package name (portable truth/surface.json); a file its absolute path
    name = str(path) if str(path).startswith("package:") else str(Path(path).resolve())
    return replace(params, shape_harmonics=name, shape_lmax=int(lmax),
                   longwave_amplitude_m=0.0, polar_drop_m=0.0)


def surface_from_dict(d: dict[str, Any]) -> Surface:
    """The truth surface of a mission's ``truth/surface.json`` (``params`` and ``radius_m``)."""
    return Surface(SurfaceParams.from_dict(d["params"]), radius_m=d["radius_m"])
