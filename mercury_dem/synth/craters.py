"""Craters of the synthetic Mercury: population, spatial index and compiled profiles.

A crater population is a columnar table (one row per crater, columns named by
the ``C_*`` constants) drawn from a power-law size-frequency distribution,
``N(>D) = k * D**-slope`` per km^2 with D in km. Three morphologies:

* simple bowls (D below the simple-to-complex transition, ~10 km on Mercury):
  parabolic bowl, rim-to-floor depth ``0.2 D``, raised rim, ejecta falling off as r^-3;
* complex craters: flat floor (a growing fraction of the radius), terraced-looking
  smooth walls, a central peak, depth growing slowly with D (d ~ D^0.2, at most 3.5 km);
* multi-ring basins: flooded flat floor, an inner peak ring, the main rim and an
  outer ring scarp.

Older craters are shallower (degradation) and craters older than the smooth
plains are erased where the plains are. The youngest craters carry bright
ejecta haloes and rays in the albedo field.

Evaluation does not loop over all craters per point: craters are bucketed in a
lat/lon cell grid by the cap their influence reaches (a CSR list per cell), and
a point visits only the craters of its cell.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

# Columns of the crater table.
C_X, C_Y, C_Z = 0, 1, 2  # unit vector of the centre, body-fixed
C_RADIUS = 3  # rim radius, m
C_KIND = 4  # 0 simple, 1 complex, 2 basin
C_DEPTH = 5  # rim-to-floor depth, m
C_RIM = 6  # rim height above the surroundings, m
C_FLOOR = 7  # flat-floor radius / rim radius (complex, basin)
C_PEAK = 8  # central peak height (complex) or ring height (basin), m
C_AMP = 9  # degradation and flooding factor applied to the whole profile
C_REACH = 10  # influence radius / rim radius (height)
C_AGE = 11  # 0 oldest .. 1 youngest
C_RAYLEN = 12  # ray extent / rim radius (0: no rays)
C_RAYAMP = 13  # relative albedo boost of halo and rays
C_RAYK = 14  # three ray azimuthal frequencies (14, 15, 16) and phases (17, 18, 19)
N_COLS = 20

KIND_SIMPLE, KIND_COMPLEX, KIND_BASIN = 0, 1, 2


@dataclass(frozen=True)
class CraterIndex:
    """Craters bucketed in a lat/lon cell grid (CSR: ``starts`` of length n_cells + 1, ``members``)."""

    cell_deg: float
    n_lat: int
    n_lon: int
    starts: NDArray[np.int64]
    members: NDArray[np.int64]
    #: (len(members), 4): centre unit vector and squared chord of the reach of each member,
    #: stored in CSR order so the rejection test of a cell reads contiguous memory.
    cand: NDArray[np.float64]
    #: (n_table,) angular reach (rad) of every crater of the table the index was built on.
    reach_rad: NDArray[np.float64]


def sample_diameters(rng: np.random.Generator, n: int, d_min: float, d_max: float, slope: float) -> NDArray[np.float64]:
    """Diameters from a truncated cumulative power law N(>D) ~ D**-slope (inverse CDF)."""
    u = rng.random(n)
    q = (d_min / d_max) ** slope
    return d_min * (1.0 - u * (1.0 - q)) ** (-1.0 / slope)


def random_unit_vectors(rng: np.random.Generator, n: int) -> NDArray[np.float64]:
    """Points uniform on the unit sphere, shape (n, 3)."""
    z = rng.uniform(-1.0, 1.0, n)
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    s = np.sqrt(1.0 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1)


def build_crater_table(
    centres: NDArray[np.float64],
    diameters_m: NDArray[np.float64],
    ages: NDArray[np.float64],
    kinds: NDArray[np.int64],
    rng: np.random.Generator,
    transition_m: float,
    fresh_age: float,
    ray_length: float,
) -> NDArray[np.float64]:
    """The crater table (n, N_COLS) from centres, diameters, ages and kinds (morphometry from D)."""
    n = diameters_m.shape[0]
    t = np.zeros((n, N_COLS))
    t[:, C_X:C_Z + 1] = centres
    d = diameters_m
    t[:, C_RADIUS] = d / 2.0
    t[:, C_KIND] = kinds
    simple = kinds == KIND_SIMPLE
    complex_ = kinds == KIND_COMPLEX
    basin = kinds == KIND_BASIN
    # Complex craters deepen slowly with D and stay within ~3.5 km (Mercury's large craters).
    depth = np.where(
        simple, 0.2 * d, np.minimum(0.2 * transition_m * (np.maximum(d, transition_m) / transition_m) ** 0.2, 3500.0)
    )
    depth = np.where(basin, rng.uniform(2500.0, 3500.0, n), depth)
    rim = np.where(simple, 0.04 * d, 0.04 * transition_m * (np.maximum(d, transition_m) / transition_m) ** 0.45)
    rim = np.where(basin, 0.25 * depth, rim)
    floor = np.where(
        complex_, 0.2 + 0.35 * np.clip((d - transition_m) / 120e3, 0.0, 1.0), 0.0
    )
    floor = np.where(basin, 0.5, floor)
    peak = np.where(complex_ & (d > 1.5 * transition_m), 0.35 * depth, 0.0)
    peak = np.where(basin, 0.25 * depth, peak)
    # Degradation: old craters keep ~35 % of their relief; basins keep theirs (flooded instead).
    amp = np.where(basin, 1.0, 0.35 + 0.65 * ages**0.7)
    reach = np.where(basin, 2.2, 2.5)
    t[:, C_DEPTH] = depth
    t[:, C_RIM] = rim
    t[:, C_FLOOR] = floor
    t[:, C_PEAK] = peak
    t[:, C_AMP] = amp
    t[:, C_REACH] = reach
    t[:, C_AGE] = ages
    fresh = (ages >= fresh_age) & ~basin
    t[:, C_RAYLEN] = np.where(fresh, ray_length * rng.uniform(0.6, 1.4, n), 0.0)
    t[:, C_RAYAMP] = np.where(fresh, rng.uniform(0.5, 1.2, n), 0.0)
    t[:, C_RAYK:C_RAYK + 3] = rng.integers(5, 23, (n, 3))
    t[:, C_RAYK + 3:C_RAYK + 6] = rng.uniform(0.0, 2.0 * np.pi, (n, 3))
    return t


@numba.njit(cache=True, nogil=True)
def _fill_index(
    lat: NDArray[np.float64],
    lon: NDArray[np.float64],
    reach_rad: NDArray[np.float64],
    cell_deg: float,
    n_lat: int,
    n_lon: int,
    starts: NDArray[np.int64],
    members: NDArray[np.int64],
    count_only: bool,
) -> NDArray[np.int64]:
    counts = np.zeros(n_lat * n_lon, dtype=np.int64)
    for j in range(lat.shape[0]):
        rho = np.degrees(reach_rad[j]) + 1e-9
        la0 = lat[j] - rho
        la1 = lat[j] + rho
        b0 = max(0, int(np.floor((la0 + 90.0) / cell_deg)))
        b1 = min(n_lat - 1, int(np.floor((la1 + 90.0) / cell_deg)))
        all_lon = la1 >= 90.0 or la0 <= -90.0
        k0, k1 = 0, n_lon - 1
        if not all_lon:
            s = np.sin(reach_rad[j]) / np.cos(np.radians(lat[j]))
            if s >= 1.0:
                all_lon = True
            else:
                dl = np.degrees(np.arcsin(s)) + 1e-9
                k0 = int(np.floor((lon[j] - dl) / cell_deg))
                k1 = int(np.floor((lon[j] + dl) / cell_deg))
                if k1 - k0 + 1 >= n_lon:
                    all_lon = True
        if all_lon:
            k0, k1 = 0, n_lon - 1
        for b in range(b0, b1 + 1):
            for k in range(k0, k1 + 1):
                c = b * n_lon + (k % n_lon)
                if not count_only:
                    members[starts[c] + counts[c]] = j
                counts[c] += 1
    return counts


def build_index(table: NDArray[np.float64], reach_col_factor: NDArray[np.float64], datum_radius_m: float, cell_deg: float) -> CraterIndex:
    """Bucket craters by the cells their influence cap (``reach_col_factor`` x rim radius) touches."""
    n_lat = int(np.ceil(180.0 / cell_deg))
    n_lon = int(np.ceil(360.0 / cell_deg))
    lat = np.degrees(np.arcsin(np.clip(table[:, C_Z], -1.0, 1.0)))
    lon = np.mod(np.degrees(np.arctan2(table[:, C_Y], table[:, C_X])), 360.0)
    reach = np.minimum(reach_col_factor * table[:, C_RADIUS] / datum_radius_m, np.pi)
    dummy = np.zeros(1, dtype=np.int64)
    counts = _fill_index(lat, lon, reach, cell_deg, n_lat, n_lon, np.zeros(n_lat * n_lon + 1, np.int64), dummy, True)
    starts = np.zeros(n_lat * n_lon + 1, dtype=np.int64)
    np.cumsum(counts, out=starts[1:])
    members = np.empty(int(starts[-1]), dtype=np.int64)
    _fill_index(lat, lon, reach, cell_deg, n_lat, n_lon, starts, members, False)
    cand = np.empty((members.size, 4))
    cand[:, 0:3] = table[members, 0:3]
    cand[:, 3] = (2.0 * np.sin(0.5 * reach[members])) ** 2
    return CraterIndex(cell_deg, n_lat, n_lon, starts, members, np.ascontiguousarray(cand), reach)


@numba.njit(cache=True, inline="always")
def _smooth(x: float) -> float:
    """Smoothstep on [0, 1] (clamped)."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    return x * x * (3.0 - 2.0 * x)


