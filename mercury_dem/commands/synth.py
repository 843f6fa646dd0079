"""``mercury-dem synth OUT --preset tiny|demo|large``: generate a synthetic mission."""

from __future__ import annotations

import argparse
import json
import sys

from mercury_dem.config import Config
from mercury_dem.config.base import from_dict, to_dict
from mercury_dem.config.synth import SynthConfig

NAME = "synth"
HELP = "generate a synthetic MESSENGER-like mission (images, catalog, truth) at OUT"
DESCRIPTION = (
    "Generate a synthetic Mercury mission: a procedural truth surface, MDIS NAC/WAC images rendered from "
    "the true poses, a catalog with SPICE-like a-priori pointing errors, and truth/ kept apart. "
    "Presets: tiny (tests, ~40 images of 256^2), demo (global, ~300 images of 512^2), large (1024^2, >10^4 images)."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("out", metavar="OUT", help="mission directory to create")
    p.add_argument("--preset", help="tiny, demo or large (default: tiny)")
    p.add_argument("--body", choices=("mercury", "moon"),
                   help="target body (default mercury): its datum sphere, IAU CRS and orbit constants; the "
                        "preset's area, cameras and pixel scales are kept (on the Moon its area holds fewer images)")
    p.add_argument("--seed", type=int, help="seed of the surface, the mission and the noise")
    p.add_argument("--pointing-sigma-urad", type=float, help="a-priori pointing error per axis (1 sigma), microradians")
    p.add_argument("--position-sigma-m", type=float, help="a-priori position error per axis (1 sigma), metres")
    p.add_argument("--render-grid-px", type=float,
                   help="renderer's surface-grid spacing in ground pixels (default: the preset's, 1); 0.5 draws "
                        "every view from a twice finer grid of the same surface (two views agree ~30 %% better on "
                        "km-scale pairs) at ~3.5x the render time")
    p.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    p.add_argument("--workers", type=int, default=1,
                   help="render on a local Dask cluster of this many processes (default 1: plain loop)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="render on a running Dask cluster (tcp://host:port); OUT must be on a file system the workers share")
    sel = p.add_mutually_exclusive_group()
    sel.add_argument("--limit", type=int, metavar="N",
                     help="generate only the first N images of the design (a PARTIAL mission, marked so in mission.json)")
    sel.add_argument("--images", metavar="A:B",
                     help="generate only images A..B-1 of the design (a PARTIAL mission, marked so in mission.json)")
    p.add_argument("--shape-harmonics", metavar="SHA_TAB",
                   help="opt-in: take the surface's long wavelengths from this PDS SHADR shape table (MLA's "
                        "GTMES_150V05_SHA.TAB) instead of the synthetic long-wave relief and polar depression")
    p.add_argument("--shape-lmax", type=int, default=148, metavar="L",
                   help="degree to which --shape-harmonics is expanded (default 148, GTMES's usable degree)")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")


def synth_config(args: argparse.Namespace) -> SynthConfig:
    """The generator's settings: its defaults overlaid by the flags (validated: errors name the key).

    The run configuration holds no generator settings (``mercury_dem.config.apriori``): the mission
    records the pointing sigma it injected, and a run may override it with ``apriori.pointing_sigma_urad``.
    """
    data = to_dict(SynthConfig())
    for flag, key in (("preset", "preset"), ("body", "body"), ("seed", "seed"), ("pointing_sigma_urad", "pointing_sigma_urad"),
                      ("position_sigma_m", "position_sigma_m"), ("render_grid_px", "render_grid_px")):
        v = getattr(args, flag)
        if v is not None:
            data[key] = v
    return from_dict(SynthConfig, data, prefix="synth.")


def run(args: argparse.Namespace, config: Config) -> int:
    from mercury_dem.io.location import UPLOAD_HINT, refuse_remote
    from mercury_dem.synth.generate import generate_mission

    refuse_remote(args.out, "mission", UPLOAD_HINT)
    cfg = synth_config(args)

    from mercury_dem.progress import Reporter, counter

    progress = counter(Reporter(None if args.quiet else sys.stderr), "synth: rendering", "images")
    design = None
    if args.shape_harmonics:
        from dataclasses import replace

        from mercury_dem.synth.presets import get_preset
        from mercury_dem.synth.terrain import with_shape_harmonics

        base = get_preset(cfg.preset)
        design = replace(base, surface=with_shape_harmonics(base.surface, args.shape_harmonics, args.shape_lmax))
    summary = generate_mission(
        args.out, cfg, tile_size_deg=config.tiling.tile_size_deg, overwrite=args.overwrite,
        workers=max(1, args.workers), progress=progress, scheduler=args.scheduler,
        images=args.images if args.images is not None else args.limit, design=design,
    )
    print(json.dumps(summary, indent=2))
    return 0


__all__ = ["NAME", "HELP", "add_arguments", "run"]
