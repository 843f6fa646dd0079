"""A region's, hemisphere's or the globe's merged network from its children's stored networks (stage runner part).

In memory (every child's network read, :func:`~mercury_dem.network.merge.merge_networks`), or, for the levels of
``adjust.streamed_merge_levels``, by parts straight from the children's stores
(:func:`~mercury_dem.io.merged_network_store.stream_merged_network`): the same network bit for bit
(tests/network/test_streamed_merge.py, tests/pipeline/test_unit_streamed_merge.py), without the children's
networks and the merge in memory at once.
"""

from __future__ import annotations

import contextlib
import shutil
from collections.abc import Iterator
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from mercury_dem.exceptions import CorruptUnitError
from mercury_dem.io.run_store import RunStore, unit_name
from mercury_dem.plan.tree import ADJUSTED_LEVELS
from mercury_dem.plan.tree import CHILD_LEVEL as LEVEL_CHILD

if TYPE_CHECKING:
    from mercury_dem.config import Config
    from mercury_dem.io.merged_network_store import StreamedMergeSummary
    from mercury_dem.mission import Mission
    from mercury_dem.network.blocks import ImageTable
    from mercury_dem.network.model import ControlNetwork


def mission_image_table(mission: Mission, ids: NDArray[np.str_]) -> ImageTable:
    """The a-priori geometry of images ``ids`` from the mission (one camera entry per distinct camera model)."""
    from mercury_dem.network.blocks import ImageTable

    cams: list[object] = []
    index: dict[int, int] = {}
    image_camera = np.empty(len(ids), np.int64)
    poses = [mission.a_priori_pose(str(i)) for i in ids]
    for k, i in enumerate(ids):
        cam = mission.camera(str(i))
        image_camera[k] = index.setdefault(id(cam), len(cams))
        if image_camera[k] == len(cams):
            cams.append(cam)
    return ImageTable(tuple(cams), image_camera,  # type: ignore[arg-type]
                      np.array([p[0] for p in poses], np.float64).reshape(-1, 3),
                      np.array([p[1] for p in poses], np.float64).reshape(-1, 3, 3))


def checked_children(store: RunStore, level: str, kids: list[int]) -> None:
    """Each child's files checked against its marker; a damaged child is withdrawn (its marker first) so the
    resumed run recomputes it, and :class:`CorruptUnitError` says which files.
    """
    child_level = LEVEL_CHILD[level]
    for c in kids:
        try:
            store.check_unit(child_level, c)
        except CorruptUnitError:
            store.invalidate_unit(child_level, c)
            raise


def merge_children(store: RunStore, level: str, unit_id: int, kids: list[int], config: Config,
                   mission: Mission | None = None) -> ControlNetwork:
    """The unit's merged network (every image of its children kept: ``MergeResult.network``), its children's
    rejections cleared when they were adjusted (:func:`~mercury_dem.adjust.cascade.rejudged_network`).

    ``mission``: the run's mission (the streamed merge records its images' geometry); None: opened from the
    run when needed (a child's damaged files are found before that).
    """
    from mercury_dem.adjust.cascade import rejudged_network

    child_level = LEVEL_CHILD[level]
    checked_children(store, level, kids)
    tol = config.network.merge_tolerance_px
    if level not in config.adjust.streamed_merge_levels:
        from mercury_dem.io.network_store import read_network
        from mercury_dem.network.merge import merge_networks

        nets = [rejudged_network(read_network(store.network_path(child_level, c)), child_level) for c in kids]
        return merge_networks(nets, tolerance_px=tol).network
    from mercury_dem.io.merged_network_store import stream_merged_network

    if mission is None:
        from mercury_dem.mission import open_mission

        mission = open_mission(store.read_run()["mission"])
    scratch = store.unit_dir(level, unit_id).parent / f".{int(unit_id)}.merge"
    children = [(unit_name(child_level, c), store.network_path(child_level, c)) for c in kids]
    merged, _ = stream_merged_network(
        unit_name(level, unit_id), children, scratch, partial(mission_image_table, mission),
        tolerance_px=tol, part_measures=config.adjust.streamed_merge_part_measures,
        block_points=config.adjust.blocked_block_points, clear_rejections=child_level in ADJUSTED_LEVELS)
    return merged


@contextlib.contextmanager
def streamed_children(store: RunStore, level: str, unit_id: int, kids: list[int], config: Config,
                      mission: Mission) -> Iterator[tuple[Path, StreamedMergeSummary]]:
    """The unit's children merged by parts into a scratch store beside the unit's directory (the merged network
    and its point blocks: :func:`~mercury_dem.io.merged_network_store.stream_merge`), removed on leaving.
    """
    from mercury_dem.io.merged_network_store import stream_merge

    child_level = LEVEL_CHILD[level]
    checked_children(store, level, kids)
    scratch = store.unit_dir(level, unit_id).parent / f".{int(unit_id)}.merge"
    children = [(unit_name(child_level, c), store.network_path(child_level, c)) for c in kids]
    try:
        summary = stream_merge(
            unit_name(level, unit_id), children, scratch, partial(mission_image_table, mission),
            tolerance_px=config.network.merge_tolerance_px, part_measures=config.adjust.streamed_merge_part_measures,
            block_points=config.adjust.blocked_block_points, overwrite=True,
            clear_rejections=child_level in ADJUSTED_LEVELS)
        yield scratch, summary
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def adjusted_scratch(store: RunStore, level: str, unit_id: int) -> Path:
    """Where a unit adjusted from its merged store writes its adjusted network before it is moved into the unit
    (a failed attempt's leftover removed).
    """
    path = store.unit_dir(level, unit_id).parent / f".{int(unit_id)}.adjusted.zarr"
    shutil.rmtree(path, ignore_errors=True)
    return path
