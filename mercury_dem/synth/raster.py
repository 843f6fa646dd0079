"""Compiled kernels of the renderer: the local height grid drawn as a triangle mesh.

The renderer (:mod:`mercury_dem.synth.render`) samples the truth surface once on
a local grid; these kernels turn that grid into an image:

* :func:`node_fields` — per grid node: the outward normal (central differences),
  the lit flag of the shadow sweep, the albedo times the phase function, and the
  unit view direction from the camera;
* :func:`project_nodes` — every node through the camera model (rotation,
  perspective, the MDIS distortion polynomial) to sub-sample coordinates, with
  its depth along the boresight;
* :func:`rasterize` — each grid cell as two triangles, z-buffered onto the
  sub-sample raster (nearest surface wins: hidden terrain is hidden exactly,
  whatever the slope or the view angle);
* :func:`shade` — the Lommel–Seeliger/Lambert mix at every covered sub-sample
  from the barycentric interpolation of the node fields;
* :func:`psf_box` — Gaussian point-spread blur and box average of the
  sub-samples, in one separable pass per axis.

Why a rasterizer and not a ray march: casting 10^6 rays onto the height grid
(block-maximum skipping, Lipschitz steps, regula falsi) spent ~0.3 s per 512^2
image at 2 x 2 sub-samples in latency-bound per-ray loops; drawing the 8 x 10^5
triangles of the grid takes ~0.03 s and gives the same picture (triangles
instead of bilinear patches between nodes spaced one ground pixel apart: mean
|dI/F| 0.4 % per pixel, see docs/benchmarks/synth.md). Nodes are spaced about
one ground pixel apart, so each triangle covers about two sub-samples and the
interpolation of the fields over a triangle is as fine as the grid itself.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray


@numba.njit(cache=True, nogil=True, fastmath=True)
def grid_directions(
    centre: NDArray[np.float64], east: NDArray[np.float64], north: NDArray[np.float64], radius: float,
    x0: float, y0: float, spacing: float, nx: int, ny: int,
) -> NDArray[np.float64]:
    """Unit vectors (ny, nx, 3) of the nodes of a gnomonic grid (see ``LocalGrid``)."""
    out = np.empty((ny, nx, 3))
    for j in range(ny):
        y = y0 + spacing * j
        bx = radius * centre[0] + y * north[0]
        by = radius * centre[1] + y * north[1]
        bz = radius * centre[2] + y * north[2]
        for i in range(nx):
            x = x0 + spacing * i
            vx = bx + x * east[0]
            vy = by + x * east[1]
            vz = bz + x * east[2]
            n = 1.0 / np.sqrt(vx * vx + vy * vy + vz * vz)
            out[j, i, 0] = vx * n
            out[j, i, 1] = vy * n
            out[j, i, 2] = vz * n
    return out


@numba.njit(cache=True, nogil=True, fastmath=True, inline="always")
def grid_normal(points: NDArray[np.float64], j0: int, j: int, j1: int, i0: int, i: int,
                i1: int) -> tuple[float, float, float]:
    """Outward unit normal at node (j, i) of a grid of points (ny, nx, 3) (x = east, y = north):
    the cross product of the central differences along i (i0 -> i1) and along j (j0 -> j1).
    """
    ax = points[j, i1, 0] - points[j, i0, 0]
    ay = points[j, i1, 1] - points[j, i0, 1]
    az = points[j, i1, 2] - points[j, i0, 2]
    bx = points[j1, i, 0] - points[j0, i, 0]
    by = points[j1, i, 1] - points[j0, i, 1]
    bz = points[j1, i, 2] - points[j0, i, 2]
    cx = ay * bz - az * by
    cy = az * bx - ax * bz
    cz = ax * by - ay * bx
    n = 1.0 / np.sqrt(cx * cx + cy * cy + cz * cz)
    return cx * n, cy * n, cz * n


@numba.njit(cache=True, nogil=True, fastmath=True)
def node_fields(
    points: NDArray[np.float64], lit: NDArray[np.float64], albedo: NDArray[np.float64],
    position: NDArray[np.float64], sun_dir: NDArray[np.float64], phase_scale_rad: float,
) -> NDArray[np.float64]:
    """Per-node shading inputs (ny, nx, 8): normal (3), lit, albedo x phase function, view direction (3).

    points : (ny, nx, 3) body-fixed node positions, m (x along the grid's east, y its north)
    lit : (ny, nx) 1 lit, 0 in shadow
    albedo : (ny, nx) normal albedo
    position : (3,) camera position, m; sun_dir : (3,) unit vector toward the sun (parallel rays)
    phase_scale_rad : e-folding angle of the exponential phase function
    """
    ny, nx = lit.shape
    out = np.empty((ny, nx, 8))
    for j in range(ny):
        j0, j1 = max(j - 1, 0), min(j + 1, ny - 1)
        for i in range(nx):
            i0, i1 = max(i - 1, 0), min(i + 1, nx - 1)
            cx, cy, cz = grid_normal(points, j0, j, j1, i0, i, i1)
            out[j, i, 0] = cx
            out[j, i, 1] = cy
            out[j, i, 2] = cz
            out[j, i, 3] = lit[j, i]
            dx = points[j, i, 0] - position[0]
            dy = points[j, i, 1] - position[1]
            dz = points[j, i, 2] - position[2]
            d = 1.0 / np.sqrt(dx * dx + dy * dy + dz * dz)
            dx, dy, dz = dx * d, dy * d, dz * d
            cos_phase = -(sun_dir[0] * dx + sun_dir[1] * dy + sun_dir[2] * dz)
            phase = np.arccos(min(1.0, max(-1.0, cos_phase)))
            out[j, i, 4] = albedo[j, i] * np.exp(-phase / phase_scale_rad)
            out[j, i, 5] = dx
            out[j, i, 6] = dy
            out[j, i, 7] = dz
    return out


@numba.njit(cache=True, nogil=True, fastmath=True)
def project_nodes(
    points: NDArray[np.float64], position: NDArray[np.float64], rot: NDArray[np.float64],
    focal_mm: float, pixel_mm: float, boresight_sample: float, boresight_line: float,
    dist_x: NDArray[np.float64], dist_y: NDArray[np.float64], supersample: int,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Sub-sample coordinates (ny, nx, 2) and depth (ny, nx) of body-fixed points (ny, nx, 3).

    The camera model of :meth:`FramingCamera.camera_to_pixel` (perspective, then the
    10-term transverse distortion polynomial if ``dist_x`` has 10 terms); pixel
    (sample, line) maps to sub-sample ``(p + 0.5) * supersample - 0.5``, so integer
    sub-sample coordinates are sub-sample centres. Depth is the camera-frame Z (m);
    points behind the camera get NaN coordinates.
    """
    ny, nx = points.shape[0], points.shape[1]
    uv = np.empty((ny, nx, 2))
    z = np.empty((ny, nx))
    distorted = dist_x.shape[0] == 10
    for j in range(ny):
        for i in range(nx):
            px = points[j, i, 0] - position[0]
            py = points[j, i, 1] - position[1]
            pz = points[j, i, 2] - position[2]
            vx = rot[0, 0] * px + rot[0, 1] * py + rot[0, 2] * pz
            vy = rot[1, 0] * px + rot[1, 1] * py + rot[1, 2] * pz
            vz = rot[2, 0] * px + rot[2, 1] * py + rot[2, 2] * pz
            z[j, i] = vz
            if vz <= 0.0:
                uv[j, i, 0] = np.nan
                uv[j, i, 1] = np.nan
                continue
            x = focal_mm * vx / vz
            y = focal_mm * vy / vz
            if distorted:
                xx, xy, yy = x * x, x * y, y * y
                xd = (dist_x[0] + dist_x[1] * x + dist_x[2] * y + dist_x[3] * xx + dist_x[4] * xy + dist_x[5] * yy
                      + dist_x[6] * xx * x + dist_x[7] * xx * y + dist_x[8] * x * yy + dist_x[9] * yy * y)
                yd = (dist_y[0] + dist_y[1] * x + dist_y[2] * y + dist_y[3] * xx + dist_y[4] * xy + dist_y[5] * yy
                      + dist_y[6] * xx * x + dist_y[7] * xx * y + dist_y[8] * x * yy + dist_y[9] * yy * y)
                x, y = xd, yd
            uv[j, i, 0] = (boresight_sample + x / pixel_mm + 0.5) * supersample - 0.5
            uv[j, i, 1] = (boresight_line + y / pixel_mm + 0.5) * supersample - 0.5
    return uv, z


@numba.njit(cache=True, nogil=True)
def rasterize(
    uv: NDArray[np.float64], z: NDArray[np.float64], n_u: int, n_v: int
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """Z-buffer the two triangles of every grid cell onto an (n_v, n_u) sub-sample raster.

    Cell (j, i) with corners a = (j, i), b = (j, i+1), c = (j+1, i), d = (j+1, i+1)
    is split into triangles 0 = (a, b, d) and 1 = (a, d, c). A sub-sample is in a
    triangle when its three barycentric weights are >= -1e-9 (shared edges are
    covered twice, never missed; the z-test keeps one). Returns per sub-sample the
    triangle id ``2 * (j * nx + i) + k`` (-1: no surface) and the weights of its
    second and third vertices (the first one's is ``1 - w1 - w2``).
    """
    ny, nx = z.shape
    zbuf = np.full((n_v, n_u), np.inf)
    tri_id = np.full((n_v, n_u), -1, np.int64)
    w1b = np.zeros((n_v, n_u))
    w2b = np.zeros((n_v, n_u))
    for j in range(ny - 1):
        for i in range(nx - 1):
            u0, v0, z0 = uv[j, i, 0], uv[j, i, 1], z[j, i]
            for k in range(2):
                j1, i1 = (j, i + 1) if k == 0 else (j + 1, i + 1)
                j2, i2 = (j + 1, i + 1) if k == 0 else (j + 1, i)
                u1, v1 = uv[j1, i1, 0], uv[j1, i1, 1]
                u2, v2 = uv[j2, i2, 0], uv[j2, i2, 1]
                umin = min(u0, min(u1, u2))
                umax = max(u0, max(u1, u2))
                vmin = min(v0, min(v1, v2))
                vmax = max(v0, max(v1, v2))
                # Off the raster, or a vertex behind the camera (NaN fails every comparison).
                if not (umax >= 0.0 and vmax >= 0.0 and umin <= n_u - 1 and vmin <= n_v - 1):
                    continue
                area = (u1 - u0) * (v2 - v0) - (u2 - u0) * (v1 - v0)
                if area == 0.0:
                    continue
                inv = 1.0 / area
                z1, z2 = z[j1, i1], z[j2, i2]
                a0 = max(int(np.ceil(umin)), 0)
                a1 = min(int(np.floor(umax)), n_u - 1)
                b0 = max(int(np.ceil(vmin)), 0)
                b1 = min(int(np.floor(vmax)), n_v - 1)
                tid = 2 * (j * nx + i) + k
                for vv in range(b0, b1 + 1):
                    for uu in range(a0, a1 + 1):
                        w1 = ((uu - u0) * (v2 - v0) - (u2 - u0) * (vv - v0)) * inv
                        w2 = ((u1 - u0) * (vv - v0) - (uu - u0) * (v1 - v0)) * inv
                        w0 = 1.0 - w1 - w2
                        if w0 < -1e-9 or w1 < -1e-9 or w2 < -1e-9:
                            continue
                        depth = w0 * z0 + w1 * z1 + w2 * z2
                        if depth < zbuf[vv, uu]:
                            zbuf[vv, uu] = depth
                            tri_id[vv, uu] = tid
                            w1b[vv, uu] = w1
                            w2b[vv, uu] = w2
    return tri_id, w1b, w2b


@numba.njit(cache=True, nogil=True, fastmath=True)
def shade(
    tri_id: NDArray[np.int64], w1b: NDArray[np.float64], w2b: NDArray[np.float64], fields: NDArray[np.float64],
    sun_dir: NDArray[np.float64], lambert_weight: float,
) -> NDArray[np.float64]:
    """I/F (n_v, n_u) of the rasterized sub-samples (0 where no surface, in shadow or facing away).

    I/F = albedo * phase function * [(1 - w) * 2 mu0 / (mu0 + mu) + w * mu0] * lit,
    the fields (:func:`node_fields`) interpolated with the barycentric weights.
    """
    n_v, n_u = tri_id.shape
    nx = fields.shape[1]
    out = np.zeros((n_v, n_u))
    sx, sy, sz = sun_dir[0], sun_dir[1], sun_dir[2]
    for vv in range(n_v):
        for uu in range(n_u):
            tid = tri_id[vv, uu]
            if tid < 0:
                continue
            k = tid % 2
            q = tid // 2
            j, i = q // nx, q % nx
            j1, i1 = (j, i + 1) if k == 0 else (j + 1, i + 1)
            j2, i2 = (j + 1, i + 1) if k == 0 else (j + 1, i)
            w1, w2 = w1b[vv, uu], w2b[vv, uu]
            w0 = 1.0 - w1 - w2
            lit = w0 * fields[j, i, 3] + w1 * fields[j1, i1, 3] + w2 * fields[j2, i2, 3]
            if lit <= 0.0:
                continue
            nxv = w0 * fields[j, i, 0] + w1 * fields[j1, i1, 0] + w2 * fields[j2, i2, 0]
            nyv = w0 * fields[j, i, 1] + w1 * fields[j1, i1, 1] + w2 * fields[j2, i2, 1]
            nzv = w0 * fields[j, i, 2] + w1 * fields[j1, i1, 2] + w2 * fields[j2, i2, 2]
            dx = w0 * fields[j, i, 5] + w1 * fields[j1, i1, 5] + w2 * fields[j2, i2, 5]
            dy = w0 * fields[j, i, 6] + w1 * fields[j1, i1, 6] + w2 * fields[j2, i2, 6]
            dz = w0 * fields[j, i, 7] + w1 * fields[j1, i1, 7] + w2 * fields[j2, i2, 7]
            nn = 1.0 / np.sqrt(nxv * nxv + nyv * nyv + nzv * nzv)
            mu0 = (nxv * sx + nyv * sy + nzv * sz) * nn
            mu = -(nxv * dx + nyv * dy + nzv * dz) * nn
            if mu0 <= 0.0 or mu <= 0.0:
                continue
            alb = w0 * fields[j, i, 4] + w1 * fields[j1, i1, 4] + w2 * fields[j2, i2, 4]
            refl = (1.0 - lambert_weight) * 2.0 * mu0 / (mu0 + mu) + lambert_weight * mu0
            out[vv, uu] = alb * refl * lit
    return out


def gaussian_weights(sigma: float, truncate: float = 4.0) -> NDArray[np.float64]:
    """Normalised 1-D Gaussian kernel of radius ``int(truncate * sigma + 0.5)`` (scipy.ndimage's)."""
    radius = int(truncate * sigma + 0.5)
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    w = np.exp(-0.5 * (x / sigma) ** 2)
    return w / w.sum()


@numba.njit(cache=True, nogil=True, fastmath=True)
def _blur_decimate_rows(img: NDArray[np.float64], taps: NDArray[np.float64], first: int, ss: int) -> NDArray[np.float64]:
    """out[r, p] = sum_m taps[m] * img[r, clamp(p * ss + first + m)] (edge values repeated)."""
    n_r, n_c = img.shape
    n_p = n_c // ss
    out = np.empty((n_r, n_p))
    nt = taps.shape[0]
    for r in range(n_r):
        for p in range(n_p):
            s = 0.0
            base = p * ss + first
            for m in range(nt):
                c = min(max(base + m, 0), n_c - 1)
                s += taps[m] * img[r, c]
            out[r, p] = s
    return out


def psf_box(img: NDArray[np.float64], sigma_px: float, supersample: int) -> NDArray[np.float64]:
    """Gaussian blur (sigma in image pixels, edges repeated) then ss x ss box average, (n_v, n_u) -> pixels.

    Equal (to rounding) to ``scipy.ndimage.gaussian_filter(img, sigma_px * ss, mode="nearest")``
    followed by the box average; written here because the blur and the decimation
    fold into one kernel per axis that is evaluated only at the output pixels
    (about 4x less work than blurring every sub-sample).
    """
    ss = supersample
    if sigma_px > 0:
        w = gaussian_weights(sigma_px * ss)
    else:
        w = np.ones(1)
    radius = (w.size - 1) // 2
    taps = np.convolve(w, np.full(ss, 1.0 / ss))  # blur then box, per axis
    rows = _blur_decimate_rows(np.ascontiguousarray(img), taps, -radius, ss)
    return np.ascontiguousarray(_blur_decimate_rows(np.ascontiguousarray(rows.T), taps, -radius, ss).T)
