"""The bundle adjustment over point blocks: out of core in one process, or distributed (issue #17).

The in-memory adjuster's Levenberg-Marquardt loop (:func:`~mercury_dem.adjust.lm.run_levenberg_marquardt`:
same damping, gain ratio, rejection rounds and cycle rule; the same robust reweighting and
per-point rejection rules of :mod:`mercury_dem.adjust.solver`) over a :class:`BlockedEngine`,
which cuts the problem along the one seam it has: given the
cameras, points are independent. So everything per point or per measure lives in
a :class:`PointBlockState` (its points, measures, Jacobians, the point blocks
``V``, the per-measure ``W = Jc^T Jp``, its share of the Schur pair structure,
its accepted flags), and only camera-sized sums travel:

* linearize: each block gives its ``U = sum Jc^T Jc`` and ``g_c`` (per camera it sees);
* each damped trial: its Schur contribution ``-sum W V^-1 W^T`` (its camera-pair
  blocks) and ``sum W V^-1 g_p``; the client sums them into the reduced camera
  system and solves it (dense / CHOLMOD / SuperLU / PCG: :class:`~mercury_dem.adjust.schur.ReducedSolver`);
* each block back-substitutes its points from the camera step and returns scalars
  (predicted decrease, cost, step norm);
* rejection: each block computes the deletion statistic of its measures; the
  limit (median + k MAD over all measures) needs them all, so the norms (8 bytes
  a measure) go to the client, which sends the limit back; the blocks decide
  per point, the client only counts changes and watches for cycles.

A :class:`BlockShard` holds several blocks and sums over them before anything
leaves it (the first level of the reduction tree; the client sums the shards').
One shard in the caller's process is the in-memory/out-of-core run
(:class:`SyncEngine`); one shard per Dask worker, as a Dask *actor* that loads
its blocks from the store itself and keeps them in worker memory across
iterations, is the distributed run (``pipeline.shard_engine.DaskShardEngine``: Dask
stays in the orchestration layer). The loop,
:func:`blocked_levenberg_marquardt`, does not know which.

Pointing corrections only (camera_dim 3, positions fixed); a-posteriori covariances of the images and sigmas of the points
(:func:`blocked_posterior_sigmas`, exact at any size: :mod:`~mercury_dem.adjust.posterior`); no island diagnosis (the in-memory adjuster's :mod:`~mercury_dem.adjust.diagnose`).
Why our own: no library offers a distributed Schur-complement bundle adjustment
(Ceres and scipy are single-process; the Dask engine underneath is distributed's
actors and futures).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import resource
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits

from mercury_dem.adjust.framing import FramingModel, FramingState, inverse_left_jacobian
from mercury_dem.adjust.kernels import (
    normal_blocks,
    point_rhs,
    prior_blocks,
    reduced_rhs,
    schur_pairs_grouped,
    schur_pairs_table,
)
from mercury_dem.adjust.lm import Proposal, Trial, run_levenberg_marquardt
from mercury_dem.adjust.posterior import (
    image_covariances,
    inverse_pair_blocks,
    keyed_pair_blocks,
    point_covariances,
    selected_inverse,
    sigmas_of,
)
from mercury_dem.adjust.problem import AdjustmentProblem, pointing_sigma_radians, unprojectable, unprojectable_error
from mercury_dem.adjust.robust import loss_rho
from mercury_dem.adjust.schur import ReducedSolver, SchurStructure, choose_method, inv3
from mercury_dem.adjust.solver import SolverOptions, deletion_statistic, kept_in_either, proposed_accepted
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.exceptions import AdjustmentError
from mercury_dem.geometry.camera import FramingCamera
from mercury_dem.geometry.pose import angles_from_rotation, rotation_from_angles
from mercury_dem.network.blocks import BlockData

C = 3  # camera unknowns: pointing corrections


def _libc_malloc_trim() -> Any:
    """glibc's ``malloc_trim`` (None elsewhere: musl, macOS)."""
    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
    except (OSError, AttributeError):  # pragma: no cover - not glibc
        return None


_MALLOC_TRIM = _libc_malloc_trim()
#: when a shard gives glibc's free heap pages back to the system: ``"block"`` after every block's step (the
#: default: a block's temporaries, ~1 kB a measure, otherwise stay resident in holes between the blocks'
#: long-lived arrays, docs/benchmarks/adjust.md), ``"call"`` after each shard method, ``"never"``
HEAP_TRIM = "block"


def release_heap() -> None:
    """Return the free pages of glibc's heap to the system (``malloc_trim(0)``); nothing elsewhere."""
    if _MALLOC_TRIM is not None:
        _MALLOC_TRIM(0)


@dataclass(frozen=True)
class CameraSetup:
    """What every block needs of the images (sent once to every shard)."""

    cameras: tuple[FramingCamera, ...]
    image_camera: NDArray[np.int64]
    positions: NDArray[np.float64]
    rotations: NDArray[np.float64]  # a-priori, the centre of the pointing constraint
    held: NDArray[np.bool_]
    pointing_sigma_urad: float  # the a-priori pointing sigma per axis (AdjustmentProblem.pointing_sigma_urad)
    point_sigma_m: tuple[float | None, float | None, float | None]
    #: float32 storage of what a block keeps that only shapes the step or rounds observations below their
    #: precision: W = Jc^T Jp, the measures and their sigmas (see :class:`PointBlockState`); False: all float64
    #: (bit for bit the in-memory adjuster's sums)
    float32: bool = False
    #: W not kept between the linearization and the trials but recomputed from the Jacobians at each trial's
    #: reduction and back-substitution (36 B a measure in float32 fewer, two more Jacobian evaluations a trial)
    recompute_w: bool = False

    @property
    def n_images(self) -> int:
        return len(self.positions)


def options_from_config(config: AdjustConfig, median_sigma_px: float = 1.0) -> SolverOptions:
    """The solver options the in-memory adjuster derives from ``config`` (see ``bundle.solver_options``)."""
    return SolverOptions(
        max_iterations=config.max_iterations, function_tolerance=2.0 * config.sigma0_tolerance,
        step_tolerance=config.step_tolerance, loss=config.robust_loss, loss_scale=config.robust_scale,
        reject_k=config.reject_k_mad if config.reject_outliers else None,
        reject_floor=config.reject_min_px / median_sigma_px, min_point_measures=config.min_point_measures,
        solver=config.solver, direct_max_unknowns=config.direct_max_unknowns, pcg_tolerance=config.pcg_tolerance,
        pcg_max_iterations=config.pcg_max_iterations,
    )


