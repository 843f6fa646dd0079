"""Cost of the blocked path's a-posteriori pointing sigmas on a stored network (docs/benchmarks/adjust.md).

Usage: blocked_posterior_cost.py STORE. All blocks in one process, the system at the a-priori state (the cost does
not depend on the state), sigma0 = 1; the selected inverse of the CHOLMOD factor (the column solves and block-Jacobi
bounds this script once compared are gone; bench_posterior.py measures the cost without a store).
"""
import sys
import time
import types

import numpy as np
from harness import peak_rss_bytes

from mercury_dem.adjust.blocked import (
    BlockShard,
    SyncEngine,
    blocked_posterior_sigmas,
    options_from_config,
    setup_from_config,
)
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.io.synthetic_network_store import BlockedNetwork, StoredBlocks

net = BlockedNetwork(sys.argv[1]); im = net.images
cfg = AdjustConfig()
setup = setup_from_config(im.cameras, im.image_camera, im.positions, im.rotations, cfg, float32=True, pointing_sigma_urad=450.0)
opt = options_from_config(cfg)
t = time.perf_counter()
eng = SyncEngine([BlockShard(StoredBlocks(str(net.root), tuple(range(net.n_blocks))), setup, opt)])
eng.call("initial_cost", np.zeros((setup.n_images, 3)))
print("loaded", round(time.perf_counter() - t, 1), "s", flush=True)
res = types.SimpleNamespace(omega=np.zeros((setup.n_images, 3)), sigma0=1.0)
for _ in range(1):
    p = blocked_posterior_sigmas(eng, setup, res)
    print(setup.n_images, "images", p.method, round(p.seconds, 1), "s, median sigma urad", round(float(np.median(p.image_sigmas)) * 1e6, 3),
          "peak GB", peak_rss_bytes() / 1e9, flush=True)
