"""The per-unit adjustment strategy (:func:`mercury_dem.adjust.unit.adjust_unit_network`) on synthetic networks."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from mercury_dem.adjust.datum import LevellingDecision
from mercury_dem.adjust.unit import adjust_unit_network, flagged_images
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.network import ControlNetwork
from mercury_dem.validate.synthetic_network import SyntheticNetwork, make_synthetic_network, pointing_errors

NOISE_PX = 0.25
DATUM_M = 2_439_400.0
CFG = AdjustConfig(point_prior_center="network")
POINTING_SIGMA_URAD = 450.0  # the synthetic network's a-priori pointing error (1 sigma per axis)


def _unit(seed: int) -> tuple[SyntheticNetwork, ControlNetwork, list[Any]]:
    syn = make_synthetic_network(3000, rng=np.random.default_rng(seed), min_views=3, outlier_fraction=0.0,
                                 noise_px=NOISE_PX, measures_per_image=150)
    p = syn.problem
    net = ControlNetwork.from_arrays(np.array(p.image_ids), np.arange(p.n_points), p.measure_point, p.measure_image,
                                     p.measures[:, 0], p.measures[:, 1], apriori_xyz=p.points,
                                     sigma=np.ones((p.n_measures, 2)))
    return syn, net, [p.cameras[k] for k in p.image_camera]


@pytest.fixture(scope="module")
def unit() -> tuple[SyntheticNetwork, ControlNetwork, list[Any]]:
    """The synthetic unit of seed 3 (clean, 0.25 px noise), made once."""
    return _unit(3)


def _adjust(unit: tuple[SyntheticNetwork, ControlNetwork, list[Any]], cfg: AdjustConfig = CFG, **kw: Any) -> Any:
    syn, net, cams = unit
    return adjust_unit_network(net, cams, syn.problem.positions, syn.problem.rotations, cfg,
                               pointing_sigma_urad=POINTING_SIGMA_URAD, datum_radius_m=DATUM_M, **kw)


@pytest.mark.parametrize("seed", [3, 29])  # 3 (and 11) looked at when writing the bounds; 29 not
def test_residuals_come_down_to_the_injected_noise(seed: int) -> None:
    """Residual RMS = noise x sqrt(redundancy); the relative pointing error falls 4x; nothing flagged."""
    unit = _unit(seed)
    adj = _adjust(unit)
    s = adj.summary
    m, n, k = s["measures"], s["points"], s["images"]
    expected = NOISE_PX * np.sqrt((2 * m - 3 * n - 3 * k) / (2 * m))  # least squares: noise x sqrt(redundancy)
    assert s["rms_px"] == pytest.approx(expected, rel=0.1)
    assert s["initial_rms_px"] > 10 * expected
    assert s["rejected"] < 0.03 * m  # Gaussian noise only: the 3 x MAD tail
    syn, _, cams = unit
    ifov = np.array([c.ifov_rad for c in cams])
    _, _, before = pointing_errors(syn.problem.rotations, syn.true_rotations)
    _, _, after = pointing_errors(adj.rotations, syn.true_rotations)
    px = [float(np.sqrt(np.mean((np.linalg.norm(e[:, :2], axis=1) / ifov) ** 2))) for e in (before, after)]
    assert px[1] < px[0] / 4  # the relative pointing error (block rotation removed), in pixels
    assert s["flagged_images"] == [] and s["islands"] == [] and s["images_without_measures"] == []
    assert s["point_prior_centre"] == {"centre": "network", "radius_sigma_m": CFG.radius_sigma_m}
    assert np.array_equal(adj.image_measures, np.bincount(adj.network.measure_image[~adj.network.measure_rejected],
                                                          minlength=k))


def test_rms_flag_px_is_the_configured_threshold(unit: tuple[SyntheticNetwork, ControlNetwork, list[Any]]) -> None:
    """``adjust.rms_flag_px`` decides which images are flagged (default 2 px)."""
    base = _adjust(unit)
    threshold = float(np.median(base.image_rms_px))
    flagged = _adjust(unit, AdjustConfig(**{**CFG.__dict__, "rms_flag_px": threshold})).summary["flagged_images"]
    ids = np.asarray(unit[1].image_ids).astype(str)
    assert [f["image"] for f in flagged] == [str(i) for i in ids[base.image_rms_px > threshold]]
    assert 0 < len(flagged) < len(ids) and all(f["rms_px"] > threshold for f in flagged)
    assert AdjustConfig().rms_flag_px == 2.0


def test_flagged_images_ignores_nan() -> None:
    """An image without an RMS (NaN) is not flagged."""
    ids = np.array(["a", "b", "c"])
    assert flagged_images(ids, np.array([3.0, np.nan, 1.0]), 2.0) == [{"image": "a", "rms_px": 3.0}]


class _Heights:
    """A stand-in for the altimetry's part: a fixed levelling decision, and a marker for the shots' adjustment."""

    def __init__(self, recentre: bool, shots: bool):
        self.decision = LevellingDecision(recentre, True, 42.0, 0.1, "test decision")
        self.shots = shots
        self.calls: list[str] = []

    def levelling(self, points_xyz: Any, cfg: AdjustConfig) -> LevellingDecision:
        self.calls.append("levelling")
        return self.decision

    def adjust(self, problem: Any, cfg: AdjustConfig, solve: Any) -> Any:
        self.calls.append("adjust")
        return (solve(problem, cfg), {"shots": 7}) if self.shots else None


def test_the_levelling_decision_and_the_shots_are_the_height_terms(
        unit: tuple[SyntheticNetwork, ControlNetwork, list[Any]]) -> None:
    """The levelling decision and the shots' adjustment come from the HeightTerms, in that order."""
    cfg = AdjustConfig(**{**CFG.__dict__, "point_prior_center": "datum", "max_iterations": 5})
    h = _Heights(recentre=True, shots=True)
    s = _adjust(unit, cfg, heights=h, recentre_point_priors=True).summary
    assert h.calls == ["levelling", "adjust"]
    assert s["levelling"] == h.decision.summary() and s["point_prior"]["recentred_points"] > 0
    assert s["altimetry"] == {"shots": 7}
    assert s["point_prior_centre"]["centre"] == "datum"
    h = _Heights(recentre=False, shots=False)
    s = _adjust(unit, cfg, heights=h, recentre_point_priors=True).summary
    assert "point_prior" not in s and "altimetry" not in s and s["levelling"]["recentre"] is False
    h = _Heights(recentre=True, shots=False)
    s = _adjust(unit, cfg, heights=h).summary  # a level not re-centred: no decision asked for
    assert h.calls == ["adjust"] and "levelling" not in s and "point_prior" not in s


