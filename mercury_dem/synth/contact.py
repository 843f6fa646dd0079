"""Contact sheet: a grid of a mission's images with their geometry, as a PNG (matplotlib, Agg)."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from mercury_dem.mission import Mission

from pathlib import Path

import numpy as np


def contact_sheet(mission: Mission, path: str | Path, image_ids: list[str] | None = None, columns: int = 4,
                  max_images: int = 12) -> Path:
    """Write a PNG of up to ``max_images`` images (default: spread over the catalog) with id, instrument,
    pixel scale, incidence and emission in the titles. Returns the path.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cat = mission.catalog.set_index("image_id")
    if image_ids is None:
        ids = mission.image_ids
        pick = np.linspace(0, len(ids) - 1, min(max_images, len(ids))).round().astype(int)
        image_ids = [ids[i] for i in np.unique(pick)]
    n = len(image_ids)
    rows = int(np.ceil(n / columns))
    fig, axes = plt.subplots(rows, columns, figsize=(3.2 * columns, 3.5 * rows), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, image_id in zip(axes.ravel(), image_ids):
        img = mission.read_image(image_id)
        r = cat.loc[image_id]
        lo, hi = np.percentile(img, [1.0, 99.0])
        ax.imshow(img, cmap="gray", vmin=lo, vmax=max(hi, lo + 1), interpolation="nearest")
        ax.set_title(
            f"{image_id} {str(r['instrument'])[-3:]}\n{r['pixel_scale_m']:.0f} m/px  i={r['incidence_deg']:.0f}°"
            f"  e={r['emission_deg']:.0f}°",
            fontsize=8,
        )
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
