"""Inputs several benchmarks share, built one way: scenario builders and the reference runs beside them.

* synthetic networks: :func:`synthetic_network_store` (``mercury-dem synth-network``, N measures, made once),
  :func:`clean_store` (the same without gross outliers), :func:`problem_from_store` (a small store as one
  ``AdjustmentProblem``); :func:`least_squares_anchor` (scipy ``least_squares`` on ``bundle_adjust``'s cost);
* a tiny mission: :func:`tiny_mission` (``mercury-dem synth --preset tiny``, made once);
* a BAL problem: :func:`bal_file` (a path, or a name under ``../shared/data/bal``);
* a gridding cloud and gdal_grid: :func:`make_points`, :func:`write_point_inputs`, :func:`write_cloud_files`,
  :func:`run_gdal`, :func:`median_and_min`;
* a registration scene: :class:`Surface`, :func:`make_dem`, :func:`make_shots` (a global DEM and pole-to-pole
  altimetry profiles on Mercury's datum, ``R``);
* a mission's a-priori overlaps: :func:`a_priori_overlaps`.

Mercury here is the scene of these benchmarks (as in ``mercury_dem.validate``'s scenes), not a default of the
library.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from harness.measure import Measurement, measure
from mercury_dem.geometry.body import DATUM_RADIUS_M, latlon_to_xyz, xyz_to_latlon


def tiny_mission(directory: str | Path, seed: int = 7, preset: str = "tiny") -> Path:
    """A synthetic mission (``mercury-dem synth DIR --preset tiny --seed S``) under ``directory``, made once."""
    mission = Path(directory) / f"{preset}_s{seed}"
    if not (mission / "mission.json").exists():  # the generator writes mission.json last
        subprocess.run([sys.executable, "-m", "mercury_dem.cli", "synth", str(mission), "--preset", preset,
                        "--seed", str(seed), "--progress", "none", "--overwrite"], check=True, capture_output=True)
    return mission


#: The BAL problems of the development machine (``../shared/data/bal`` beside the checkout), as the tests find them.
BAL_DIR = Path(__file__).resolve().parents[4] / "shared" / "data" / "bal"


def bal_file(name: str | Path) -> Path:
    """A BAL problem file: ``name`` as a path, else ``BAL_DIR / name`` (e.g. ``problem-49-7776-pre.txt``)."""
    for path in (Path(name), BAL_DIR / str(name)):
        if path.is_file():
            return path
    raise FileNotFoundError(f"no BAL file {name} (nor {BAL_DIR / str(name)}); the problems are at "
                            "https://grail.cs.washington.edu/projects/bal/")


def synthetic_network_store(directory: str | Path, measures: float, seed: int, *extra: str) -> Path:
    """A ``mercury-dem synth-network`` store of about ``measures`` measures under ``directory``, made once."""
    tag = "_".join(a.lstrip("-") for a in extra)
    store = Path(directory) / (f"net_{measures:.0e}_s{seed}" + (f"_{tag}" if tag else ""))
    if not store.exists():
        subprocess.run([sys.executable, "-m", "mercury_dem.cli", "synth-network", str(store), "--measures",
                        str(int(measures)), "--seed", str(seed), "--progress", "none", *extra], check=True,
                       capture_output=True)
    return store


# ---- from bench_blocked_anchor.py ------------------------------------------------------------


def least_squares_anchor(p: Any, cfg: Any) -> dict[str, Any]:
    """``scipy.optimize.least_squares`` on ``bundle_adjust``'s cost (no robust loss): seconds, cost, nfev, pointing."""
    import scipy.sparse as sp
    from scipy.optimize import least_squares

    from mercury_dem.adjust.bundle import make_model
    from mercury_dem.adjust.framing import FramingState

    model = make_model(p, cfg)
    ni, npt, m = p.n_images, p.n_points, p.n_measures
    zeros = np.zeros((ni, 3))

    def fun(x: np.ndarray) -> np.ndarray:
        st = FramingState(x[: 3 * ni].reshape(ni, 3), zeros, x[3 * ni:].reshape(npt, 3))
        parts = [model.residuals(st).ravel(), model.camera_prior(st)[0].ravel()]
        pp = model.point_prior(st)
        if pp is not None:
            parts.append(pp[0].ravel())
        return np.concatenate(parts)

    rows, cols = [], []
    mi, mp = p.measure_image, p.measure_point
    for k in range(2):
        for s in range(3):
            rows += [2 * np.arange(m) + k, 2 * np.arange(m) + k]
            cols += [3 * mi + s, 3 * ni + 3 * mp + s]
    for s in range(3):
        for s2 in range(3):
            rows.append(2 * m + 3 * np.arange(ni) + s)
            cols.append(3 * np.arange(ni) + s2)
    pp0 = model.point_prior(model.initial_state())
    npp = 0 if pp0 is None else pp0[0].shape[1]
    for s in range(npp):
        for s2 in range(3):
            rows.append(2 * m + 3 * ni + npp * np.arange(npt) + s)
            cols.append(3 * ni + 3 * np.arange(npt) + s2)
    r, c = np.concatenate(rows), np.concatenate(cols)
    nres = 2 * m + 3 * ni + npp * npt
    sparsity = sp.coo_matrix((np.ones(len(r)), (r, c)), shape=(nres, 3 * ni + 3 * npt)).tocsr()
    sparsity.data[:] = 1
    x0 = np.concatenate([np.zeros(3 * ni), p.points.ravel()])
    t = time.perf_counter()
    ls = least_squares(fun, x0, jac_sparsity=sparsity, x_scale="jac", ftol=1e-4, method="trf")
    return {"seconds": time.perf_counter() - t, "cost": float(ls.cost), "nfev": int(ls.nfev),
            "omega": ls.x[: 3 * ni].reshape(ni, 3)}


