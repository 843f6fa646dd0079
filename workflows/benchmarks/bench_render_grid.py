"""Render cost of the renderer's surface grid: the 1-pixel grid (default) vs the half-pixel grid (issue 31).

One image per call (``render_image``, warm, in this process: numba kernels compiled and the surface built
before timing), the two settings interleaved A B A B ..., ``--repeats`` rounds; the tiny preset's surface and
image size (256^2, 2 km/px) and the demo's (512^2 at 1.5 km/px over the demo-like default surface),
geometry of ``bench_render.py`` (incidence 70 deg, emission 25 deg). Reported: median wall and CPU seconds
per image, and the new/old ratios. Record: ``records/bench_render_grid.jsonl``.

Run: ``flock /tmp/mercury_bench.lock env NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1 .venv/bin/python
workflows/benchmarks/bench_render_grid.py``
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_render import geometry  # noqa: E402
from harness.measure import interleave, measure_here, median  # noqa: E402
from harness.records import append_record  # noqa: E402

from mercury_dem.synth.presets import get_preset  # noqa: E402
from mercury_dem.synth.render import RenderSettings, render_image  # noqa: E402
from mercury_dem.synth.terrain import Surface  # noqa: E402

OLD = RenderSettings(grid_spacing_px=1.0, surface_resolution_px=0.0)


def main() -> None:
    """Time both settings on both scenes and append the record."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    new = RenderSettings(grid_spacing_px=0.5, surface_resolution_px=1.0)  # mercury-dem synth --render-grid-px 0.5
    values = {}
    for name, preset, samples, scale in (("tiny", "tiny", 256, 2000.0), ("demo", "demo", 512, 1500.0)):
        params = get_preset(preset).surface
        if params.shape_harmonics:  # the packaged shape file: keep the timing about the renderer
            params = replace(params, shape_harmonics="")
        surface = Surface(params)
        cam, c, r, sun = geometry(samples, scale)
        for st in (OLD, new):
            render_image(surface, cam, c, r, sun, np.random.default_rng(0), st)  # warm-up

        def run(st: RenderSettings, label: str, scene: tuple = (surface, cam, c, r, sun)):
            return lambda: measure_here(render_image, *scene, np.random.default_rng(0), st, label=label)

        res = interleave({"old": run(OLD, "old"), "new": run(new, "new")}, a.repeats)
        for fig in ("wall_s", "cpu_s"):
            o, n = median(res["old"], fig), median(res["new"], fig)
            values[f"{name}_{fig}_old"], values[f"{name}_{fig}_new"], values[f"{name}_{fig}_ratio"] = o, n, n / o
        print(f"{name} {samples}^2 at {scale:.0f} m/px: old {values[f'{name}_wall_s_old']:.3f} s, new "
              f"{values[f'{name}_wall_s_new']:.3f} s wall (x{values[f'{name}_wall_s_ratio']:.2f}); CPU x"
              f"{values[f'{name}_cpu_s_ratio']:.2f}", flush=True)
    append_record("bench_render_grid", {"repeats": a.repeats, "old": "grid_spacing_px 1.0",
                                        "new": f"grid_spacing_px {new.grid_spacing_px}, surface_resolution_px "
                                               f"{new.surface_resolution_px}"}, values)


if __name__ == "__main__":
    main()