@numba.njit(cache=True, inline="always")
def crater_profile(table: NDArray[np.float64], j: int, r: float) -> float:
    """Height (m, relative to the pre-crater surface) at r = distance / rim radius for crater ``j``."""
    kind = int(table[j, C_KIND])
    depth = table[j, C_DEPTH]
    rim = table[j, C_RIM]
    reach = table[j, C_REACH]
    if r >= reach:
        return 0.0
    if r >= 1.0:
        # Ejecta blanket: falls as r^-3, tapered to zero at the reach.
        taper = _smooth((r - 1.0) / (reach - 1.0))
        h = rim / (r * r * r) * (1.0 - taper * taper)
        if kind == KIND_BASIN:
            # Outer ring scarp at 1.5 radii.
            q = (r - 1.5) / 0.06
            h += table[j, C_PEAK] * 0.6 * np.exp(-q * q)
        return h
    if kind == KIND_SIMPLE:
        return rim - depth * (1.0 - r * r)
    f = table[j, C_FLOOR]
    floor = rim - depth
    if r <= f:
        h = floor
    else:
        x = (r - f) / (1.0 - f)
        h = floor + depth * _smooth(x) ** 1.3
    peak = table[j, C_PEAK]
    if peak > 0.0:
        q = r / 0.12 if kind == KIND_COMPLEX else (r - 0.5) / 0.05
        if q * q < 30.0:
            h += peak * np.exp(-q * q)
    return h


