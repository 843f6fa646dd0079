"""The DEM stage's comparison with reference heights: laser altimetry, a reference DEM, a shape model.

For a real mission there is no truth; the geodetic frame is altimetry (LOLA for the Moon,
MLA for Mercury). Each reference named in the configuration's ``reference`` section is
read (:mod:`mercury_dem.reference`) and the DEM minus it is summarised on the DEM's own
datum (``dem.reference`` in report.json). A reference that cannot be read, or that
shares no ground with the DEM, is recorded with its reason; the run goes on.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from mercury_dem.exceptions import MercuryDemError

if TYPE_CHECKING:  # annotations only: 'mercury-dem report' prints reference_table without xarray or numpy
    import xarray as xr

    from mercury_dem.geometry.body import Body


def compare_with_references(dem: xr.Dataset, body: Body, cfg: Any) -> dict[str, Any]:
    """{reference name: statistics or {"error": why}} for every reference in ``cfg`` (a ReferenceConfig)."""
    import numpy as np

    from mercury_dem.reference.compare import compare_dem_with_harmonics, compare_dem_with_shots, compare_heights
    from mercury_dem.reference.lola import read_altimetry_csv, read_lola_ldem
    from mercury_dem.reference.sampling import sample_reference_dem
    from mercury_dem.reference.sha import read_shadr

    near = dem["distance_to_nearest_point"] <= cfg.max_point_distance_m
    elev = dem["elevation"].where(near).load()
    elev.attrs["datum_radius_m"] = body.datum_radius_m
    out: dict[str, Any] = {}

    def guard(name: str, fn: Any) -> None:
        try:
            stats = fn()
            if not stats.get("n"):
                stats = {**stats, "error": "no DEM pixel and reference value in common (different area?)"}
            out[name] = stats
        except (MercuryDemError, OSError, ValueError) as exc:
            out[name] = {"error": str(exc)}

    if cfg.dem:
        def vs_dem() -> dict[str, Any]:
            ref = read_lola_ldem(cfg.dem)
            la, lo = np.meshgrid(elev["lat"].values, elev["lon"].values, indexing="ij")
            h = sample_reference_dem(ref, la.ravel(), np.mod(lo.ravel(), 360.0))
            stats = dict(compare_heights(elev.values.ravel(), datum_radius_m=body.datum_radius_m,
                                         reference_heights_m=h,
                                         reference_datum_radius_m=float(ref.attrs["datum_radius_m"])))
            res = abs(float(ref["lat"][1] - ref["lat"][0])) if ref.sizes["lat"] > 1 else float("nan")
            return {**stats, "reference": f"DEM {cfg.dem}", "reference_pixel_deg": res}
        guard(f"dem:{cfg.dem}", vs_dem)
    for path in cfg.altimetry:
        def vs_shots(path: str = path) -> dict[str, Any]:
            shots = read_altimetry_csv(path, body.datum_radius_m)
            stats = compare_dem_with_shots(elev, shots.table, body.datum_radius_m)
            return {**stats, "shots_read": int(len(shots.table)), "rows_dropped": dict(shots.dropped)}
        guard(f"altimetry:{path}", vs_shots)
    if cfg.shape_harmonics:
        def vs_shape() -> dict[str, Any]:
            shape = read_shadr(cfg.shape_harmonics)
            return compare_dem_with_harmonics(elev, shape, body.datum_radius_m, cfg.shape_lmax)
        guard(f"shape:{cfg.shape_harmonics}", vs_shape)
    return out


def reference_table(ref: dict[str, Any]) -> str:
    """The printed form of ``dem.reference``: DEM minus each reference, metres."""
    if not ref:
        return ""
    lines = ["\nDEM minus reference (m)" + "".join(f"{c:>9}" for c in ("n", "bias", "median", "std", "NMAD", "RMSE"))]
    for name, s in ref.items():
        if s.get("error"):
            lines.append(f"  {name}: not compared ({s['error']})")
            continue
        lines.append(f"  {name}\n" + " " * 23 + "".join(
            f"{s.get(k, float('nan')):>9.1f}" if k != "n" else f"{s.get(k, 0):>9d}"
            for k in ("n", "bias_m", "median_m", "std_m", "nmad_m", "rmse_m")))
        lw = s.get("long_wavelength")
        if lw:
            bands = " ".join(f"{b['lat_min']:+.0f}..{b['lat_max']:+.0f}: {b['bias_m']:+.0f}"
                             for b in lw.get("error_vs_latitude", []) if b.get("n"))
            lines.append(f"    long wavelengths (area-weighted): bias {lw['bias_m']:+.1f} m; by latitude band {bands}")
            low = lw.get("low_degree")
            if low:
                lines.append("    RMS per degree 0.." + str(low["lmax"]) + ": "
                             + " ".join(f"{x:.0f}" for x in low["degree_rms_m"]) + " m")
    return "\n".join(lines) + "\n"


def reference_by_map_table(by_map: dict[str, Any]) -> str:
    """The printed form of ``dem.reference_by_map`` (the registered and merged maps against the references)."""
    parts = []
    for key, ref in by_map.items():
        if ref.get("error"):
            parts.append(f"\n{key.capitalize()} DEM: not compared with the references ({ref['error']})\n")
        else:
            parts.append(reference_table(ref).replace("DEM minus reference", f"{key.capitalize()} DEM minus reference", 1))
    return "".join(parts)
