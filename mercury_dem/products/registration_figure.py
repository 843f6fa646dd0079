"""The registration's figure: residual RMS per tile and per profile, before and after (seed 004's Figure 1).

A product of the registration stage (``registration/rms_per_tile.png``, copied to the products by
:func:`mercury_dem.pipeline.register_stage.make_registration_products`). It sits with the products, not in
``viz/``: the stage writes it, and ``viz/`` (figures of a run, read back from its store) is a layer above
the pipeline that calls this (docs/architecture.md).
"""

from __future__ import annotations

import io

import numpy as np
import pandas as pd

__all__ = ["rms_per_tile_png"]


def rms_per_tile_png(table: pd.DataFrame, profiles: pd.DataFrame) -> bytes:
    """PNG bytes: per registered tile (by tile id) the RMS shot − DEM residual of the DEM as given (blue),
    after the tile transform (orange) and after the profile offsets (red); per fitted profile before/after.

    ``table``: one row per tile (``tile_id``, ``ok``, ``rms_before_m``, ``rms_registered_m``,
    ``rms_after_m``); ``profiles``: one row per profile (``fitted``, ``rms_before_m``, ``rms_after_m``).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    ok = table[table["ok"].astype(bool)].sort_values("tile_id")  # astype: an empty object column would select columns
    x = np.arange(len(ok))
    ax = axes[0]
    ax.semilogy(x, ok["rms_before_m"], "o", ms=3, color="tab:blue", label="image DEM as given")
    ax.semilogy(x, ok["rms_registered_m"], "s", ms=3, color="tab:orange", label="after tile transform")
    ax.semilogy(x, ok["rms_after_m"], "^", ms=3, color="tab:red", label="after profile offsets")
    ax.set_xlabel("registered tile (by tile id)")
    ax.set_ylabel("RMS shot − DEM residual (m)")
    ax.set_title("per tile")
    ax.legend(fontsize=8)
    ax = axes[1]
    fp = profiles[profiles["fitted"]] if len(profiles) else profiles
    if len(fp):
        k = np.arange(len(fp))
        ax.semilogy(k, fp["rms_before_m"], ".", ms=2, color="tab:blue", label="before profile offset")
        ax.semilogy(k, fp["rms_after_m"], ".", ms=2, color="tab:red", label="after")
        ax.legend(fontsize=8)
    ax.set_xlabel("profile")
    ax.set_title("per profile (registered DEM)")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()
