"""Configuration of feature matching (``mercury_dem.match``).

Defaults follow Becker et al. (2016) -- FAST detector, SIFT descriptors,
brute-force k=2 matching, ratio/symmetry/fundamental/homography outlier chain,
at most 400 matches per pair -- plus guided matching, an area-based (NCC)
fallback, illumination limits and sub-pixel refinement. The illumination
limits and tolerances were chosen from the measurements in
``docs/benchmarks/match.md`` (rendered cratered terrain, true errors).
"""

from __future__ import annotations

from dataclasses import dataclass

from mercury_dem.config.base import ConfigSection, param

DETECTORS = ("FAST", "SIFT", "ORB", "AKAZE", "BRISK")
DESCRIPTORS = ("SIFT", "ORB", "AKAZE", "BRISK")


@dataclass(frozen=True)
class MatchConfig(ConfigSection):
    """The ``match`` section: pre-transform, features, guidance, outlier chain and fallback of tile matching."""

    # -- features ------------------------------------------------------------
    detector: str = param("FAST", "OpenCV feature detector", choices=DETECTORS)
    descriptor: str = param("SIFT", "OpenCV descriptor extractor", choices=DESCRIPTORS)
    matcher: str = param(
        "BF", "Descriptor matcher: brute force (exact) or FLANN (approximate; float descriptors and guided=false only, else BF)",
        choices=("BF", "FLANN"),
    )
    fast_threshold: int = param(12, "FAST intensity threshold (8-bit scale, after the robust stretch)", lo=1, hi=255)
    max_keypoints: int = param(
        1500, "Most keypoints kept per image (strongest, spread over a grid)", lo=10, hi=100000
    )
    keypoint_size_px: float = param(
        4.0, "Size given to FAST keypoints for the descriptor (SIFT support is about 6 x this); 0 = OpenCV's", unit="px",
        lo=0.0, hi=256.0,
    )
    keypoint_grid: int = param(8, "Cells per image side used to spread the kept keypoints", lo=1, hi=64)
    stretch_low_percentile: float = param(
        0.5, "Lower percentile of the 12-bit -> 8-bit robust stretch", unit="%", lo=0.0, hi=50.0
    )
    stretch_high_percentile: float = param(
        99.5, "Upper percentile of the 12-bit -> 8-bit robust stretch", unit="%", lo=50.0, hi=100.0
    )
    saturated_dn: int = param(4095, "DN at or above which a pixel counts as saturated", lo=1, hi=65535)
    max_saturated_fraction: float = param(
        0.5, "An image with more saturated pixels than this fails the pair", lo=0.0, hi=1.0
    )
    min_dynamic_range_dn: float = param(
        8.0, "An image whose robust DN range is below this is 'textureless' and fails the pair", unit="DN", lo=0.0
    )
    # -- outlier chain -------------------------------------------------------
    ratio: float = param(
        0.9, "Lowe ratio test threshold, both directions (looser than the unguided 0.8: the guidance window "
        "already removes distant look-alikes)", lo=0.1, hi=1.0,
    )
    fundamental_tolerance_px: float = param(
        1.5, "Fundamental-matrix RANSAC epipolar distance tolerance", unit="px", lo=0.01, hi=100.0
    )
    fundamental_confidence: float = param(0.999, "Fundamental-matrix RANSAC confidence", lo=0.5, hi=0.999999)
    homography_tolerance_px: float = param(
        3.0, "Homography RANSAC reprojection tolerance (allows relief parallax after the pre-transform)",
        unit="px", lo=0.01, hi=100.0,
    )
    max_matches: int = param(400, "Most matches kept per image pair (best, spatially spread)", lo=1, hi=100000)
    tracks: bool = param(
        True, "Track propagation: after every pair of a tile is matched, each image's matched keypoints are "
        "refined into its other pairs, so the network gets points of 3+ rays (false: pairwise matches only; "
        "cheaper, see docs/benchmarks/match.md session 11 for what it buys)"
    )
    propagate_extra: float = param(
        0.125, "Track propagation: each direction of a pair refines at most its free room below max_matches plus "
        "this share of max_matches in anchors (which may replace single-pair matches in the thinning; a full pair "
        "refines only these). 0: a full pair receives no anchors (cheaper, fewer rays per point)", lo=0.0, hi=10.0,
    )
    min_matches: int = param(
        20, "Fewer matches than this after the chain: try the NCC fallback, else fail the pair", lo=4, hi=100000
    )
    ransac_seed: int = param(0, "Seed of OpenCV's RANSAC (per pair, so results do not depend on threads)", lo=0)
    # -- geometric pre-transform and guidance --------------------------------
    pretransform: bool = param(
        True, "Warp the match image into the reference geometry (datum homography) before detection"
    )
    warp_finer: bool = param(
        True, "Keep the coarser image of a pair in its own geometry and warp the finer one onto it "
        "(else the reference is always kept)"
    )
    swap_scale_ratio: float = param(
        1.15, "Scale ratio above which the coarser image is kept when warp_finer is on", lo=1.0, hi=100.0
    )
    psf_sigma_px: float = param(
        0.7, "Point-spread sigma of the images in their own pixels (pixel footprint included); the finer image "
        "of a pair is blurred to the coarser one's resolution before warping", unit="px", lo=0.0, hi=10.0,
    )
    pretransform_grid: int = param(9, "Points per side of the grid fitted by the pre-transform homography", lo=3, hi=64)
    guided: bool = param(
        True, "Restrict descriptor candidates to a window around the a-priori predicted position"
    )
    # (the a-priori pointing sigma is an argument of match_tile, pointing_sigma_urad: configured as
    # apriori.pointing_sigma_urad or declared by the mission, mercury_dem.config.apriori)
    position_sigma_m: float = param(
        100.0, "A-priori spacecraft position uncertainty per axis (1 sigma), seen as an angle from the camera",
        unit="m", lo=0.0, hi=1e7,
    )
    guidance_sigmas: float = param(3.0, "Guidance window half-width in pointing sigmas", lo=0.5, hi=20.0)
    guidance_margin_px: float = param(
        8.0, "Added to the guidance half-width for relief parallax and model error", unit="px", lo=0.0, hi=1e4
    )
    # -- area-based fallback -------------------------------------------------
    ncc_fallback: bool = param(
        True, "Area-based fallback (NCC at reference corners within the guidance window) when descriptors yield too few"
    )
    ncc_template_px: int = param(31, "NCC fallback template size (odd)", unit="px", lo=5, hi=255)
    ncc_min_score: float = param(0.6, "Lowest NCC peak accepted by the fallback", lo=-1.0, hi=1.0)
    ncc_max_points: int = param(300, "Most reference corners tried by the fallback", lo=1, hi=100000)
    # -- illumination --------------------------------------------------------
    max_incidence_difference_deg: float = param(
        50.0, "Skip pairs whose incidence angles differ by more than this", unit="deg", lo=0.0, hi=180.0
    )
    max_sun_azimuth_difference_deg: float = param(
        45.0, "Skip pairs whose sun azimuths differ by more than this", unit="deg", lo=0.0, hi=180.0
    )
    # -- view geometry --------------------------------------------------------
    max_convergence_deg: float = param(
        180.0, "Skip pairs whose views converge (angle between the two cameras' rays at the overlap centre) by more "
        "than this: beyond ~60 deg the relief and the emission-dependent brightness look different enough that the "
        "matches carry a consistent per-pair offset of 0.2-0.9 px of the coarser image (docs/benchmarks/match.md, "
        "issue 21), which the adjustment cannot reject and which bends the finer images' pointing", unit="deg",
        lo=0.0, hi=180.0,
    )
    redundant_convergence_deg: float = param(
        45.0, "Pairs whose views converge by more than this are matched only when no narrower route joins their "
        "images: they are skipped (status skipped, reason 'redundant') when a third image of the tile is matched "
        "to both by pairs converging by at most this and covers redundant_route_cover of their overlap, so the "
        "tracks join them through its points. Their matches carry up to ~1 px of relief and emission error that "
        "no refinement removes (docs/benchmarks/match.md, issue 21, session 14); 180 = match every pair",
        unit="deg", lo=0.0, hi=180.0,
    )
    redundant_route_min_matches: int = param(
        20, "A route's pairs count only if each gave at least this many matches", lo=1, hi=100000,
    )
    redundant_route_cover: float = param(
        0.5, "A route's third image must see at least this share of the wide pair's a-priori overlap",
        lo=0.0, hi=1.0,
    )
    # -- sub-pixel refinement ------------------------------------------------
    refine: bool = param(True, "Sub-pixel refinement of every measure on the pre-transformed images")
    refine_window_px: int = param(21, "Refinement correlation window (odd)", unit="px", lo=5, hi=101)
    refine_search_px: int = param(3, "Refinement integer search radius around the matched position", unit="px", lo=1, hi=32)
    refine_normalize_sigma_px: float = param(
        2.0, "Refinement positions found on both images locally normalized ((DN - local mean) / local std, Gaussian "
        "weights of this sigma; removes the smooth shading that differs between views and suns); the score stays the "
        "NCC of the DN windows. 0 = on the DN", unit="px", lo=0.0, hi=50.0,
    )
    refine_iterations: int = param(
        4, "Gauss-Newton (Lucas-Kanade, gain and offset) steps after the correlation peak fit", lo=0, hi=50
    )
    refine_min_score: float = param(
        0.5, "Measures whose refined NCC is below this are dropped", lo=-1.0, hi=1.0
    )
    refine_max_shift_px: float = param(
        1.5, "Measures the refinement moves farther than this are dropped (it jumped to another peak)",
        unit="px", lo=0.1, hi=64.0,
    )
    flow_refine: bool = param(
        True, "After the refinement, read each measure's partner position from a dense DIS optical flow of the "
        "pair (8-px patches, variational refinement; on the locally normalized images): follows the relief "
        "parallax inside the correlation window of convergent views. Needs refine_normalize_sigma_px > 0",
    )
    flow_min_convergence_deg: float = param(
        20.0, "Only pairs whose views converge (angle between the two cameras' rays at the overlap centre) by at "
        "least this use the flow (below it the window's parallax is small)", unit="deg", lo=0.0, hi=180.0,
    )
    flow_tolerance_px: float = param(
        1.0, "Measures whose flow position and refined position differ by more than this are dropped", unit="px",
        lo=0.01, hi=100.0,
    )
    flow_variational_iterations: int = param(
        10, "Iterations of DIS's variational refinement per scale", lo=0, hi=100
    )
    local_tolerance_px: float = param(
        1.0, "After refinement, drop matches whose displacement differs from their neighbours' median by more "
        "than this (0 = off)", unit="px", lo=0.0, hi=100.0,
    )
    local_neighbours: int = param(8, "Neighbours of the local-consistency check", lo=2, hi=100)
    # -- execution -----------------------------------------------------------
    threads: int = param(2, "Threads over pairs inside one tile task (OpenCV releases the GIL; its own threads are set to 1 meanwhile)", lo=1, hi=256)
