"""Benchmark: merge_networks, validate and the ISIS codec on a planetary-size synthetic network.

A network of N points with 5 measures each (default N = 10^6, M = 5*10^6) over
K = 20,000 images of 1024^2 pixels is generated vectorized, then cut into 4
"tile" networks that share 10 % of their points with the next tile (the same
measures, as two tiles that matched the same image pair), so that the merge
must join them back. Measured, each in one process, one after the other:

* ``merge_networks(tiles)`` and ``validate(merged)``: seconds and peak memory
  (resident high-water mark above the level before the call, from
  /proc/self/status after resetting it via /proc/self/clear_refs: ``harness.peak_window``);
* side by side, the straightforward references on the same data: a
  pandas ``duplicated``/``groupby`` validation of the same checks, and a
  per-measure Python dict union-find merge (the way ISIS tools loop per point)
  on a 1 % sample, extrapolated linearly and marked so;
* the ISIS ``.net`` version 5 encode/decode of the merged network.

Run: ``flock /tmp/mercury_bench.lock .venv/bin/python workflows/benchmarks/bench_network.py [--points N]``
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from harness import peak_window

from mercury_dem.io.isis_net import read_isis_network
from mercury_dem.network import ControlNetwork, merge_networks, validate
from mercury_dem.network.isis import encode_isis_network


def measure(fn, *args, **kw):
    """(result, seconds, peak extra resident memory in MiB) of one call, in this process (``harness.peak_window``)."""
    with peak_window() as w:
        t0 = time.perf_counter()
        out = fn(*args, **kw)
        sec = time.perf_counter() - t0
    return out, sec, w.extra_bytes / 1024.0**2


def synthetic_network(n_points: int, n_images: int, per_point: int = 5, seed: int = 0) -> ControlNetwork:
    rng = np.random.default_rng(seed)
    base = np.sort(rng.integers(0, n_images, n_points))
    mi = (base[:, None] + np.arange(per_point)) % n_images
    m = n_points * per_point
    return ControlNetwork.from_arrays(
        np.array([f"EN{1000000000 + i}M" for i in range(n_images)]),
        np.arange(n_points, dtype=np.int64),
        np.repeat(np.arange(n_points, dtype=np.int64), per_point),
        mi.ravel(),
        rng.uniform(0, 1023, m),
        rng.uniform(0, 1023, m),
        apriori_xyz=rng.normal(0, 1, (n_points, 3)) * 2.4394e6,
        sigma=np.full((m, 2), 0.3),
    )


def tiles_of(net: ControlNetwork, n_tiles: int = 4, shared: float = 0.10, seed: int = 1) -> list[ControlNetwork]:
    """Cut by point order into tiles; a fraction of each tile's points also goes to the next tile."""
    rng = np.random.default_rng(seed)
    n = net.n_points
    tile = np.minimum(np.arange(n) * n_tiles // n, n_tiles - 1)
    dup = rng.random(n) < shared
    out = []
    for t in range(n_tiles):
        sel = (tile == t) | (dup & (tile == (t - 1) % n_tiles))
        sub = net.take_points(np.flatnonzero(sel))
        out.append(sub)
    return out


def pandas_validate(net: ControlNetwork) -> dict:
    """The same checks written the obvious way with pandas (reference)."""
    import pandas as pd
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    df = pd.DataFrame({"point": net.measure_point, "image": net.measure_image, "s": net.sample, "l": net.line})
    dups = int(df.duplicated(["point", "image"]).sum())
    per_point = df.groupby("point").size()
    lt2 = int((per_point < 2).sum())
    per_image = df.groupby("image").size()
    few = int((per_image < 3).sum())
    outside = int(((df.s < -0.5) | (df.s > 1023.5) | (df.l < -0.5) | (df.l > 1023.5)).sum())
    k, n = net.n_images, net.n_points
    g = coo_matrix((np.ones(len(df)), (df.image.to_numpy(), k + df.point.to_numpy())), shape=(k + n, k + n))
    n_comp, _ = connected_components(g, directed=False)
    return {"dups": dups, "lt2": lt2, "few": few, "outside": outside, "components": n_comp}


def dict_merge(nets: list[ControlNetwork], tolerance_px: float = 1.0) -> int:
    """Per-measure Python merge with a dict of rounded pixels and union-find (reference)."""
    parent: dict[tuple[int, int], tuple[int, int]] = {}

    def find(x):
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    seen: dict[tuple[str, int, int], tuple[int, int]] = {}
    for t, net in enumerate(nets):
        for m in range(net.n_measures):
            p = (t, int(net.measure_point[m]))
            parent.setdefault(p, p)
            key = (str(net.image_ids[net.measure_image[m]]), int(net.sample[m] // tolerance_px), int(net.line[m] // tolerance_px))
            if key in seen:
                a, b = find(p), find(seen[key])
                if a != b:
                    parent[a] = b
            else:
                seen[key] = p
    return len({find(p) for p in parent})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--images", type=int, default=20_000)
    args = ap.parse_args()
    print(f"date: {time.strftime('%Y-%m-%d %H:%M:%S %Z')}, cores: {os.cpu_count()}")
    t0 = time.perf_counter()
    net = synthetic_network(args.points, args.images)
    tiles = tiles_of(net)
    gen = time.perf_counter() - t0
    n_in = sum(t.n_points for t in tiles)
    m_in = sum(t.n_measures for t in tiles)
    print(f"network: {net.n_points} points, {net.n_measures} measures, {net.n_images} images "
          f"(generated in {gen:.1f} s); 4 tiles hold {n_in} points / {m_in} measures")
    rows = []

    (merged, stats), sec, mem = measure(merge_networks, tiles)
    rows.append(("merge_networks (4 tiles)", sec, mem))
    print(f"merge: {stats}")
    print(f"merged back to {merged.n_points} points (truth {net.n_points}; extra joins from chance "
          f"coincidences within 1 px: {net.n_points - merged.n_points})")

    rep, sec_v, mem_v = measure(validate, merged, np.full((merged.n_images, 2), 1024))
    rows.append(("validate (merged)", sec_v, mem_v))
    print(rep.summary())

    ref, sec_pv, mem_pv = measure(pandas_validate, merged)
    rows.append(("reference: pandas validate", sec_pv, mem_pv))
    print(f"pandas reference: {ref}")

    frac = 0.01
    sample_tiles = [t.take_points(np.arange(0, t.n_points, int(1 / frac))) for t in tiles]
    _, sec_dm, mem_dm = measure(dict_merge, sample_tiles)
    rows.append(("reference: dict union-find merge (1 % sample, time x100)", sec_dm / frac, float("nan")))

    data, sec_enc, mem_enc = measure(encode_isis_network, merged, 5)
    rows.append((f"encode ISIS .net v5 ({len(data) / 2**20:.0f} MiB)", sec_enc, mem_enc))
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "big.net"
        p.write_bytes(data)
        del data
        back, sec_dec, mem_dec = measure(read_isis_network, p, None, merged.image_ids)
        rows.append(("decode ISIS .net v5", sec_dec, mem_dec))
        assert back.n_measures == merged.n_measures
    print()
    print("| step | seconds | peak extra memory (MiB) |")
    print("|---|---|---|")
    for name, s, mb in rows:
        print(f"| {name} | {s:.2f} | {'n/a' if np.isnan(mb) else f'{mb:.0f}'} |")
    print()
    print(f"ratio validate / pandas reference: {sec_v / sec_pv:.2f}")
    print(f"ratio merge / dict reference (extrapolated): {sec / (sec_dm / frac):.3f}")


if __name__ == "__main__":
    main()