@numba.njit(cache=True, inline="always")
def _cell_of(px: float, py: float, pz: float, cell_deg: float, n_lat: int, n_lon: int) -> int:
    lat = np.degrees(np.arcsin(min(1.0, max(-1.0, pz))))
    lon = np.degrees(np.arctan2(py, px))
    if lon < 0.0:
        lon += 360.0
    b = min(n_lat - 1, max(0, int(np.floor((lat + 90.0) / cell_deg))))
    k = int(np.floor(lon / cell_deg)) % n_lon
    return b * n_lon + k


@numba.njit(cache=True, nogil=True)
def _order_by_cell(cells: NDArray[np.int64], n_cells: int) -> NDArray[np.int64]:
    """Indices that visit the points cell by cell (counting sort, O(n + n_cells))."""
    counts = np.zeros(n_cells + 1, dtype=np.int64)
    for i in range(cells.shape[0]):
        counts[cells[i] + 1] += 1
    for c in range(n_cells):
        counts[c + 1] += counts[c]
    order = np.empty(cells.shape[0], dtype=np.int64)
    for i in range(cells.shape[0]):
        order[counts[cells[i]]] = i
        counts[cells[i]] += 1
    return order


@numba.njit(cache=True, inline="always")
def _height_term(table: NDArray[np.float64], j: int, chord2: float, datum_radius_m: float) -> float:
    """Relief (m) of crater ``j`` at a point at squared chord ``chord2`` (unit sphere) from its centre."""
    dist = 2.0 * np.arcsin(min(1.0, 0.5 * np.sqrt(chord2))) * datum_radius_m
    r = dist / table[j, C_RADIUS]
    if r < table[j, C_REACH]:
        return table[j, C_AMP] * crater_profile(table, j, r)
    return 0.0


