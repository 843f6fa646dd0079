"""What the blocked adjustment's block states keep (issue #17 §2, memory): the lighter forms give the same sums."""

from __future__ import annotations

import dataclasses

import numpy as np

from mercury_dem.adjust import blocked
from mercury_dem.adjust.blocked import (
    BlockShard,
    SyncEngine,
    blocked_levenberg_marquardt,
    blocks_from_problem,
    options_from_config,
    setup_from_config,
)
from mercury_dem.adjust.kernels import schur_pairs_grouped, schur_pairs_table
from mercury_dem.adjust.schur import SchurStructure
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.validate.synthetic_network import make_synthetic_network


def _problem(seed: int):
    return make_synthetic_network(4_000, rng=np.random.default_rng(seed), min_views=3).problem


def test_pair_table_gives_the_pair_index_sums_bit_for_bit() -> None:
    """``schur_pairs_table`` (a table of the block's images) against ``schur_pairs_grouped`` (a per-pair index)."""
    p = _problem(53)
    rng = np.random.default_rng(8)
    cam, pt = p.measure_image.astype(np.int32), p.measure_point.astype(np.int32)
    held = np.zeros(p.n_points, bool)
    held[::7] = True
    s = SchurStructure.build(cam, pt, p.n_images, p.n_points, 3, eliminate=~held)
    w = rng.normal(size=(p.n_measures, 3, 3)).astype(np.float32)
    a = rng.normal(size=(p.n_points, 3, 3))
    v_inv = np.matmul(a, a.transpose(0, 2, 1)) + np.eye(3)
    use = np.flatnonzero(~held[pt])
    use = use[np.argsort(pt[use], kind="stable")].astype(np.int32)
    ptr = np.concatenate([[0], np.cumsum(np.bincount(pt[use], minlength=p.n_points))]).astype(np.int32)
    ref = np.zeros((s.n_blocks, 3, 3))
    schur_pairs_grouped(w, v_inv, pt, cam, use, ptr, s.pair_block.astype(np.int32), ref)
    table = np.full((p.n_images, p.n_images), -1, np.int32)
    table[s.block_row, s.block_col] = np.arange(s.n_blocks, dtype=np.int32)
    got = np.zeros_like(ref)
    schur_pairs_table(w, v_inv, pt, cam, use, ptr, table, got)
    assert np.array_equal(got, ref) and np.abs(ref).max() > 0


def _adjust(p, monkeypatch, table: bool, trim: str, recompute_w: bool = False):
    cfg = AdjustConfig()
    setup = setup_from_config(p.cameras, p.image_camera, p.positions, p.rotations, cfg, float32=True, pointing_sigma_urad=450.0)
    setup = dataclasses.replace(setup, recompute_w=recompute_w)
    opt = options_from_config(cfg, float(np.median(p.measure_sigma)))
    monkeypatch.setattr(blocked, "HEAP_TRIM", trim)
    shard = BlockShard(blocks_from_problem(p, 3), setup, opt)
    if not table:  # the per-pair index, as a block that sees too many images for a table keeps it
        for b in shard.blocks:
            assert b.pair_table is not None
            b.struct.pair_block = _pair_index(b)
            b.pair_table = None
    res = blocked_levenberg_marquardt(SyncEngine([shard]), setup, opt)
    return res, shard


def _pair_index(b) -> np.ndarray:
    """The per-pair block index in the enumeration order of the kernels (pairs of a point, cam[m1] <= cam[m2])."""
    out = []
    for g in range(len(b.pair_ptr) - 1):
        run = b.pair_order[b.pair_ptr[g]:b.pair_ptr[g + 1]]
        for m1 in run:
            for m2 in run:
                if b.cam[m1] <= b.cam[m2]:
                    out.append(b.pair_table[b.cam[m1], b.cam[m2]])
    return np.asarray(out, np.int32)


def test_table_index_and_heap_trim_change_nothing(monkeypatch) -> None:
    """The same iterations, rejected set and pointing, bit for bit, with the table or the index, trimming the
    heap after every block or never (seed 59)."""
    p = _problem(59)
    a, sa = _adjust(p, monkeypatch, table=True, trim="block")
    b, sb = _adjust(p, monkeypatch, table=False, trim="never")
    assert a.iterations == b.iterations and a.rejected == b.rejected and a.rejected > 10
    assert np.array_equal(a.omega, b.omega)
    for x, y in zip(sa.blocks, sb.blocks):
        assert np.array_equal(x.points, y.points) and np.array_equal(x.active, y.active)


def test_recomputed_w_changes_nothing(monkeypatch) -> None:
    """``recompute_w``: W rebuilt at each trial from the Jacobians of the last linearization, the same bits as
    the kept W, so the same adjustment (seed 61), and no W held between calls."""
    p = _problem(61)
    a, sa = _adjust(p, monkeypatch, table=True, trim="block")
    b, sb = _adjust(p, monkeypatch, table=True, trim="block", recompute_w=True)
    assert all(x.wm is None for x in sb.blocks) and all(x.wm is not None for x in sa.blocks)
    assert a.iterations == b.iterations and a.rejected == b.rejected and a.rejected > 10
    assert np.array_equal(a.omega, b.omega)
    for x, y in zip(sa.blocks, sb.blocks):
        assert np.array_equal(x.points, y.points) and np.array_equal(x.active, y.active)