def setup_from_config(cameras: tuple[FramingCamera, ...], image_camera: NDArray[np.int64], positions: NDArray[np.float64],
                      rotations: NDArray[np.float64], config: AdjustConfig, *, pointing_sigma_urad: float,
                      float32: bool = False) -> CameraSetup:
    """The camera setup with the configured a-priori constraints (as ``bundle.make_model``) and the a-priori
    pointing sigma of ``rotations`` (µrad per axis, :attr:`AdjustmentProblem.pointing_sigma_urad`).
    """
    if config.solve_positions:
        raise AdjustmentError("the blocked adjustment solves pointing only: set adjust.solve_positions: false")
    return CameraSetup(tuple(cameras), np.asarray(image_camera, np.int64), np.asarray(positions, np.float64),
                       np.asarray(rotations, np.float64), np.zeros(len(positions), bool),
                       float(pointing_sigma_urad),
                       (config.point_longitude_sigma_m, config.point_latitude_sigma_m, config.radius_sigma_m), float32,
                       config.blocked_recompute_w)


def blocks_from_problem(problem: AdjustmentProblem, n_blocks: int) -> list[BlockData]:
    """An in-memory problem cut into ``n_blocks`` blocks of consecutive points (for tests and small runs)."""
    order = np.argsort(problem.measure_point, kind="stable")
    mp = problem.measure_point[order]
    edges = np.linspace(0, problem.n_points, n_blocks + 1).astype(np.int64)
    out = []
    for b in range(n_blocks):
        p0, p1 = int(edges[b]), int(edges[b + 1])
        m0, m1 = np.searchsorted(mp, [p0, p1])
        sel = order[m0:m1]
        out.append(BlockData(b, p0, problem.points[p0:p1], problem.measure_image[sel], mp[m0:m1] - p0,
                             problem.measures[sel], problem.measure_sigma[sel], problem.held_points[p0:p1], None, None))
    return out


