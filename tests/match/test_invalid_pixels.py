"""Invalid pixels (ISIS special pixels, NaN in a float image) never carry keypoints."""

from __future__ import annotations

import numpy as np

from mercury_dem.config import load_config
from mercury_dem.match.prepare import prepare_image


def test_no_keypoints_on_or_next_to_invalid_pixels() -> None:
    rng = np.random.default_rng(3)
    from scipy.ndimage import gaussian_filter

    img = (0.05 + 0.2 * gaussian_filter(rng.normal(0.0, 0.1, (256, 256)), 2.0)).astype(np.float32)  # I/F-like
    img[:, 100:140] = np.nan  # a band of NULL pixels
    cfg = load_config().match
    feats = prepare_image(img, img.shape, cfg, radiometry=(float("nan"), 0.5 / 4095)).features
    assert feats.size > 50
    s = feats.points[:, 0]
    assert not np.any((s > 100 - 4 - 1) & (s < 140 + 4)), "a keypoint sits on or at the edge of invalid pixels"
    # the same image without the band has keypoints there: the mask, not the texture, removed them
    clean = np.where(np.isfinite(img), img, (0.05 + 0.2 * gaussian_filter(rng.normal(0.0, 0.1, img.shape), 2.0))).astype(np.float32)
    s2 = prepare_image(clean, clean.shape, cfg, radiometry=(float("nan"), 0.5 / 4095)).features.points[:, 0]
    assert np.any((s2 > 95) & (s2 < 145))