def clean_store(directory: str | Path, measures: float, seed: int) -> Path:
    """A ``synth-network`` store without gross outliers under ``directory`` (made once, then reused)."""
    store = Path(directory) / f"clean_{measures:.0e}_s{seed}"
    if not store.exists():
        subprocess.run([sys.executable, "-m", "mercury_dem.cli", "synth-network", str(store), "--measures",
                        str(int(measures)), "--seed", str(seed), "--outlier-fraction", "0", "--progress",
                        "none"], check=True, capture_output=True)
    return store


def problem_from_store(store: Path, pointing_sigma_urad: float = 450.0) -> Any:
    """The whole stored network as one AdjustmentProblem (small stores only).

    ``pointing_sigma_urad``: its a-priori pointing sigma (the stores' injected one,
    ``SyntheticSpec.pointing_error_rad`` = 450 µrad).
    """
    from mercury_dem.adjust.problem import AdjustmentProblem
    from mercury_dem.io.synthetic_network_store import BlockedNetwork

    net = BlockedNetwork(store)
    im = net.images
    blocks = [net.read_block(b) for b in range(net.n_blocks)]
    cat = np.concatenate
    return AdjustmentProblem(
        cameras=tuple(im.cameras), image_camera=im.image_camera, positions=im.positions, rotations=im.rotations,
        points=cat([b.apriori_points for b in blocks]), measure_image=cat([b.measure_image for b in blocks]),
        measure_point=cat([b.measure_point + b.point_start for b in blocks]), measures=cat([b.measures for b in blocks]),
        measure_sigma=cat([b.sigma for b in blocks]), held_points=cat([b.held_points for b in blocks]),
        pointing_sigma_urad=pointing_sigma_urad)


# ---- from bench_grid.py ------------------------------------------------------------


def truth_height(lat, lon):
    la, lo = np.radians(lat), np.radians(lon)
    return (1500.0 * np.sin(2 * la) * np.cos(3 * lo) + 800.0 * np.cos(la) * np.sin(2 * lo + 0.3)
            + 300.0 * np.sin(7 * la) * np.sin(11 * lo))


def make_points(n, lat_range, lon_range, seed=0, noise=20.0, outliers=0.005):
    rng = np.random.default_rng(seed)
    z = rng.uniform(np.sin(np.radians(lat_range[0])), np.sin(np.radians(lat_range[1])), n)
    lat = np.degrees(np.arcsin(z))
    lon = rng.uniform(lon_range[0], lon_range[1], n)
    h = truth_height(lat, lon) + rng.normal(0.0, noise, n)
    bad = rng.random(n) < outliers
    h[bad] += rng.choice([-3000.0, 3000.0], int(bad.sum()))
    return latlon_to_xyz(lat, lon, h, datum_radius_m=DATUM_RADIUS_M)