class PointBlockState:
    """One block's points, measures and their share of every sum; lives where its shard lives.

    What it keeps between iterations is what the next step needs, no more (bytes a measure: docs/design/adjust.md,
    "Memory"): the Jacobians are not kept (the rejection test's point Jacobians are recomputed, bit for bit, at
    the state of the last linearization; the residuals at the current state when asked, :attr:`r_now`).

    With ``setup.float32``: ``W = Jc^T Jp`` is stored in float32. It only enters the reduced camera matrix, the
    ``W V^-1 g_p`` term of its right-hand side and the back-substitution, never the gradient ``g_c``, ``g_p`` nor
    the cost (float64): a step ``dc = 0`` gives ``dp = -V^-1 g_p``, so the iteration stops exactly where ``g_c``
    and ``g_p`` vanish, whatever the rounding of W; it changes the path (an inexact Newton step, relative error
    ~1e-7), not the solution. The measures (sample, line) and sigmas are stored in float32 too: that rounds the
    observations by at most 2^-24 of their magnitude (3e-5 px at 512 px, 6e-5 px at 1024), 10^-4 of the 0.25 px
    noise, and the weights by 6e-8 relative (the bound the tests check on the pointing: 1e-3 px).
    """

    #: this block's cameras and camera pairs in the engine's tables (set by :class:`BlockedEngine`)
    cam_map: NDArray[np.intp]
    pair_map: NDArray[np.intp]

    def __init__(self, data: BlockData, setup: CameraSetup, opt: SolverOptions):
        self.block, self.point_start = data.block, data.point_start
        cams, local = np.unique(data.measure_image, return_inverse=True)
        self.cams = cams
        problem = AdjustmentProblem(
            cameras=setup.cameras, image_camera=setup.image_camera[cams], positions=setup.positions[cams],
            rotations=setup.rotations[cams], points=data.apriori_points, measure_image=local,
            measure_point=data.measure_point, measures=data.measures, measure_sigma=data.sigma,
            held_points=data.held_points, image_ids=("",) * len(cams), point_radius_sigma=data.point_radius_sigma,
            pointing_sigma_urad=setup.pointing_sigma_urad,
        )
        self.model = FramingModel(problem, None, setup.point_sigma_m)
        # int32 measure indices (a block has < 2^31 measures and points): the same arrays serve the model, the
        # Schur structure and the kernels (numba specializes them), 16 bytes a measure instead of 32
        mi, mp = problem.measure_image.astype(np.int32), problem.measure_point.astype(np.int32)
        object.__setattr__(problem, "measure_image", mi)
        object.__setattr__(problem, "measure_point", mp)
        self.model.camera_index, self.model.point_index = mi, mp
        self.model._groups = [(k, g.astype(np.int32)) for k, g in self.model._groups]
        self.float32 = bool(setup.float32)
        self.recompute_w = bool(setup.recompute_w)
        self.wm: NDArray[np.float64] | None = None
        if self.float32:  # the block's own copies (AdjustmentProblem validates in float64, then they are narrowed)
            object.__setattr__(problem, "measures", problem.measures.astype(np.float32))
            self.model._inv_sigma = self.model._inv_sigma.astype(np.float32)
        # the model whitens with 1 / sigma; the sigmas themselves are not kept (pixels: :meth:`pixels`)
        object.__setattr__(problem, "measure_sigma", np.zeros(0, np.float32))
        self.opt = opt
        self.cam, self.pt = self.model.camera_index, self.model.point_index
        self.n_cam, self.n_pt, self.m = len(cams), problem.n_points, problem.n_measures
        self.held_c = setup.held[cams]
        self.held_p = np.asarray(data.held_points, bool)
        self.points = problem.points.copy()
        self.zero_pos = np.zeros((self.n_cam, 3))
        self.struct = SchurStructure.build(self.cam, self.pt, self.n_cam, self.n_pt, C, eliminate=~self.held_p)
        # The pair lists are the largest index arrays (~4.4 pairs a measure at 7 views a point): only the pair
        # blocks are kept (int32: a block has < 2^31 pairs), the pairs themselves are enumerated from the measures
        # grouped by point (kernels.schur_pairs_grouped, same order as SchurStructure's lists).
        use = np.flatnonzero(~self.held_p[self.pt])
        use = use[np.argsort(self.pt[use], kind="stable")]
        self.pair_order = use.astype(np.int32)
        self.pair_ptr = np.concatenate([[0], np.cumsum(np.bincount(self.pt[use], minlength=self.n_pt))]).astype(np.int32)
        # each pair's camera-pair block: from a table of the block's images where that is smaller (the usual case:
        # a block of 25,000 neighbouring points sees a few hundred images), else the per-pair index
        self.pair_table: NDArray[np.int32] | None = None
        if 4 * self.n_cam**2 < 2 * len(self.struct.pair_block):
            self.pair_table = np.full((self.n_cam, self.n_cam), -1, np.int32)
            self.pair_table[self.struct.block_row, self.struct.block_col] = np.arange(self.struct.n_blocks, dtype=np.int32)
            self.struct.pair_block = np.zeros(0, np.int32)
        else:
            self.struct.pair_block = self.struct.pair_block.astype(np.int32)
        self.struct.pair_first = self.struct.pair_second = np.zeros(0, np.int32)
        self.struct.camera_index, self.struct.point_index = self.cam, self.pt  # not its int64 copies
        n = setup.n_images
        self.pair_keys = cams[self.struct.block_row] * n + cams[self.struct.block_col]  # global upper-triangle keys
        self.active = np.ones(self.m, bool)
        self.use, self.frozen = self._usable(self.active)
        self.outlier = data.outlier
        self.true_points = data.true_points
        self._omega_c: NDArray[np.float64] | None = None  # the block's cameras' pointing at the current state

    # -- helpers ---------------------------------------------------------------
    def _usable(self, active: NDArray[np.bool_]) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
        counts = np.bincount(self.pt[active], minlength=self.n_pt)
        frozen = (counts < self.opt.min_point_measures) & ~self.held_p
        return active & ~frozen[self.pt], frozen

    def _state(self, omega: NDArray[np.float64], points: NDArray[np.float64]) -> FramingState:
        return FramingState(omega[self.cams], self.zero_pos, points)

    def pixels(self, r: NDArray[np.float64]) -> NDArray[np.float64]:
        """Whitened residuals (M, 2) in pixels."""
        return r / self.model._inv_sigma[:, None]

    @property
    def r_now(self) -> NDArray[np.float64]:
        """Whitened residuals (M, 2) at the current state (recomputed: 16 bytes a measure not kept)."""
        assert self._omega_c is not None  # set by the first linearization
        return self.model.residuals(FramingState(self._omega_c, self.zero_pos, self.points))

    def cost(self, omega: NDArray[np.float64], points: NDArray[np.float64] | None = None) -> tuple[float, NDArray[np.float64]]:
        """The block's cost 0.5 sum rho(|r|^2) over measures in use plus its point priors, and its residuals."""
        st = self._state(omega, self.points if points is None else points)
        r = self.model.residuals(st)
        s = np.sum(r * r, axis=1)
        rho, _ = loss_rho(np.where(self.use, s, 0.0), self.opt.loss, self.opt.loss_scale)
        pp = self.model.point_prior(st)
        c = 0.5 * float(np.sum(rho[self.use])) + (0.0 if pp is None else 0.5 * float(np.sum(pp[0] ** 2)))
        if np.any(~np.isfinite(s[self.use])):
            c = float("nan")
        return c, r

    # -- the steps of one iteration ----------------------------------------------
    def _weighted_jacobians(self, st: FramingState) -> tuple[NDArray[np.float64], ...]:
        """Robustly weighted residuals and Jacobians at ``st`` (held cameras' and fixed points' columns zero)."""
        r, jc, jp = self.model.linearize(st)
        s = np.sum(r * r, axis=1)
        _, w = loss_rho(np.where(self.use, s, 0.0), self.opt.loss, self.opt.loss_scale)
        sw = np.sqrt(np.where(self.use, w, 0.0))
        r = r * sw[:, None]
        jc = jc * sw[:, None, None]
        jp *= sw[:, None, None]
        jc[self.held_c[self.cam]] = 0.0
        jp[(self.held_p | self.frozen)[self.pt]] = 0.0
        return r, jc, jp

    def _w(self) -> NDArray[np.float64]:
        """``W = Jc^T Jp`` of the last linearization: kept, or (``setup.recompute_w``) recomputed from the
        Jacobians at that state, the same bits (same code, same state, same weights: the accepted set only
        changes between a rejection round and the next linearization).
        """
        if self.wm is not None:
            return self.wm
        r, jc, jp = self._weighted_jacobians(FramingState(self._lin[0], self.zero_pos, self._lin[1]))
        wm = np.empty((self.m, C, 3), np.float32 if self.float32 else np.float64)
        normal_blocks(r, jc, jp, self.cam, self.pt, np.zeros((self.n_cam, C, C)), np.zeros((self.n_cam, C)),
                      np.zeros((self.n_pt, 3, 3)), np.zeros((self.n_pt, 3)), wm)
        return wm

    def linearize(self, omega: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
        """Normal blocks at the current state; returns this block's U (n_cam, c, c), g_c (n_cam, c), prior rows."""
        st = self._state(omega, self.points)
        r, jc, jp = self._weighted_jacobians(st)
        self._lin = (st.omega, self.points)  # where the rejection test's point Jacobians are recomputed
        fixed = self.held_p | self.frozen
        u = np.zeros((self.n_cam, C, C))
        g_c = np.zeros((self.n_cam, C))
        if getattr(self, "v", None) is None:  # allocated once, refilled in place at every linearization
            self.v, self.g_p = np.empty((self.n_pt, 3, 3)), np.empty((self.n_pt, 3))
            if not self.recompute_w:
                self.wm = np.empty((self.m, C, 3), np.float32 if self.float32 else np.float64)
        v, g_p = self.v, self.g_p
        wm = self.wm if self.wm is not None else np.empty((self.m, C, 3), np.float32 if self.float32 else np.float64)
        v.fill(0.0)
        g_p.fill(0.0)
        normal_blocks(r, jc, jp, self.cam, self.pt, u, g_c, v, g_p, wm)
        del r, jc, jp, wm
        pp = self.model.point_prior(st)
        n_prior = 0
        if pp is not None:
            n_prior = int(np.sum(~fixed)) * pp[0].shape[1]
            prior_blocks(pp[0], pp[1], v, g_p)
        v[fixed], g_p[fixed] = np.eye(3), 0.0
        self.dv = np.clip(np.diagonal(v, axis1=1, axis2=2), 1e-6, 1e32)
        return u, g_c, n_prior

    def _v_inv(self, lam: float) -> NDArray[np.float64]:
        """Inverses of the damped point blocks ``V + lam diag(V)``: recomputed by :meth:`reduce` and :meth:`step`
        (the same bits both times) rather than kept between them (72 B a point, ~10 B a measure).
        """
        vd = self.v.copy()
        vd[:, range(3), range(3)] += lam * self.dv
        return inv3(vd)

    def point_sigmas(self, keys: NDArray[np.int64], blocks: NDArray[np.float64], n_images: int,
                     sigma0: float) -> NDArray[np.float64]:
        """A-posteriori XYZ sigmas (n_pt, 3) m of the block's points at the last linearization (undamped), from the
        reduced system's inverse blocks ``blocks`` of the pair ``keys`` (:func:`posterior.point_covariances`;
        held and frozen points 0).
        """
        fixed = self.held_p | self.frozen
        get = keyed_pair_blocks(keys, blocks, self.cams, n_images)
        cov = point_covariances(get, C, sigma0, self._w(), self._v_inv(0.0), self.cam, self.pt, ~fixed, self.held_c)
        sig = sigmas_of(cov)
        sig[fixed] = 0.0
        return sig

    def reduce(self, lam: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Damped point blocks; returns the Schur pair blocks ``-sum W V^-1 W^T`` and ``sum W V^-1 g_p`` (per camera)."""
        v_inv = self._v_inv(lam)
        blocks = np.zeros((self.struct.n_blocks, C, C))
        s = self.struct
        wm = self._w()
        if self.pair_table is not None:
            schur_pairs_table(wm, v_inv, self.pt, self.cam, self.pair_order, self.pair_ptr, self.pair_table, blocks)
        else:
            schur_pairs_grouped(wm, v_inv, self.pt, self.cam, self.pair_order, self.pair_ptr, s.pair_block, blocks)
        t_p = np.matmul(v_inv, self.g_p[:, :, None])[:, :, 0]
        b = np.zeros((self.n_cam, C))
        reduced_rhs(wm, t_p, self.cam, self.pt, b)
        return -blocks, b

    def step(self, lam: float, dc_all: NDArray[np.float64], new_omega: NDArray[np.float64]) -> tuple[float, float, float, float]:
        """Back-substitute the points for camera step ``dc_all`` (n_img, c); cost at the trial state.

        Returns ``(lam sum dv dp^2 - sum g_p dp, trial cost, sum dp^2, sum of the current points^2)``;
        the trial is kept until :meth:`accept`.
        """
        dc = dc_all[self.cams]
        q = np.zeros((self.n_pt, 3))
        point_rhs(self._w(), dc, self.cam, self.pt, q)
        dp = np.matmul(self._v_inv(lam), (-self.g_p - q)[:, :, None])[:, :, 0]
        dp[self.held_p | self.frozen] = 0.0
        pred = lam * float(np.sum(self.dv * dp * dp)) - float(np.sum(self.g_p * dp))
        new_points = self.points + dp
        c, _ = self.cost(new_omega, new_points)
        self._trial = (new_points, new_omega[self.cams])
        return pred, c, float(np.sum(dp * dp)), float(np.sum(self.points**2))

    def accept(self) -> None:
        self.points, self._omega_c = self._trial
        del self._trial

    def deletion(self) -> NDArray[np.float64]:
        """Square roots of the deletion statistic of every measure (see ``solver.deletion_statistic``)."""
        self._member = self.use | (self.frozen & ~self.held_p)[self.pt]
        jp_raw = self.model.linearize(FramingState(self._lin[0], self.zero_pos, self._lin[1]))[2]
        delta, self._ssr = deletion_statistic(self.r_now, jp_raw, self.pt, self._member, self.held_p)
        self._norms = np.sqrt(np.maximum(delta, 0.0))
        return self._norms

    def propose(self, limit: float) -> tuple[int, int]:
        """The new accepted set under ``limit`` (``solver.proposed_accepted``); (changes, hash)."""
        new = proposed_accepted(self.pt, self._norms, self._ssr, self.active, self._member, self.held_p, limit,
                                self.opt.min_point_measures)
        self._proposal = new
        return int(np.sum(new != self.active)), hash(np.packbits(new).tobytes())

    def settle(self, union: bool) -> int:
        """Finalize the proposal (``union``: keep every measure accepted before or now, the cycle rule); changes."""
        if union:
            self._proposal = kept_in_either(self._proposal, self.active, self.pt, self.held_p, self.opt.min_point_measures)
        del self._norms, self._ssr, self._member  # until the next round
        return int(np.sum(self._proposal != self.active))

    def apply(self, omega: NDArray[np.float64]) -> float:
        """Adopt the settled set; the cost at the current state under it."""
        self.active = self._proposal
        del self._proposal
        self.use, self.frozen = self._usable(self.active)
        self._omega_c = omega[self.cams]
        return self.cost(omega)[0]


class Partial(NamedTuple):
    """A share of a sum over point blocks in global indices: ``(keys, values)`` per term, and counts.

    The unit of the reduction tree. A shard's sums over its blocks are its first level
    (:meth:`BlockShard.partial`); partials are merged pairwise by :func:`merge_partials`, on the
    workers (``DaskShardEngine``'s tree) or by the client, and added into the client's dense arrays
    last. Keys are sorted and unique within a term: camera indices (``cams``) or camera-pair keys
    (``row * n_images + col``).
    """

    terms: tuple[tuple[NDArray[np.int64], NDArray[np.float64]], ...]
    counts: tuple[int, ...]


def merge_partials(a: Partial, b: Partial) -> Partial:
    """The sum of two partials: each term over the union of their keys (``a``'s values added first).

    Terms over the same key arrays (``linearize``'s ``u`` and ``g``, both over ``cams``) share one union
    and its positions, and the result's terms share its key array again, so merges up a tree sort once.
    """
    terms = []
    unions: dict[tuple[int, int], tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]] = {}
    for (ka, va), (kb, vb) in zip(a.terms, b.terms):
        pair = (id(ka), id(kb))
        if pair not in unions:
            keys = np.union1d(ka, kb)
            unions[pair] = (keys, np.searchsorted(keys, ka), np.searchsorted(keys, kb))
        keys, at_a, at_b = unions[pair]
        vals = np.zeros((len(keys),) + va.shape[1:], dtype=np.result_type(va, vb))
        vals[at_a] += va
        vals[at_b] += vb
        terms.append((keys, vals))
    return Partial(tuple(terms), tuple(x + y for x, y in zip(a.counts, b.counts)))


def tree_rounds(n: int) -> list[list[tuple[int, int]]]:
    """The pairwise merges of a reduction tree over ``n`` shards: per round, ``(absorber, absorbed)`` pairs.

    Round ``k`` merges shard ``i + 2^k`` into shard ``i`` for every ``i`` a multiple of ``2^(k+1)``;
    after ceil(log2 n) rounds shard 0 holds the sum of all, each other shard given up exactly once.
    """
    rounds, step = [], 1
    while step < n:
        rounds.append([(i, i + step) for i in range(0, n - step, 2 * step)])
        step *= 2
    return rounds


class BlockShard:
    """Several point blocks in one process; every method sums over its blocks (first level of the tree sum).

    Camera-indexed results are over :attr:`cams` (the union of its blocks' images) and
    pair blocks over :attr:`pair_keys` (the union of its blocks' camera pairs), each
    computed once; the client maps them into the global system.
    """

    def __init__(self, blocks: Iterable[BlockData], setup: CameraSetup, opt: SolverOptions):
        # ``blocks``: a list, or blocks read as they are iterated (a worker reads its own blocks:
        # ``mercury_dem.io.synthetic_network_store.StoredBlocks``), one block's raw data at a time: read, turned
        # into its state, dropped (a list of them all held the shard's whole store data, ~48 B a measure, beside
        # the states while they were built)
        source: Any = iter(blocks)
        with threadpool_limits(limits=1, user_api="blas"):
            self.blocks = [PointBlockState(d, setup, opt) for d in source if len(d.measure_image)]
        del source
        self.n_images = setup.n_images
        self.cams = np.unique(np.concatenate([b.cams for b in self.blocks])) if self.blocks else np.zeros(0, np.int64)
        self.pair_keys = np.unique(np.concatenate([b.pair_keys for b in self.blocks])) if self.blocks else np.zeros(0, np.int64)
        for b in self.blocks:
            b.cam_map = np.searchsorted(self.cams, b.cams)
            b.pair_map = np.searchsorted(self.pair_keys, b.pair_keys)
        self._held: Partial | None = None
        #: seconds this shard spent computing in its blocks' methods (the workers' share of an iteration,
        #: against the client's reductions and solve: docs/benchmarks/cascade.md uses it)
        self.busy_seconds = 0.0

    def _each(self, fn: Any) -> list[Any]:
        t = time.perf_counter()
        out = []
        with threadpool_limits(limits=1, user_api="blas"):
            for b in self.blocks:
                out.append(fn(b))
                if HEAP_TRIM == "block":
                    release_heap()
        if HEAP_TRIM == "call":
            release_heap()
        self.busy_seconds += time.perf_counter() - t
        return out

    def busy(self) -> float:
        """Seconds spent in the blocks' computations since the shard was made."""
        return float(self.busy_seconds)

    def structure(self) -> tuple[NDArray[np.int64], NDArray[np.int64], int, int]:
        """(cams, pair keys, measures, points) of this shard."""
        return self.cams, self.pair_keys, sum(b.m for b in self.blocks), sum(b.n_pt for b in self.blocks)

    def initial_cost(self, omega: NDArray[np.float64]) -> float:
        """The cost at the starting state; raises AdjustmentError naming measures that cannot be projected."""
        out = 0.0
        for b in self.blocks:
            c, r = b.cost(omega)
            b._omega_c = omega[b.cams]
            bad = unprojectable(r)
            if bad.size:
                which = bad[:10]
                raise unprojectable_error(bad.size, f" of block {b.block}", (b.pt[which] + b.point_start).tolist(),
                                          b.cams[b.cam[which]].tolist())
            out += c
        return out

    def linearize(self, omega: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
        u = np.zeros((len(self.cams), C, C))
        g = np.zeros((len(self.cams), C))
        n_prior = 0
        for b, (ub, gb, nb) in zip(self.blocks, self._each(lambda b: b.linearize(omega))):
            u[b.cam_map] += ub
            g[b.cam_map] += gb
            n_prior += nb
        return u, g, n_prior

    def reduce(self, lam: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        s = np.zeros((len(self.pair_keys), C, C))
        rhs = np.zeros((len(self.cams), C))
        for b, (sb, rb) in zip(self.blocks, self._each(lambda b: b.reduce(lam))):
            s[b.pair_map] += sb
            rhs[b.cam_map] += rb
        return s, rhs

    def partial(self, method: str, *args: Any) -> Partial:
        """The shard's sum of ``linearize`` or ``reduce`` as a :class:`Partial` (global camera / pair keys)."""
        if method == "linearize":
            u, g, n_prior = self.linearize(*args)
            return Partial(((self.cams, u), (self.cams, g)), (n_prior,))
        if method == "reduce":
            s, rhs = self.reduce(*args)
            return Partial(((self.pair_keys, s), (self.cams, rhs)), ())
        raise ValueError(f"no partial sum for BlockShard.{method}")

    def hold(self, method: str, *args: Any) -> None:
        """Compute :meth:`partial` and keep it here for the tree's merges (:meth:`absorb`, :meth:`take`)."""
        self._held = self.partial(method, *args)

    def take(self) -> Partial:
        """The partial held here (and forget it)."""
        held, self._held = self._held, None
        if held is None:
            raise AdjustmentError("the blocked adjustment's reduction tree asked a shard for a sum it does not hold")
        return held

    def absorb(self, other: Any) -> None:
        """Merge the partial held by ``other`` (a shard, or a Dask actor handle of one) into this one's.

        On a cluster ``other`` lives on another worker: its partial moves worker to worker, not
        through the client.
        """
        got = other.take()
        got = got.result() if hasattr(got, "result") else got
        self._held = merge_partials(self.take(), got)

    def step(self, lam: float, dc: NDArray[np.float64], new_omega: NDArray[np.float64]) -> tuple[float, ...]:
        parts = self._each(lambda b: b.step(lam, dc, new_omega))
        return tuple(float(sum(p[k] for p in parts)) for k in range(4))

    def accept(self) -> None:
        """Adopt the trial state of every block."""
        for b in self.blocks:
            b.accept()

    def counts(self) -> tuple[int, int]:
        """(measures in use, adjusted points)."""
        return (int(sum(np.sum(b.use) for b in self.blocks)),
                int(sum(np.sum(~b.held_p & ~b.frozen) for b in self.blocks)))

    def deletion(self) -> NDArray[np.float64]:
        parts = self._each(lambda b: b.deletion())
        return np.concatenate(parts) if parts else np.zeros(0)

    def propose(self, limit: float) -> tuple[int, list[int]]:
        parts = self._each(lambda b: b.propose(limit))
        return sum(p[0] for p in parts), [p[1] for p in parts]

    def settle(self, union: bool) -> int:
        return sum(b.settle(union) for b in self.blocks)

    def apply(self, omega: NDArray[np.float64]) -> float:
        return float(sum(self._each(lambda b: b.apply(omega))))

    def rejected(self) -> int:
        return int(sum(np.sum(~b.active) for b in self.blocks))

    def summary(self) -> dict[str, Any]:
        """Per-image accepted counts, rejection and truth statistics of this shard (small)."""
        acc = np.zeros(self.n_images, np.int64)
        out: dict[str, Any] = {"outliers": 0, "outliers_rejected": 0, "good": 0, "good_rejected": 0,
                               "underdetermined_points": 0, "point_error_m": [], "sum_sq_px": 0.0, "n_px": 0}
        for b in self.blocks:
            keep = b.active & ~b.frozen[b.pt]
            acc += np.bincount(b.cams[b.cam[keep]], minlength=self.n_images)
            out["underdetermined_points"] += int(np.sum(b.frozen))
            resid = b.pixels(b.r_now)
            out["sum_sq_px"] += float(np.sum(resid[keep] ** 2))
            out["n_px"] += int(2 * np.sum(keep))
            if b.outlier is not None:
                out["outliers"] += int(np.sum(b.outlier))
                out["outliers_rejected"] += int(np.sum(b.outlier & ~b.active))
                out["good"] += int(np.sum(~b.outlier))
                out["good_rejected"] += int(np.sum(~b.outlier & ~b.active))
            if b.true_points is not None:
                err = np.linalg.norm(b.points - b.true_points, axis=1)[~b.frozen]
                out["point_error_m"].append(err.astype(np.float32))
        out["accepted_per_image"] = acc
        out["point_error_m"] = np.concatenate(out["point_error_m"]) if out["point_error_m"] else np.zeros(0, np.float32)
        return out

    def initial_residuals(self, omega: NDArray[np.float64]) -> list[tuple[int, NDArray[np.float64]]]:
        """(block, residuals in pixels (m, 2), NaN where a measure cannot be projected) at ``omega``, per block."""
        out = []
        for b in self.blocks:
            _, r = b.cost(omega)
            out.append((b.block, b.pixels(r)))
        return out

    def initial_residual_sums(self, omega: NDArray[np.float64]) -> list[tuple[float, int, int]]:
        """(sum of squared residuals px², residual coordinates, measures that cannot be projected) at ``omega``,
        per block: :meth:`initial_residuals` summed where it is computed (a unit adjusted from its store).
        """
        out = []
        for b in self.blocks:
            _, r = b.cost(omega)
            px = b.pixels(r)
            out.append((float(np.sum(px * px)), int(px.size), int(np.sum(~np.all(np.isfinite(px), axis=1)))))
        return out

    def point_sigmas(self, keys: NDArray[np.int64], blocks: NDArray[np.float64],
                     sigma0: float) -> list[tuple[int, NDArray[np.float64]]]:
        """(block, a-posteriori point sigmas (n_pt, 3)) of every block (see :meth:`PointBlockState.point_sigmas`)."""
        return [(b.block, b.point_sigmas(keys, blocks, self.n_images, sigma0)) for b in self.blocks]

    def block_results(self) -> list[tuple[int, NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_],
                                          NDArray[np.float64]]]:
        """(block, points, frozen points, accepted measures, residuals in pixels) of every block at the current state."""
        return [(b.block, b.points, b.frozen, b.active, b.pixels(b.r_now))
                for b in self.blocks]

    def block_results_of(self, ids: tuple[int, ...]) -> list[tuple[int, NDArray[np.float64], NDArray[np.bool_],
                                                                   NDArray[np.bool_], NDArray[np.float64]]]:
        """:meth:`block_results` of the blocks ``ids`` this shard holds (none if it holds none of them): the
        adjusted network is fetched a few blocks at a time, never the whole of it at once.
        """
        want = {int(b) for b in ids}
        return [(b.block, b.points, b.frozen, b.active, b.pixels(b.r_now)) for b in self.blocks if b.block in want]

    def solution(self) -> list[tuple[int, int, NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_]]]:
        """(block, first point, points, accepted measures, frozen points) of every block (tests, small runs)."""
        return [(b.block, b.point_start, b.points, b.active, b.frozen) for b in self.blocks]

    def peak_rss_bytes(self) -> int:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


class Engine(Protocol):
    """Runs :class:`BlockShard` methods on every shard.

    ``call`` returns the results in shard order; ``summed`` returns :class:`Partial` s whose sum is
    the sum over all shards of ``linearize`` or ``reduce`` (one per shard, or fewer when the engine
    merged them on its side: a reduction tree).
    """

    def call(self, method: str, *args: Any) -> list[Any]: ...

    def summed(self, method: str, *args: Any) -> list[Partial]: ...


class SyncEngine:
    """The shards in this process (one shard: the plain out-of-core run)."""

    def __init__(self, shards: list[BlockShard]):
        self.shards = shards

    def call(self, method: str, *args: Any) -> list[Any]:
        return [getattr(s, method)(*args) for s in self.shards]

    def summed(self, method: str, *args: Any) -> list[Partial]:
        return [s.partial(method, *args) for s in self.shards]


@dataclass
class BlockedResult:
    """Outcome of :func:`blocked_levenberg_marquardt` (cameras in full; points stay in the shards)."""

    omega: NDArray[np.float64]
    rotations: NDArray[np.float64]
    initial_cost: float
    final_cost: float
    sigma0: float
    iterations: int
    converged: bool
    reason: str
    rejected: int
    log: list[dict[str, Any]] = field(default_factory=list)
    seconds: float = 0.0
    setup_seconds: float = 0.0
    linear_method: str = ""
    measures: int = 0
    points: int = 0
    dof: int = 0


class GlobalStructure:
    """The reduced camera system's block layout from the shards' pair keys (as :class:`SchurStructure`)."""

    def __init__(self, keys: NDArray[np.int64], n_cam: int):
        diag = np.arange(n_cam, dtype=np.int64) * (n_cam + 1)
        self.keys = np.union1d(keys, diag)
        self.n_cam = n_cam
        row, col = self.keys // n_cam, self.keys % n_cam
        self.diag_block = np.searchsorted(self.keys, diag)
        self._off = np.flatnonzero(row != col)
        rows = np.concatenate([row, col[self._off]])
        cols = np.concatenate([col, row[self._off]])
        self._order = np.lexsort((cols, rows))
        self._indices = cols[self._order].astype(np.int32)
        self._indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=n_cam))]).astype(np.int32)

    def to_bsr(self, blocks: NDArray[np.float64]) -> sp.bsr_matrix:
        full = np.concatenate([blocks, blocks[self._off].transpose(0, 2, 1)])[self._order]
        n = self.n_cam * C
        return sp.bsr_matrix((full, self._indices, self._indptr), shape=(n, n), blocksize=(C, C))


class BlockedEngine:
    """The :class:`~mercury_dem.adjust.lm.LMEngine` of the shards of ``engine``: cameras here, points in the shards.

    Keeps the pointing corrections ``omega`` (n_img, 3) and the reduced camera system; each trial sums the
    shards' Schur contributions into it, solves, and has the shards back-substitute their points and return
    scalars (see the module docstring).
    """

    def __init__(self, engine: Engine, setup: CameraSetup, opt: SolverOptions, initial_omega: NDArray[np.float64] | None):
        self.engine, self.setup, self.opt = engine, setup, opt
        self.n_cam = setup.n_images
        self.held_c = setup.held
        structs = engine.call("structure")
        self.n_measures = int(sum(s[2] for s in structs))
        self.n_points = int(sum(s[3] for s in structs))
        self.glob = GlobalStructure(np.unique(np.concatenate([s[1] for s in structs])), self.n_cam)
        del structs
        self.method = choose_method(opt.solver, self.n_cam * C, opt.direct_max_unknowns)
        self.lin_solver = ReducedSolver(self.method, C, opt.pcg_tolerance, opt.pcg_max_iterations)
        self.sigma_c = pointing_sigma_radians(setup.pointing_sigma_urad)
        self.pos_sq = float(np.sum(setup.positions**2))
        self.omega = np.zeros((self.n_cam, 3)) if initial_omega is None else np.asarray(initial_omega, np.float64).copy()
        self.n_cam_prior = self.n_pt_prior = 0
        self.started = 0.0  # time.perf_counter() once the initial cost is known (the end of the setup)
        self._times = {"reduce_seconds": 0.0, "solve_seconds": 0.0, "step_seconds": 0.0}

    def _cam_prior_cost(self, om: NDArray[np.float64]) -> float:
        return 0.5 * float(np.sum((om / self.sigma_c) ** 2))

    def start(self) -> float:
        cost = float(sum(self.engine.call("initial_cost", self.omega))) + self._cam_prior_cost(self.omega)
        self.started = time.perf_counter()
        return cost

    def linearize(self) -> None:
        n_cam, held_c, omega = self.n_cam, self.held_c, self.omega
        u = np.zeros((n_cam, C, C))
        g_c = np.zeros((n_cam, C))
        self.n_pt_prior = 0
        for part in self.engine.summed("linearize", omega):
            (cams_u, us), (cams_g, gs) = part.terms
            u[cams_u] += us
            g_c[cams_g] += gs
            self.n_pt_prior += part.counts[0]
        # the camera prior, as FramingModel.camera_prior
        self.n_cam_prior = int(np.sum(~held_c)) * C
        prior_blocks(omega / self.sigma_c, inverse_left_jacobian(omega) / self.sigma_c, u, g_c)
        u[held_c], g_c[held_c] = np.eye(C), 0.0
        self.u, self.g_c = u, g_c
        self.du = np.clip(np.diagonal(u, axis1=1, axis2=2), 1e-6, 1e32)
        self._times = {"reduce_seconds": 0.0, "solve_seconds": 0.0, "step_seconds": 0.0}

    def trial(self, lam: float) -> Trial:
        glob, g_c, du = self.glob, self.g_c, self.du
        ta = time.perf_counter()
        blocks = np.zeros((len(glob.keys), C, C))
        b = -g_c
        for part in self.engine.summed("reduce", lam):
            (keys, ss), (cams, rs) = part.terms
            blocks[np.searchsorted(glob.keys, keys)] += ss
            b[cams] += rs
        ud = self.u.copy()
        ud[:, range(C), range(C)] += lam * du
        blocks[glob.diag_block] += ud
        tb = time.perf_counter()
        dc, info = self.lin_solver.solve(glob.to_bsr(blocks), blocks[glob.diag_block], b.ravel())
        del blocks
        tc = time.perf_counter()
        self._times["reduce_seconds"] += tb - ta
        self._times["solve_seconds"] += tc - tb
        dc = dc.reshape(self.n_cam, C)
        dc[self.held_c] = 0.0
        new_cost, pred, step_norm = float("nan"), 0.0, float("nan")
        if info.ok and np.all(np.isfinite(dc)):
            new_omega = angles_from_rotation(np.matmul(rotation_from_angles(dc), rotation_from_angles(self.omega)))
            parts = self.engine.call("step", lam, dc, new_omega)
            pred_p = sum(p[0] for p in parts)
            new_cost = sum(p[1] for p in parts) + self._cam_prior_cost(new_omega)
            dp_sq = sum(p[2] for p in parts)
            pts_sq = sum(p[3] for p in parts)
            pred = 0.5 * (lam * float(np.sum(du * dc * dc)) + pred_p - float(np.sum(g_c * dc)))
            step_norm = float(np.sqrt(np.sum(dc * dc) + dp_sq))
            self._trial = (new_omega, pts_sq)
        self._times["step_seconds"] += time.perf_counter() - tc
        return Trial(pred, new_cost, step_norm, info.iterations)

    def accept(self) -> float:
        self.engine.call("accept")
        new_omega, pts_sq = self._trial
        del self._trial
        x_norm = float(np.sqrt(pts_sq + np.sum(self.omega**2) + self.pos_sq))  # at the state before the step
        self.omega = new_omega
        return x_norm

    def dof_counts(self) -> tuple[int, int]:
        counts = self.engine.call("counts")
        n_obs = 2 * sum(c[0] for c in counts) + self.n_cam_prior + self.n_pt_prior
        n_unk = C * int(np.sum(~self.held_c)) + 3 * sum(c[1] for c in counts)
        return n_obs, n_unk

    def deletion_norms(self) -> NDArray[np.float64]:
        return np.concatenate(self.engine.call("deletion"))

    def propose(self, limit: float) -> Proposal:
        props = self.engine.call("propose", limit)
        return Proposal(sum(p[0] for p in props), hash(tuple(h for p in props for h in p[1])))

    def settle(self, union: bool) -> int:
        return int(sum(self.engine.call("settle", union)))

    def apply_rejection(self) -> float:
        return float(sum(self.engine.call("apply", self.omega))) + self._cam_prior_cost(self.omega)

    def n_rejected(self) -> int:
        return int(sum(self.engine.call("rejected")))

    def timings(self) -> dict[str, float]:
        return dict(self._times)


def blocked_levenberg_marquardt(engine: Engine, setup: CameraSetup, opt: SolverOptions,
                                initial_omega: NDArray[np.float64] | None = None) -> BlockedResult:
    """Minimise the (robust) cost over all blocks of ``engine`` (see the module docstring).

    The client keeps the cameras (pointing corrections ``omega`` (n_img, 3)) and the
    reduced camera system; the shards keep the points. The loop (step control, rejection
    and convergence) is the in-memory adjuster's: :func:`~mercury_dem.adjust.lm.run_levenberg_marquardt`
    over a :class:`BlockedEngine`.
    """
    with threadpool_limits(limits=1, user_api="blas"):
        t0 = time.perf_counter()
        lm = BlockedEngine(engine, setup, opt, initial_omega)
        out = run_levenberg_marquardt(lm, opt, t0)
    return BlockedResult(
        omega=lm.omega, rotations=np.matmul(rotation_from_angles(lm.omega), setup.rotations),
        initial_cost=out.initial_cost, final_cost=out.final_cost, sigma0=out.sigma0, iterations=out.iterations,
        converged=out.converged, reason=out.reason, rejected=out.rejected, log=out.log, seconds=out.seconds,
        setup_seconds=lm.started - t0, linear_method=lm.method, measures=lm.n_measures, points=lm.n_points, dof=out.dof,
    )


@dataclass(frozen=True)
class BlockedPosterior:
    """A-posteriori pointing covariances of the blocked adjustment (see :func:`blocked_posterior_sigmas`).

    ``image_covariances`` (n_img, 3, 3) rad^2 and ``image_sigmas`` (n_img, 3) rad, 0 for held images: exact, the
    diagonal blocks of ``sigma0^2 S^-1`` (:mod:`~mercury_dem.adjust.posterior`); ``method``: the factorization
    (``"cholmod"`` or ``"splu"``); ``factor_nnz``: the factor's non-zeros (the memory: ~2 x 8 bytes each).
    """

    image_sigmas: NDArray[np.float64]
    method: str
    seconds: float
    image_covariances: NDArray[np.float64] | None = None
    factor_nnz: int = 0
    factor_seconds: float = 0.0
    recurrence_seconds: float = 0.0
    #: with ``points``: (block, point sigmas (n_pt, 3) m) of every block, from the shards
    point_sigmas: list[tuple[int, NDArray[np.float64]]] | None = None


def blocked_posterior_sigmas(engine: Engine, setup: CameraSetup, result: BlockedResult,
                             method: str = "auto", points: bool = False) -> BlockedPosterior:
    """Per-image a-posteriori pointing covariances and sigmas at the solution of :func:`blocked_levenberg_marquardt`.

    The undamped reduced camera system ``S`` (the shards' ``linearize`` and ``reduce(0)`` at the final state,
    the same robust weights and accepted set as the last iteration, plus the pointing prior) is assembled as in
    an iteration; the covariances are ``sigma0^2 (S^-1)_ii``, as the in-memory adjuster's
    (``bundle.posterior_sigmas``), from the selected inverse of ``S``'s sparse factor
    (:func:`mercury_dem.adjust.posterior.selected_inverse`: CHOLMOD, or SuperLU with ``method="splu"`` or without
    scikit-sparse), exact at any size the factor fits in this process. With ``points``, the inverse's blocks of
    every image pair of ``S`` (72 bytes each) go to every shard, which returns its points' sigmas (24 bytes a
    point): ``sigma0^2 (V^-1 + sum Y^T S^-1 Y)`` over the pairs of each point's measures.

    Leaves the shards' linearization at the final state (their points, accepted sets and residuals unchanged).
    """
    t0 = time.perf_counter()
    n_cam, held_c = setup.n_images, setup.held
    with threadpool_limits(limits=1, user_api="blas"):
        structs = engine.call("structure")
        glob = GlobalStructure(np.unique(np.concatenate([s[1] for s in structs])), n_cam)
        del structs
        u = np.zeros((n_cam, C, C))
        for part in engine.summed("linearize", result.omega):
            cams, us = part.terms[0]
            u[cams] += us
        sigma_c = pointing_sigma_radians(setup.pointing_sigma_urad)
        prior_blocks(result.omega / sigma_c, inverse_left_jacobian(result.omega) / sigma_c, u, np.zeros((n_cam, C)))
        u[held_c] = np.eye(C)
        blocks = np.zeros((len(glob.keys), C, C))
        for part in engine.summed("reduce", 0.0):
            keys, ss = part.terms[0]
            blocks[np.searchsorted(glob.keys, keys)] += ss
        blocks[glob.diag_block] += u
        del u
        # the held images' rows and columns: identity (their W are zero, their pair blocks with others too)
        inverse = selected_inverse(glob.to_bsr(blocks), method)
        nonzero = np.any(blocks != 0, axis=(1, 2))
        del blocks
        cov = image_covariances(inverse, n_cam, C, result.sigma0, held_c)
        cost = (inverse.method, inverse.nnz, inverse.factor_seconds, inverse.recurrence_seconds)
        pt_sig = None
        if points:
            pair = inverse_pair_blocks(inverse, glob.keys, n_cam, C, held_c, nonzero)
            del inverse
            pt_sig = [x for part in engine.call("point_sigmas", glob.keys, pair, result.sigma0) for x in part]
    return BlockedPosterior(sigmas_of(cov), cost[0], time.perf_counter() - t0, cov, *cost[1:], point_sigmas=pt_sig)
