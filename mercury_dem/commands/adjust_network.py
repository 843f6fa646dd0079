"""``mercury-dem adjust-network STORE``: the blocked bundle adjustment of a stored network, in this process or on Dask.

See :mod:`mercury_dem.adjust.blocked` (the loop) and :mod:`mercury_dem.pipeline.network_adjust`
(the runner). ``--sync`` runs in this process; ``--workers N`` on a LocalCluster of N
single-threaded workers (default 2); ``--scheduler ADDR`` on an existing cluster whose
workers see STORE.
"""

from __future__ import annotations

import argparse
import json

from mercury_dem.config import Config

NAME = "adjust-network"
HELP = "bundle-adjust a stored network by point blocks (in process, LocalCluster or a Dask scheduler)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("store", metavar="STORE", help="a synth-network OUT directory (or its network group)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--sync", action="store_true", help="run in this process")
    where.add_argument("--workers", type=int, metavar="N", help="LocalCluster of N single-threaded workers (default 2)")
    where.add_argument("--scheduler", metavar="ADDR", help="an existing Dask scheduler, e.g. tcp://host:8786")
    p.add_argument("--max-iterations", type=int, default=None, help="iteration limit (default: adjust.max_iterations)")
    p.add_argument("--json", action="store_true", help="print a JSON record")


def run(args: argparse.Namespace, config: Config) -> int:
    import dataclasses

    import numpy as np

    from mercury_dem.config.apriori import missionless_pointing_sigma_urad
    from mercury_dem.pipeline.network_adjust import adjust_blocked_store

    # no mission here: apriori.pointing_sigma_urad when set, else the mission-less default (0.2 deg)
    sigma_urad = missionless_pointing_sigma_urad(config.apriori.pointing_sigma_urad)
    cfg = config.adjust
    if args.max_iterations:
        cfg = dataclasses.replace(cfg, max_iterations=args.max_iterations)
    if args.sync:
        record = adjust_blocked_store(args.store, cfg, pointing_sigma_urad=sigma_urad)
    else:
        from mercury_dem.compute import open_client

        # distributed's nannies set MALLOC_TRIM_THRESHOLD_=65536, which also turns off glibc's dynamic mmap
        # threshold: every temporary array > 128 kB is then mmapped, faulted in and unmapped again. The blocks'
        # linearization and Schur sums are made of such temporaries and ran 1.4-1.8x slower on the workers
        # than in process (measured on a 4e5-measure store, 2 workers, 4 alternating runs); without it, as fast.
        with open_client(args.workers or 2, args.scheduler, host=config.execution.host,
                         nanny_environ={"MALLOC_TRIM_THRESHOLD_": None}) as client:
            record = adjust_blocked_store(args.store, cfg, client, pointing_sigma_urad=sigma_urad)
    if args.json:
        print(json.dumps(record, indent=2, default=float))
        return 0
    print(f"{record['store']}: {record['images']} images, {record['points']} points, {record['measures']} measures "
          f"in {record['blocks']} blocks ({record['engine']})")
    print(f"iterations {record['iterations']} ({record['reason']}), {record['seconds']:.1f} s "
          f"(median {np.median(record['seconds_per_iteration']):.2f} s per iteration), {record['linear_method']}")
    print(f"sigma0 {record['sigma0']:.4f}, RMS {record['rms_px']:.3f} px, {record['rejected']} measures rejected, "
          f"peak memory {record['peak_memory_bytes'] / 1e9:.2f} GB (largest process)")
    t = record.get("truth")
    if t:
        print(f"truth: pointing {t['pointing_error_px_rms']:.3f} px RMS (a priori {t['apriori_pointing_error_px_rms']:.2f}), "
              f"{100 * t['outliers_rejected_share']:.2f} % of {t['outliers']} outliers rejected, "
              f"{100 * t['good_rejected_share']:.2f} % of good measures; point error median {t['point_error_m_median']:.0f} m")
    return 0
