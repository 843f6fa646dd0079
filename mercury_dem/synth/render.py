"""Rendering a framing-camera image of the truth surface from a (true) pose.

How an image is made (:func:`render_image`):

1. **Local grid.** The image footprint (rays of the border pixels intersected
   with the spheres of the lowest and highest possible heights) is mapped by a
   gnomonic projection onto the plane tangent at the footprint centre, widened
   on the sun side by the length of the longest shadow, and the procedural
   surface is sampled once on a square grid of that plane (spacing
   ``grid_spacing_px``, one ground pixel by default; roughness and albedo octaves
   shorter than twice ``surface_resolution_px`` -- by default the grid spacing --
   are left out). Each grid
   node is a body-fixed 3-D point ``direction * (R + h)``.
2. **Shadows** are computed on the grid by a sweep from the sun side: along a
   sun ray the coordinate ``b = P . u`` (``u`` perpendicular to the sun
   direction, in the vertical plane of the sun) is constant, so a node is lit
   when its ``b`` is not below the running maximum of ``b`` of the nodes between
   it and the sun. This is exact for parallel sun rays up to the grid's
   interpolation and costs O(nodes).
3. **Drawing**: every node goes through the camera model (rotation,
   perspective, the distortion polynomial of :func:`mercury_dem.geometry.pose.project`)
   to sub-sample coordinates, ``supersample`` x ``supersample`` per pixel, and each
   grid cell is drawn as two triangles into a z-buffer (the nearest surface wins,
   so terrain hidden behind a ridge is hidden exactly). See
   :mod:`mercury_dem.synth.raster`.
4. **Photometry:** a Lommel–Seeliger / Lambert mix with an exponential phase
   function, the albedo field (including rays of fresh craters) and the lit
   flag of the sweep, all interpolated at each sub-sample from the nodes of its
   triangle; local incidence and emission use the grid normals (parallel sun rays
   from the grid centre, as the shadow sweep).
5. **Sensor:** Gaussian point-spread blur, box average of the sub-samples,
   automatic exposure (a high percentile of the scene to a fixed DN), shot
   noise (Poisson in electrons), read noise, 12-bit quantisation, ``uint16``.

The compiled kernels (numba) replace a numpy ray march that took 8 s per 512^2
image at 2 x 2 sub-samples and a compiled ray march that took 0.3 s of the
0.7 s per image (see docs/benchmarks/synth.md). All randomness
comes from the ``rng`` argument: the same inputs give a bit-identical image.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from mercury_dem.exceptions import GeometryError
from mercury_dem.geometry.camera import FramingCamera
from mercury_dem.geometry.pose import intersect_sphere, pixel_rays
from mercury_dem.synth import raster as rs

#: Conservative height bounds (m) of any synthetic surface, used to bound the footprint.
DEFAULT_HEIGHT_BOUNDS_M = (-9000.0, 7000.0)


class SurfaceModel(Protocol):
    """What the renderer needs from a surface (``Surface`` satisfies it)."""

    radius_m: float

    def height_unit(self, units: ArrayLike, resolution_m: float | None = None) -> NDArray[np.float64]: ...

    def albedo_unit(self, units: ArrayLike, resolution_m: float | None = None) -> NDArray[np.float64]: ...


@dataclass(frozen=True)
class RenderSettings:
    """Rendering and sensor parameters.

    supersample : sub-samples per pixel side (2 means 2 x 2)
    grid_spacing_px : local height-grid spacing in ground pixels at the footprint centre. 1 draws each view
        from its own piecewise-linear sampling of the surface's shortest wavelengths; 0.5 with
        ``surface_resolution_px`` 1 (the same surface, a finer grid; ``mercury-dem synth --render-grid-px
        0.5``) makes two noise-free views of a km-scale mission agree to 0.18-0.33 px instead of 0.25-0.47 px
        (1.4826 MAD of the dense matcher's disparity error) at 3.5-3.7x the render cost (docs/design/dense.md)
    psf_sigma_px : Gaussian point-spread sigma, image pixels
    lambert_weight : weight of the Lambert term in the Lommel–Seeliger/Lambert mix (0..1)
    phase_scale_deg : e-folding angle of the exponential phase function, degrees
    exposure_dn : DN given to the median of the lit scene (auto-exposure; bright rays may saturate)
    gain_e_per_dn : electrons per DN (shot noise)
    read_noise_dn : read noise, DN (1 sigma)
    dark_dn : dark/bias level added before quantisation, DN
    shadows : cast shadows on/off
    max_shadow_m : longest shadow the grid is widened for, metres
    height_bounds_m : (lowest, highest) possible surface height, metres
    surface_resolution_px : resolution the surface (roughness and albedo octaves) is band-limited to, in
        ground pixels of the view (shortest wavelength twice that); 0: the grid spacing (sessions <= 19)
    surface_resolution_m : the same in metres, one resolution for every view of a mission (takes
        precedence over ``surface_resolution_px`` when > 0); 0: per view
    """

    supersample: int = 2
    grid_spacing_px: float = 1.0
    psf_sigma_px: float = 0.6
    lambert_weight: float = 0.25
    phase_scale_deg: float = 60.0
    exposure_dn: float = 1500.0
    gain_e_per_dn: float = 25.0
    read_noise_dn: float = 1.2
    dark_dn: float = 10.0
    shadows: bool = True
    max_shadow_m: float = 120e3
    height_bounds_m: tuple[float, float] = DEFAULT_HEIGHT_BOUNDS_M
    max_grid_nodes: int = 40_000_000
    surface_resolution_px: float = 0.0
    surface_resolution_m: float = 0.0

    def __post_init__(self) -> None:
        if self.supersample < 1 or self.supersample > 8:
            raise GeometryError(f"render setting 'supersample' must be 1..8, got {self.supersample}")
        if not self.grid_spacing_px > 0:
            raise GeometryError(f"render setting 'grid_spacing_px' must be > 0, got {self.grid_spacing_px}")
        if self.surface_resolution_px < 0 or self.surface_resolution_m < 0:
            raise GeometryError("render settings 'surface_resolution_px' and 'surface_resolution_m' must be >= 0, "
                                f"got {self.surface_resolution_px}, {self.surface_resolution_m}")

    def surface_resolution(self, grid_spacing_m: float) -> float:
        """Resolution (m) the surface is sampled at on a view's grid of spacing ``grid_spacing_m``."""
        if self.surface_resolution_m > 0:
            return float(self.surface_resolution_m)
        if self.surface_resolution_px > 0:
            return float(self.surface_resolution_px * grid_spacing_m / self.grid_spacing_px)
        return float(grid_spacing_m)


@dataclass(frozen=True)
class LocalGrid:
    """A gnomonic grid on the plane tangent at ``centre`` (unit vector), spacing ``spacing_m``.

    Node (j, i) has plane coordinates ``x = x0 + i * spacing``, ``y = y0 + j * spacing``
    along the tangent unit vectors ``east`` and ``north`` (any right-handed tangent
    pair: the renderer aligns them with the image axes so the grid hugs the
    footprint); its direction is ``normalize(R * centre + x * east + y * north)``.
    """

    centre: NDArray[np.float64]
    east: NDArray[np.float64]
    north: NDArray[np.float64]
    radius_m: float
    x0: float
    y0: float
    spacing_m: float
    nx: int
    ny: int

    def directions(self) -> NDArray[np.float64]:
        """Unit vectors of the nodes, shape (ny, nx, 3)."""
        return rs.grid_directions(
            np.asarray(self.centre, float), np.asarray(self.east, float), np.asarray(self.north, float),
            float(self.radius_m), float(self.x0), float(self.y0), float(self.spacing_m), int(self.nx), int(self.ny),
        )

    def plane_coords(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        """Gnomonic plane coordinates (..., 2) of body-fixed points (..., 3)."""
        pc = points @ self.centre
        return self.radius_m * np.stack([points @ self.east, points @ self.north], -1) / pc[..., None]


def tangent_frame(centre: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """East and north unit vectors at a unit vector (x axis used as 'north' fallback at the poles)."""
    z = np.array([0.0, 0.0, 1.0])
    east = np.cross(z, centre)
    if np.linalg.norm(east) < 1e-9:
        east = np.cross(np.array([1.0, 0.0, 0.0]), centre)
    east /= np.linalg.norm(east)
    north = np.cross(centre, east)
    return east, north


def footprint_grid(
    camera: FramingCamera,
    position: NDArray[np.float64],
    rotation: NDArray[np.float64],
    sun_position: NDArray[np.float64],
    radius_m: float,
    settings: RenderSettings,
) -> LocalGrid:
    """The local grid covering what the camera can see (plus the sun-side shadow margin)."""
    lo, hi = settings.height_bounds_m
    centre_px = np.array([[(camera.samples - 1) / 2.0, (camera.lines - 1) / 2.0]])
    pix = np.concatenate([camera.edge_pixels(16), centre_px])
    o, d = pixel_rays(camera, position, rotation, pix)
    p_lo, hit_lo = intersect_sphere(o, d, radius_m + lo)
    p_hi, hit_hi = intersect_sphere(o, d, radius_m + hi)
    if not hit_hi[-1]:
        raise GeometryError("the image centre does not see the body; cannot render")
    centre = p_hi[-1] / np.linalg.norm(p_hi[-1])
    # Grid axes along the image's sample direction projected on the tangent plane.
    east = rotation[0] - (rotation[0] @ centre) * centre
    if np.linalg.norm(east) < 1e-6:
        east, north = tangent_frame(centre)
    else:
        east = east / np.linalg.norm(east)
        north = np.cross(centre, east)
    slant = np.linalg.norm(p_hi[-1] - position)
    spacing = settings.grid_spacing_px * slant * camera.ifov_rad
    pts = np.concatenate([p_lo[hit_lo], p_hi[hit_hi]])
    tmp = LocalGrid(centre, east, north, radius_m, 0.0, 0.0, spacing, 1, 1)
    xy = tmp.plane_coords(pts)
    xmin, ymin = xy.min(0)
    xmax, ymax = xy.max(0)
    if settings.shadows:
        s = sun_position - centre * radius_m
        s = s / np.linalg.norm(s)
        elev = np.arcsin(np.clip(s @ centre, -1.0, 1.0))
        if elev <= 0:
            raise GeometryError("the sun is below the horizon at the image centre; nothing to render")
        extent = max(xmax - xmin, ymax - ymin)
        margin = min(settings.max_shadow_m, (hi - lo) / np.tan(elev), extent)
        sh = np.array([s @ east, s @ north])
        sh = sh / max(np.linalg.norm(sh), 1e-12)
        xmin, xmax = min(xmin, xmin + margin * sh[0]), max(xmax, xmax + margin * sh[0])
        ymin, ymax = min(ymin, ymin + margin * sh[1]), max(ymax, ymax + margin * sh[1])
    pad = 3 * spacing
    nx = int(np.ceil((xmax - xmin + 2 * pad) / spacing)) + 1
    ny = int(np.ceil((ymax - ymin + 2 * pad) / spacing)) + 1
    if nx * ny > settings.max_grid_nodes:
        raise GeometryError(
            f"the footprint needs a {nx} x {ny} height grid (more than {settings.max_grid_nodes} nodes); "
            "the view is too oblique or the grid too fine (raise grid_spacing_px)"
        )
    return LocalGrid(centre, east, north, radius_m, xmin - pad, ymin - pad, spacing, nx, ny)


@numba.njit(cache=True, nogil=True)
def _sweep_shadows(b: NDArray[np.float64], dy: float) -> NDArray[np.float64]:
    """Lit (1) / shadowed (0) nodes by a running-max sweep along +x toward the sun.

    ``b`` (ny, nx): the sun-ray coordinate of each node; the sun lies toward
    increasing column index, one column per step with ``dy`` rows of lateral
    drift (|dy| <= 1).
    """
    ny, nx = b.shape
    lit = np.ones((ny, nx))
    run = np.empty((ny, nx))
    run[:, nx - 1] = b[:, nx - 1]
    for i in range(nx - 2, -1, -1):
        for j in range(ny):
            yj = j + dy
            j0 = int(np.floor(yj))
            w = yj - j0
            if j0 < 0 or j0 + 1 > ny - 1:
                # The upstream node is off the grid: nothing casts a shadow from there.
                run[j, i] = b[j, i]
                continue
            up = (1.0 - w) * run[j0, i + 1] + w * run[j0 + 1, i + 1]
            if b[j, i] < up:
                lit[j, i] = 0.0
                run[j, i] = up
            else:
                run[j, i] = b[j, i]
    return lit


def shadow_grid(points: NDArray[np.float64], grid: LocalGrid, sun_position: NDArray[np.float64]) -> NDArray[np.float64]:
    """Lit fraction (0 or 1) of the grid nodes, shape (ny, nx)."""
    s = sun_position - grid.centre * grid.radius_m
    s = s / np.linalg.norm(s)
    u = grid.centre - (grid.centre @ s) * s
    if np.linalg.norm(u) < 1e-9:
        return np.ones((grid.ny, grid.nx))
    u /= np.linalg.norm(u)
    b = points @ u
    se, sn = s @ grid.east, s @ grid.north
    if abs(se) >= abs(sn):
        bb = b if se > 0 else b[:, ::-1]
        lit = _sweep_shadows(np.ascontiguousarray(bb), sn / abs(se))
        return lit if se > 0 else lit[:, ::-1]
    bb = b.T if sn > 0 else b[::-1, :].T
    lit = _sweep_shadows(np.ascontiguousarray(bb), se / abs(sn))
    return lit.T if sn > 0 else lit.T[::-1, :]


@numba.njit(cache=True, nogil=True)
def _grid_normals(points: NDArray[np.float64]) -> NDArray[np.float64]:
    ny, nx, _ = points.shape
    out = np.empty((3, ny, nx))
    for j in range(ny):
        j0, j1 = max(j - 1, 0), min(j + 1, ny - 1)
        for i in range(nx):
            out[0, j, i], out[1, j, i], out[2, j, i] = rs.grid_normal(
                points, j0, j, j1, max(i - 1, 0), i, min(i + 1, nx - 1))
    return out


def grid_normals(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Outward unit normals (3, ny, nx) of a grid of 3-D points (ny, nx, 3) (x = east, y = north),
    by central differences (one-sided at the border).
    """
    return _grid_normals(np.ascontiguousarray(points))


def subsample_pixels(samples: int, lines: int, supersample: int) -> NDArray[np.float64]:
    """Sub-pixel positions (lines*ss, samples*ss, 2) (sample, line), 0-based pixel centres."""
    off = (np.arange(supersample) + 0.5) / supersample - 0.5
    s = (np.arange(samples)[:, None] + off[None, :]).ravel()
    l = (np.arange(lines)[:, None] + off[None, :]).ravel()
    ss, ll = np.meshgrid(s, l)
    return np.stack([ss, ll], -1)


def sun_direction(grid: LocalGrid, sun_position: ArrayLike) -> NDArray[np.float64]:
    """Unit vector toward the sun from the grid centre (the renderer's parallel sun rays)."""
    s = np.asarray(sun_position, dtype=np.float64) - grid.centre * grid.radius_m
    return s / np.linalg.norm(s)


def render_reflectance(
    surface: SurfaceModel,
    camera: FramingCamera,
    position: ArrayLike,
    rotation: ArrayLike,
    sun_position: ArrayLike,
    settings: RenderSettings = RenderSettings(),
) -> NDArray[np.float64]:
    """Noise-free radiance factor I/F (lines, samples), before PSF and sensor effects (box-averaged)."""
    img = _render_supersampled(surface, camera, position, rotation, sun_position, settings)
    ss = settings.supersample
    return img.reshape(camera.lines, ss, camera.samples, ss).mean(axis=(1, 3))


def sample_surface(
    surface: SurfaceModel, grid: LocalGrid, dirs: NDArray[np.float64], resolution_m: float | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Heights (m) and albedo of the grid nodes, each (ny, nx), band-limited to ``resolution_m``
    (default: the grid spacing).

    ``dirs`` : (ny, nx, 3) the node directions (``grid.directions()``).
    Uses the surface's ``sample_grid(grid, dirs, resolution_m)`` when it has one (the truth ``Surface``
    evaluates craters per crater over the grid instead of per point), else
    ``height_unit``/``albedo_unit`` at the node directions.
    """
    res = grid.spacing_m if resolution_m is None else resolution_m
    fast = getattr(surface, "sample_grid", None)
    if fast is not None:
        return fast(grid, dirs, res)
    return surface.height_unit(dirs, res), surface.albedo_unit(dirs, res)


def _render_supersampled(
    surface: SurfaceModel,
    camera: FramingCamera,
    position: ArrayLike,
    rotation: ArrayLike,
    sun_position: ArrayLike,
    settings: RenderSettings,
) -> NDArray[np.float64]:
    if camera.focal_plane_map or camera.distortion_model not in ("none", "transverse"):
        # the compiled projection knows only L = p I and the transverse polynomial
        raise GeometryError(f"camera {camera.name}: rendering supports square-pixel cameras with 'transverse' "
                            f"or no distortion, not a general focal_plane_map or "
                            f"'{camera.distortion_model}' distortion")
    c = np.asarray(position, dtype=np.float64)
    r = np.ascontiguousarray(rotation, dtype=np.float64)
    sun = np.asarray(sun_position, dtype=np.float64)
    radius = float(surface.radius_m)
    grid = footprint_grid(camera, c, r, sun, radius, settings)
    dirs = grid.directions()
    heights, alb = sample_surface(surface, grid, dirs, settings.surface_resolution(grid.spacing_m))
    points = dirs * (radius + heights)[..., None]
    lit = shadow_grid(points, grid, sun) if settings.shadows else np.ones(heights.shape)
    s = sun_direction(grid, sun)
    fields = rs.node_fields(points, lit, np.ascontiguousarray(alb, dtype=np.float64), c, s,
                            float(np.radians(settings.phase_scale_deg)))
    ss = settings.supersample
    dist_x = np.asarray(camera.distortion_x, dtype=np.float64)
    dist_y = np.asarray(camera.distortion_y, dtype=np.float64)
    uv, depth = rs.project_nodes(points, c, r, camera.focal_length_mm, camera.pixel_size_mm, camera.boresight_sample,
                                 camera.boresight_line, dist_x, dist_y, ss)
    tri, w1, w2 = rs.rasterize(uv, depth, camera.samples * ss, camera.lines * ss)
    return rs.shade(tri, w1, w2, fields, s, settings.lambert_weight)


def render_image(
    surface: SurfaceModel,
    camera: FramingCamera,
    position: ArrayLike,
    rotation: ArrayLike,
    sun_position: ArrayLike,
    rng: np.random.Generator,
    settings: RenderSettings = RenderSettings(),
) -> NDArray[np.uint16]:
    """A 12-bit image (lines, samples) uint16 of ``surface`` seen from a pose.

    Parameters
    ----------
    surface : the truth surface (anything with ``radius_m``, ``height_unit``, ``albedo_unit``)
    camera : interior orientation (its ``samples`` x ``lines`` is the image size)
    position : (3,) camera position, body-fixed metres (the TRUE pose)
    rotation : (3, 3) body-fixed -> camera rotation (the TRUE pose)
    sun_position : (3,) body-fixed metres
    rng : noise generator (the only source of randomness)
    settings : :class:`RenderSettings`

    Returns
    -------
    ndarray (lines, samples) uint16, DN in 0..4095; pixels that miss the body are dark-level noise.
    """
    img = _render_supersampled(surface, camera, position, rotation, sun_position, settings)
    img = rs.psf_box(img, settings.psf_sigma_px, settings.supersample)
    return expose(img, rng, settings)


def expose(reflectance: NDArray[np.float64], rng: np.random.Generator, settings: RenderSettings) -> NDArray[np.uint16]:
    """I/F image -> 12-bit DN with auto-exposure, shot noise, read noise and quantisation."""
    lit = reflectance[reflectance > 0]
    level = float(np.median(lit)) if lit.size else 0.0
    scale = settings.exposure_dn / level if level > 0 else 0.0
    signal_e = np.maximum(reflectance * scale, 0.0) * settings.gain_e_per_dn
    electrons = rng.poisson(signal_e).astype(np.float64)
    dn = electrons / settings.gain_e_per_dn + settings.dark_dn + rng.normal(0.0, settings.read_noise_dn, reflectance.shape)
    return np.clip(np.rint(dn), 0, 4095).astype(np.uint16)