def write_point_inputs(work: Path, n_points: int, span: float) -> tuple[np.ndarray, Path, Path, Path, Path]:
    """The benchmark cloud and the files each side reads: points.npy (ours), points.csv + .vrt and
    points.fgb (gdal_grid). Returns (points, npy, csv, vrt, fgb)."""
    pts = make_points(n_points, (-span / 2 - 0.2, span / 2 + 0.2), (-0.2, span + 0.2))
    return (pts, *write_cloud_files(work, pts, DATUM_RADIUS_M))


def write_cloud_files(work: Path, pts: np.ndarray, datum_radius_m: float) -> tuple[Path, Path, Path, Path]:
    """The files each side reads of a cloud (N, 3) body-fixed metres: points.npy (ours), and for gdal_grid
    points.csv (lon in [-180, 180), lat, height above the datum ``datum_radius_m``) + its OGR VRT, and
    points.fgb (FlatGeobuf). Returns (npy, csv, vrt, fgb)."""
    npy = work / "points.npy"
    np.save(npy, pts)
    lat, lon, h = xyz_to_latlon(pts, datum_radius_m)
    lon = np.where(lon > 180, lon - 360, lon)
    csv = work / "points.csv"
    np.savetxt(csv, np.column_stack([lon, lat, h]), delimiter=",", header="lon,lat,elev", comments="", fmt="%.8f")
    vrt = work / "points.vrt"
    vrt.write_text(
        '<OGRVRTDataSource><OGRVRTLayer name="points"><SrcDataSource>' + str(csv) + "</SrcDataSource>"
        '<GeometryType>wkbPoint</GeometryType><GeometryField encoding="PointFromColumns" x="lon" y="lat" '
        'z="elev"/></OGRVRTLayer></OGRVRTDataSource>'
    )
    fgb = work / "points.fgb"
    subprocess.run(["ogr2ogr", "-f", "FlatGeobuf", str(fgb), str(vrt), "-nln", "points", "-nlt", "POINT25D"],
                   check=True)
    return npy, csv, vrt, fgb


def run_gdal(src, algo, size, extent, work):
    """gdal_grid over ``extent`` (lon0, lon1, lat0, lat1 in degrees) with ``size`` columns x rows (an int: square);
    returns (seconds, the grid with NaN for no value, the command)."""
    m, a, cmd = gdal_grid(src, algo, size, extent, work)
    return m.wall_s, a, cmd


def gdal_grid(src, algo, size, extent, work) -> tuple[Measurement, np.ndarray, str]:
    """:func:`run_gdal` measured by the harness: (wall, CPU and peak of the gdal_grid process, the grid, the
    command)."""
    out = work / f"gdal_{algo.split(':')[0]}.tif"
    lon0, lon1, lat0, lat1 = extent
    nx, ny = (size, size) if isinstance(size, int) else size
    cmd = ["gdal_grid", "-q", "--config", "GDAL_NUM_THREADS", "2", "-a", algo, "-txe", str(lon0), str(lon1), "-tye", str(lat1), str(lat0),
           "-outsize", str(nx), str(ny), "-ot", "Float32", "-of", "GTiff", "-l", "points", str(src), str(out)]
    m = measure(cmd, label="gdal_grid")
    import rasterio

    with rasterio.open(out) as src:
        a = src.read(1).astype(np.float64)
        nod = src.nodata
    if nod is not None and not np.isnan(nod):
        a[a == nod] = np.nan
    return m, a, " ".join(cmd)


def median_and_min(ts):
    """(median, minimum) of repeated timings."""
    ts = np.asarray(ts, dtype=float)
    return float(np.median(ts)), float(ts.min())


# ---- from bench_register.py ------------------------------------------------------------


R = 2_439_400.0


