"""Bad input and unsolvable networks: clear errors naming images and points (issue #5, sections 3 and 7)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mercury_dem.adjust.bundle import bundle_adjust
from mercury_dem.adjust.diagnose import diagnose
from mercury_dem.adjust.problem import AdjustmentProblem
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.exceptions import AdjustmentError


def _fields(p: AdjustmentProblem) -> dict:
    return dict(cameras=p.cameras, image_camera=p.image_camera, positions=p.positions, rotations=p.rotations,
                points=p.points, measure_image=p.measure_image, measure_point=p.measure_point, measures=p.measures,
                measure_sigma=p.measure_sigma, image_ids=p.image_ids)


def test_unknown_image_and_point_indices(small_network):
    f = _fields(small_network.problem)
    mi = f["measure_image"].copy()
    mi[5] = 999
    with pytest.raises(AdjustmentError, match="unknown images .*999"):
        AdjustmentProblem(**{**f, "measure_image": mi})
    mp = f["measure_point"].copy()
    mp[0] = -1
    with pytest.raises(AdjustmentError, match=r"unknown points \(indices \[-1\]"):
        AdjustmentProblem(**{**f, "measure_point": mp})


def test_nan_measures_and_bad_sigmas_are_named(small_network):
    f = _fields(small_network.problem)
    meas = f["measures"].copy()
    meas[3, 1] = np.nan
    with pytest.raises(AdjustmentError, match=r"NaN/inf .*images \['SYN"):
        AdjustmentProblem(**{**f, "measures": meas})
    sig = f["measure_sigma"].copy()
    sig[7] = 0.0
    p = small_network.problem
    named = rf"sigma <= 0 .*points \[{p.point_ids[p.measure_point[7]]}\], images \['{p.image_ids[p.measure_image[7]]}'\]"
    with pytest.raises(AdjustmentError, match=named):
        AdjustmentProblem(**{**f, "measure_sigma": sig})
    sig[7] = -1.0
    with pytest.raises(AdjustmentError, match="sigma <= 0"):
        AdjustmentProblem(**{**f, "measure_sigma": sig})
    with pytest.raises(AdjustmentError, match="shape"):
        AdjustmentProblem(**{**f, "points": f["points"][:, :2]})


def test_empty_network(small_network):
    f = _fields(small_network.problem)
    with pytest.raises(AdjustmentError, match="no measures"):
        AdjustmentProblem(**{**f, "measure_image": [], "measure_point": [], "measures": np.zeros((0, 2)), "measure_sigma": 1.0})


def test_islands_are_found_and_named(small_network):
    """Two copies of a network side by side (no shared point) are two islands: an error naming the
    smaller one, unless islands are allowed."""
    p = small_network.problem
    n_img, n_pt = p.n_images, p.n_points
    ids = p.image_ids + tuple(f"COPY{i}" for i in range(n_img))
    two = AdjustmentProblem(
        cameras=p.cameras, image_camera=np.concatenate([p.image_camera, p.image_camera]),
        positions=np.concatenate([p.positions, p.positions]), rotations=np.concatenate([p.rotations, p.rotations]),
        points=np.concatenate([p.points, p.points]), measure_image=np.concatenate([p.measure_image, p.measure_image + n_img]),
        measure_point=np.concatenate([p.measure_point, p.measure_point + n_pt]),
        measures=np.concatenate([p.measures, p.measures]), measure_sigma=1.0, image_ids=ids,
        pointing_sigma_urad=p.pointing_sigma_urad)
    d = diagnose(two)
    assert len(d.islands) == 2 and sorted(map(len, d.islands)) == [n_img, n_img]
    with pytest.raises(AdjustmentError, match="2 islands"):
        bundle_adjust(two, AdjustConfig())
    res = bundle_adjust(two, AdjustConfig(allow_islands=True, max_iterations=3))
    assert len(res.diagnosis.islands) == 2


def test_image_without_measures_is_an_error_naming_it(small_network):
    p = small_network.problem
    extra = AdjustmentProblem(
        cameras=p.cameras, image_camera=np.append(p.image_camera, 0), positions=np.vstack([p.positions, p.positions[:1]]),
        rotations=np.concatenate([p.rotations, p.rotations[:1]]), points=p.points, measure_image=p.measure_image,
        measure_point=p.measure_point, measures=p.measures, measure_sigma=p.measure_sigma,
        image_ids=p.image_ids + ("LONELY_IMAGE",), pointing_sigma_urad=p.pointing_sigma_urad)
    with pytest.raises(AdjustmentError, match="LONELY_IMAGE"):
        bundle_adjust(extra)
    # held, it is fine (it is not adjusted)
    bundle_adjust(replace(extra, held_images=np.append(np.zeros(p.n_images, bool), True)), AdjustConfig(max_iterations=2))


def test_points_with_one_measure_are_flagged_not_dropped(small_network):
    p = small_network.problem
    # give one point a single measure by deleting the others
    j = p.measure_point[0]
    keep = (p.measure_point != j) | (np.arange(p.n_measures) == 0)
    q = replace(p, measure_image=p.measure_image[keep], measure_point=p.measure_point[keep],
                measures=p.measures[keep], measure_sigma=p.measure_sigma[keep])
    d = diagnose(q)
    assert j in d.underdetermined_points
    res = bundle_adjust(q, AdjustConfig(max_iterations=3))
    assert res.underdetermined_points[j]
    np.testing.assert_array_equal(res.points[j], q.points[j])  # not adjusted
    assert "UNDER-DETERMINED POINTS" in __import__("mercury_dem.adjust.report", fromlist=["x"]).text_report(res)


def test_unknown_held_image_id(small_network):
    with pytest.raises(AdjustmentError, match="held_images names images not in the network"):
        bundle_adjust(small_network.problem, AdjustConfig(held_images=("NOPE",)))


def test_divergent_solve_keeps_the_best_state_and_reports_why(small_network, monkeypatch):
    """Every trial step raises the cost (sigma0 would rise): the adjustment stops, keeps the a-priori
    state (the best seen), is not converged, and the reason is in the result and the report."""
    from mercury_dem.adjust import framing
    from mercury_dem.adjust.report import text_report

    real = framing.FramingModel.retract

    def diverging(self, state, d_camera, d_point):  # every step lands 1 mrad off, however small it is
        return real(self, state, d_camera + 1e-3, d_point)

    monkeypatch.setattr(framing.FramingModel, "retract", diverging)
    p = small_network.problem
    res = bundle_adjust(p, AdjustConfig(max_iterations=5))
    assert not res.converged
    assert res.reason.startswith("no decrease possible")
    assert np.all(res.pointing_corrections == 0.0)
    np.testing.assert_array_equal(res.points, p.points)
    assert res.log[-1]["cost"] == res.log[0]["cost"] and not res.log[-1]["step_accepted"]
    assert "no decrease possible" in text_report(res)
