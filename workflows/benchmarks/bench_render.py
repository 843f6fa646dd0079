"""Rendering speed: the compiled renderer vs a straightforward numpy ray-cast, in one run.

Both render the same 512^2 image (MDIS-WAC, ~1.5 km/pixel, incidence 70 deg,
emission 25 deg) of the demo surface from the same local height grid; the
numpy reference marches all rays at once in half-cell steps, then bisects, and
casts a shadow ray from every hit point toward the sun in half-cell steps (the
approach the issue measured at 4 s per image and 1 sample/pixel).
Reported: seconds per image at 1x1 and 2x2 sub-samples — wall and CPU time on
one thread (``render_image`` in this process; numba kernels are not
parallelised), wall time per image with two images rendered concurrently (the
kernels release the GIL) —, the numpy reference's wall time, the mean
|difference| between the two renderers' I/F images (they agree up to the shadow
test and interpolation details: triangles vs bilinear patches), and where the
time of one 2x2 image goes.

Run: ``flock /tmp/mercury_bench.lock env NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1 .venv/bin/python workflows/benchmarks/bench_render.py``
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import numpy as np

from mercury_dem.geometry.body import DATUM_RADIUS_M, latlon_to_unit
from mercury_dem.geometry.camera import mdis_wac
from mercury_dem.geometry.pose import look_at_rotation, pixel_rays, rotation_from_angles
from mercury_dem.synth import render as rd
from mercury_dem.synth.presets import get_preset
from mercury_dem.synth.terrain import Surface


def geometry(samples: int, scale_m: float = 1500.0):
    cam = mdis_wac(samples)
    lat, lon = 12.0, 35.0
    up = latlon_to_unit(lat, lon)
    east = np.array([-np.sin(np.radians(lon)), np.cos(np.radians(lon)), 0.0])
    north = np.cross(up, east)
    e, i = np.radians(25.0), np.radians(70.0)
    c = up * DATUM_RADIUS_M + (np.cos(e) * up + np.sin(e) * north) * scale_m / cam.ifov_rad
    r = rotation_from_angles([0, 0, 0.4]) @ look_at_rotation(c, up * DATUM_RADIUS_M)
    sun = up * DATUM_RADIUS_M + 5.8e10 * (np.cos(i) * up + np.sin(i) * east)
    return cam, c, r, sun


def numpy_reference(surface, cam, c, r, sun, supersample: int, settings: rd.RenderSettings) -> np.ndarray:
    """Straightforward numpy ray-cast with shadow rays (fixed steps), on the same local grid."""
    grid = rd.footprint_grid(cam, c, r, sun, surface.radius_m, settings)
    dirs = grid.directions()
    h = surface.height_unit(dirs, grid.spacing_m)
    alb = surface.albedo_unit(dirs, grid.spacing_m)
    pts = dirs * (surface.radius_m + h)[..., None]
    normals = rd.grid_normals(pts)
    g = grid.spacing_m
    rad = surface.radius_m

    def bilinear(a, fx, fy):
        i = np.clip(np.floor(fx).astype(int), 0, a.shape[1] - 2)
        j = np.clip(np.floor(fy).astype(int), 0, a.shape[0] - 2)
        u = np.clip(fx - i, 0, 1)
        v = np.clip(fy - j, 0, 1)
        return (1 - v) * ((1 - u) * a[j, i] + u * a[j, i + 1]) + v * ((1 - u) * a[j + 1, i] + u * a[j + 1, i + 1])

    def gap(p):
        pc = p @ grid.centre
        fx = (rad * (p @ grid.east) / pc - grid.x0) / g
        fy = (rad * (p @ grid.north) / pc - grid.y0) / g
        return np.linalg.norm(p, axis=-1) - rad - bilinear(h, fx, fy), fx, fy

    pix = rd.subsample_pixels(cam.samples, cam.lines, supersample).reshape(-1, 2)
    o, d = pixel_rays(cam, c, r, pix)
    b = d @ c
    top = rad + h.max() + 1
    t = -b - np.sqrt(np.maximum(b * b - (c @ c - top * top), 0))
    active = np.ones(len(d), bool)
    t_prev = t.copy()
    hit = np.zeros(len(d), bool)
    for _ in range(20000):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        f, _, _ = gap(c + t[idx, None] * d[idx])
        below = f <= 0
        hit[idx[below]] = True
        active[idx[below]] = False
        go = idx[~below]
        t_prev[go] = t[go]
        t[go] += g * 0.5
        active[go[t[go] > -b[go] + 1e7]] = False
    lo, hi = t_prev.copy(), t.copy()
    for _ in range(12):
        mid = 0.5 * (lo + hi)
        f, _, _ = gap(c + mid[:, None] * d)
        lo = np.where(f > 0, mid, lo)
        hi = np.where(f > 0, hi, mid)
    p = c + hi[:, None] * d
    _, fx, fy = gap(p)
    s_dir = sun - p
    s_dir /= np.linalg.norm(s_dir, axis=-1, keepdims=True)
    # Shadow rays: march toward the sun until above the grid's highest point or out of the grid.
    lit = np.ones(len(d), bool)
    q = p + s_dir * 1.0
    alive = hit.copy()
    for _ in range(int(settings.max_shadow_m / (0.5 * g)) + 2):
        idx = np.flatnonzero(alive)
        if idx.size == 0:
            break
        q[idx] += s_dir[idx] * 0.5 * g
        f, qx, qy = gap(q[idx])
        under = f < 0
        lit[idx[under]] = False
        out = (np.linalg.norm(q[idx], axis=-1) > top) | (qx < 0) | (qy < 0) | (qx > grid.nx - 1) | (qy > grid.ny - 1)
        alive[idx[under | out]] = False
    n = np.stack([bilinear(normals[k], fx, fy) for k in range(3)], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    mu0 = np.sum(n * s_dir, -1)
    mu = -np.sum(n * d, -1)
    phase = np.arccos(np.clip(-np.sum(s_dir * d, -1), -1, 1))
    with np.errstate(invalid="ignore", divide="ignore"):
        ls = 2 * mu0 / (mu0 + mu)
    refl = (1 - settings.lambert_weight) * ls + settings.lambert_weight * mu0
    val = bilinear(alb, fx, fy) * np.exp(-phase / np.radians(settings.phase_scale_deg)) * refl * lit
    val = np.where(hit & (mu0 > 0) & (mu > 0), val, 0.0)
    ss = supersample
    return val.reshape(cam.lines, ss, cam.samples, ss).mean(axis=(1, 3))


def stages(surface, cam, c, r, sun, st: rd.RenderSettings, repeats: int) -> dict[str, float]:
    """CPU seconds of each stage of render_image (best of ``repeats``)."""
    from mercury_dem.synth import raster as rs

    best: dict[str, float] = {}
    for _ in range(repeats):
        t = time.process_time()
        times = {}

        def lap(name: str) -> None:
            nonlocal t
            now = time.process_time()
            times[name] = now - t
            t = now

        grid = rd.footprint_grid(cam, c, r, sun, surface.radius_m, st)
        dirs = grid.directions()
        lap("footprint + grid directions")
        h, alb = rd.sample_surface(surface, grid, dirs)
        lap("surface on the grid (craters, rays, noise)")
        pts = dirs * (surface.radius_m + h)[..., None]
        lit = rd.shadow_grid(pts, grid, sun)
        lap("shadow sweep")
        s = rd.sun_direction(grid, sun)
        fields = rs.node_fields(pts, lit, alb, c, s, float(np.radians(st.phase_scale_deg)))
        lap("node normals + photometric fields")
        ss = st.supersample
        uv, depth = rs.project_nodes(pts, c, np.ascontiguousarray(r), cam.focal_length_mm, cam.pixel_size_mm,
                                     cam.boresight_sample, cam.boresight_line, np.asarray(cam.distortion_x, float),
                                     np.asarray(cam.distortion_y, float), ss)
        tri, w1, w2 = rs.rasterize(uv, depth, cam.samples * ss, cam.lines * ss)
        lap("projection + rasterization (z-buffer)")
        img = rs.shade(tri, w1, w2, fields, s, st.lambert_weight)
        lap("shading")
        img = rs.psf_box(img, st.psf_sigma_px, ss)
        rd.expose(img, np.random.default_rng(0), st)
        lap("PSF + box + exposure/noise/quantisation")
        for k, v in times.items():
            best[k] = min(best.get(k, np.inf), v)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=512)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--skip-numpy-2x2", action="store_true", help="skip the slowest reference run")
    args = ap.parse_args()
    surface = Surface(replace(get_preset("demo").surface, seed=42))
    cam, c, r, sun = geometry(args.samples)
    rows = []
    for ss in (1, 2):
        st = replace(get_preset("demo").render, supersample=ss)
        rd.render_image(surface, cam, c, r, sun, np.random.default_rng(0), st)  # compile / warm
        wall, cpu = [], []
        for k in range(args.repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            rd.render_image(surface, cam, c, r, sun, np.random.default_rng(k), st)
            wall.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        with ThreadPoolExecutor(2) as pool:
            t0 = time.perf_counter()
            list(pool.map(lambda k: rd.render_image(surface, cam, c, r, sun, np.random.default_rng(k), st),
                          range(2 * args.repeats)))
            two = (time.perf_counter() - t0) / (2 * args.repeats)
        ours = rd.render_reflectance(surface, cam, c, r, sun, st)
        if ss == 2 and args.skip_numpy_2x2:
            ref_t, diff = float("nan"), float("nan")
        else:
            t0 = time.perf_counter()
            ref = numpy_reference(surface, cam, c, r, sun, ss, st)
            ref_t = time.perf_counter() - t0
            diff = float(np.mean(np.abs(ours - ref)) / np.mean(ref))
        rows.append((ss, min(wall), min(cpu), two, ref_t, diff))
    print(f"image {args.samples}x{args.samples}, MDIS-WAC ~1.5 km/px, i=70, e=25; seconds per image (best of {args.repeats})")
    print("subsamples | ours 1 thread wall | ours 1 thread CPU | ours 2 threads (per image) | numpy reference | ref/ours | mean|dI/F|/I/F")
    for ss, one, cpu, two, ref_t, diff in rows:
        print(f"{ss}x{ss}        | {one:18.3f} | {cpu:17.3f} | {two:26.3f} | {ref_t:15.2f} | {ref_t / one:8.1f} | {diff:.4f}")
    st = replace(get_preset("demo").render, supersample=2)
    parts = stages(surface, cam, c, r, sun, st, args.repeats)
    print("2x2 image, CPU seconds by stage (best of repeats):")
    for k, v in parts.items():
        print(f"  {k:45s} {v:.3f}")
    print(f"  {'sum':45s} {sum(parts.values()):.3f}")


if __name__ == "__main__":
    main()
