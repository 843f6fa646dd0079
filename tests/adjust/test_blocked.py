"""The blocked bundle adjustment (issue #17): the in-memory adjuster's results, by point blocks, in process and on Dask."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mercury_dem.adjust.blocked import (
    BlockShard,
    Partial,
    SyncEngine,
    blocked_levenberg_marquardt,
    blocked_posterior_sigmas,
    blocks_from_problem,
    merge_partials,
    options_from_config,
    setup_from_config,
    tree_rounds,
)
from mercury_dem.adjust.bundle import bundle_adjust
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.io.synthetic_network_store import BlockedNetwork, StoredBlocks, write_synthetic_network
from mercury_dem.network.synthetic import SyntheticSpec
from mercury_dem.validate.synthetic_network import make_synthetic_network

CFG = AdjustConfig()


def _assemble(shards: list[BlockShard], n_points: int, n_measures_per_block: list[int]) -> tuple[np.ndarray, list[np.ndarray]]:
    pts = np.full((n_points, 3), np.nan)
    accepted = []
    for s in shards:
        for _, p0, x, a, _f in s.solution():
            pts[p0:p0 + len(x)] = x
            accepted.append(a)
    return pts, accepted


@pytest.mark.parametrize("n_blocks,n_shards", [(1, 1), (7, 3)])
def test_blocked_equals_the_in_memory_adjuster(n_blocks: int, n_shards: int) -> None:
    """Same iterations, rejected set, pointing and points as bundle_adjust (seed 31, not used for tuning)."""
    net = make_synthetic_network(10_000, rng=np.random.default_rng(31), min_views=3)
    p = net.problem
    ref = bundle_adjust(p, CFG)
    setup = setup_from_config(p.cameras, p.image_camera, p.positions, p.rotations, CFG, pointing_sigma_urad=450.0)
    opt = options_from_config(CFG, float(np.median(p.measure_sigma)))
    blocks = blocks_from_problem(p, n_blocks)
    shards = [BlockShard([blocks[i] for i in g], setup, opt) for g in np.array_split(np.arange(n_blocks), n_shards)]
    res = blocked_levenberg_marquardt(SyncEngine(shards), setup, opt)
    assert res.iterations == ref.iterations and res.converged and ref.converged
    assert res.rejected == int(ref.rejected.sum()) > 0
    # solver tolerance: the sums run in another order, nothing else differs
    assert np.abs(res.omega - ref.pointing_corrections).max() < 1e-10  # rad (the pointing errors are ~5e-4)
    pts, accepted = _assemble(shards, p.n_points, [])
    assert np.abs(pts - ref.points).max() < 1e-4  # m
    order = np.argsort(p.measure_point, kind="stable")
    assert np.array_equal(np.concatenate(accepted), ~ref.rejected[order])
    assert res.final_cost == pytest.approx(ref.log[-1]["cost"], rel=1e-10)


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("bigadj") / "syn"
    write_synthetic_network(SyntheticSpec(15_000, seed=23, measures_per_image=100, block_points=400), out)
    return out


@pytest.mark.integration  # the whole adjust-network command on a synthetic store
def test_adjust_network_sync_recovers_the_truth(store: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Through the command: pointing from ~11 px a priori to below 1 px, the gross outliers rejected."""
    from mercury_dem.cli import main

    assert main(["adjust-network", str(store), "--sync", "--json", "--progress", "none"]) == 0
    rec = json.loads(capsys.readouterr().out)
    bn = BlockedNetwork(store)
    assert (rec["measures"], rec["points"], rec["images"]) == (bn.n_measures, bn.n_points, bn.n_images)
    assert rec["converged"] and rec["iterations"] == len(rec["seconds_per_iteration"]) and rec["peak_memory_bytes"] > 0
    t = rec["truth"]
    assert t["apriori_pointing_error_px_rms"] > 8.0
    # 0.25 px noise, ~100 measures per image: boresight errors of a few tenths of a pixel (docs/design/adjust.md)
    assert t["pointing_error_px_rms_images_ge30"] < 0.8
    assert t["outliers_rejected_share"] >= 0.97 and t["good_rejected_share"] < 0.015
    assert 0.2 < rec["rms_px"] < 0.3  # 0.25 px noise, 0.19-0.22 px after the fit's own share


@pytest.mark.integration
def test_localcluster_equals_sync(store: Path) -> None:
    """Two Dask workers, each keeping its blocks as an actor: the same solution as in process."""
    from distributed import Client, LocalCluster

    from mercury_dem.pipeline.shard_engine import DaskShardEngine

    bn = BlockedNetwork(store)
    im = bn.images
    setup = setup_from_config(im.cameras, im.image_camera, im.positions, im.rotations, CFG, pointing_sigma_urad=450.0)
    opt = options_from_config(CFG)
    shard = BlockShard(StoredBlocks(str(store), tuple(range(bn.n_blocks))), setup, opt)
    sync = blocked_levenberg_marquardt(SyncEngine([shard]), setup, opt)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=":0") as cl, \
            Client(cl) as client:
        engine = DaskShardEngine(client, str(store), bn.n_blocks, setup, opt)
        assert len(engine.actors) == 2
        dist = blocked_levenberg_marquardt(engine, setup, opt)
        got = {b: (x, a) for part in engine.call("solution") for b, _, x, a, _ in part}
        post = blocked_posterior_sigmas(engine, setup, dist, points=True)  # the points' sigmas on the workers
    assert dist.iterations == sync.iterations and dist.rejected == sync.rejected
    assert np.abs(dist.omega - sync.omega).max() < 1e-12
    for b, _, x, a, _ in shard.solution():
        assert np.abs(got[b][0] - x).max() < 1e-6 and np.array_equal(got[b][1], a)
    ref = blocked_posterior_sigmas(SyncEngine([shard]), setup, sync, points=True)
    assert np.abs(post.image_covariances - ref.image_covariances).max() < 1e-6 * ref.image_covariances.max()
    pts, pts_ref = dict(post.point_sigmas), dict(ref.point_sigmas)
    assert pts.keys() == pts_ref.keys()
    for b, sig in pts_ref.items():
        assert np.all(sig >= 0) and np.allclose(pts[b], sig, rtol=1e-6, atol=0)


