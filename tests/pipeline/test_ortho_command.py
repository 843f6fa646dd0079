"""``mercury-dem ortho`` on the tiny run: orthoimages and tile mosaics from the run's adjusted poses and DEM."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytestmark = pytest.mark.integration


def test_ortho_command_writes_images_and_mosaics_and_names_bad_images(
    sync_run: tuple[Path, dict[str, Any]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Two controlled images and one unknown id: the unknown one is named and skipped, the others get COGs in
    the body's CRS, their tile a mosaic whose index layer names only them.
    """
    import rasterio

    from mercury_dem.cli import main
    from mercury_dem.io.run_store import read_solution

    run, _ = sync_run
    sid, _, _, table = read_solution(run / "global" / "0" / "solution.parquet")
    good = [str(i) for i, n in zip(sid, table["n_measures"]) if n > 0][:2]
    out = tmp_path / "ortho"
    assert main(["ortho", str(run), "--images", *good, "no-such-image", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "no-such-image" in err
    summary = json.loads((out / "ortho.json").read_text())
    assert set(summary["images"]) == set(good) and set(summary["skipped"]) == {"no-such-image"}
    for i in good:
        with rasterio.open(out / f"{i}.tif") as ds:
            assert ds.tags()["CRS_CODE"].startswith("IAU_2015:199") and ds.overviews(1)
            v = ds.read(1)
            assert np.isfinite(v).mean() > 0.3
    mosaics = [m for m in summary["mosaics"].values() if "path" in m]
    assert mosaics
    with rasterio.open(mosaics[0]["index"]) as ds:
        idx = ds.read(1)
        names = json.loads(ds.tags()["SOURCE_IMAGES"])
    assert set(names) <= set(good) and idx.max() >= 0 and set(np.unique(idx)) <= {-1, *range(len(names))}
