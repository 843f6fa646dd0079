"""The block-streamed synthetic network generator and its store (issue #17)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mercury_dem.exceptions import NetworkError, StoreError
from mercury_dem.io.network_store import read_network
from mercury_dem.io.synthetic_network_store import BlockedNetwork, write_synthetic_network
from mercury_dem.network.synthetic import SyntheticSpec, make_images, point_block
from mercury_dem.validate.synthetic_network import pointing_errors

SPEC = SyntheticSpec(20_000, seed=11, measures_per_image=100, block_points=600)


def test_a_block_is_the_same_whoever_makes_it_and_seeds_differ() -> None:
    images = make_images(SPEC)
    a, b = point_block(SPEC, images, 3), point_block(SPEC, make_images(SPEC), 3)
    assert np.array_equal(a.measures, b.measures) and np.array_equal(a.measure_image, b.measure_image)
    other = point_block(SyntheticSpec(20_000, seed=12, measures_per_image=100, block_points=600),
                        make_images(SyntheticSpec(20_000, seed=12, measures_per_image=100, block_points=600)), 3)
    assert not np.array_equal(a.true_points[:5], other.true_points[:5])


def test_statistics_of_a_network() -> None:
    images = make_images(SPEC)
    blocks = [point_block(SPEC, images, b) for b in range(SPEC.n_blocks)]
    m = sum(b.n_measures for b in blocks)
    assert 0.85 * SPEC.n_measures < m < 1.15 * SPEC.n_measures
    views = np.concatenate([np.bincount(b.measure_point) for b in blocks])
    assert views.min() >= 2 and views.max() <= 15 and 5.5 < views.mean() < 8.0
    # images per point are those that see it: every measure projects inside its image
    n_out = sum(int(b.outlier.sum()) for b in blocks)
    assert abs(n_out - 0.01 * m) < 4 * np.sqrt(0.01 * m)  # binomial, 4 sigma
    # the injected pointing error is what the spec says (per axis, 450 urad)
    raw, _, _ = pointing_errors(images.rotations, images.true_rotations)
    assert abs(np.std(raw) / 450e-6 - 1) < 4 / np.sqrt(raw.size / 2)
    # a-priori points: the intersection of the a-priori rays, off the truth by the pointing error's size
    err = np.concatenate([np.linalg.norm(b.apriori_points - b.true_points, axis=1) for b in blocks])
    assert 50 < np.median(err) < 3000
    # blocks are equal-area cells: their point counts agree with a spatial partition (no shared points)
    used = np.zeros(images.n_images, int)
    for b in blocks:
        used += np.bincount(b.measure_image, minlength=images.n_images)
    assert (used > 0).mean() > 0.95


def test_spec_checks_its_arguments() -> None:
    with pytest.raises(NetworkError, match="outlier fraction"):
        SyntheticSpec(10_000, outlier_fraction=0.7)
    with pytest.raises(NetworkError, match="too small"):
        SyntheticSpec(10)


def test_store_round_trip_blocks_and_truth(tmp_path: Path) -> None:
    out = tmp_path / "syn"
    s = write_synthetic_network(SPEC, out)
    net = read_network(out / "network")  # an ordinary network store
    assert (net.n_images, net.n_points, net.n_measures) == (s.images, s.points, s.measures)
    bn = BlockedNetwork(out)
    assert bn.n_blocks == SPEC.n_blocks and bn.truth_path is not None
    images = make_images(SPEC)
    for b in (0, bn.n_blocks - 1):
        got, want = bn.read_block(b), point_block(SPEC, images, b)
        assert np.array_equal(got.measures, want.measures) and np.array_equal(got.measure_point, want.measure_point)
        assert np.array_equal(got.outlier, want.outlier) and np.array_equal(got.true_points, want.true_points)
        p0 = int(bn.point_offsets[b])
        assert np.array_equal(net.measure_point[bn.measure_offsets[b]:bn.measure_offsets[b + 1]], want.measure_point + p0)
    assert np.array_equal(bn.truth_images(), images.true_rotations)
    with pytest.raises(StoreError, match="already exists"):
        write_synthetic_network(SPEC, out)


def test_store_without_geometry_is_named(tmp_path: Path) -> None:
    from mercury_dem.io.network_store import write_network

    p = write_network(read_network_from(tmp_path), tmp_path / "plain")
    with pytest.raises(StoreError, match=r"plain.*geometry"):
        BlockedNetwork(p)


def read_network_from(tmp_path: Path):  # noqa: ANN201 - a small plain network
    out = tmp_path / "syn_small"
    write_synthetic_network(SyntheticSpec(2_000, seed=2, measures_per_image=100), out)
    return read_network(out / "network")


@pytest.mark.integration  # a memory measurement of the generator (tracemalloc over a whole store), not a recovery test
def test_generation_memory_is_bounded_by_a_block_not_the_network(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Four times the measures, same block size: the traced peak stays (the columns are flushed per chunk)."""
    import tracemalloc

    import mercury_dem.io.synthetic_network_store as ss

    monkeypatch.setattr(ss, "CHUNK_ROWS", 4096)
    peaks = []
    for n in (20_000, 80_000):
        tracemalloc.start()
        write_synthetic_network(SyntheticSpec(n, seed=7, measures_per_image=100, block_points=500), tmp_path / f"n{n}")
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    # the image set grows 4x too (~1 kB an image), the rest is one block and one chunk of each column
    assert peaks[1] < 1.5 * peaks[0], peaks
