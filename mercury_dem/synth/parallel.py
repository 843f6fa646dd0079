"""Rendering many images: a plain loop, or batches on Dask for the large preset.

The ``large`` mission (~10^4 images of 1024^2) needs a cluster: its client comes from
:mod:`mercury_dem.compute` (nothing in :mod:`mercury_dem.synth` imports Dask).
Every worker rebuilds the truth surface once from its parameters (cached per
process) and writes its images straight into the mission under construction,
so only image ids and timings travel between processes. Each image has its own
noise generator seeded by (seed, image index): the result does not depend on
the number of workers or the order of execution.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from mercury_dem.compute.client import ComputeClient
from mercury_dem.geometry.camera import camera_preset
from mercury_dem.mission.store import write_image
from mercury_dem.synth.render import RenderSettings, render_image
from mercury_dem.synth.terrain import Surface, SurfaceParams

_SURFACES: dict[str, Surface] = {}

RENDER_COLUMNS = (
    ["image_id", "instrument", "samples", "index"]
    + [f"true_position_{a}" for a in "xyz"]
    + [f"true_rotation_{i}{j}" for i in range(3) for j in range(3)]
    + [f"sun_{a}" for a in "xyz"]
)


def cached_surface(params: dict[str, Any], radius_m: float) -> Surface:
    """The surface of ``params``, built once per process."""
    key = json.dumps([params, radius_m], sort_keys=True)
    if key not in _SURFACES:
        _SURFACES.clear()
        _SURFACES[key] = Surface(SurfaceParams.from_dict(params), radius_m=radius_m)
    return _SURFACES[key]


def image_rng(seed: int, index: int) -> np.random.Generator:
    """The noise generator of image ``index`` (independent of execution order)."""
    return np.random.default_rng([seed, 0x1A6E, index])


def render_batch(
    root: str, rows: list[dict[str, Any]], params: dict[str, Any], radius_m: float, settings: RenderSettings, seed: int
) -> list[tuple[str, float]]:
    """Render and store a batch of images; returns (image_id, seconds) per image."""
    surface = cached_surface(params, radius_m)
    out = []
    for row in rows:
        t0 = time.perf_counter()
        cam = camera_preset(row["instrument"], int(row["samples"]))
        c = np.array([row[f"true_position_{a}"] for a in "xyz"])
        r = np.array([row[f"true_rotation_{i}{j}"] for i in range(3) for j in range(3)]).reshape(3, 3)
        sun = np.array([row[f"sun_{a}"] for a in "xyz"])
        img = render_image(surface, cam, c, r, sun, image_rng(seed, int(row["index"])), settings)
        write_image(root, str(row["image_id"]), img)
        out.append((str(row["image_id"]), time.perf_counter() - t0))
    return out


def render_all(
    root: str | Path,
    plan: pd.DataFrame,
    params: dict[str, Any],
    radius_m: float,
    settings: RenderSettings,
    seed: int,
    workers: int = 1,
    client: ComputeClient | None = None,
    batch_size: int = 8,
    progress: Callable[[int, int], None] | None = None,
    scheduler: str | None = None,
) -> list[tuple[str, float]]:
    """Render every image of ``plan`` into the mission at ``root``.

    ``plan`` may carry an ``index`` column (the image's index in the full design,
    which seeds its noise); without it the rows are numbered 0..n-1.

    ``workers <= 1`` and no ``client``/``scheduler``: a plain loop in this
    process. Otherwise batches are submitted to ``client`` (a
    ``distributed.Client``), to the scheduler at ``scheduler``
    (``tcp://host:port``; the workers must see ``root`` on a shared file system),
    or to a temporary LocalCluster of ``workers`` single-threaded processes.
    """
    if "index" not in plan.columns:  # the image's index in its design (seeds its noise)
        plan = plan.assign(index=np.arange(len(plan)))
    table = plan[RENDER_COLUMNS]
    rows = table.to_dict("records")
    if client is None and scheduler is None and workers <= 1:
        done: list[tuple[str, float]] = []
        for k, row in enumerate(rows):
            done += render_batch(str(root), [row], params, radius_m, settings, seed)
            if progress:
                progress(k + 1, len(rows))
        return done
    batches = [rows[i:i + batch_size] for i in range(0, len(rows), batch_size)]
    if client is not None:
        return _run_on(client, str(root), batches, params, radius_m, settings, seed, progress, len(rows))
    from mercury_dem.compute import open_client

    # a scheduler's address (TLS only through Dask's config: env.sh), or a LocalCluster on the loopback
    with open_client(max(workers, 1), scheduler, host="127.0.0.1", source="synth --scheduler") as c:
        return _run_on(c, str(root), batches, params, radius_m, settings, seed, progress, len(rows))


def _run_on(
    client: ComputeClient, root: str, batches: list[list[dict[str, Any]]], params: dict[str, Any], radius_m: float,
    settings: RenderSettings, seed: int, progress: Callable[[int, int], None] | None, total: int,
) -> list[tuple[str, float]]:
    from mercury_dem.compute import as_completed

    futures = [client.submit(render_batch, root, b, params, radius_m, settings, seed, pure=False) for b in batches]
    done: list[tuple[str, float]] = []
    for fut in as_completed(client, futures):
        done += fut.result()
        if progress:
            progress(len(done), total)
    return done
