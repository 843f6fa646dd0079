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
    from mercury_dem.reference.body_shape import BodyShape


def mission_body_shape(mission: Any) -> tuple[BodyShape | None, str | None]:
    """The shape a mission's DEM is checked against: (shape, None) or (None, why there is none).

    A real mission: its body's packaged shape (:func:`mercury_dem.reference.body_shape.body_shape`:
    GTMES for Mercury, LOLA LDEM_4 reduced for the Moon). A synthetic mission's body is its truth
    surface, not the real body: it is checked against GTMES when that surface is built on it
    (the ``demo`` preset's long wavelengths), otherwise against its stored truth DEM
    (:func:`~mercury_dem.reference.body_shape.truth_shape`), so every run gets the gross-error check.
    """
    from mercury_dem.reference.body_shape import body_shape, truth_shape
    from mercury_dem.reference.sha import GTMES_PACKAGED

    body = mission.body
    if mission.truth is not None:
        params = getattr(mission.truth.surface(), "params", None)
        if body.name == "MERCURY" and getattr(params, "shape_harmonics", "") == GTMES_PACKAGED:
            return body_shape(body.name), None
        return truth_shape(mission.truth.dem(), body_name=body.name,
                           source=str(mission.truth.path / "dem.zarr")), None
    shape = body_shape(body.name)
    return shape, None if shape is not None else f"no packaged shape model of {body.name.title()}"


def check_against_body_shape(dem: xr.Dataset, mission: Any, max_point_distance_m: float) -> dict[str, Any]:
    """Every run's DEM minus its body's shape (:func:`mercury_dem.reference.body_shape.shape_check`), on the
    body's datum (not the DEM's stated one: a DEM gridded on the wrong datum is what this catches), over
    the pixels within ``max_point_distance_m`` of a control point. A shape that cannot be read is said so.
    """
    from mercury_dem.exceptions import ReferenceDataError, StoreError
    from mercury_dem.reference.body_shape import shape_check

    body = mission.body
    try:
        shape, why = mission_body_shape(mission)
    except (ReferenceDataError, StoreError, OSError, KeyError) as exc:
        return {"status": "not_compared", "body": body.name, "reason": f"the shape model cannot be read ({exc})"}
    elev = dem["elevation"].where(dem["distance_to_nearest_point"] <= max_point_distance_m).load()
    return shape_check(elev, body_name=body.name, datum_radius_m=body.datum_radius_m, shape=shape,
                       reason_without=why)


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


def shape_check_lines(check: dict[str, Any] | None) -> list[str]:
    """The printed form of a run's shape check (``dem.shape_check``; report and verify); ``[]`` for a run without one."""
    if not check:
        return []
    status = check.get("status")
    if status == "not_compared":
        return [f"DEM minus the body's shape: not compared ({check.get('reason')})"]
    shape = check.get("shape") or {}
    lines = [f"DEM minus the body's shape ({shape.get('name')}, {shape.get('resolution_km', float('nan')):.0f} km): "
             f"bias {check['bias_m']:+.1f} m, RMSE {check['rmse_m']:.1f} m, std {check['std_m']:.1f} m "
             f"({check['n']} pixels)"]
    bands = [b for b in check.get("by_latitude") or [] if b.get("n")]
    if bands:
        lines.append("  by latitude band (bias / RMSE, m): " + "; ".join(
            f"{b['lat_min']:+.0f}..{b['lat_max']:+.0f}: {b['bias_m']:+.0f} / {b['rmse_m']:.0f}" for b in bands))
    if status == "gross_error":
        lines.append(f"ERROR: the DEM's bias against {shape.get('name')} is {check['bias_m'] / 1000:+.1f} km, beyond "
                     f"the gross-error bound of {shape.get('gross_bias_m', float('nan')) / 1000:.0f} km for "
                     f"{str(check.get('body', '')).title()}: {check.get('cause')}")
    return lines
