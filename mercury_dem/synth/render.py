"""Rendering a framing-camera image of the truth surface from a (true) pose.

How an image is made (:func:`render_image`):

1. **Local grid.** The image footprint (rays of the border pixels intersected
   with the spheres of the lowest and highest possible heights) is mapped by a
   gnomonic projection onto the plane tangent at the footprint centre, widened
   on the sun side by the length of the longest shadow, and the procedural
   surface is sampled once on a square grid of that plane (spacing about one
   ground pixel; roughness octaves finer than the grid are left out). Each grid
   node is a body-fixed 3-D point ``direction * (R + h)``.
2. **Shadows** are computed on the grid by a sweep from the sun side: along a
   sun ray the coordinate ``b = P . u`` (``u`` perpendicular to the sun
   direction, in the vertical plane of the sun) is constant, so a node is lit
   when its ``b`` is not below the running maximum of ``b`` of the nodes between
   it and the sun. This is exact for parallel sun rays up to the grid's
   interpolation and costs O(nodes).
3. **Primary rays**, ``supersample`` x ``supersample`` per pixel, are cast from the
   camera through the distorted pixel positions (the inverse of the camera
   model used by :func:`mercury_dem.geometry.pose.project`) and marched onto the
   bilinearly interpolated height grid with steps bounded by the grid's steepest
   slope (they never skip through a ridge), then refined by regula falsi to
   the converged intersection.
4. **Photometry:** a Lommel–Seeliger / Lambert mix with an exponential phase
   function, the albedo field (including rays of fresh craters) and the shadow
   fraction, all interpolated at the hit point; local incidence and emission
   use the grid normals.
5. **Sensor:** Gaussian point-spread blur, box average of the sub-samples,
   automatic exposure (a high percentile of the scene to a fixed DN), shot
   noise (Poisson in electrons), read noise, 12-bit quantisation, ``uint16``.

The compiled kernels (numba) replace a numpy ray march that took 4 s per 512^2
image at one sample per pixel (see docs/benchmarks/synth.md). All randomness
comes from the ``rng`` argument: the same inputs give a bit-identical image.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import gaussian_filter

from mercury_dem.exceptions import GeometryError
from mercury_dem.geometry.camera import FramingCamera
from mercury_dem.geometry.pose import intersect_sphere, pixel_rays

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
    grid_spacing_px : local height-grid spacing in ground pixels at the footprint centre
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

    def __post_init__(self) -> None:
        if self.supersample < 1 or self.supersample > 8:
            raise GeometryError(f"render setting 'supersample' must be 1..8, got {self.supersample}")
        if not self.grid_spacing_px > 0:
            raise GeometryError(f"render setting 'grid_spacing_px' must be > 0, got {self.grid_spacing_px}")


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
        x = self.x0 + self.spacing_m * np.arange(self.nx)
        y = self.y0 + self.spacing_m * np.arange(self.ny)
        v = (
            self.radius_m * self.centre[None, None, :]
            + x[None, :, None] * self.east[None, None, :]
            + y[:, None, None] * self.north[None, None, :]
        )
        return v / np.linalg.norm(v, axis=-1, keepdims=True)

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
            i0, i1 = max(i - 1, 0), min(i + 1, nx - 1)
            ax = points[j, i1, 0] - points[j, i0, 0]
            ay = points[j, i1, 1] - points[j, i0, 1]
            az = points[j, i1, 2] - points[j, i0, 2]
            bx = points[j1, i, 0] - points[j0, i, 0]
            by = points[j1, i, 1] - points[j0, i, 1]
            bz = points[j1, i, 2] - points[j0, i, 2]
            cx = ay * bz - az * by
            cy = az * bx - ax * bz
            cz = ax * by - ay * bx
            n = np.sqrt(cx * cx + cy * cy + cz * cz)
            out[0, j, i] = cx / n
            out[1, j, i] = cy / n
            out[2, j, i] = cz / n
    return out


def grid_normals(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Outward unit normals (3, ny, nx) of a grid of 3-D points (ny, nx, 3) (x = east, y = north),
    by central differences (one-sided at the border)."""
    return _grid_normals(np.ascontiguousarray(points))


@numba.njit(cache=True, inline="always")
def _bilinear(a: NDArray[np.float64], fx: float, fy: float) -> float:
    ny, nx = a.shape
    i = min(max(int(np.floor(fx)), 0), nx - 2)
    j = min(max(int(np.floor(fy)), 0), ny - 2)
    u = min(max(fx - i, 0.0), 1.0)
    v = min(max(fy - j, 0.0), 1.0)
    return (1 - v) * ((1 - u) * a[j, i] + u * a[j, i + 1]) + v * ((1 - u) * a[j + 1, i] + u * a[j + 1, i + 1])


