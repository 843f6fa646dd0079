"""The tile stage's per-image fault check (``match.prepare.pixel_faults``) names unusable images, and only them."""

from __future__ import annotations

import numpy as np

from mercury_dem.config.match import MatchConfig
from mercury_dem.match.prepare import pixel_faults


def test_blank_saturated_and_flat_images_are_named_textured_and_unread_are_not() -> None:
    cfg = MatchConfig()
    rng = np.random.default_rng(3)
    textured = rng.normal(1500.0, 300.0, (128, 128)).clip(0, 4000).astype(np.float32)
    pixels = {
        "good": textured,
        "blank": np.zeros((128, 128), np.float32),
        "saturated": np.full((128, 128), 4095.0, np.float32),
        "flat": np.full((128, 128), 1200.0, np.float32),
        "unread": None,
    }
    radiometry = {k: (4095.0, 1.0) for k in pixels}
    faults = pixel_faults(pixels, radiometry, cfg)
    assert set(faults) == {"blank", "saturated", "flat"}
    for image_id, message in faults.items():
        assert message.startswith(f"image {image_id}: ") and "uncontrolled" in message
