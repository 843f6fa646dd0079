"""``mercury-dem ingest MISSION FILE...``: a mission from ISIS cubes with SPICE and/or images with CSM ISDs."""

from __future__ import annotations

import argparse
import json
import sys

from mercury_dem.config import Config

NAME = "ingest"
HELP = "build a mission from real images: ISIS cubes after spiceinit attach=true, or images beside CSM ISDs"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("mission", metavar="MISSION", help="mission directory to create")
    p.add_argument("files", metavar="FILE", nargs="+",
                   help="cubes (.cub), CSM ISDs (JSON, any extension) or images with an ISD of the same stem "
                        "(X.json, X.isd or X); globs allowed")
    p.add_argument("--isd-dir", metavar="DIR", help="where the ISDs of the given image files are")
    p.add_argument("--image-list", metavar="CSV",
                   help="ISD,IMAGE pairs (one a line) when an ISD's image does not share its file stem")
    p.add_argument("--min-scale-m", type=float, help="drop images with a finer pixel scale (seed 000: 75)")
    p.add_argument("--max-scale-m", type=float, help="drop images with a coarser pixel scale (seed 000: 800)")
    p.add_argument("--instrument", action="append", metavar="NAME",
                   help="keep only this instrument (e.g. MDIS-NAC); repeat for several")
    p.add_argument("--pointing-sigma-urad", type=float, metavar="URAD",
                   help="how wrong the a-priori pointing may be (1 sigma per axis): sizes the matcher's guidance "
                        "window and weights the adjustment's pointing constraint (without it, a run needs "
                        "apriori.pointing_sigma_urad in its configuration)")
    p.add_argument("--altimetry", nargs="+", metavar="CSV",
                   help="LOLA/MLA RDR shot tables (CSV) to keep with the mission (read against the mission's body)")
    p.add_argument("--altimetry-sigma-m", type=float, metavar="M",
                   help="1-sigma height uncertainty given to each shot (default 1 m: the laser's range precision)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing MISSION")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")


def run(args: argparse.Namespace, config: Config) -> int:
    from mercury_dem.io.location import UPLOAD_HINT, refuse_remote
    from mercury_dem.mission.ingest import describe, ingest_mission
    from mercury_dem.progress import Reporter, counter

    refuse_remote(args.mission, "mission", UPLOAD_HINT)
    summary = ingest_mission(
        args.mission, args.files, isd_dir=args.isd_dir, min_scale_m=args.min_scale_m, max_scale_m=args.max_scale_m,
        instruments=args.instrument, tile_size_deg=config.tiling.tile_size_deg, overwrite=args.overwrite,
        pointing_sigma_urad=args.pointing_sigma_urad, image_list=args.image_list,
        altimetry=args.altimetry, altimetry_sigma_m=args.altimetry_sigma_m,
        progress=counter(Reporter(sys.stderr), "ingest: reading", "files"),
    )
    if args.json:
        cat = summary.pop("catalog")
        summary["images_table"] = json.loads(cat.to_json(orient="records"))
        print(json.dumps(summary, indent=2))
    else:
        print(describe(summary))
    return 0
