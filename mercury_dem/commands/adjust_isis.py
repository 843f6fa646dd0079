"""``mercury-dem adjust-isis NET.net --cameras FILE... [--serials CSV] --out OUT.net [--json]``."""

from __future__ import annotations

import argparse
import json

from mercury_dem.config import Config

NAME = "adjust-isis"
HELP = "bundle adjust an ISIS3 control network (.net) with its images' cubes or ISDs, as ISIS jigsaw does"
DESCRIPTION = (
    "Adjust an existing ISIS3 control network (version 2 or 5) with the cameras of its images: ISIS cubes with "
    "SPICE attached (spiceinit attach=true) and/or CSM frame ISDs; only their geometry is read. Network serial "
    "numbers are matched to the cameras' ISIS serial numbers, to a --serials CSV (file,serial), or to the "
    "cameras' image ids (file stems, as export-isis writes them). Writes OUT.net (ISIS v5, adjusted points, "
    "residuals, jigsawRejected flags), OUT_bundleout.txt and corrected ISDs in OUT_isds/. The adjustment "
    "settings are the 'adjust' section of --config."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("net", metavar="NET.net", help="ISIS3 binary control network")
    p.add_argument("--cameras", nargs="+", required=True, metavar="FILE",
                   help="cubes with SPICE attached (.cub) and/or CSM frame ISDs of the network's images "
                        "(recognised by content: .json, .isd or any extension)")
    p.add_argument("--serials", metavar="CSV", help="'file,serial' lines: the ISIS serial number of a camera file")
    p.add_argument("--out", required=True, metavar="OUT.net", help="adjusted network to write (ISIS v5)")
    p.add_argument("--require-all", action="store_true",
                   help="fail when a serial number of the network has no camera (default: report and ignore its measures)")
    p.add_argument("--no-isds", action="store_true", help="do not write corrected ISDs")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")


def run(args: argparse.Namespace, config: Config) -> int:
    from mercury_dem.config.apriori import missionless_pointing_sigma_urad
    from mercury_dem.pipeline.adjust_isis import describe, run_adjust_isis

    # no mission here: apriori.pointing_sigma_urad when set, else the mission-less default (0.2 deg)
    summary = run_adjust_isis(args.net, args.cameras, args.out, config.adjust,
                              pointing_sigma_urad=missionless_pointing_sigma_urad(config.apriori.pointing_sigma_urad),
                              serials_csv=args.serials,
                              require_all=args.require_all, write_isds=not args.no_isds)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(describe(summary))
    return 0
