"""Peak RSS of one shard of N blocks of a store adjusted in this process (SyncEngine): memory, not speed.

Usage: shard_peak.py STORE N_BLOCKS MAX_ITERATIONS [block|call|never] [recompute_w] (when the shard trims glibc's
heap, ``blocked.HEAP_TRIM``; default block; ``recompute_w``: W not kept, ``CameraSetup.recompute_w``). The store's other images have no measures here and are held
by the camera prior; the marginal bytes a measure between two N is the shard's growth (docs/benchmarks/adjust.md).
In one process the client's share (the rejection limit over all measures' norms) is in the same peak.
"""

import ctypes
import dataclasses
import sys
import time

from harness import peak_rss_bytes

from mercury_dem.adjust import blocked
from mercury_dem.adjust.blocked import (
    BlockShard,
    SyncEngine,
    blocked_levenberg_marquardt,
    options_from_config,
    setup_from_config,
)
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.io.synthetic_network_store import BlockedNetwork, StoredBlocks


def rss() -> int:
    """This process's peak resident bytes so far (``harness.peak_rss_bytes``)."""
    return peak_rss_bytes()


class Mallinfo2(ctypes.Structure):
    _fields_ = [(k, ctypes.c_size_t) for k in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks",
                                               "uordblks", "fordblks", "keepcost")]


def heap() -> str:
    """glibc's heap: bytes in use, free (in holes), mmapped (glibc >= 2.33)."""
    libc = ctypes.CDLL("libc.so.6")
    libc.mallinfo2.restype = Mallinfo2
    m = libc.mallinfo2()
    return f"heap in use {m.uordblks / 1e9:.3f} free {m.fordblks / 1e9:.3f} mmapped {m.hblkhd / 1e9:.3f} GB"


def current_rss() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096


def main() -> None:
    store, n, its = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    blocked.HEAP_TRIM = sys.argv[4] if len(sys.argv) > 4 else "block"
    net = BlockedNetwork(store)
    im = net.images
    cfg = dataclasses.replace(AdjustConfig(), max_iterations=its)
    setup = setup_from_config(im.cameras, im.image_camera, im.positions, im.rotations, cfg, float32=True, pointing_sigma_urad=450.0)
    setup = dataclasses.replace(setup, recompute_w="recompute_w" in sys.argv[5:])
    opt = options_from_config(cfg)
    r0, t = rss(), time.perf_counter()
    sh = BlockShard(StoredBlocks(str(store), tuple(range(n))), setup, opt)
    r1 = rss()
    res = blocked_levenberg_marquardt(SyncEngine([sh]), setup, opt)
    r2 = rss()
    m = sum(b.m for b in sh.blocks)
    print(f"blocks {n} measures {m} its {res.iterations} rejected {res.rejected} | peak GB: start {r0 / 1e9:.3f} "
          f"built {r1 / 1e9:.3f} adjusted {r2 / 1e9:.3f} | {time.perf_counter() - t:.0f} s | trim {blocked.HEAP_TRIM}, recompute_w {setup.recompute_w} | "
          f"now: rss {current_rss() / 1e9:.3f} GB, {heap()}", flush=True)


if __name__ == "__main__":
    main()