@pytest.mark.integration
def test_localcluster_tree_sum_equals_sync(store: Path) -> None:
    """Five Dask workers, the sums merged on the workers (a tree of 3 rounds): the in-process solution."""
    from distributed import Client, LocalCluster

    from mercury_dem.pipeline.shard_engine import DaskShardEngine

    bn = BlockedNetwork(store)
    im = bn.images
    setup = setup_from_config(im.cameras, im.image_camera, im.positions, im.rotations, CFG, pointing_sigma_urad=450.0)
    opt = options_from_config(CFG)
    sync = blocked_levenberg_marquardt(SyncEngine([BlockShard(StoredBlocks(str(store), tuple(range(bn.n_blocks))), setup, opt)]),
                                       setup, opt)
    with LocalCluster(n_workers=5, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=":0") as cl, \
            Client(cl) as client:
        engine = DaskShardEngine(client, str(store), bn.n_blocks, setup, opt, tree_min_workers=2)
        assert len(engine.actors) == 5
        parts = engine.summed("linearize", np.zeros((setup.n_images, 3)))
        assert len(parts) == 1  # merged on the workers: the client received one partial
        dist = blocked_levenberg_marquardt(engine, setup, opt)
    assert dist.iterations == sync.iterations and dist.rejected == sync.rejected
    assert np.abs(dist.omega - sync.omega).max() < 1e-12


@pytest.mark.parametrize("n", [1, 2, 3, 5, 8, 13])
def test_tree_rounds_merge_every_shard_once_into_the_first(n: int) -> None:
    holds = {i: {i} for i in range(n)}
    for merges in tree_rounds(n):
        absorbed = [j for _, j in merges]
        assert len(set(absorbed)) == len(absorbed)
        for i, j in merges:
            holds[i] |= holds.pop(j)  # a shard given up is never used again
    assert holds == {0: set(range(n))}
    assert len(tree_rounds(n)) == int(np.ceil(np.log2(n))) if n > 1 else tree_rounds(n) == []


def test_merge_partials_sums_over_the_union_of_keys() -> None:
    rng = np.random.default_rng(5)
    dense = np.zeros((40, 3, 3))
    counts = 0
    parts = []
    for k in range(4):
        keys = np.unique(rng.integers(0, 40, 15))
        vals = rng.normal(size=(len(keys), 3, 3))
        dense[keys] += vals
        counts += k
        parts.append(Partial(((keys, vals),), (k,)))
    got = parts[0]
    for p in parts[1:]:
        got = merge_partials(got, p)
    (keys, vals), = got.terms
    assert np.array_equal(keys, np.unique(np.concatenate([p.terms[0][0] for p in parts])))
    assert np.allclose(vals, dense[keys], rtol=0, atol=1e-12) and got.counts == (counts,)


def test_shards_merged_as_a_tree_give_the_flat_sums() -> None:
    """The tree's merges (BlockShard.hold / absorb / take, as DaskShardEngine runs them on workers) in process."""
    net = make_synthetic_network(3_000, rng=np.random.default_rng(41), min_views=3)
    p = net.problem
    setup = setup_from_config(p.cameras, p.image_camera, p.positions, p.rotations, CFG, pointing_sigma_urad=450.0)
    opt = options_from_config(CFG, float(np.median(p.measure_sigma)))
    blocks = blocks_from_problem(p, 5)
    shards = [BlockShard([b], setup, opt) for b in blocks]
    omega = np.zeros((setup.n_images, 3))
    for s in shards:
        s.initial_cost(omega)
    for method, args in (("linearize", (omega,)), ("reduce", (1e-3,))):
        flat = SyncEngine(shards).summed(method, *args)
        total = flat[0]
        for q in flat[1:]:
            total = merge_partials(total, q)
        for s in shards:
            s.hold(method, *args)
        for merges in tree_rounds(len(shards)):
            for i, j in merges:
                shards[i].absorb(shards[j])
        tree = shards[0].take()
        for (kf, vf), (kt, vt) in zip(total.terms, tree.terms):
            assert np.array_equal(kf, kt)
            assert np.allclose(vt, vf, rtol=1e-12, atol=1e-12 * np.abs(vf).max())
        assert tree.counts == total.counts


def test_unprojectable_measure_is_named() -> None:
    from mercury_dem.exceptions import AdjustmentError

    net = make_synthetic_network(3_000, rng=np.random.default_rng(8), min_views=3)
    p = net.problem
    setup = setup_from_config(p.cameras, p.image_camera, p.positions, p.rotations, CFG, pointing_sigma_urad=450.0)
    opt = options_from_config(CFG)
    blocks = blocks_from_problem(p, 2)
    blocks[1].apriori_points[0] *= 3.0  # the first point of block 1 above (behind) its cameras
    with pytest.raises(AdjustmentError, match=rf"block 1 cannot be projected.*points \[{blocks[1].point_start}"):
        blocked_levenberg_marquardt(SyncEngine([BlockShard(blocks, setup, opt)]), setup, opt)