@numba.njit(cache=True, inline="always")
def _ray_term(
    table: NDArray[np.float64], j: int, px: float, py: float, pz: float, chord2: float, datum_radius_m: float
) -> float:
    """Relative albedo boost of the halo and rays of crater ``j`` at unit vector (px, py, pz)."""
    row = table[j]
    length = row[C_RAYLEN]
    dist = 2.0 * np.arcsin(min(1.0, 0.5 * np.sqrt(chord2))) * datum_radius_m
    r = dist / row[C_RADIUS]
    if r >= length:
        return 0.0
    # Bright halo over the crater and its continuous ejecta.
    q = r / 1.6
    b = np.exp(-q * q * q * q)
    if r > 0.8:
        # Azimuth about the centre in its local east/north frame.
        cx, cy, cz = row[C_X], row[C_Y], row[C_Z]
        ex, ey = -cy, cx
        en = np.sqrt(ex * ex + ey * ey)
        if en < 1e-9:
            ex, ey, en = 1.0, 0.0, 1.0
        ex /= en
        ey /= en
        nx, ny, nz = -cz * ey, cz * ex, cx * ey - cy * ex
        az = np.arctan2(px * nx + py * ny + pz * nz, px * ex + py * ey)
        s = (
            np.cos(row[C_RAYK] * az + row[C_RAYK + 3])
            + np.cos(row[C_RAYK + 1] * az + row[C_RAYK + 4])
            + np.cos(row[C_RAYK + 2] * az + row[C_RAYK + 5])
        ) / 3.0
        if s > 0.2:
            s = (s - 0.2) / 0.8
            fade_in = _smooth((r - 0.8) / 0.7)
            fade_out = (1.0 - r / length) ** 2
            b += 0.9 * s * s * fade_in * fade_out
    return row[C_RAYAMP] * b


@numba.njit(cache=True, nogil=True)
def crater_sum(
    units: NDArray[np.float64],
    table: NDArray[np.float64],
    cell_deg: float,
    n_lat: int,
    n_lon: int,
    starts: NDArray[np.int64],
    members: NDArray[np.int64],
    cand: NDArray[np.float64],
    datum_radius_m: float,
    albedo: bool,
) -> NDArray[np.float64]:
    """Sum over the craters reaching each unit vector of their relief (``albedo=False``, m)
    or of their halo/ray albedo boost (``albedo=True``).

    Points are visited in order of their index cell so the candidate lists
    stay in cache (a large gain for scattered points).
    """
    n = units.shape[0]
    out = np.zeros(n)
    cells = np.empty(n, dtype=np.int64)
    for i in range(n):
        cells[i] = _cell_of(units[i, 0], units[i, 1], units[i, 2], cell_deg, n_lat, n_lon)
    order = _order_by_cell(cells, n_lat * n_lon)
    for ii in range(n):
        i = order[ii]
        px, py, pz = units[i, 0], units[i, 1], units[i, 2]
        c = cells[i]
        total = 0.0
        for m in range(starts[c], starts[c + 1]):
            dx = px - cand[m, 0]
            dy = py - cand[m, 1]
            dz = pz - cand[m, 2]
            chord2 = dx * dx + dy * dy + dz * dz
            if chord2 >= cand[m, 3]:
                continue
            if albedo:
                total += _ray_term(table, members[m], px, py, pz, chord2, datum_radius_m)
            else:
                total += _height_term(table, members[m], chord2, datum_radius_m)
        out[i] = total
    return out


