"""The compiled refinement (``dense.refine_kernel``) against the numpy implementation it replaced.

Reference: the old code, verbatim (``reference_refine.py``), run as it was (float32 images and window
moments) and with every dtype raised to float64. The kernel computes the same model in float64, so it must be
very close to the float64 reference, and differ from the float32 one by about that one's own rounding. The
only method differences left: a pixel whose first-pass estimate lies within rounding of a quantisation
boundary may start the second pass one quantum away (a few pixels per chip, <= 0.05 px).

Tolerances (measured on this chip at commit dd978f1: new vs float64 median 2e-6 px, p99.9 1.5e-4 px,
max 0.016 px; float32 reference vs float64 median 3e-5 px, p99.9 3.4e-3 px, max 0.29 px) are asserted with
some margin below.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from dense_scene import chip_of
from reference_refine import reference_module

from mercury_dem.dense.disparity import MatcherSettings, refine_disparity_blocks, sgbm_disparity, to_8bit


def diffs(a: tuple[np.ndarray, ...], b: tuple[np.ndarray, ...]) -> tuple[int, list[np.ndarray]]:
    """Pixels valid in one result only (disparity), and |a - b| of each output where both are valid."""
    mism = int(np.sum(np.isfinite(a[0]) != np.isfinite(b[0])))
    out = []
    for x, y in zip(a, b):
        both = np.isfinite(x) & np.isfinite(y)
        out.append(np.abs(x[both].astype(np.float64) - y[both]))
    return mism, out


@pytest.mark.parametrize("quantum", [0.125, 0.0])
def test_kernel_equals_the_numpy_refinement_within_rounding(lambert_pair, quantum: float) -> None:
    """Disparity, precision, score and slope of the kernel vs the old implementation on the rendered pair."""
    rect = chip_of(lambert_pair)
    s = dataclasses.replace(MatcherSettings(), refine_quantum_px=quantum)
    l8, r8 = to_8bit(rect.left, rect.right, rect.left_valid & rect.right_valid)
    seed = np.round(sgbm_disparity(l8, r8, rect.disparity_min_px, rect.disparity_max_px, s))
    new = refine_disparity_blocks(rect.left, rect.right, seed, s)
    # the old default blocks (128 px); in fast mode the whole chip, as the old blocks' margins were too narrow
    # for it (its dense step resamples each window at its neighbours' first-pass disparities, whose windows
    # reach beyond the margin: up to 2 px differences at 0.1 % of the pixels near block edges)
    as_it_ran = dataclasses.replace(s, refine_block_px=128 if quantum > 0 else 0)
    ref32 = reference_module().refine_disparity_blocks(rect.left, rect.right, seed, as_it_ran)
    ref64 = reference_module(float64=True).refine_disparity_blocks(rect.left, rect.right, seed, as_it_ran)
    n_valid = int(np.isfinite(ref64[0]).sum())
    assert n_valid > 40_000

    mism, (dd, ds, dz, _) = diffs(new, ref64)
    assert mism <= 5
    p999 = 1e-3 if quantum > 0 else 5e-3  # fast mode: every window sees its neighbours' resampled pixels
    assert np.median(dd) < 1e-5 and np.quantile(dd, 0.999) < p999 and dd.max() < 0.05, dd.max()
    assert np.quantile(ds, 0.999) < 5e-3 and np.quantile(dz, 0.999) < 1e-3

    mism32, (dd32, _, dz32, _) = diffs(new, ref32)
    assert mism32 <= 5
    assert np.median(dd32) < 2e-4 and np.quantile(dd32, 0.99) < 5e-3 and np.quantile(dz32, 0.99) < 3e-3
    # and the kernel is the more exact of the two: closer to the float64 reference than the old code is
    _, (dd_old, *_) = diffs(ref32, ref64)
    assert np.quantile(dd, 0.99) < np.quantile(dd_old, 0.99)


def test_kernel_result_does_not_depend_on_the_blocks(lambert_pair) -> None:
    """Each pixel's window sums are summed in a fixed order: blocks of 48 px give the whole chip's bits (the
    disparity within one float32 rounding: a block refines ``d + offset`` of its cut right chip, then removes it).

    Default mode only: in fast mode (``refine_quantum_px = 0``) the dense step resamples the right chip at a
    pixel without an SGBM disparity at a fill value (0 in the block's own columns), which differs per block.
    """
    from mercury_dem.dense.disparity import refine_disparity

    rect = chip_of(lambert_pair)
    s = MatcherSettings()
    l8, r8 = to_8bit(rect.left, rect.right, rect.left_valid & rect.right_valid)
    seed = np.round(sgbm_disparity(l8, r8, rect.disparity_min_px, rect.disparity_max_px, s))
    whole = refine_disparity(rect.left, rect.right, seed, s)
    blocks = refine_disparity_blocks(rect.left, rect.right, seed, dataclasses.replace(s, refine_block_px=48))
    assert np.array_equal(np.isnan(whole[0]), np.isnan(blocks[0]))
    np.testing.assert_allclose(whole[0], blocks[0], rtol=0, atol=4e-6)
    for a, b in zip(whole[1:], blocks[1:]):
        assert np.array_equal(a, b, equal_nan=True)


def test_warm_compiles_every_signature_the_refinement_uses(lambert_pair) -> None:
    """``refine_kernel.warm`` (run by ``mercury_dem.pipeline.warm``) compiles the kernels for the very types
    ``dense_disparity`` passes, so a first chip in a fresh worker loads them from numba's cache.
    """
    from mercury_dem.dense import refine_kernel as rk
    from mercury_dem.dense.disparity import dense_disparity

    kernels = [rk.window_fit, rk.after_first_pass, rk.quanta_present, rk.shift_and_phase, rk.finish_second_pass,
               rk.flag_holes]
    rk.warm()
    warmed = [set(k.signatures) for k in kernels]
    rect = chip_of(lambert_pair)
    for quantum in (0.125, 0.0):
        dense_disparity(rect.left, rect.right, rect.left_valid, rect.right_valid, rect.disparity_min_px,
                        rect.disparity_max_px, MatcherSettings(refine_quantum_px=quantum))
    assert [set(k.signatures) for k in kernels] == warmed