@numba.njit(cache=True, inline="always")
def _height_gap(
    px: float, py: float, pz: float, frame: NDArray[np.float64], radius: float, x0: float, y0: float, g: float,
    heights: NDArray[np.float64],
) -> tuple[float, float, float]:
    """(height of the point above the interpolated surface, grid fx, grid fy)."""
    pc = px * frame[0, 0] + py * frame[0, 1] + pz * frame[0, 2]
    x = radius * (px * frame[1, 0] + py * frame[1, 1] + pz * frame[1, 2]) / pc
    y = radius * (px * frame[2, 0] + py * frame[2, 1] + pz * frame[2, 2]) / pc
    fx = (x - x0) / g
    fy = (y - y0) / g
    h = _bilinear(heights, fx, fy)
    r = np.sqrt(px * px + py * py + pz * pz)
    return r - radius - h, fx, fy


@numba.njit(cache=True, nogil=True, fastmath=True)
def _cast_and_shade(
    origin: NDArray[np.float64],
    dirs: NDArray[np.float64],
    frame: NDArray[np.float64],
    radius: float,
    x0: float,
    y0: float,
    g: float,
    heights: NDArray[np.float64],
    fields: NDArray[np.float64],
    block_max: NDArray[np.float64],
    block: int,
    h_lo: float,
    h_hi: float,
    slope_max: float,
    sun: NDArray[np.float64],
    lambert_weight: float,
    phase_scale_rad: float,
) -> NDArray[np.float64]:
    """I/F of each ray (N,) (0 where it misses the body), by marching onto the height grid."""
    n = dirs.shape[0]
    out = np.zeros(n)
    ox, oy, oz = origin[0], origin[1], origin[2]
    oo = ox * ox + oy * oy + oz * oz
    tol = 1e-2 * g
    min_step = 0.05 * g
    ny, nx = heights.shape
    for k in range(n):
        dx, dy, dz = dirs[k, 0], dirs[k, 1], dirs[k, 2]
        bq = ox * dx + oy * dy + oz * dz
        r_hi = radius + h_hi
        disc = bq * bq - (oo - r_hi * r_hi)
        if disc < 0.0:
            continue
        t = -bq - np.sqrt(disc)
        if t < 0.0:
            t = 0.0
        r_lo = radius + h_lo
        disc_lo = bq * bq - (oo - r_lo * r_lo)
        t_end = -bq - np.sqrt(disc_lo) if disc_lo >= 0.0 else -bq + np.sqrt(disc)
        # Lipschitz bound of the height gap along the ray.
        px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
        rr = np.sqrt(px * px + py * py + pz * pz)
        a = abs(px * dx + py * dy + pz * dz) / rr
        lip = a + 1.1 * slope_max * np.sqrt(max(0.0, 1.0 - a * a)) + 1e-6
        f, fx, fy = _height_gap(px, py, pz, frame, radius, x0, y0, g, heights)
        # Block phase: while the ray is above the highest node within one block
        # (``block_max`` is dilated by a block), descend to that height in one step,
        # moving at most one block sideways (safe: nothing there reaches the ray).
        reach = 0.9 * block * g
        for _ in range(256):
            bi = min(max(int(fx) // block, 0), block_max.shape[1] - 1)
            bj = min(max(int(fy) // block, 0), block_max.shape[0] - 1)
            above = rr - radius - block_max[bj, bi]
            if above < g:
                break
            rate = -(px * dx + py * dy + pz * dz) / rr
            step = reach if rate <= 1e-9 else min(above / rate, reach)
            t += step
            if t > t_end + g:
                break
            px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
            rr = np.sqrt(px * px + py * py + pz * pz)
            f, fx, fy = _height_gap(px, py, pz, frame, radius, x0, y0, g, heights)
        t_prev, f_prev = t, f
        hit = False
        for _ in range(10000):
            if f < tol:
                hit = True
                break
            t_prev, f_prev = t, f
            t += max(f / lip, min_step)
            if t > t_end + g:
                break
            px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
            f, fx, fy = _height_gap(px, py, pz, frame, radius, x0, y0, g, heights)
        if not hit:
            continue
        if f < -tol:
            # Regula falsi (Illinois) between the last point above and the first below.
            ta, fa, tb, fb = t_prev, f_prev, t, f
            side = 0
            for _ in range(30):
                tm = (ta * fb - tb * fa) / (fb - fa)
                px, py, pz = ox + tm * dx, oy + tm * dy, oz + tm * dz
                fm, fx, fy = _height_gap(px, py, pz, frame, radius, x0, y0, g, heights)
                if abs(fm) < tol:
                    break
                if fm > 0.0:
                    ta, fa = tm, fm
                    if side == 1:
                        fb *= 0.5
                    side = 1
                else:
                    tb, fb = tm, fm
                    if side == -1:
                        fa *= 0.5
                    side = -1
        if fx < 0.0 or fy < 0.0 or fx > nx - 1 or fy > ny - 1:
            continue
        # Shading at the hit point: one bilinear stencil for the packed fields
        # (normal x, y, z, lit fraction, albedo) of shape (ny, nx, 5).
        ii = min(max(int(np.floor(fx)), 0), nx - 2)
        jj = min(max(int(np.floor(fy)), 0), ny - 2)
        uu = min(max(fx - ii, 0.0), 1.0)
        vv = min(max(fy - jj, 0.0), 1.0)
        w00 = (1.0 - uu) * (1.0 - vv)
        w01 = uu * (1.0 - vv)
        w10 = (1.0 - uu) * vv
        w11 = uu * vv
        nxv = w00 * fields[jj, ii, 0] + w01 * fields[jj, ii + 1, 0] + w10 * fields[jj + 1, ii, 0] + w11 * fields[jj + 1, ii + 1, 0]
        nyv = w00 * fields[jj, ii, 1] + w01 * fields[jj, ii + 1, 1] + w10 * fields[jj + 1, ii, 1] + w11 * fields[jj + 1, ii + 1, 1]
        nzv = w00 * fields[jj, ii, 2] + w01 * fields[jj, ii + 1, 2] + w10 * fields[jj + 1, ii, 2] + w11 * fields[jj + 1, ii + 1, 2]
        nn = np.sqrt(nxv * nxv + nyv * nyv + nzv * nzv)
        nxv, nyv, nzv = nxv / nn, nyv / nn, nzv / nn
        sx, sy, sz = sun[0] - px, sun[1] - py, sun[2] - pz
        sn = np.sqrt(sx * sx + sy * sy + sz * sz)
        sx, sy, sz = sx / sn, sy / sn, sz / sn
        mu0 = nxv * sx + nyv * sy + nzv * sz
        mu = -(nxv * dx + nyv * dy + nzv * dz)
        if mu0 <= 0.0 or mu <= 0.0:
            continue
        shade = w00 * fields[jj, ii, 3] + w01 * fields[jj, ii + 1, 3] + w10 * fields[jj + 1, ii, 3] + w11 * fields[jj + 1, ii + 1, 3]
        if shade <= 0.0:
            continue
        alb = w00 * fields[jj, ii, 4] + w01 * fields[jj, ii + 1, 4] + w10 * fields[jj + 1, ii, 4] + w11 * fields[jj + 1, ii + 1, 4]
        cos_phase = -(sx * dx + sy * dy + sz * dz)
        phase = np.arccos(min(1.0, max(-1.0, cos_phase)))
        ls = 2.0 * mu0 / (mu0 + mu)
        refl = (1.0 - lambert_weight) * ls + lambert_weight * mu0
        out[k] = alb * np.exp(-phase / phase_scale_rad) * refl * shade
    return out


@numba.njit(cache=True, nogil=True)
def _interp_directions(
    lattice: NDArray[np.float64], step: int, n_lines: int, n_samples: int, rot: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Body-fixed unit ray directions (n_lines * n_samples, 3) by bilinear interpolation of
    undistorted focal-plane vectors given every ``step`` sub-samples (``lattice`` (La, Lb, 3))."""
    out = np.empty((n_lines * n_samples, 3))
    la, lb = lattice.shape[0], lattice.shape[1]
    for row in range(n_lines):
        j = min(row // step, la - 2)
        v = (row - j * step) / step
        for col in range(n_samples):
            i = min(col // step, lb - 2)
            u = (col - i * step) / step
            w00 = (1 - u) * (1 - v)
            w01 = u * (1 - v)
            w10 = (1 - u) * v
            w11 = u * v
            cx = w00 * lattice[j, i, 0] + w01 * lattice[j, i + 1, 0] + w10 * lattice[j + 1, i, 0] + w11 * lattice[j + 1, i + 1, 0]
            cy = w00 * lattice[j, i, 1] + w01 * lattice[j, i + 1, 1] + w10 * lattice[j + 1, i, 1] + w11 * lattice[j + 1, i + 1, 1]
            cz = w00 * lattice[j, i, 2] + w01 * lattice[j, i + 1, 2] + w10 * lattice[j + 1, i, 2] + w11 * lattice[j + 1, i + 1, 2]
            nrm = np.sqrt(cx * cx + cy * cy + cz * cz)
            cx, cy, cz = cx / nrm, cy / nrm, cz / nrm
            k = row * n_samples + col
            # Body-fixed direction R^T v.
            out[k, 0] = rot[0, 0] * cx + rot[1, 0] * cy + rot[2, 0] * cz
            out[k, 1] = rot[0, 1] * cx + rot[1, 1] * cy + rot[2, 1] * cz
            out[k, 2] = rot[0, 2] * cx + rot[1, 2] * cy + rot[2, 2] * cz
    return out


def subsample_directions(
    camera: FramingCamera, rotation: NDArray[np.float64], supersample: int, step: int = 8
) -> NDArray[np.float64]:
    """Body-fixed unit directions (lines*ss * samples*ss, 3) of all sub-pixel rays, row-major.

    The camera model (with its distortion) is evaluated exactly on a lattice every
    ``step`` sub-samples; in between, the undistorted focal-plane vectors are
    interpolated bilinearly (exact for a pinhole; below 1e-3 pixel for the MDIS
    NAC polynomial).
    """
    n_l, n_s = camera.lines * supersample, camera.samples * supersample
    rows = np.arange(0, n_l - 1 + step, step)
    cols = np.arange(0, n_s - 1 + step, step)
    off = 0.5 / supersample - 0.5
    ss, ll = np.meshgrid(cols / supersample + off, rows / supersample + off)
    p = camera.pixel_size_mm
    xd = (ss - camera.boresight_sample) * p
    yd = (ll - camera.boresight_line) * p
    x, y = camera.undistort(xd, yd)
    lattice = np.stack([x, y, np.full_like(x, camera.focal_length_mm)], -1)
    return _interp_directions(np.ascontiguousarray(lattice), step, n_l, n_s, np.ascontiguousarray(rotation))


BLOCK = 16


def block_maxima(heights: NDArray[np.float64], block: int) -> NDArray[np.float64]:
    """Highest node of each ``block`` x ``block`` cell, dilated by one block (nby, nbx).

    Node (j, i) is in block (j // block, i // block); a point of block (bj, bi) is
    within one block of every node counted in its entry.
    """
    ny, nx = heights.shape
    nby, nbx = -(-ny // block), -(-nx // block)
    pad = np.full((nby * block, nbx * block), -np.inf)
    pad[:ny, :nx] = heights
    bm = pad.reshape(nby, block, nbx, block).max(axis=(1, 3))
    out = bm.copy()
    p = np.pad(bm, 1, constant_values=-np.inf)
    for dj in (0, 1, 2):
        for di in (0, 1, 2):
            out = np.maximum(out, p[dj:dj + nby, di:di + nbx])
    return np.ascontiguousarray(out)


def subsample_pixels(samples: int, lines: int, supersample: int) -> NDArray[np.float64]:
    """Sub-pixel positions (lines*ss, samples*ss, 2) (sample, line), 0-based pixel centres."""
    off = (np.arange(supersample) + 0.5) / supersample - 0.5
    s = (np.arange(samples)[:, None] + off[None, :]).ravel()
    l = (np.arange(lines)[:, None] + off[None, :]).ravel()
    ss, ll = np.meshgrid(s, l)
    return np.stack([ss, ll], -1)


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


def _render_supersampled(
    surface: SurfaceModel,
    camera: FramingCamera,
    position: ArrayLike,
    rotation: ArrayLike,
    sun_position: ArrayLike,
    settings: RenderSettings,
) -> NDArray[np.float64]:
    c = np.asarray(position, dtype=np.float64)
    r = np.asarray(rotation, dtype=np.float64)
    sun = np.asarray(sun_position, dtype=np.float64)
    radius = float(surface.radius_m)
    grid = footprint_grid(camera, c, r, sun, radius, settings)
    dirs = grid.directions()
    heights = surface.height_unit(dirs, grid.spacing_m)
    alb = surface.albedo_unit(dirs, grid.spacing_m)
    points = dirs * (radius + heights)[..., None]
    normals = grid_normals(points)
    lit = shadow_grid(points, grid, sun) if settings.shadows else np.ones(heights.shape)
    gy, gx = np.gradient(heights, grid.spacing_m)
    slope_max = float(np.sqrt(gx * gx + gy * gy).max())
    ss = settings.supersample
    d = subsample_directions(camera, r, ss)
    frame = np.stack([grid.centre, grid.east, grid.north])
    out = _cast_and_shade(
        c, np.ascontiguousarray(d), frame, radius, grid.x0, grid.y0, grid.spacing_m,
        np.ascontiguousarray(heights), np.ascontiguousarray(np.stack([normals[0], normals[1], normals[2], lit, alb], -1)),
        block_maxima(heights, BLOCK), BLOCK,
        float(heights.min()) - 1.0, float(heights.max()) + 1.0, slope_max, sun,
        settings.lambert_weight, np.radians(settings.phase_scale_deg),
    )
    return out.reshape(camera.lines * ss, camera.samples * ss)


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
    ss = settings.supersample
    if settings.psf_sigma_px > 0:
        img = gaussian_filter(img, settings.psf_sigma_px * ss, mode="nearest")
    img = img.reshape(camera.lines, ss, camera.samples, ss).mean(axis=(1, 3))
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
