"""``mercury-dem geometry ISD.json``: image geometry from a CSM frame-camera ISD (like ISIS ``caminfo``).

Prints the image centre's and corners' latitude/longitude, slant distance, pixel
scale, incidence/emission/phase, sub-spacecraft and sub-solar points. With
``--label LBL`` (a PDS3 label of the same image) it also prints the label's values
and our differences, computed on the label's own sphere (TARGET_CENTER_DISTANCE -
SPACECRAFT_ALTITUDE) and at the label's centre pixel (RA_DEC_REF_PIXEL, 1-based),
and exits with status 1 when a quantity with a tolerance is outside it.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mercury_dem.config import Config
from mercury_dem.exceptions import GeometryError, IsdError

if TYPE_CHECKING:  # the geometry modules (numpy, scipy) are imported when the command runs
    from mercury_dem.geometry.caminfo import CamInfo, Comparison
    from mercury_dem.geometry.isd import IsdGeometry

NAME = "geometry"
HELP = "image geometry (centre/corner lat/lon, slant distance, pixel scale, angles) from a CSM ISD"

_ROWS: list[tuple[str, str, str]] = [  # (CamInfo field, label, format)
    ("centre_lat", "centre latitude (deg)", ".5f"),
    ("centre_lon", "centre longitude (deg E)", ".5f"),
    ("slant_distance_m", "slant distance (m)", ".1f"),
    ("pixel_scale_m", "pixel scale (m)", ".5f"),
    ("incidence_deg", "incidence (deg)", ".5f"),
    ("emission_deg", "emission (deg)", ".5f"),
    ("phase_deg", "phase (deg)", ".5f"),
    *[(f"corner_lat[{i}]", f"corner {i} latitude", ".5f") for i in range(4)],
    *[(f"corner_lon[{i}]", f"corner {i} longitude", ".5f") for i in range(4)],
    ("sub_spacecraft_lat", "sub-spacecraft latitude", ".5f"),
    ("sub_spacecraft_lon", "sub-spacecraft longitude", ".5f"),
    ("spacecraft_altitude_m", "spacecraft altitude (m)", ".1f"),
    ("target_center_distance_m", "distance to centre (m)", ".1f"),
    ("sub_solar_lat", "sub-solar latitude", ".5f"),
    ("sub_solar_lon", "sub-solar longitude", ".5f"),
    ("centre_ra_deg", "centre RA J2000 (deg)", ".5f"),
    ("centre_dec_deg", "centre Dec J2000 (deg)", ".5f"),
]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("isd", metavar="ISD", help="CSM frame-camera ISD (ALE or usgscsm layout; JSON, any extension)")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--label", metavar="LBL", help="PDS3 label of the same image: also print its values and our differences")
    p.add_argument("--radius-km", type=float, metavar="R",
                   help="sphere radius for the ground points (default: the ISD's radii.semimajor)")
    p.add_argument("--no-sun", action="store_true",
                   help="accept an ISD without a usable sun_position (incidence/phase left undefined)")


def _value(info: CamInfo, name: str) -> float:
    if name.endswith("]"):
        field, index = name[:-1].split("[")
        return float(getattr(info, field)[int(index)])
    return float(getattr(info, name))


def _fmt(x: float | None, spec: str) -> str:
    return "-" if x is None or not math.isfinite(x) else format(x, spec)


def _camera_dict(g: IsdGeometry) -> dict[str, Any]:
    c = g.camera
    return {"name": c.name, "focal_length_mm": c.focal_length_mm, "pixel_size_mm": c.pixel_size_mm,
            "summing": c.summing, "samples": c.samples, "lines": c.lines,
            "boresight_sample": float(c.boresight_sample), "boresight_line": float(c.boresight_line),
            "distortion": c.has_distortion}


def _label_run(g: IsdGeometry, path: str) -> tuple[dict[str, float], CamInfo, list[Comparison], tuple[float, float] | None]:
    from mercury_dem.geometry.caminfo import compare_with_label, compute_caminfo, label_values, parse_pds3_label

    try:
        text = Path(path).read_text(errors="replace")
    except OSError as exc:
        raise IsdError(f"label {path}: cannot be read ({exc.strerror or exc})") from None
    raw = parse_pds3_label(text)
    lab = label_values(raw)
    if not any(k in lab for k in ("centre_lat", "slant_distance_m", "incidence_deg")):
        raise IsdError(f"label {path}: no geometry keywords (CENTER_LATITUDE, SLANT_DISTANCE, ...): not an MDIS PDS3 label?")
    ref = raw.get("RA_DEC_REF_PIXEL")
    centre = None
    if isinstance(ref, tuple) and len(ref) == 2 and all(isinstance(v, float) for v in ref):
        centre = (ref[0] - 1.0, ref[1] - 1.0)  # 1-based in the label (docs/design/isd-check.md)
        if not (-0.5 <= centre[0] <= g.camera.samples - 0.5 and -0.5 <= centre[1] <= g.camera.lines - 0.5):
            raise IsdError(f"label {path}: RA_DEC_REF_PIXEL {ref} is not a pixel of the "
                           f"{g.camera.samples}x{g.camera.lines} image")
    info = compute_caminfo(g.camera, g.position, g.rotation, g.sun_position,
                           radius_m=lab.get("radius_m", g.radius_m), j2000_to_body=g.j2000_to_body,
                           centre_pixel=centre)
    return lab, info, compare_with_label(info, lab), centre


def run(args: argparse.Namespace, config: Config) -> int:
    from mercury_dem.geometry.caminfo import compute_caminfo
    from mercury_dem.geometry.isd import read_isd

    try:
        g = read_isd(args.isd, require_sun=not args.no_sun)
    except IsdError as exc:
        if "sun_position" in str(exc):
            raise IsdError(f"{exc} (--no-sun goes on without incidence/phase)") from None
        raise
    radius = g.radius_m if args.radius_km is None else args.radius_km * 1000.0
    if not (math.isfinite(radius) and radius > 0):
        raise GeometryError(f"--radius-km must be a positive number, got {args.radius_km}")
    info = compute_caminfo(g.camera, g.position, g.rotation, g.sun_position, radius_m=radius,
                           j2000_to_body=g.j2000_to_body)
    lab = rows = centre = linfo = None
    if args.label:
        lab, linfo, rows, centre = _label_run(g, args.label)
    failed = [r.quantity for r in rows or [] if r.ok is False]

    if args.json:
        out: dict[str, Any] = {"isd": g.source, "flavour": g.flavour, "camera": _camera_dict(g),
                               "warnings": list(g.warnings), "caminfo": info.as_dict()}
        if rows is not None:
            out["label"] = {
                "file": args.label, "radius_m": lab.get("radius_m") if lab else None,
                "centre_pixel": list(centre) if centre else None,
                "caminfo": linfo.as_dict() if linfo else None,
                "comparison": [{k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                                for k, v in vars(r).items()} for r in rows],
                "all_ok": not failed,
            }
        print(json.dumps(out, indent=2))
        return 1 if failed else 0

    c = g.camera
    print(f"ISD {g.source} ({g.flavour} layout)")
    print(f"camera {c.name}: f = {c.focal_length_mm:.4f} mm, pixel {c.pixel_size_mm * 1000:.1f} um "
          f"(summing {c.summing}), {c.samples} x {c.lines}, boresight at sample {c.boresight_sample:.2f}, "
          f"line {c.boresight_line:.2f} (0-based), distortion {'yes' if c.has_distortion else 'no'}")
    for w in g.warnings:
        print(f"warning: {w}")
    print(f"ground points on a sphere of {radius / 1000:.3f} km; centre pixel ({info.centre_sample:.1f}, "
          f"{info.centre_line:.1f}); corners 0..3 = pixels (0,0), (last,0), (0,last), (last,last)")
    by_name = {r.quantity: r for r in rows or []}
    if rows is None:
        print(f"{'quantity':28s} {'ours':>16s}")
        for name, text, spec in _ROWS:
            print(f"{text:28s} {_fmt(_value(info, name), spec):>16s}")
        return 0
    assert lab is not None and linfo is not None
    print(f"label {args.label}: sphere {lab.get('radius_m', math.nan) / 1000:.3f} km, centre pixel "
          + (f"({centre[0]:.1f}, {centre[1]:.1f}) (RA_DEC_REF_PIXEL, 1-based)" if centre else "image centre"))
    head = f"{'quantity':28s} {'ours':>15s} {'ours@label':>15s} {'label':>15s} {'difference':>12s} {'tolerance':>10s}"
    print(head)
    for name, text, spec in _ROWS:
        r = by_name.get(name)
        ours = _fmt(_value(info, name), spec)
        if r is None:
            print(f"{text:28s} {ours:>15s} {_fmt(_value(linfo, name), spec):>15s} {'-':>15s}")
            continue
        diff = f"{r.difference * 100:+.3f} %" if r.kind == "rel" else f"{r.difference:+.5f}"
        tol = "-" if r.tolerance is None else (f"{r.tolerance * 100:g} %" if r.kind == "rel" else f"{r.tolerance:g}")
        flag = "" if r.ok is None else ("  ok" if r.ok else "  FAIL")
        print(f"{text:28s} {ours:>15s} {_fmt(r.ours, spec):>15s} {_fmt(r.label, spec):>15s} {diff:>12s} {tol:>10s}{flag}")
    checked = [r for r in rows if r.ok is not None]
    if failed:
        print(f"{len(failed)} of {len(checked)} checked quantities outside tolerance: {', '.join(failed)}")
        return 1
    print(f"all {len(checked)} checked quantities within tolerance (ours@label: same ISD pose on the label's sphere)")
    return 0
