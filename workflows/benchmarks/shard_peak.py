"""Peak RSS of one shard of N blocks of a store adjusted in this process (SyncEngine): memory, not speed.

Usage: shard_peak.py STORE N_BLOCKS MAX_ITERATIONS. The store's other images have no measures here and are held
by the camera prior; the marginal bytes a measure between two N is the shard's growth (docs/benchmarks/adjust.md).
In one process the client's share (the rejection limit over all measures' norms) is in the same peak.
"""

import dataclasses
import resource
import sys
import time

from mercury_dem.adjust.blocked import (
    BlockShard,
    SyncEngine,
    blocked_levenberg_marquardt,
    options_from_config,
    setup_from_config,
)
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.network.synthetic_store import BlockedNetwork


def rss() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def main() -> None:
    store, n, its = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    net = BlockedNetwork(store)
    im = net.images
    cfg = dataclasses.replace(AdjustConfig(), pointing_sigma_deg=0.025783100780887047, max_iterations=its)
    setup = setup_from_config(im.cameras, im.image_camera, im.positions, im.rotations, cfg, float32=True)
    opt = options_from_config(cfg)
    r0, t = rss(), time.perf_counter()
    sh = BlockShard((store, list(range(n))), setup, opt)
    r1 = rss()
    res = blocked_levenberg_marquardt(SyncEngine([sh]), setup, opt)
    r2 = rss()
    m = sum(b.m for b in sh.blocks)
    print(f"blocks {n} measures {m} its {res.iterations} rejected {res.rejected} | peak GB: start {r0 / 1e9:.3f} "
          f"built {r1 / 1e9:.3f} adjusted {r2 / 1e9:.3f} | {time.perf_counter() - t:.0f} s", flush=True)


if __name__ == "__main__":
    main()