# --------------------------------------------------------------------------- local grids
@numba.njit(cache=True, nogil=True)
def _members_of_cells(
    b0: int, b1: int, k0: int, k1: int, n_lon: int, starts: NDArray[np.int64], members: NDArray[np.int64], n_table: int
) -> NDArray[np.int64]:
    """Sorted distinct members of the cells of latitude rows b0..b1 and longitude columns k0..k1 (mod n_lon)."""
    seen = np.zeros(n_table, dtype=np.bool_)
    count = 0
    for b in range(b0, b1 + 1):
        for kk in range(k0, k1 + 1):
            c = b * n_lon + (kk % n_lon)
            for m in range(starts[c], starts[c + 1]):
                j = members[m]
                if not seen[j]:
                    seen[j] = True
                    count += 1
    out = np.empty(count, dtype=np.int64)
    n = 0
    for j in range(n_table):
        if seen[j]:
            out[n] = j
            n += 1
    return out


def grid_candidates(index: CraterIndex, units: NDArray[np.float64], n_table: int) -> NDArray[np.int64]:
    """Craters of ``index`` that may reach any of the unit vectors ``units`` (ny, nx, 3) of a local grid.

    The grid's cells are those of its latitude/longitude box (from its border
    nodes, widened by one cell; all longitudes when it comes near a pole), so
    every crater listed in the cell of any node is returned.
    """
    border = np.concatenate([units[0], units[-1], units[:, 0], units[:, -1]])
    lat = np.degrees(np.arcsin(np.clip(border[:, 2], -1.0, 1.0)))
    centre = units[units.shape[0] // 2, units.shape[1] // 2]
    lon_c = np.degrees(np.arctan2(centre[1], centre[0]))
    dlon = (np.degrees(np.arctan2(border[:, 1], border[:, 0])) - lon_c + 180.0) % 360.0 - 180.0
    cd = index.cell_deg
    lat_lo, lat_hi = lat.min() - cd, lat.max() + cd
    # A pole inside the grid: the border does not enclose it in latitude.
    z = units[..., 2]
    if z.max() > np.sin(np.radians(90.0 - 2 * cd)) or z.min() < -np.sin(np.radians(90.0 - 2 * cd)):
        if z.max() > 0:
            lat_hi = 90.0
        if z.min() < 0:
            lat_lo = -90.0
    all_lon = lat_hi >= 90.0 - 2 * cd or lat_lo <= -90.0 + 2 * cd or dlon.max() - dlon.min() > 180.0
    b0 = max(0, int(np.floor((lat_lo + 90.0) / cd)))
    b1 = min(index.n_lat - 1, int(np.floor((lat_hi + 90.0) / cd)))
    if all_lon:
        k0, k1 = 0, index.n_lon - 1
    else:
        k0 = int(np.floor((lon_c + dlon.min() - cd) / cd))
        k1 = int(np.floor((lon_c + dlon.max() + cd) / cd))
    return _members_of_cells(b0, b1, k0, k1, index.n_lon, index.starts, index.members, n_table)


@numba.njit(cache=True, nogil=True)
def _grid_box(
    cx: float, cy: float, cz: float, reach: float, frame: NDArray[np.float64], radius: float,
    x0: float, y0: float, g: float, nx: int, ny: int,
) -> tuple[int, int, int, int]:
    """Node index box (i0, i1, j0, j1) that holds every node within angle ``reach`` of a centre.

    The gnomonic map stretches distances at angle theta from the tangent point by at
    most 1 / cos^2(theta), so the cap lies within ``R * reach / cos^2(theta_c + reach)``
    of the projected centre; an empty box (i0 > i1) when the cap misses the grid.
    """
    cos_c = cx * frame[0, 0] + cy * frame[0, 1] + cz * frame[0, 2]
    theta = np.arccos(min(1.0, max(-1.0, cos_c)))
    if theta - reach >= 0.5 * np.pi:
        return 0, -1, 0, -1
    if theta + reach >= 1.3:  # strongly stretched (or unprojectable): the whole grid
        return 0, nx - 1, 0, ny - 1
    xc = radius * (cx * frame[1, 0] + cy * frame[1, 1] + cz * frame[1, 2]) / cos_c
    yc = radius * (cx * frame[2, 0] + cy * frame[2, 1] + cz * frame[2, 2]) / cos_c
    c2 = np.cos(theta + reach) ** 2
    half = radius * reach / c2 + g
    i0 = max(0, int(np.floor((xc - half - x0) / g)))
    i1 = min(nx - 1, int(np.ceil((xc + half - x0) / g)))
    j0 = max(0, int(np.floor((yc - half - y0) / g)))
    j1 = min(ny - 1, int(np.ceil((yc + half - y0) / g)))
    return i0, i1, j0, j1


@numba.njit(cache=True, nogil=True)
def crater_heights_grid(
    units: NDArray[np.float64], table: NDArray[np.float64], ids: NDArray[np.int64], reach_rad: NDArray[np.float64],
    frame: NDArray[np.float64], radius: float, x0: float, y0: float, g: float, datum_radius_m: float,
) -> NDArray[np.float64]:
    """Summed crater relief (m) at the nodes (ny, nx) of a local gnomonic grid, crater by crater.

    The same relief as :func:`crater_sum` (``albedo=False``) at ``units`` (up to the order of the
    sum): each candidate crater ``ids`` visits only the nodes of its box.
    ``frame`` rows: the grid's centre, east and north unit vectors; the grid's
    node (j, i) sits at plane coordinates (x0 + i g, y0 + j g) on the plane tangent
    at distance ``radius``.
    """
    ny, nx = units.shape[0], units.shape[1]
    out = np.zeros((ny, nx))
    for q in range(ids.shape[0]):
        k = ids[q]
        cx, cy, cz = table[k, C_X], table[k, C_Y], table[k, C_Z]
        reach = reach_rad[k]
        lim = (2.0 * np.sin(0.5 * reach)) ** 2
        i0, i1, j0, j1 = _grid_box(cx, cy, cz, reach, frame, radius, x0, y0, g, nx, ny)
        for j in range(j0, j1 + 1):
            for i in range(i0, i1 + 1):
                dx = units[j, i, 0] - cx
                dy = units[j, i, 1] - cy
                dz = units[j, i, 2] - cz
                chord2 = dx * dx + dy * dy + dz * dz
                if chord2 >= lim:
                    continue
                out[j, i] += _height_term(table, k, chord2, datum_radius_m)
    return out


@numba.njit(cache=True, nogil=True)
def ray_albedo_grid(
    units: NDArray[np.float64], table: NDArray[np.float64], ids: NDArray[np.int64], reach_rad: NDArray[np.float64],
    frame: NDArray[np.float64], radius: float, x0: float, y0: float, g: float, datum_radius_m: float,
) -> NDArray[np.float64]:
    """Albedo boost of haloes and rays (as :func:`crater_sum` (``albedo=True``)) at the nodes of a local grid, crater by crater."""
    ny, nx = units.shape[0], units.shape[1]
    out = np.zeros((ny, nx))
    for q in range(ids.shape[0]):
        k = ids[q]
        cx, cy, cz = table[k, C_X], table[k, C_Y], table[k, C_Z]
        reach = reach_rad[k]
        lim = (2.0 * np.sin(0.5 * reach)) ** 2
        i0, i1, j0, j1 = _grid_box(cx, cy, cz, reach, frame, radius, x0, y0, g, nx, ny)
        for j in range(j0, j1 + 1):
            for i in range(i0, i1 + 1):
                px, py, pz = units[j, i, 0], units[j, i, 1], units[j, i, 2]
                dx = px - cx
                dy = py - cy
                dz = pz - cz
                chord2 = dx * dx + dy * dy + dz * dz
                if chord2 >= lim:
                    continue
                out[j, i] += _ray_term(table, k, px, py, pz, chord2, datum_radius_m)
    return out
