"""``mercury-dem info MISSION [--json]``: summarise a mission and write its coverage map."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from mercury_dem.config import Config

NAME = "info"
HELP = "summarise a mission (images by instrument, scales, angles, images per tile, coverage) and map its coverage"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("mission", metavar="MISSION", help="mission directory (from 'mercury-dem synth' or 'mercury-dem ingest')")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--coverage-map", metavar="PNG",
                   help="where to write the coverage map (default: MISSION_coverage.png beside the mission)")
    p.add_argument("--no-map", action="store_true",
                   help="do not write the coverage map (skips matplotlib: the summary alone, about twice as fast)")
    p.add_argument("--step-deg", type=float, help="grid step of the coverage count (default from the mission size)")
    p.add_argument("--radius-km", type=float,
                   help="sphere the per-image statistics (--json) are evaluated on (default: the body's datum; "
                        "e.g. 2440 to compare with an ISIS cube's CameraStatistics made on that sphere)")
    p.add_argument("--pixel-step", type=int, default=1,
                   help="evaluate the per-image statistics at every N-th pixel (default 1: all, as camstats)")


def run(args: argparse.Namespace, config: Config) -> int:
    from mercury_dem.mission import open_mission
    from mercury_dem.mission.summary import coverage_map, image_statistics, mission_summary

    mission = open_mission(args.mission)
    summary, cov = mission_summary(mission, args.step_deg)
    png = None
    if not args.no_map:
        png = Path(args.coverage_map) if args.coverage_map else mission.path.parent / f"{mission.path.name}_coverage.png"
        coverage_map(cov, png, title=f"{mission.path.name}: {summary['images']} images")
    summary["coverage_map"] = str(png) if png else None
    if args.json:
        radius = None if args.radius_km is None else args.radius_km * 1000.0
        summary["image_statistics"] = image_statistics(mission, radius, max(1, args.pixel_step))
        print(json.dumps(summary, indent=2))
        return 0
    c = summary["coverage"]
    per_tile = summary["images_per_tile"]
    lines = [
        f"mission      {summary['mission']} ({summary['body']['name'].title()}, "
        + (f"preset {summary['preset']}" if summary['preset'] else f"source {summary['source']}")
        + f", truth: {'yes' if summary['has_truth'] else 'no'})",
        f"images       {summary['images']}  " + ", ".join(f"{k}: {v}" for k, v in summary["images_by_instrument"].items())
        + f"  size {', '.join(summary['image_size'])}",
        f"pixel scale  {summary['pixel_scale_m'][0]:.0f} - {summary['pixel_scale_m'][1]:.0f} m/pixel",
        f"incidence    {summary['incidence_deg'][0]:.1f} - {summary['incidence_deg'][1]:.1f} deg;  "
        f"emission {summary['emission_deg'][0]:.1f} - {summary['emission_deg'][1]:.1f} deg",
        f"tiles        {summary['tiles_with_images']} with images; images per tile min {per_tile['min']}, "
        f"median {per_tile['median']:.0f}, max {per_tile['max']}",
        f"coverage     seen {100 * c['fraction_seen']:.1f} %, >=3 images {100 * c['fraction_seen_3x']:.1f} %, "
        f">=3 images with >=5 deg convergence {100 * c['fraction_stereo_3x_5deg']:.1f} % "
        f"(grid {c['grid_step_deg']} deg over {'the area ' + str(c['area_deg']) if c['area_deg'] else 'the whole body'})",
    ]
    if png:
        lines.append(f"coverage map {png}")
    alt = summary.get("altimetry")
    if alt:
        drops = ", ".join(f"{k} {v}" for k, v in alt["dropped"].items() if v) or "none"
        lines.append(f"altimetry    {alt['n_shots']} shots in {alt['n_profiles']} profiles over {alt['n_tiles']} tiles "
                     f"({alt['tile_size_deg']:g} deg); dropped: {drops}")
    if summary.get("partial"):
        lines.insert(1, f"PARTIAL      {summary['partial'].get('note', 'a subset of the design')}")
    print("\n".join(lines))
    return 0
