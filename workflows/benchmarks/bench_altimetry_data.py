"""Simulated altimetry and its store: generation time, size, and a per-tile read beside a whole read.

For the ``tiny`` and ``demo`` presets (seed 42): the truth surface is built, the design's MLA profiles
simulated and written as the mission's altimetry store (``write_simulated_altimetry``, the code path of
``mercury-dem synth``); then the densest tile is read alone (``read_tile``: its row group only) and the
whole store is read, in the same run. Printed: shots, profiles, seconds, Parquet size, read times, shots
per 30-degree latitude band.

Run: ``flock /tmp/mercury_bench.lock /usr/bin/time -v .venv/bin/python workflows/benchmarks/bench_altimetry_data.py``
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from mercury_dem.altimetry.store import open_altimetry
from mercury_dem.geometry.body import MERCURY
from mercury_dem.mission.store import MissionWriter
from mercury_dem.synth.generate import write_simulated_altimetry
from mercury_dem.synth.parallel import cached_surface
from mercury_dem.synth.presets import get_preset


def bench(preset: str, seed: int) -> None:
    design = get_preset(preset)
    t = time.perf_counter()
    surface = cached_surface(replace(design.surface, seed=seed).to_dict(), MERCURY.datum_radius_m)
    surface.height(np.array([0.0]), np.array([0.0]))  # compile
    t_surface = time.perf_counter() - t
    root = Path(tempfile.mkdtemp(prefix=f"bench_alt_{preset}_"))
    try:
        (root / "truth").mkdir()
        writer = MissionWriter(root)
        out = write_simulated_altimetry(writer, root, design, surface, MERCURY, seed, 10.0)
        store = open_altimetry(root / "altimetry")
        dense = max(store.tiles, key=store.tiles.get)
        t = time.perf_counter()
        one = store.read_tile(dense)
        t_tile = time.perf_counter() - t
        t = time.perf_counter()
        every = store.read()
        t_all = time.perf_counter() - t
        bands = (every["lat"] // 30 * 30).astype(int).value_counts().sort_index().to_dict()
        print(f"{preset}: surface {t_surface:.1f} s; simulate + screen + write {out['seconds']:.1f} s: "
              f"{out['n_shots']} shots kept of {out['n_simulated']}, {out['n_profiles']} profiles, "
              f"{len(store.tiles)} tiles, dropped {out['dropped']['flagged']} flagged; "
              f"shots.parquet {os.path.getsize(store.file) / 1e6:.1f} MB")
        print(f"  read densest tile {dense} ({len(one)} shots) {t_tile:.3f} s; read all ({len(every)}) {t_all:.2f} s; "
              f"shots per 30-deg band {bands}")
    finally:
        shutil.rmtree(root, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", nargs="+", default=["tiny", "demo"])
    ap.add_argument("--seed", type=int, default=42)
    args = ap.parse_args()
    for p in args.presets:
        bench(p, args.seed)


if __name__ == "__main__":
    main()
