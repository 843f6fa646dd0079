"""Configuration of the bundle adjustment."""

from __future__ import annotations

from dataclasses import dataclass

from mercury_dem.config.base import ConfigSection, param


@dataclass(frozen=True)
class AdjustConfig(ConfigSection):
    """The ``adjust`` section: a-priori constraints, robustness, solver and outputs of the bundle adjustment."""

    # -- a-priori constraints (weighted pseudo-observations) -------------------
    # (the pointing constraint's sigma is the problem's: AdjustmentProblem.pointing_sigma_urad, configured as
    # apriori.pointing_sigma_urad or declared by the mission, mercury_dem.config.apriori)
    solve_positions: bool = param(False, "Also solve for spacecraft position corrections")
    position_sigma_m: float = param(100.0, "A-priori position constraint when solve_positions (1 sigma)", unit="m", lo=1e-6)
    point_latitude_sigma_m: float | None = param(
        None, "A-priori point constraint along latitude, on the ground (1 sigma; null: none)", unit="m", lo=1e-6
    )
    point_longitude_sigma_m: float | None = param(
        None, "A-priori point constraint along longitude, on the ground (1 sigma; null: none)", unit="m", lo=1e-6
    )
    radius_sigma_m: float | None = param(
        10000.0, "A-priori point radius constraint (1 sigma; null: none)", unit="m", lo=1e-6
    )
    point_prior_center: str = param(
        "shape", "Where the point constraints are centred (and points start): 'shape' puts each a-priori point "
        "on the body's known shape along its direction (GTMES for Mercury, LOLA LDEM_4 for the Moon, as ISIS's "
        "spiceinit shape= does), with the radius sigma point_prior_shape_sigma_m, so a block without altimetry "
        "does not float; where the run has no shape (a synthetic mission, a body without one) it is 'datum'. "
        "'datum' puts each point on the datum sphere (as ISIS does with an ellipsoid shape model); 'network' "
        "uses the network's a-priori coordinates (rays intersected with the a-priori pointing, biased by its errors)",
        choices=("shape", "datum", "network"),
    )
    point_prior_shape_sigma_m: float | None = param(
        None, "Radius constraint (1 sigma) of points centred on the body's shape (point_prior_center: shape); "
        "null: the shape's own (1000 m: the relief a 23-50 km shape model lacks). Replaces radius_sigma_m there; "
        "altimetry-constrained points keep theirs", unit="m", lo=1e-6,
    )
    point_prior_recentre_levels: tuple[str, ...] = param(
        ("global",), "Levels whose point radius constraints may be re-centred on the block's own surface: a first "
        "pass with the radius constraint at point_prior_first_pass_sigma_m, then each point's constraint centred on "
        "the median radius of its point_prior_neighbours nearest points and the adjustment run again (centred on the "
        "datum sphere, the constraint pulls weakly determined points toward it and the block bends with the body's "
        "long-wavelength shape; docs/design/adjust.md). Whether a block is re-centred is decided from the block "
        "(point_prior_recentre_min_extent_deg, point_prior_recentre_max_altimetry_share; the unit's summary "
        "'levelling' says why). Empty: never"
    )
    point_prior_recentre_min_extent_deg: float = param(
        10.0, "Smallest block re-centred: the angular radius holding 95 % of its points around their mean "
        "direction (a strip or stereo pair of a few images cannot carry its own surface: with the loose first pass "
        "its height floats with its pointing; the real Apollo strip and MDIS pair came out 1.5-2 km off). 0: any",
        unit="deg", lo=0.0, hi=180.0,
    )
    point_prior_recentre_max_altimetry_share: float = param(
        0.5, "Where the altimetry constrains more than this share of the block's tie points, its heights are the "
        "altimetry's: the radius priors are not re-centred and the registered DEM is not levelled on the shots' "
        "mean (dem stage). 1: always both", lo=0.0, hi=1.0,
    )
    point_prior_first_pass_sigma_m: float = param(
        100000.0, "Radius constraint of the re-centring's first pass (loose: the points follow their rays)",
        unit="m", lo=1.0,
    )
    point_prior_neighbours: int = param(50, "Points whose median radius centres a point's re-centred constraint",
                                        lo=1, hi=100000)
    held_images: tuple[str, ...] = param((), "Image ids whose pointing (and position) are held fixed")
    # -- robustness ----------------------------------------------------------
    robust_loss: str = param("huber", "Robust loss applied by iterative reweighting", choices=("none", "huber", "cauchy"))
    robust_scale: float = param(1.0, "Robust loss threshold, in units of the measure sigma", lo=1e-3, hi=1e3)
    reject_outliers: bool = param(True, "Reject measures beyond k x MAD between iterations (with re-admission)")
    reject_k_mad: float = param(3.0, "Reject measures beyond median + k x 1.4826 MAD of the residual norms", lo=0.5, hi=100.0)
    reject_min_px: float = param(0.5, "Never reject a measure whose residual is below this", unit="px", lo=0.0)
    min_point_measures: int = param(2, "Points with fewer accepted measures are flagged and not adjusted", lo=1, hi=100)
    min_image_measures: int = param(3, "Images with fewer accepted measures are flagged as weak", lo=0, hi=100000)
    allow_islands: bool = param(False, "Adjust networks whose image graph is disconnected (otherwise an error)")
    # -- laser altimetry --------------------------------------------------------
    altimetry_levels: tuple[str, ...] = param(
        ("global",), "Levels whose adjustment constrains the tie points' radii to the mission's laser altimetry, "
        "when the mission has any (region, hemisphere, global; empty: never, the heights then float on the datum)"
    )
    altimetry_search_m: tuple[float, ...] = param(
        (1000.0, 3000.0, 10000.0), "Shots within these ground distances of a tie point constrain it (a plane or "
        "profile fitted to them, its sigma from the fit and the terrain's roughness at that scale); each point takes "
        "the radius whose fit has the smallest sigma", unit="m"
    )
    altimetry_surface: str = param(
        "quadratic", "Surface fitted to the shots around a tie point: 'quadratic' (follows the terrain's curvature "
        "over the search disc; where too few shots or shots on one or two profiles leave it undetermined, the "
        "plane) or 'plane'", choices=("quadratic", "plane"),
    )
    altimetry_min_shots: int = param(6, "Fewer shots around a tie point leave it unconstrained", lo=3, hi=100000)
    altimetry_horizontal_sigma_m: float = param(
        50.0, "How far the first pass's tie points may be from their true place; times the slope it widens the "
        "altimetry constraint", unit="m", lo=0.0, hi=1e6
    )
    # -- solver ----------------------------------------------------------------
    max_iterations: int = param(30, "Levenberg-Marquardt iteration limit", lo=1, hi=10000)
    sigma0_tolerance: float = param(1e-5, "Converged when sigma0 changes by less than this, relative", lo=0.0, hi=1.0)
    step_tolerance: float = param(1e-10, "Converged when the step is below this, relative to the parameters", lo=0.0, hi=1.0)
    solver: str = param("auto", "Reduced camera system: direct factorization, PCG, or by size", choices=("auto", "direct", "pcg"))
    direct_max_unknowns: int = param(30000, "auto: factor directly up to this many camera unknowns, PCG above", lo=1)
    pcg_tolerance: float = param(0.1, "Relative residual at which PCG stops (inexact Newton)", lo=1e-12, hi=0.9)
    pcg_max_iterations: int = param(500, "PCG iteration limit per step", lo=1)
    blocked_min_measures: int | None = param(
        None, "Units of blocked_levels with at least this many measures are adjusted over point blocks "
        "(mercury_dem.adjust.blocked_bundle: the same solution to solver tolerance, pointing only, no a-posteriori "
        "sigmas; docs/design/adjust.md). Null (the default): never; 0: always", lo=0
    )
    blocked_levels: tuple[str, ...] = param(
        ("hemisphere", "global"), "Levels whose units may use the blocked adjustment (see blocked_min_measures)"
    )
    blocked_block_points: int = param(25000, "Points per block of the blocked adjustment", lo=1)
    streamed_merge_levels: tuple[str, ...] = param(
        (), "Levels whose units merge their children's stored networks by parts (mercury_dem.io.merged_network_store."
        "stream_merge: the same merged network bit for bit, never the children's networks and the merge in memory "
        "at once); a unit adjusted by blocks is then adjusted from that store's blocks and its adjusted network "
        "written back by blocks (never whole in the unit's process), other units (altimetry passes, re-centring, "
        "posterior sigmas, not blocked) read it back and adjust in memory, their summary saying why. Empty (the "
        "default): the in-memory merge"
    )
    streamed_merge_part_measures: int = param(
        500000, "Measures per part of the streamed merge (streamed_merge_levels): bounds the merge's memory", lo=1
    )
    blocked_on_workers: bool = param(
        True, "A blocked unit running on a Dask worker spreads its point blocks over the run's workers (one shard "
        "actor each, the unit's task seceded while it drives the loop); false: its blocks stay in the unit's process"
    )
    blocked_tree_min_workers: int = param(
        4, "From this many Dask workers holding point blocks on, the blocked adjustment's sums (the reduced camera "
        "system) are merged pairwise on the workers in log2(N) rounds and the client receives one; below, every "
        "worker's sum goes to the client", lo=2
    )
    blocked_float32: bool = param(
        True, "The blocked adjustment stores W = Jc^T Jp, the measures and their inverse sigmas in float32 (107 "
        "instead of 155 bytes a measure held; the same stationary point, observations rounded by < 1e-4 px: "
        "docs/design/adjust.md, 'Memory'); false: float64 throughout, the in-memory adjuster's sums bit for bit"
    )
    blocked_recompute_w: bool = param(
        False, "The blocked adjustment rebuilds W = Jc^T Jp from the Jacobians at each trial step instead of "
        "keeping it (36 fewer bytes a measure held in float32, the same results bit for bit, two more Jacobian "
        "evaluations a trial: docs/benchmarks/adjust.md)"
    )
    # -- outputs ----------------------------------------------------------------
    rms_flag_px: float = param(2.0, "Images whose RMS residual exceeds this are flagged in the unit's summary "
                               "(flagged_images in report.json); the solution is not changed", unit="px", lo=0.0)
    posterior_sigmas: bool = param(False, "Compute a-posteriori sigmas of images and points (small networks)")
    posterior_max_unknowns: int = param(6000, "Skip a-posteriori sigmas above this many camera unknowns", lo=1)
