"""Laser altimetry inside the bundle adjustment: a radius constraint for every tie point near shots.

ISIS ``jigsaw`` (LIDARDATA) ties altimetry into the adjustment by constraining points to the
lidar radii with the lidar's sigma. Here each tie point with enough altimetry shots around it
gets a radius prior: a quadratic surface ``r = a + b e + c n + d e² + f e n + g n²`` (where the shots
determine one; otherwise a plane ``r = a + b e + c n``, or a line along a single profile) fitted by
least squares to the shots within ``search_radius_m`` in the point's local east/north frame,
evaluated at the point (``a``). Its sigma is what the fit can promise at the point: the variance of
``a`` from the fit plus the shots' scatter about the surface (the terrain's roughness at that scale,
which the surface cannot follow), never below ``sigma_floor_m``. The adjustment then centres the point's radius
constraint there (:class:`mercury_dem.adjust.problem.AdjustmentProblem`
``point_radius_sigma``), instead of on the datum with a loose sigma, so the heights are right at
the source and the pointing follows them.

Why our own accumulation rather than one ``lstsq`` per point: the normal equations of all
points are summed at once with ``np.bincount`` over the (point, shot) pairs the kd-tree
(``scipy.spatial.cKDTree``) returns, and solved as one batched 3x3 system; a Python loop over
10⁵–10⁶ points would dominate the adjustment's time.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

if TYPE_CHECKING:
    from mercury_dem.adjust.problem import AdjustmentProblem
    from mercury_dem.adjust.result import AdjustmentResult
    from mercury_dem.config.adjust import AdjustConfig

__all__ = ["AltimetryShotsArrays", "RadiusPriors", "altimetry_radius_priors", "bundle_adjust_with_altimetry",
           "constrain_to_altimetry", "radius_priors_within", "shot_tiles_for_points", "unit_vectors"]


@dataclass(frozen=True, eq=False)
class RadiusPriors:
    """Per-point radius constraints from altimetry.

    Attributes
    ----------
    radius_m : (n_pt,) radius at each point's direction (NaN: no constraint)
    sigma_m : (n_pt,) its 1-sigma (NaN where no constraint)
    n_shots : (n_pt,) shots used for each point
    roughness_m : (n_pt,) RMS of the shots about the fitted plane (NaN below 4 shots)
    """

    radius_m: NDArray[np.float64]
    sigma_m: NDArray[np.float64]
    n_shots: NDArray[np.int64]
    roughness_m: NDArray[np.float64]

    @property
    def constrained(self) -> NDArray[np.bool_]:
        return np.isfinite(self.radius_m)

    def summary(self) -> dict[str, float | int]:
        """Counts and medians for the run report."""
        c = self.constrained
        return {
            "points": int(len(self.radius_m)),
            "constrained_points": int(c.sum()),
            "median_sigma_m": float(np.median(self.sigma_m[c])) if c.any() else float("nan"),
            "median_shots": float(np.median(self.n_shots[c])) if c.any() else 0.0,
        }


def unit_vectors(lat_deg: ArrayLike, lon_deg: ArrayLike) -> NDArray[np.float64]:
    """Body-fixed unit vectors of planetocentric latitudes and east longitudes (degrees)."""
    lat, lon = np.radians(np.asarray(lat_deg, np.float64)), np.radians(np.asarray(lon_deg, np.float64))
    return np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=-1)


def altimetry_radius_priors(
    points_xyz: ArrayLike,
    shot_lat_deg: ArrayLike,
    shot_lon_deg: ArrayLike,
    shot_radius_m: ArrayLike,
    *,
    search_radius_m: float | Sequence[float] = 1000.0,
    **options: Any,
) -> RadiusPriors:
    """Radius constraints for tie points from the altimetry shots around them.

    ``search_radius_m`` may be several radii: each point then takes the fit with the smallest
    sigma among them (dense shots give a tight plane within a small radius; where the profiles
    are kilometres apart only a larger radius reaches any, with a sigma that says so). The other
    options are those of :func:`radius_priors_within`.
    """
    radii = [float(search_radius_m)] if np.isscalar(search_radius_m) else [float(r) for r in search_radius_m]  # type: ignore[arg-type]
    if not radii:
        raise ValueError("search_radius_m: give at least one radius")
    if options.get("tree") is None and len(radii) > 1:
        options["tree"] = cKDTree(unit_vectors(shot_lat_deg, shot_lon_deg).reshape(-1, 3))
    best: RadiusPriors | None = None
    for radius in sorted(radii):
        pri = radius_priors_within(points_xyz, shot_lat_deg, shot_lon_deg, shot_radius_m, search_radius_m=radius,
                                   **options)
        if best is None:
            best = pri
            continue
        better = pri.constrained & (~best.constrained | (pri.sigma_m < best.sigma_m))
        best = RadiusPriors(
            radius_m=np.where(better, pri.radius_m, best.radius_m),
            sigma_m=np.where(better, pri.sigma_m, best.sigma_m),
            n_shots=np.where(better, pri.n_shots, best.n_shots),
            roughness_m=np.where(better, pri.roughness_m, best.roughness_m),
        )
    assert best is not None
    return best


def radius_priors_within(
    points_xyz: ArrayLike,
    shot_lat_deg: ArrayLike,
    shot_lon_deg: ArrayLike,
    shot_radius_m: ArrayLike,
    *,
    shot_sigma_m: float | ArrayLike = 1.0,
    search_radius_m: float = 1000.0,
    min_shots: int = 6,
    sigma_floor_m: float = 1.0,
    horizontal_sigma_m: float = 0.0,
    cross_track_slope: float = 0.05,
    surface: str = "quadratic",
    quadratic_min_shots: int = 12,
    tree: cKDTree | None = None,
) -> RadiusPriors:
    """Radius constraints for tie points from the altimetry shots within one search radius.

    Parameters
    ----------
    points_xyz : (n_pt, 3) body-fixed tie points, metres (only their directions are used)
    shot_lat_deg, shot_lon_deg, shot_radius_m : (n_shot,) the shots (planetocentric, east, from
        the centre of mass; the columns of :mod:`mercury_dem.reference.lola`'s table)
    shot_sigma_m : the shots' radius sigma (scalar or per shot)
    search_radius_m : shots within this ground distance of a point are used
    min_shots : a plane is fitted where at least this many shots surround the point; with fewer, or
        with shots along one profile, at least 3 shots give a profile fit (see ``cross_track_slope``)
    sigma_floor_m : smallest sigma given
    horizontal_sigma_m : how far (1 sigma, on the ground) the points may be from where they are
        said to be; the fitted slope turns it into height: ``slope x horizontal_sigma_m`` is added
        to the sigma in quadrature (a point 100 m off on a 10 % slope is 10 m off in height)
    cross_track_slope : where the shots around a point lie along one profile, the slope assumed
        across it (besides the along-track slope): times the point's distance from the profile it
        widens the sigma
    surface : ``"quadratic"``: where at least ``quadratic_min_shots`` shots surround the point and
        they determine it (shots spread across the search disc, not on one or two profiles), a
        quadratic ``r = a + b e + c n + d e² + f e n + g n²`` is fitted, which follows the terrain's
        curvature over the disc (over 10 km a plane misses a crater's bowl: its intercept is the
        disc's mean height, not the height at the centre); elsewhere the plane, then the profile
        fit. ``"plane"``: the plane only
    quadratic_min_shots : fewest shots for a quadratic (6 parameters: twice as many)
    tree : a kd-tree of the shots' unit vectors, when the caller reuses one

    Returns
    -------
    RadiusPriors
    """
    pts = np.asarray(points_xyz, np.float64).reshape(-1, 3)
    r_shot = np.asarray(shot_radius_m, np.float64).ravel()
    u_shot = unit_vectors(shot_lat_deg, shot_lon_deg).reshape(-1, 3)
    n_pt = len(pts)
    nan = np.full(n_pt, np.nan)
    empty = RadiusPriors(nan.copy(), nan.copy(), np.zeros(n_pt, np.int64), nan.copy())
    if n_pt == 0 or len(r_shot) == 0:
        return empty
    if min_shots < 3:
        raise ValueError(f"min_shots must be >= 3 (a plane has 3 parameters), got {min_shots}")
    sig_shot = np.broadcast_to(np.asarray(shot_sigma_m, np.float64), r_shot.shape)
    radius_scale = float(np.median(r_shot))
    norm = np.linalg.norm(pts, axis=1)
    ok = np.isfinite(norm) & (norm > 0)
    up = np.where(ok[:, None], pts / np.where(ok, norm, 1.0)[:, None], 0.0)
    tree = tree if tree is not None else cKDTree(u_shot)
    # Chord on the unit sphere of a ground distance d: 2 sin(d / 2R).
    chord = 2.0 * np.sin(min(search_radius_m / radius_scale, np.pi) / 2.0)
    sparse = tree.sparse_distance_matrix(cKDTree(up[ok]), chord, output_type="coo_matrix")
    shot_idx = sparse.row
    pt_idx = np.flatnonzero(ok)[sparse.col]
    if len(pt_idx) == 0:
        return empty
    east = np.cross(np.array([0.0, 0.0, 1.0]), up)
    en = np.linalg.norm(east, axis=1, keepdims=True)
    east = np.where(en > 1e-12, east / np.where(en > 1e-12, en, 1.0), np.array([0.0, 1.0, 0.0]))
    north = np.cross(up, east)
    d = u_shot[shot_idx] - up[pt_idx]
    e = radius_scale * np.einsum("ij,ij->i", d, east[pt_idx])
    n = radius_scale * np.einsum("ij,ij->i", d, north[pt_idx])
    h = r_shot[shot_idx]
    w = 1.0 / sig_shot[shot_idx] ** 2
    if surface not in ("quadratic", "plane"):
        raise ValueError(f"surface must be 'quadratic' or 'plane', got {surface!r}")
    # Weighted normal equations of r = a + b e + c n, summed per point.
    cols = (np.ones_like(e), e, n)

    def acc(values: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.bincount(pt_idx, weights=values, minlength=n_pt)

    normal = np.empty((n_pt, 3, 3))
    rhs = np.empty((n_pt, 3))
    for i in range(3):
        rhs[:, i] = acc(w * cols[i] * h)
        for j in range(i, 3):
            normal[:, i, j] = normal[:, j, i] = acc(w * cols[i] * cols[j])
    count = np.bincount(pt_idx, minlength=n_pt)
    use = count >= min_shots
    # Shots on one line (a single profile) cannot fix the cross-track slope: need a well-conditioned plane.
    with np.errstate(divide="ignore", invalid="ignore"):
        cond = np.linalg.cond(np.where(use[:, None, None], normal, np.eye(3)))
    use &= np.isfinite(cond) & (cond < 1e12)
    beta = np.zeros((n_pt, 3))
    cov_aa = np.full(n_pt, np.nan)
    if use.any():
        inv = np.linalg.inv(normal[use])
        beta[use] = np.einsum("kij,kj->ki", inv, rhs[use])
        cov_aa[use] = inv[:, 0, 0]
    fit = beta[pt_idx, 0] + beta[pt_idx, 1] * e + beta[pt_idx, 2] * n
    dof = count - 3
    if surface == "quadratic":
        quad = use & (count >= max(quadratic_min_shots, 7))
        if quad.any():
            q_beta, q_cov, q_ok = _quadratic_fit(pt_idx, e, n, h, w, quad, n_pt, search_radius_m)
            beta = np.where(q_ok[:, None], q_beta[:, :3], beta)
            cov_aa = np.where(q_ok, q_cov, cov_aa)
            qf = q_ok[pt_idx]
            fit = np.where(qf, q_beta[pt_idx, 0] + q_beta[pt_idx, 1] * e + q_beta[pt_idx, 2] * n
                           + q_beta[pt_idx, 3] * e * e + q_beta[pt_idx, 4] * e * n + q_beta[pt_idx, 5] * n * n, fit)
            dof = np.where(q_ok, count - 6, dof)
    ss = acc((h - fit) ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        roughness = np.where(dof > 0, np.sqrt(ss / np.maximum(dof, 1)), np.nan)
        # cov_aa is the fit's variance with the shots' own sigmas; the roughness (what the surface cannot
        # follow, plus any shots' excess noise) scales it, and its part beyond the shots' own noise (the
        # terrain's, which the point itself sits on; the shots' noise is in cov_aa already) is added once.
        mean_w = acc(w) / np.maximum(count, 1)
        scale2 = np.where(np.isfinite(roughness), roughness**2 * mean_w, 1.0)
        slope2 = beta[:, 1] ** 2 + beta[:, 2] ** 2
        terrain2 = np.maximum(np.nan_to_num(roughness) ** 2 - 1.0 / mean_w, 0.0)
        sigma = np.sqrt(cov_aa * np.maximum(scale2, 1.0) + terrain2 + slope2 * horizontal_sigma_m**2)
    radius = np.where(use, beta[:, 0], np.nan)
    sigma = np.where(use, sigma, np.nan)
    # Where the shots lie along one profile (the usual case away from crossovers: MLA's profiles are
    # kilometres apart, its shots 400 m apart), fit the profile instead: r = a + b s along its
    # principal direction, and widen the sigma by a cross-track slope times the point's distance from
    # the profile (the slope across the profile is unknown; |b| and cross_track_slope stand for it).
    line = ~use & (count >= 3)
    if line.any():
        r_line, s_line, rough_line = _profile_fit(pt_idx, e, n, h, w, count, line, n_pt, cross_track_slope,
                                                  horizontal_sigma_m)
        radius = np.where(line, r_line, radius)
        sigma = np.where(line, s_line, sigma)
        roughness = np.where(line, rough_line, roughness)
        use = use | (line & np.isfinite(r_line))
    sigma = np.maximum(sigma, sigma_floor_m)
    return RadiusPriors(
        radius_m=radius,
        sigma_m=np.where(use, sigma, np.nan),
        n_shots=count.astype(np.int64),
        roughness_m=np.where(use, roughness, np.nan),
    )


def _quadratic_fit(pt_idx: NDArray[np.int64], e: NDArray[np.float64], n: NDArray[np.float64], h: NDArray[np.float64],
                   w: NDArray[np.float64], quad: NDArray[np.bool_], n_pt: int,
                   scale_m: float) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Weighted quadratic fits ``r = a + b e + c n + d e² + f e n + g n²`` of each ``quad`` point's shots.

    Returns the coefficients (n_pt, 6) in metres (``e``, ``n`` in metres), the variance of ``a`` with
    the shots' own sigmas, and where the fit was determined: its normal matrix, built on ``e/scale_m``
    and ``n/scale_m`` so that its columns are of one size, has a condition number below 10⁸ (shots on
    one or two straight profiles leave the curvature across them undetermined: those points keep the
    plane). Same summation as the plane: 21 ``bincount`` sums over the (point, shot) pairs, then one
    batched 6×6 inverse.
    """
    x, y = e / scale_m, n / scale_m
    cols = (np.ones_like(x), x, y, x * x, x * y, y * y)
    keep = quad[pt_idx]
    pi = pt_idx[keep]
    normal = np.zeros((n_pt, 6, 6))
    rhs = np.zeros((n_pt, 6))
    for i in range(6):
        rhs[:, i] = np.bincount(pi, weights=(w * cols[i] * h)[keep], minlength=n_pt)
        for j in range(i, 6):
            normal[:, i, j] = normal[:, j, i] = np.bincount(pi, weights=(w * cols[i] * cols[j])[keep], minlength=n_pt)
    ok = quad.copy()
    with np.errstate(divide="ignore", invalid="ignore"):
        cond = np.linalg.cond(np.where(ok[:, None, None], normal, np.eye(6)))
    ok &= np.isfinite(cond) & (cond < 1e8)
    beta = np.zeros((n_pt, 6))
    cov_aa = np.full(n_pt, np.nan)
    if ok.any():
        inv = np.linalg.inv(normal[ok])
        b = np.einsum("kij,kj->ki", inv, rhs[ok])
        beta[ok] = b / np.array([1.0, scale_m, scale_m, scale_m**2, scale_m**2, scale_m**2])
        cov_aa[ok] = inv[:, 0, 0]
    return beta, cov_aa, ok


def _profile_fit(pt_idx: NDArray[np.int64], e: NDArray[np.float64], n: NDArray[np.float64], h: NDArray[np.float64],
                 w: NDArray[np.float64], count: NDArray[np.int64], line: NDArray[np.bool_], n_pt: int,
                 cross_track_slope: float, horizontal_sigma_m: float) -> tuple[NDArray[np.float64], ...]:
    """Radius, sigma and roughness at each ``line`` point from a straight-line fit of its shots."""

    def acc(values: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.bincount(pt_idx, weights=values, minlength=n_pt)

    sw = acc(w)
    with np.errstate(divide="ignore", invalid="ignore"):
        me, mn = acc(w * e) / sw, acc(w * n) / sw
        cee = acc(w * e * e) / sw - me**2
        cnn = acc(w * n * n) / sw - mn**2
        cen = acc(w * e * n) / sw - me * mn
    theta = 0.5 * np.arctan2(2 * cen, cee - cnn)  # the shots' principal direction
    ct, st = np.cos(theta), np.sin(theta)
    s = (e - me[pt_idx]) * ct[pt_idx] + (n - mn[pt_idx]) * st[pt_idx]
    s1, ss, sh, ssh = acc(w), acc(w * s * s), acc(w * h), acc(w * s * h)
    with np.errstate(divide="ignore", invalid="ignore"):
        b = ssh / ss  # s is centred, so a and b decouple
        a = sh / s1
        var_a, var_b = 1.0 / s1, 1.0 / ss
        resid = h - (a[pt_idx] + b[pt_idx] * s)
        dof = count - 2
        rough = np.where(dof > 0, np.sqrt(acc(resid**2) / np.maximum(dof, 1)), np.nan)
        mean_w = s1 / np.maximum(count, 1)
        scale2 = np.maximum(np.where(np.isfinite(rough), rough**2 * mean_w, 1.0), 1.0)
        s_p = -(me * ct + mn * st)  # the point (0, 0) along the profile
        d = np.abs(me * st - mn * ct)  # and its distance across it
        slope2 = b**2 + cross_track_slope**2
        radius = a + b * s_p
        sigma = np.sqrt((var_a + var_b * s_p**2) * scale2 + np.maximum(np.nan_to_num(rough) ** 2 - 1.0 / mean_w, 0.0)
                        + slope2 * (d**2 + horizontal_sigma_m**2))
    good = line & np.isfinite(radius) & np.isfinite(sigma) & (ss > 0)
    return (np.where(good, radius, np.nan), np.where(good, sigma, np.nan), np.where(good, rough, np.nan))


def constrain_to_altimetry(problem: Any, priors: RadiusPriors, directions: ArrayLike | None = None) -> Any:
    """The problem with its altimetry-constrained points placed at the altimetry's radius.

    ``directions`` (n_pt, 3): where the points are (e.g. a first adjustment's points); default the
    problem's own a-priori points. Points without a prior keep their a-priori coordinates and the
    configured radius constraint.
    """
    import dataclasses

    pts = np.asarray(problem.points if directions is None else directions, np.float64)
    c = priors.constrained & ~np.asarray(problem.held_points, bool)
    norm = np.linalg.norm(pts, axis=1)
    c &= np.isfinite(norm) & (norm > 0)
    new_points = np.array(problem.points, np.float64, copy=True)
    new_points[c] = pts[c] / norm[c, None] * priors.radius_m[c, None]
    sigma = np.where(c, priors.sigma_m, np.nan)
    return dataclasses.replace(problem, points=new_points, point_radius_sigma=sigma)


@dataclass(frozen=True, eq=False)
class AltimetryShotsArrays:
    """The shot columns an adjustment needs (planetocentric deg, east deg, metres from the centre)."""

    lat_deg: NDArray[np.float64]
    lon_deg: NDArray[np.float64]
    radius_m: NDArray[np.float64]
    sigma_m: NDArray[np.float64] | float = 1.0

    @classmethod
    def from_table(cls, table: Any, default_sigma_m: float = 1.0) -> AltimetryShotsArrays:
        """From a shot DataFrame (:mod:`mercury_dem.reference.lola` columns; ``sigma_m`` when present)."""
        sigma = table["sigma_m"].to_numpy(np.float64) if "sigma_m" in table else default_sigma_m
        return cls(table["lat"].to_numpy(np.float64), table["lon"].to_numpy(np.float64),
                   table["radius_m"].to_numpy(np.float64), sigma)


def bundle_adjust_with_altimetry(
    problem: AdjustmentProblem,
    config: AdjustConfig,
    shots: AltimetryShotsArrays,
    *,
    search_radius_m: float | Sequence[float] = (1000.0, 3000.0, 10_000.0),
    min_shots: int = 6,
    sigma_floor_m: float = 1.0,
    horizontal_sigma_m: float = 50.0,
    surface: str = "quadratic",
    adjust: Callable[[AdjustmentProblem, AdjustConfig], AdjustmentResult] | None = None,
) -> tuple[AdjustmentResult, RadiusPriors]:
    """Bundle adjustment with the tie points' radii constrained by altimetry (two passes).

    Pass 1 adjusts as usual; the altimetry's radius and sigma are then found around each adjusted
    point (:func:`altimetry_radius_priors`: the a-priori points can be kilometres off horizontally,
    where the terrain is another height); pass 2 starts from pass 1's pointing with those points at
    the altimetry's radius and their radius constraints centred there (the others keep the
    configured constraint). ``horizontal_sigma_m`` is how far pass 1's points may still be from
    their true place on the ground (its pointing error times the range): on a slope that is height.
    ``adjust(problem, config)`` runs each pass (default :func:`~mercury_dem.adjust.bundle.bundle_adjust`;
    the pipeline passes the blocked adjustment for large units). Returns pass 2's :class:`~mercury_dem.adjust.result.AdjustmentResult`
    and the priors.
    """
    import dataclasses

    from mercury_dem.adjust.bundle import bundle_adjust

    adjust = adjust or bundle_adjust
    first = adjust(problem, config)
    priors = altimetry_radius_priors(
        first.points, shots.lat_deg, shots.lon_deg, shots.radius_m, shot_sigma_m=shots.sigma_m,
        search_radius_m=search_radius_m, min_shots=min_shots, sigma_floor_m=sigma_floor_m,
        horizontal_sigma_m=horizontal_sigma_m, surface=surface,
    )
    if not priors.constrained.any():
        return first, priors
    second = dataclasses.replace(constrain_to_altimetry(problem, priors, directions=first.points),
                                 initial_rotations=np.asarray(first.rotations))
    return adjust(second, config), priors


def shot_tiles_for_points(points_xyz: ArrayLike, tile_size_deg: float, shot_tiles: Sequence[int]) -> list[int]:
    """The altimetry tiles a block's tie points lie in: the shots an adjustment of the block needs to read.

    Parameters
    ----------
    points_xyz : (n, 3) body-fixed points (non-finite rows are ignored); the a-priori points of a
        unit's network do (the merged children's adjusted points would do as well: the tiles read only
        need to hold them).
    tile_size_deg : float
        The altimetry store's tile size.
    shot_tiles : sequence of int
        The tiles that hold shots.

    Returns
    -------
    list of int
        Sorted ids of the tiles of ``shot_tiles`` that hold at least one point; [] when none does.
    """
    from mercury_dem.geometry.tiling import TileGrid

    xyz = np.asarray(points_xyz, np.float64).reshape(-1, 3)
    xyz = xyz[np.all(np.isfinite(xyz), axis=1)]
    lat = np.degrees(np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1])))
    lon = np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0])) % 360.0
    return sorted(set(TileGrid(tile_size_deg).tile_of(lat, lon).tolist()) & {int(t) for t in shot_tiles})
