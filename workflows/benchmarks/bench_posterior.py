"""Cost of the blocked adjustment's exact a-posteriori covariances at size (issue #33 item 2; docs/benchmarks.md).

Usage::

    flock /tmp/mercury_bench.lock env PYTHONPATH=$PWD .venv/bin/python -u workflows/benchmarks/bench_posterior.py \
        --measures 1e6 3e6 1e7 [--dir /tmp/bench_posterior] [--keep] --json

For each size: (1) the reduced camera system of the synthetic network of that many measures
(:mod:`mercury_dem.network.synthetic`, seed 0, the reference's statistics: ~940 measures an image), built block by
block (each block generated, linearized and reduced by a one-block :class:`BlockShard`, its partial sums added, the
block dropped: memory bounded by one block and the camera system), at the a-priori state, saved to ``--dir``;
(2) in a fresh subprocess, so its peak RSS is the posterior's own: the saved sums replayed to
:func:`mercury_dem.adjust.blocked.blocked_posterior_sigmas` (the code a run calls: assembly of ``S``, CHOLMOD
factor, selected inverse, covariances; sigma0 = 1). Agreement: against the dense inverse of ``S`` up to
``--dense-max`` unknowns, and at every size against CHOLMOD column solves of ``--check`` random images (exact too,
an independent route). One JSON line per size, then the time and memory exponents between successive sizes.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from harness import peak_rss_bytes

C = 3


def part_path(path: Path, k: int, parts: int) -> Path:
    """Where part k of parts of a system is saved (the system itself when parts == 1)."""
    return path if parts == 1 else path.with_name(f"{path.stem}.part{k}of{parts}.npz")


def build_system(n_measures: float, path: Path, seed: int, k: int = 0, parts: int = 1) -> dict[str, Any]:
    """Stage 1: the reduced system's partial sums (U per image, S pair blocks) of the synthetic network, saved
    (its ``k``-th of ``parts`` runs of blocks only, when ``parts`` > 1: see :func:`merge_parts`).
    """
    from scipy.spatial import cKDTree

    from mercury_dem.adjust.blocked import BlockShard, merge_partials, options_from_config, setup_from_config
    from mercury_dem.config.adjust import AdjustConfig
    from mercury_dem.network.blocks import BlockData
    from mercury_dem.network.synthetic import SyntheticSpec, make_images, point_block

    t0 = time.perf_counter()
    spec = SyntheticSpec(n_measures=int(n_measures), seed=seed)
    images = make_images(spec)
    cfg = AdjustConfig()
    setup = setup_from_config(images.cameras, images.image_camera, images.positions, images.rotations, cfg, float32=True, pointing_sigma_urad=450.0)
    opt = options_from_config(cfg)
    tree = cKDTree(images.target_unit)
    omega = np.zeros((images.n_images, 3))
    lin = red = None
    m = n_pt = 0
    for b in np.array_split(np.arange(spec.n_blocks), parts)[k]:
        pb = point_block(spec, images, int(b), tree)
        if pb.n_measures == 0:
            continue
        data = BlockData(int(b), 0, pb.apriori_points, pb.measure_image, pb.measure_point, pb.measures,
                         np.ones(pb.n_measures), np.zeros(pb.n_points, bool), None, None)
        shard = BlockShard([data], setup, opt)
        del pb, data
        pl, pr = shard.partial("linearize", omega), shard.partial("reduce", 0.0)
        m += shard.structure()[2]
        n_pt += shard.structure()[3]
        del shard
        lin = pl if lin is None else merge_partials(lin, pl)
        red = pr if red is None else merge_partials(red, pr)
    assert lin is not None and red is not None
    (cams, u), _ = lin.terms
    (keys, s), _ = red.terms
    np.savez(part_path(path, k, parts), n_images=images.n_images, cams=cams, u=u, keys=keys, s=s, measures=m,
             points=n_pt, n_prior=lin.counts[0])
    return {"images": int(images.n_images), "measures": int(m), "points": int(n_pt), "pair_blocks": int(len(keys)),
            "build_seconds": round(time.perf_counter() - t0, 1),
            "build_peak_rss_gb": round(peak_rss_bytes() / 1e9, 3)}


def merge_parts(path: Path, parts: int) -> None:
    """The system of all ``parts`` (each a run of blocks, built by its own ``--part k/K`` call) saved to ``path``."""
    from mercury_dem.adjust.blocked import Partial, merge_partials

    lin = red = None
    tot: dict[str, int] = {"measures": 0, "points": 0, "n_prior": 0}
    for k in range(parts):
        z = np.load(part_path(path, k, parts))
        n_images = int(z["n_images"])
        pl = Partial(((z["cams"], z["u"]),), ())
        pr = Partial(((z["keys"], z["s"]),), ())
        lin = pl if lin is None else merge_partials(lin, pl)
        red = pr if red is None else merge_partials(red, pr)
        for key in tot:
            tot[key] += int(z[key])
    assert lin is not None and red is not None
    np.savez(path, n_images=n_images, cams=lin.terms[0][0], u=lin.terms[0][1], keys=red.terms[0][0],
             s=red.terms[0][1], **tot)


class ReplayEngine:
    """The saved sums as the one shard of an :class:`~mercury_dem.adjust.blocked.Engine` (what the shards return)."""

    def __init__(self, z: Any):
        self.cams, self.u, self.keys, self.s = z["cams"], z["u"], z["keys"], z["s"]
        self.m, self.n_pt, self.n_prior = int(z["measures"]), int(z["points"]), int(z["n_prior"])

    def call(self, method: str, *args: Any) -> list[Any]:
        assert method == "structure"
        return [(self.cams, self.keys, self.m, self.n_pt)]

    def summed(self, method: str, *args: Any) -> list[Any]:
        from mercury_dem.adjust.blocked import Partial

        if method == "linearize":
            return [Partial(((self.cams, self.u), (self.cams, np.zeros((len(self.cams), C)))), (self.n_prior,))]
        assert method == "reduce" and args[0] == 0.0
        return [Partial(((self.keys, self.s), (self.cams, np.zeros((len(self.cams), C)))), ())]


def posterior(path: Path, dense_max: int, n_check: int, seed: int) -> dict[str, Any]:
    """Stage 2 (its own process): the posterior from the saved sums, its time, peak RSS and agreement."""
    import types

    from mercury_dem.adjust.blocked import CameraSetup, GlobalStructure, blocked_posterior_sigmas
    from mercury_dem.adjust.framing import inverse_left_jacobian
    from mercury_dem.adjust.kernels import prior_blocks
    from mercury_dem.adjust.schur import _cholmod

    z = np.load(path)
    n_img = int(z["n_images"])
    eng = ReplayEngine(z)
    setup = CameraSetup((), np.zeros(n_img, np.int64), np.zeros((n_img, 3)), np.zeros((n_img, 3, 3)),
                        np.zeros(n_img, bool), 450e-6, (None, None, None))
    res: Any = types.SimpleNamespace(omega=np.zeros((n_img, 3)), sigma0=1.0)
    # compile (or load from numba's cache) the kernels first: their first call is not the posterior's cost
    import scipy.sparse as sp

    from mercury_dem.adjust.posterior import selected_inverse

    selected_inverse(sp.csc_matrix(np.eye(30) + 0.1), supernodal=True).blocks(np.arange(10), np.arange(10), 3)
    rss0 = peak_rss_bytes() / 1e9
    t = time.perf_counter()
    post = blocked_posterior_sigmas(eng, setup, res)
    seconds = time.perf_counter() - t
    peak = peak_rss_bytes() / 1e9
    assert post.image_covariances is not None
    out: dict[str, Any] = {
        "images": n_img, "unknowns": C * n_img, "measures": eng.m, "method": post.method,
        "factor_nnz": post.factor_nnz, "seconds": round(seconds, 2), "factor_seconds": round(post.factor_seconds, 2),
        "recurrence_seconds": round(post.recurrence_seconds, 2), "peak_rss_gb": round(peak, 3),
        "rss_before_gb": round(rss0, 3), "median_sigma_urad": round(float(np.median(post.image_sigmas)) * 1e6, 4),
    }
    # the same S again (as blocked_posterior_sigmas assembles it) for the independent checks
    glob = GlobalStructure(np.unique(eng.keys), n_img)
    u = np.zeros((n_img, C, C))
    u[eng.cams] += eng.u
    prior_blocks(res.omega / 450e-6, inverse_left_jacobian(res.omega) / 450e-6, u, np.zeros((n_img, C)))
    blocks = np.zeros((len(glob.keys), C, C))
    blocks[np.searchsorted(glob.keys, eng.keys)] += eng.s
    blocks[glob.diag_block] += u
    mat = glob.to_bsr(blocks).tocsc()
    cov = post.image_covariances

    def worst(ref: np.ndarray, got: np.ndarray) -> float:
        d = np.sqrt(np.diagonal(ref, axis1=1, axis2=2))
        return float(np.max(np.abs(got - ref) / (d[:, :, None] * d[:, None, :])))

    if C * n_img <= dense_max:
        inv = np.linalg.inv(mat.toarray()).reshape(n_img, C, n_img, C)
        idx = np.arange(n_img)
        out["dense_agreement"] = worst(inv[idx, :, idx, :], cov)
    if _cholmod is not None and n_check:
        pick = np.sort(np.random.default_rng(seed).choice(n_img, min(n_check, n_img), replace=False))
        factor = _cholmod.cholesky(mat, mode="supernodal")
        rhs = np.zeros((C * n_img, C * len(pick)))
        cols = (pick[:, None] * C + np.arange(C)).ravel()
        rhs[cols, np.arange(len(cols))] = 1.0
        x = factor(rhs)[cols].reshape(len(pick), C, len(pick), C)
        k = np.arange(len(pick))
        out["column_solve_agreement"] = worst(x[k, :, k, :], cov[pick])
        out["checked_images"] = int(len(pick))
    return out


def main() -> None:
    """Run the stages per size in subprocesses and print the JSON lines and exponents."""
    ap = argparse.ArgumentParser()
    ap.add_argument("--measures", nargs="+", type=float, default=[1e6])
    ap.add_argument("--dir", default="/tmp/bench_posterior")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep", action="store_true", help="reuse saved systems and keep them")
    ap.add_argument("--dense-max", type=int, default=6000, help="dense-inverse check up to this many unknowns")
    ap.add_argument("--check", type=int, default=64, help="images checked by column solves at every size")
    ap.add_argument("--json", action="store_true", help="JSON lines (the default output too)")
    ap.add_argument("--part", help="K/N: only build the K-th of N runs of blocks of the (one) size and save them; "
                    "a later call without --part merges the N parts (each part its own short hold of the lock)")
    ap.add_argument("--stage", choices=["build", "posterior"], help=argparse.SUPPRESS)
    ap.add_argument("--path", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.stage == "build":
        print(json.dumps(build_system(args.measures[0], Path(args.path), args.seed)))
        return
    if args.stage == "posterior":
        print(json.dumps(posterior(Path(args.path), args.dense_max, args.check, args.seed)))
        return
    root = Path(args.dir)
    root.mkdir(parents=True, exist_ok=True)
    if args.part:
        k, parts = (int(x) for x in args.part.split("/"))
        print(json.dumps(build_system(args.measures[0], root / f"system_{args.measures[0]:.3g}.npz", args.seed, k,
                                      parts)))
        return
    rows = []
    for n in args.measures:
        path = root / f"system_{n:.3g}.npz"
        rec: dict[str, Any] = {}
        parts = sorted(root.glob(f"system_{n:.3g}.part*of*.npz"))
        if parts and not path.exists():
            count = int(parts[0].stem.split("of")[-1])
            if len(parts) == count:
                merge_parts(path, count)
        if not (args.keep and path.exists()):
            t = time.perf_counter()
            out = subprocess.run([sys.executable, __file__, "--stage", "build", "--measures", str(n), "--path", str(path),
                                  "--seed", str(args.seed)], check=True, capture_output=True, text=True)
            rec["build"] = json.loads(out.stdout.strip().splitlines()[-1])
            rec["build"]["wall_seconds"] = round(time.perf_counter() - t, 1)
        out = subprocess.run([sys.executable, __file__, "--stage", "posterior", "--path", str(path), "--seed",
                              str(args.seed), "--dense-max", str(args.dense_max), "--check", str(args.check)],
                             check=True, capture_output=True, text=True)
        rec.update(json.loads(out.stdout.strip().splitlines()[-1]))
        print(json.dumps(rec), flush=True)
        rows.append(rec)
        if not args.keep:
            path.unlink(missing_ok=True)
    for a, b in zip(rows, rows[1:]):
        k = math.log(b["unknowns"] / a["unknowns"])
        km = math.log(b["measures"] / a["measures"])
        print(json.dumps({"from_measures": a["measures"], "to_measures": b["measures"],
                          "time_exponent_vs_unknowns": round(math.log(b["seconds"] / a["seconds"]) / k, 3),
                          "time_exponent_vs_measures": round(math.log(b["seconds"] / a["seconds"]) / km, 3),
                          "factor_nnz_exponent_vs_unknowns": round(math.log(b["factor_nnz"] / a["factor_nnz"]) / k, 3),
                          "peak_rss_exponent_vs_unknowns": round(math.log(b["peak_rss_gb"] / a["peak_rss_gb"]) / k, 3)}),
              flush=True)


if __name__ == "__main__":
    main()
