"""A/B of step 1's profile nuisance on bench_register.py's synthetic data, tile by tile (issue 16).

Accuracy only (no timing: light enough to run outside the benchmark lock): the same global DEM
(8 px/deg, misregistered by 0.02 deg lat, 0.03 deg lon, 300 m down) and shots as
``bench_register.py --seed SEED``; on NTILES random tiles (|lat| < 60, tile 397 included) the
similarity tile fit with ``profile_nuisance`` on (the default: the offsets kept out of the transform
directions they mimic), on without that (``free``: ``nuisance_min_within_share=0``, before session 11) and
off (``plain``): the transform-only RMS
(``rms_registered_m``), the RMS after step 2's profile offsets and T's translation.

Usage::

    PYTHONPATH=$PWD .venv/bin/python workflows/benchmarks/ab_register_nuisance.py SHOTS SEED NTILES [WORKDIR]
"""
import importlib.util
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

spec = importlib.util.spec_from_file_location("br", str(Path(__file__).with_name("bench_register.py")))
br = importlib.util.module_from_spec(spec); spec.loader.exec_module(br)
from pathlib import Path

from mercury_dem.altimetry.register import RegisterOptions, register_tile, tile_window
from mercury_dem.geometry.tiling import TileGrid
from mercury_dem.products.make import open_dem

R = br.R
n = float(sys.argv[1]); seed = int(sys.argv[2]); ntiles = int(sys.argv[3])
rng = np.random.default_rng(seed)
surf = br.Surface(rng, min_wavelength_m=50e3)
work = Path(sys.argv[4]) if len(sys.argv) > 4 else Path(tempfile.mkdtemp(prefix="ab_nuis_")); work.mkdir(parents=True, exist_ok=True)
if not (work / "dem.zarr").exists():
    br.make_dem(surf, 8.0, work / "dem.zarr", (0.02, 0.03, 300.0))
shots = br.make_shots(surf, int(n), rng)
ds = open_dem(work / "dem.zarr"); el = ds["elevation"].values; la = ds["lat"].values; lo = ds["lon"].values
tg = TileGrid(10.0)
tile = tg.tile_of(shots["lat"].to_numpy(), shots["lon"].to_numpy())
ids = np.unique(tile)
cent = np.array([tg.centre(int(t)) for t in ids])
ids = ids[np.abs(cent[:, 0]) < 60]
pick = np.random.default_rng(0).choice(ids, size=min(ntiles, ids.size), replace=False)
if 397 in ids and 397 not in pick: pick = np.r_[397, pick[:-1]]
variants = {"nuis": RegisterOptions(models=("similarity",)),
            "free": RegisterOptions(models=("similarity",), nuisance_min_within_share=0.0),
            "plain": RegisterOptions(models=("similarity",), profile_nuisance=False)}
rows = []
for t in pick:
    t = int(t); c = tuple(float(v) for v in tg.centre(t))
    win = tile_window(el, la, lo, tuple(float(v) for v in tg.bounds(t)), R, 1.0)
    sel = shots[tile == t]
    row = {"tile": t, "lat": c[0], "shots": len(sel), "profiles": sel["profile_id"].nunique()}
    for k, o in variants.items():
        res = register_tile(win, sel["lat"].to_numpy(), sel["lon"].to_numpy(), sel["radius_m"].to_numpy(),
                            sel["profile_id"].to_numpy(), tile_id=t, centre=c, options=o)
        tr = np.asarray(res.transform.translation_enu_m)
        row.update({f"{k}_ok": res.transform.ok, f"{k}_rms_reg": res.rms_registered_m, f"{k}_rms_after": res.rms_after_m,
                    f"{k}_tE": tr[0], f"{k}_tN": tr[1], f"{k}_tU": tr[2], f"{k}_it": res.iterations})
    row["dtr"] = float(np.max(np.abs([row["nuis_tE"] - row["plain_tE"], row["nuis_tN"] - row["plain_tN"], row["nuis_tU"] - row["plain_tU"]])))
    row["truthE"] = -1277.0 * np.cos(np.radians(c[0]))
    rows.append(row); print(row, flush=True)
df = pd.DataFrame(rows); df.to_csv(work / "ab.csv", index=False)
pd.set_option("display.width", 250)
print(df[["tile", "lat", "profiles", "nuis_rms_reg", "free_rms_reg", "plain_rms_reg", "nuis_rms_after", "plain_rms_after", "nuis_tE", "plain_tE", "truthE", "nuis_tN", "plain_tN", "nuis_tU", "plain_tU", "dtr", "nuis_it", "plain_it"]].round(2).to_string())
for k in ("nuis", "free", "plain"):
    d = df[df[k + "_ok"]]  # a tile the model did not determine reports no translation
    e = np.c_[d[k + "_tE"] - d.truthE, d[k + "_tN"] + 851.0, d[k + "_tU"] - 300.0]
    print(k, "median rms_reg", round(float(df[k + "_rms_reg"].median()), 2), "max", round(float(df[k + "_rms_reg"].max()), 1),
          "RMS translation error E/N/U vs the injected shift", np.round(np.sqrt(np.mean(e ** 2, axis=0)), 2),
          "tiles determined", int(df[k + "_ok"].sum()))
print("median rms_reg nuis/plain", df.nuis_rms_reg.median(), df.plain_rms_reg.median(), "median dtr", df.dtr.median())
