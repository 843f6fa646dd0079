"""Plane or quadratic altimetry surfaces inside the adjustment, on the synthetic networks of the tests.

For each seed: the network and shots of ``tests/altimetry/test_adjust_with_altimetry.py`` (12,000 points,
3+ views, 1.5 km relief, 8 shots within 700 m around half of the points, 1 m noise: ``SyntheticNetwork.altimetry_shots``), adjusted without
altimetry and with it, with plane and quadratic fits, with the default search radii (1, 3, 10 km) and
with 10 km alone. Prints the constrained points' radius RMS against the truth, the RMS of error/sigma
and the pointing of the determined images (>= 30 measures), px.

    PYTHONPATH=. python workflows/benchmarks/altimetry_surface_study.py 4 29 53
"""

from __future__ import annotations

import dataclasses
import sys

import numpy as np

from mercury_dem.adjust.bundle import bundle_adjust
from mercury_dem.altimetry.constraints import AltimetryShotsArrays, bundle_adjust_with_altimetry
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.geometry.body import DATUM_RADIUS_M as DATUM
from mercury_dem.validate.synthetic_network import make_synthetic_network, pointing_errors


def main(seeds: list[int]) -> None:
    for seed in seeds:
        rng = np.random.default_rng(seed)
        net = make_synthetic_network(12_000, rng=rng, min_views=3, outlier_fraction=0.0, noise_px=0.25,
                                     relief_m=1500.0)
        pts = net.problem.points
        problem = dataclasses.replace(net.problem, points=pts / np.linalg.norm(pts, axis=1, keepdims=True) * DATUM)
        cfg = AdjustConfig(radius_sigma_m=10_000.0)
        shots = AltimetryShotsArrays(*net.altimetry_shots(rng, per_point=8, reach_m=700.0, noise_m=1.0), 1.0)
        plain = bundle_adjust(problem, cfg)
        ifov = np.array([net.problem.cameras[k].ifov_rad for k in net.problem.image_camera])
        sel = plain.accepted_per_image >= 30

        def pointing(rot: np.ndarray, net=net, sel=sel, ifov=ifov) -> float:  # bound per seed
            p = np.linalg.norm(pointing_errors(rot, net.true_rotations)[0][sel, :2], axis=1) / ifov[sel]
            return float(np.sqrt(np.mean(p**2)))

        for surface in ("plane", "quadratic"):
            for radii in ((1000.0, 3000.0, 10_000.0), (10_000.0,)):
                alt, pri = bundle_adjust_with_altimetry(problem, cfg, shots, surface=surface, search_radius_m=radii)
                c = pri.constrained & np.all(np.isfinite(alt.points), axis=1)
                e = np.linalg.norm(alt.points[c], axis=1) - np.linalg.norm(net.true_points[c], axis=1)
                print(f"seed {seed} {surface:9s} radii {radii}: {c.sum()} constrained, radius RMS "
                      f"{np.sqrt(np.mean(e**2)):.2f} m, RMS(error/sigma) {np.sqrt(np.mean((e / pri.sigma_m[c]) ** 2)):.2f}; "
                      f"pointing {pointing(plain.rotations):.3f} -> {pointing(alt.rotations):.3f} px", flush=True)


if __name__ == "__main__":
    main([int(a) for a in sys.argv[1:]] or [4, 29])