class Surface:
    """Sum of plane waves on the sphere (as the tests' synthetic truth)."""

    def __init__(self, rng: np.random.Generator, n_waves: int = 12, min_wavelength_m: float = 25e3):
        self.k = rng.normal(size=(n_waves, 3))
        self.k /= np.linalg.norm(self.k, axis=1)[:, None]
        lam = rng.uniform(min_wavelength_m, 6 * min_wavelength_m, n_waves)
        self.freq = 2 * np.pi * R / lam
        self.amp = 900.0 * (lam / lam.max()) / np.sqrt(n_waves / 4)
        self.phase = rng.uniform(0, 2 * np.pi, n_waves)

    def height(self, lat: np.ndarray, lon: np.ndarray, block: int = 1 << 20) -> np.ndarray:
        from mercury_dem.geometry.body import latlon_to_unit

        lat, lon = np.broadcast_arrays(lat, lon)
        out = np.empty(lat.shape)
        fl, fo, ff = lat.ravel(), lon.ravel(), out.reshape(-1)
        for i in range(0, fl.size, block):
            u = latlon_to_unit(fl[i:i + block], fo[i:i + block])
            ff[i:i + block] = np.sin(self.freq * (u @ self.k.T) + self.phase) @ self.amp
        return out


def make_dem(surface: Surface, ppd: float, path: Path, shift: tuple[float, float, float]) -> None:
    from mercury_dem.config.dem import DemConfig
    from mercury_dem.dem.grid import GridSpec
    from mercury_dem.geometry.body import MERCURY
    from mercury_dem.pipeline.dem_stage import atomic_store, create_store

    cfg = DemConfig(pixels_per_degree=ppd, chunk_size=512, lat_min=-90, lat_max=90, lon_min=0, lon_max=360)
    grid = GridSpec.from_config(cfg, R)
    lat, lon = grid.lat_centres(), grid.lon_centres()
    h = surface.height(*np.meshgrid(lat - shift[0], lon - shift[1], indexing="ij")) - shift[2]
    with atomic_store(path) as tmp:
        _, layers = create_store(str(tmp), grid, cfg, {"source": "bench_register"}, MERCURY)
        layers["elevation"][...] = h.astype(np.float32)


def make_shots(surface: Surface, n: int, rng: np.random.Generator) -> pd.DataFrame:
    """Pole-to-pole profiles, ~400 m apart along track, a random 3-D error per profile."""
    step = 400.0 / R * 180 / np.pi
    per_track = int(180 / step)
    n_profiles = max(1, n // per_track)
    lat = np.tile(np.linspace(-89.9, 89.9, per_track), n_profiles)
    track = np.repeat(np.arange(n_profiles), per_track)
    lon0 = rng.uniform(0, 360, n_profiles)
    lon = (lon0[track] + 0.05 * lat) % 360  # slightly inclined
    from mercury_dem.altimetry.register import enu_frame
    from mercury_dem.geometry.body import latlon_to_unit, xyz_to_latlon

    x = latlon_to_unit(lat, lon) * (R + surface.height(lat, lon))[:, None]
    err = np.c_[rng.normal(0, 30, n_profiles), rng.normal(0, 30, n_profiles), rng.normal(0, 3, n_profiles)]
    E = enu_frame(lat, lon)
    x += np.einsum("nij,nj->ni", E, err[track])
    la, lo, h = xyz_to_latlon(x, R)
    return pd.DataFrame({"lat": la, "lon": lo, "radius_m": R + h + rng.normal(0, 1.0, la.size), "profile_id": track})


# ---- from bench_match.py ------------------------------------------------------------


def a_priori_overlaps(ms: Any) -> tuple[list[str], list[Any], np.ndarray, np.ndarray, list[tuple[str, str]]]:
    """A mission's a-priori overlapping pairs (footprints overlapping by >= 2 %), as the plan finds them.

    Returns the image ids, their cameras, a-priori positions (n, 3) and rotations (n, 3, 3), and the pairs.
    """
    from mercury_dem.geometry.footprints import overlap_graph

    ids = ms.image_ids
    cams = [ms.camera(i) for i in ids]
    uniq: list[Any] = []
    cam_index = []
    for c in cams:
        if c not in uniq:
            uniq.append(c)
        cam_index.append(uniq.index(c))
    pos = np.array([ms.a_priori_pose(i)[0] for i in ids])
    rot = np.array([ms.a_priori_pose(i)[1] for i in ids])
    g = overlap_graph(uniq, np.array(cam_index), pos, rot, min_fraction=0.02, radius_m=DATUM_RADIUS_M)
    return ids, cams, pos, rot, [(ids[a], ids[b]) for a, b in zip(g.i, g.j)]