class _Shape:
    name = "TEST_SHAPE"
    prior_sigma_m = 1234.0

    def radius_at_xyz(self, xyz: Any) -> Any:
        return np.full(len(xyz), DATUM_M + 500.0)


def test_points_on_a_shape_take_its_sigma_and_are_not_recentred(
        unit: tuple[SyntheticNetwork, ControlNetwork, list[Any]]) -> None:
    """On a body's shape: its sigma, no re-centring (the reason names the shape); without one, the datum."""
    cfg = AdjustConfig(**{**CFG.__dict__, "point_prior_center": "shape", "max_iterations": 5})
    h = _Heights(recentre=True, shots=False)
    s = _adjust(unit, cfg, heights=h, recentre_point_priors=True, prior_shape=_Shape()).summary
    assert s["point_prior_centre"] == {"centre": "shape", "shape": "TEST_SHAPE", "radius_sigma_m": 1234.0}
    assert s["levelling"]["recentre"] is False and "TEST_SHAPE" in s["levelling"]["reason"]
    assert "point_prior" not in s
    s = _adjust(unit, cfg, heights=h, recentre_point_priors=True).summary  # no shape: the datum, and why
    assert s["point_prior_centre"]["centre"] == "datum" and "no shape model" in s["point_prior_centre"]["why"]
    assert s["levelling"]["recentre"] is True and "point_prior" in s
