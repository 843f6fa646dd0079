"""Bytes a measure the blocked adjustment keeps between iterations, array by array (docs/design/adjust.md, "Memory").

Usage::

    .venv/bin/python workflows/benchmarks/block_bytes.py [--float64] [--recompute-w] [--dir /tmp/block_bytes]

Writes (once) ``synth-network --measures 2e5 --seed 3 --block-points 10000``, adjusts it in process with the
benchmark configuration, then walks every numpy array reachable from the block states (a view counted once, by
its base) and prints the bytes a measure of each attribute and the total, and the pointing corrections' RMS.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path
from typing import Any

import numpy as np

from mercury_dem.adjust.blocked import (
    BlockShard,
    SyncEngine,
    blocked_levenberg_marquardt,
    options_from_config,
    setup_from_config,
)
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.io.synthetic_network_store import BlockedNetwork, StoredBlocks, write_synthetic_network
from mercury_dem.network.synthetic import SyntheticSpec


def arrays(obj: Any, path: str, seen: dict[int, tuple[str, int]], depth: int = 0) -> None:
    """Record (path, bytes) of every array base under ``obj`` in ``seen``."""
    if depth > 4:
        return
    if isinstance(obj, np.ndarray):
        base = obj
        while isinstance(base.base, np.ndarray):
            base = base.base
        seen.setdefault(id(base), (path, base.nbytes))
        return
    if isinstance(obj, (list, tuple)):
        for o in obj:
            arrays(o, path + "[]", seen, depth + 1)
        return
    for k, v in getattr(obj, "__dict__", {}).items():
        if k != "cameras":
            arrays(v, f"{path}.{k}", seen, depth + 1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--float64", action="store_true", help="adjust.blocked_float32: false")
    ap.add_argument("--recompute-w", action="store_true", help="adjust.blocked_recompute_w: true")
    ap.add_argument("--dir", default="/tmp/block_bytes")
    args = ap.parse_args()
    out = Path(args.dir) / "net"
    if not out.exists():
        write_synthetic_network(SyntheticSpec(200_000, seed=3, block_points=10_000), out)
    net = BlockedNetwork(out)
    cfg = AdjustConfig(blocked_float32=not args.float64,
                       blocked_recompute_w=args.recompute_w)
    im = net.images
    setup = setup_from_config(im.cameras, im.image_camera, im.positions, im.rotations, cfg, float32=cfg.blocked_float32, pointing_sigma_urad=450.0)
    opt = options_from_config(cfg)
    shard = BlockShard(StoredBlocks(str(net.root), tuple(range(net.n_blocks))), setup, opt)
    res = blocked_levenberg_marquardt(SyncEngine([shard]), setup, opt)
    print(f"iterations {res.iterations}, rejected {res.rejected}, pointing RMS {np.sqrt(np.mean(res.omega**2)):.12e} rad")
    seen: dict[int, tuple[str, int]] = {}
    for b in shard.blocks:
        arrays(b, "", seen)
    m = sum(b.m for b in shard.blocks)
    total: dict[str, int] = {}
    for path, nbytes in seen.values():
        key = re.sub(r"(\[\])+", "[]", path)
        total[key] = total.get(key, 0) + nbytes
    for k, v in sorted(total.items(), key=lambda kv: -kv[1]):
        if v / m >= 0.5:
            print(f"{k:36s} {v / m:7.1f} B/measure")
    print(f"TOTAL {sum(total.values()) / m:.1f} B/measure over {m} measures, {len(shard.blocks)} blocks")


if __name__ == "__main__":
    main()
