"""Where the tie points' radius constraint is centred: the block's own surface, not the datum sphere.

Without ground control the radius of a weakly determined tie point (two nearly parallel rays) is
held by its a-priori radius constraint. Centred on the datum sphere (``point_prior_center:
datum``), that constraint pulls every point toward the sphere by ``σ_h² / (σ_h² + σ_p²)`` of its
true height (``σ_h`` what its rays say about its height, ``σ_p`` the constraint's sigma): a
low-pass copy of the true shape with the opposite sign. Measured on the demo (2026-11-26,
``workflows/benchmarks/shape_study.py``): the truth's polar depression (1.5 km) and long waves
came out as "poles ~+0.3…1 km high", degree 2 of DEM − truth 163 m RMS without altimetry;
with the constraint's sigma at 100 km instead of 10 km, 44 m — but the points' scatter grows
where the constraint was the only thing fixing their depth.

So the constraint is re-centred (:func:`neighbour_radii`): a first adjustment with a loose
radius constraint gives an unbiased but noisy cloud; each point's constraint is then centred on
the median radius of its nearest neighbours in that cloud, and the adjustment runs again with the
configured sigma. The weak points are held to the surface their neighbours see, at every
wavelength longer than the neighbourhood, and keep the regularization.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

__all__ = ["LevellingDecision", "block_extent_deg", "centre_point_priors", "levelling_decision", "neighbour_radii", "recentres",
           "on_datum", "recentre_on_block"]


def on_datum(xyz: NDArray[np.float64], datum_radius_m: float) -> NDArray[np.float64]:
    """Points moved radially onto the datum sphere (direction kept; zero vectors kept as they are).

    The a-priori point of a control point is, as in ISIS with an ellipsoid shape,
    where its ray meets the shape model — not the intersection of rays under the
    a-priori pointing: with pointing errors of a few hundred µrad and the small
    convergence of most pairs, that triangulation misplaces heights by kilometres, and
    a radius constraint centred there pins the points (and, through them, the pointing)
    to those errors. Measured on the tiny mission (global level, same network): image
    registration error 0.90 px with the triangulated centre, 0.37 px with the datum.
    """
    xyz = np.asarray(xyz, np.float64)
    r = np.linalg.norm(xyz, axis=-1, keepdims=True)
    return np.where(r > 0, xyz * (datum_radius_m / np.where(r > 0, r, 1.0)), xyz)


def centre_point_priors(problem: Any, point_prior_center: str, datum_radius_m: float,
                        shape: Any = None) -> Any:
    """The problem with its free points' a-priori coordinates (their radius constraints' centre) as configured.

    ``point_prior_center == "shape"`` with a ``shape``: every point that is not held moves, along its
    direction, onto the body's shape (:meth:`~mercury_dem.reference.body_shape.BodyShape.radius_at_xyz`),
    as ISIS's ``spiceinit shape=`` places a-priori points on a DEM; without a shape, and with
    ``"datum"``: onto the datum sphere (:func:`on_datum`). Held points (ground control) keep theirs.
    Any other value (``"network"``): the problem unchanged.

    Parameters
    ----------
    problem : AdjustmentProblem
    point_prior_center : str
        ``AdjustConfig.point_prior_center``.
    datum_radius_m : float
    shape : BodyShape or None
        The body's shape (a real mission's); None: the datum sphere.

    Returns
    -------
    AdjustmentProblem
    """
    if point_prior_center not in ("datum", "shape"):
        return problem
    return dataclasses.replace(problem, points=centred_points(problem.points, problem.held_points, point_prior_center,
                                                             datum_radius_m, shape))


def centred_points(points: ArrayLike, held: ArrayLike, point_prior_center: str, datum_radius_m: float,
                   shape: Any = None) -> NDArray[np.float64]:
    """The points ``(n, 3)`` as :func:`centre_point_priors` places them (``held`` ones kept; a point at a time,
    so a block of them gives the same rows as the whole: a unit adjusted from its stored blocks).
    """
    pts = np.asarray(points, np.float64)
    if point_prior_center not in ("datum", "shape"):
        return pts
    keep = np.asarray(held, bool)[:, None]
    if point_prior_center == "shape" and shape is not None:
        r = np.linalg.norm(pts, axis=1, keepdims=True)
        target = np.asarray(shape.radius_at_xyz(pts), np.float64)[:, None]
        ok = (r > 0) & np.isfinite(target)
        placed = np.where(ok, pts * (np.where(ok, target, 1.0) / np.where(r > 0, r, 1.0)), on_datum(pts, datum_radius_m))
    else:
        placed = on_datum(pts, datum_radius_m)
    out: NDArray[np.float64] = np.where(keep, pts, placed)
    return out


def neighbour_radii(points_xyz: ArrayLike, usable: ArrayLike | None = None, k: int = 50) -> NDArray[np.float64]:
    """Median radius of each point's ``k`` nearest usable points (itself included), metres.

    Parameters
    ----------
    points_xyz : (n, 3) body-fixed points, m (non-finite rows are not usable)
    usable : (n,) bool, the points whose radii may be used (e.g. not under-determined); default all
    k : neighbours (fewer when fewer points are usable)

    Returns
    -------
    (n,) float: the median radius around each point (its direction's), NaN where no point is usable
    or the point itself is not finite. The median, not the mean: a point thrown kilometres off by
    a bad ray must not move its neighbours' centre.

    Why scipy's kd-tree and ``np.median`` over an (n, k) array: 10⁵ points × 50 neighbours is
    5·10⁶ values, a fraction of a second; the neighbours are searched on unit directions (chord
    distance), so the radii themselves do not decide who is a neighbour.
    """
    xyz = np.asarray(points_xyz, np.float64).reshape(-1, 3)
    r = np.linalg.norm(xyz, axis=1)
    finite = np.isfinite(r) & (r > 0)
    ok = finite if usable is None else finite & np.asarray(usable, bool)
    out = np.full(len(xyz), np.nan)
    if not ok.any() or not finite.any():
        return out
    units = xyz[ok] / r[ok, None]
    tree = cKDTree(units)
    kk = int(min(max(k, 1), ok.sum()))
    _, idx = tree.query(xyz[finite] / r[finite, None], k=kk)
    idx = np.asarray(idx).reshape(int(finite.sum()), kk)
    out[finite] = np.median(r[ok][idx], axis=1)
    return out


def block_extent_deg(points_xyz: ArrayLike, quantile: float = 0.95) -> float:
    """Angular radius of a block of points, degrees: how far (``quantile`` of the points) they lie from their mean direction.

    Parameters
    ----------
    points_xyz : (n, 3) body-fixed points (non-finite and zero rows ignored)
    quantile : share of the points inside the returned radius (a few stray points do not widen it)

    Returns
    -------
    float: 0 for one point or none; for a block round the whole body (its mean direction says
    little) well over 90, and 180 when the directions average to nothing.
    """
    xyz = np.asarray(points_xyz, np.float64).reshape(-1, 3)
    r = np.linalg.norm(xyz, axis=1)
    ok = np.isfinite(r) & (r > 0)
    if ok.sum() < 2:
        return 0.0
    units = xyz[ok] / r[ok, None]
    mean = units.mean(axis=0)
    m = float(np.linalg.norm(mean))
    if m < 1e-12:
        return 180.0
    cos = np.clip(units @ (mean / m), -1.0, 1.0)
    return float(np.degrees(np.arccos(np.quantile(cos, 1.0 - quantile))))


@dataclass(frozen=True)
class LevellingDecision:
    """Whether a block's radius priors are re-centred on its own surface, and its registered DEM levelled on the shots.

    Attributes
    ----------
    recentre : re-centre the free points' radius constraints (:func:`neighbour_radii`)
    level_to_mean : level the registered DEM on the altimetry's mean per tile
        (:func:`mercury_dem.altimetry.merge.mean_level`) when the DEM is registered to altimetry (also
        when the adjustment did not use it, ``altimetry_constrained`` None: nothing held its points)
    extent_deg : the block's angular radius (:func:`block_extent_deg`)
    altimetry_share : share of its tie points the altimetry constrains (0 without altimetry)
    reason : why, in words
    """

    recentre: bool
    level_to_mean: bool
    extent_deg: float
    altimetry_share: float
    reason: str

    def summary(self) -> dict[str, Any]:
        return {"recentre": self.recentre, "level_to_mean": self.level_to_mean, "extent_deg": self.extent_deg,
                "altimetry_share": self.altimetry_share, "reason": self.reason}


def levelling_decision(points_xyz: ArrayLike, altimetry_constrained: ArrayLike | None = None, *,
                       min_extent_deg: float = 10.0, max_altimetry_share: float = 0.5) -> LevellingDecision:
    """Decide, from the block itself, whether its heights need the re-centring and the mean level.

    Both corrections exist for points whose heights nothing outside the images fixes:

    * the re-centring (:func:`neighbour_radii`) replaces the datum sphere as the centre of the
      radius constraints by the block's own surface, from a first pass with a loose constraint. That
      first pass must determine the block's surface: a block spanning a large part of the body does
      (its orbits and the body's curvature fix the height of the whole), a small one — a strip or a
      stereo pair of 2–4 images — does not: with the loose constraint its height floats with its
      pointing (the real Apollo 15 strip and MDIS pair came out 1.5–2 km off). Hence
      ``extent_deg >= min_extent_deg``.
    * the mean level brings the registered DEM's mean, not only its median, onto the shots; its
      offsets are means over the shots of a tile, each tile's own estimate.

    Where the altimetry constrains most of the block's tie points (``altimetry_share >
    max_altimetry_share``) the heights are the altimetry's at the source: neither correction has
    anything left to fix, and each adds its own noise (tiny seed 7: the re-centring moved its merged
    DEM's bias by −6 m, the mean level by −7 m; docs/design/altimetry.md). So both are skipped there;
    where the altimetry holds only part of a large block (the demo: 16 % of the points, all in the
    north) both apply, and the re-centred block carries the north's level into the south.

    Parameters
    ----------
    points_xyz : (n, 3) the block's tie points, body-fixed (a-priori positions do)
    altimetry_constrained : (n,) bool, the points the altimetry constrains; None: no altimetry
    min_extent_deg : smallest angular radius (:func:`block_extent_deg`) of a block re-centred
    max_altimetry_share : above this share of constrained points, neither correction applies

    Returns
    -------
    LevellingDecision
    """
    pts = np.asarray(points_xyz, np.float64).reshape(-1, 3)
    extent = block_extent_deg(pts)
    if altimetry_constrained is None or len(pts) == 0:
        share = 0.0
    else:
        c = np.asarray(altimetry_constrained, bool).ravel()
        if c.shape[0] != len(pts):
            raise ValueError(f"altimetry_constrained has {c.shape[0]} values for {len(pts)} points")
        share = float(c.mean())
    held = altimetry_constrained is not None and share > max_altimetry_share
    wide = extent >= min_extent_deg
    if held:
        reason = (f"the altimetry constrains {share:.0%} of the points (> {max_altimetry_share:.0%}): "
                  "the heights are the altimetry's")
    elif not wide:
        reason = (f"the block spans {extent:.1f} deg (< {min_extent_deg:g}): too small to carry its own surface; "
                  "its radius priors stay on the datum (levelled on the shots' mean if registered)")
    else:
        reason = (f"the block spans {extent:.1f} deg and the altimetry constrains {share:.0%} of its points: "
                  "re-centred on its own surface, levelled on the shots' mean if registered")
    return LevellingDecision(recentre=wide and not held, level_to_mean=not held,
                             extent_deg=extent, altimetry_share=share, reason=reason)


def recentres(decision: LevellingDecision, cfg: Any) -> bool:
    """Whether the radius constraints are re-centred on the block (one more adjustment before the solve).

    When the decision says so and there is a radius constraint to centre (``cfg.radius_sigma_m`` set:
    without one there is nothing to move).
    """
    return bool(decision.recentre and cfg.radius_sigma_m is not None)


def recentre_on_block(problem: Any, cfg: Any, datum_radius_m: float,
                      adjust: Any = None) -> tuple[Any, dict[str, Any]]:
    """The problem with its free points' radius constraints centred on the block's own surface.

    A first adjustment with the radius constraint loosened to ``cfg.point_prior_first_pass_sigma_m``
    (the points follow their rays, unbiased but noisy where the rays are nearly parallel); each
    point is then placed, along its first-pass direction, at the median first-pass radius of its
    ``cfg.point_prior_neighbours`` nearest determined points (:func:`neighbour_radii`), which is where
    its constraint (the configured sigma) is centred; the pointing starts from the first pass. Why:
    centred on the datum sphere, the constraint pulls weak points toward the sphere by a share of their
    true height, and the block bends with the body's long-wavelength shape (docs/design/adjust.md,
    "The block's long-wavelength shape"). Points without a usable neighbourhood keep their centre.
    Returns the new problem and a summary for the unit's report. ``adjust(problem, config)`` runs the
    first pass (default :func:`~mercury_dem.adjust.bundle.bundle_adjust`).
    """
    from mercury_dem.adjust.bundle import bundle_adjust

    first = (adjust or bundle_adjust)(problem, dataclasses.replace(cfg, radius_sigma_m=cfg.point_prior_first_pass_sigma_m))
    held = np.asarray(problem.held_points, bool)
    pts = np.asarray(first.points, np.float64)
    usable = ~np.asarray(first.underdetermined_points, bool) & np.all(np.isfinite(pts), axis=1)
    radii = neighbour_radii(pts, usable, cfg.point_prior_neighbours)
    norm = np.linalg.norm(pts, axis=1)
    move = ~held & np.isfinite(radii) & np.isfinite(norm) & (norm > 0)
    new = np.array(problem.points, np.float64, copy=True)
    new[move] = pts[move] / norm[move, None] * radii[move, None]
    heights = radii[move] - datum_radius_m
    summary = {
        "recentred_points": int(move.sum()),
        "first_pass_iterations": int(first.iterations),
        "first_pass_sigma0": float(first.sigma0),
        "centre_height_m": ({"median": float(np.median(heights)), "p5": float(np.percentile(heights, 5)),
                             "p95": float(np.percentile(heights, 95))} if move.any() else None),
    }
    return dataclasses.replace(problem, points=new, initial_rotations=np.asarray(first.rotations)), summary
