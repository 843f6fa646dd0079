"""The compiled neighbour search of the gridding kernels: caps on the sphere over the bucket index (numba).

For a query direction at latitude phi and an angular radius a, every point within a
lies in the bands covering [phi - a, phi + a] and, unless the cap reaches a pole,
within longitude +-asin(sin a / cos phi) (the bounding box of a spherical cap). Every
point within the cap is a candidate, so as soon as k candidates lie within it they are
exactly the k nearest. The k-NN search tries a cap slightly above the previous pixel's
k-th distance (``GROW`` of :mod:`mercury_dem.dem.buckets`), then one that surely holds k
points (triangle inequality), else (a block's first pixel) a cap expected to hold ~2k
points, and doubles it until k lie within or the cap exceeds ``ang_max`` (the pixel is
marked for the kd-tree). Distances are chords between footprints on the datum sphere, metres.

The index comes as one :class:`~mercury_dem.dem.index.SearchTables`, a pixel's centre as
the tuple :func:`pixel_centre` returns (latitude, longitude from the cells' origin, x, y, z,
1 / cos latitude), the per-block buffers as one tuple (:data:`SCRATCH_FIELDS`): tuples numba
passes as single arguments (a jitclass would compile much more slowly). Except in :func:`knn_unordered`,
the median11 kernel's per-pixel hot path, whose scalars and buffers stay separate arguments: packed,
that kernel measured 7-12 % slower.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple

import numba
import numpy as np
from numpy.typing import NDArray

from mercury_dem.dem.reduce import RANK_MAX

if TYPE_CHECKING:
    from mercury_dem.dem.index import SearchTables

#: Candidates buffered per pixel before ranking (beyond: ranked while scanning).
BUFFER = 2048

#: Below this (radians) the search bounds a cap's sine and angle by cheap series (conservatively).
SMALL_ANGLE = 0.01


#: The per-block buffers of a kernel, passed to :func:`knn_exact` as one plain tuple ``sc = (ranges, dk2, ik, bd2, bi)``
#: (numba's parallel transform cannot build a NamedTuple inside ``prange``; :func:`knn_unordered`, the hot
#: path, takes them one by one): ``ranges`` (2 B + 2, 2)
#: int64, the ``[start, end)`` runs of sorted points of a cap (:func:`cap_ranges`); ``dk2``/``ik``
#: float64/int64, the k nearest found (squared chord, point; room for ``max(k, BUFFER)`` where
#: :func:`knn_unordered` is used); ``bd2``/``bi`` (BUFFER,) float64/int64, a cap's candidates before ranking.
SCRATCH_FIELDS = ("ranges", "dk2", "ik", "bd2", "bi")
#: A count as the kernels pass it: numba's int64 where a loop counts with unsigned indices (:func:`collect_within`).
Count = int | np.int64
#: The type of that tuple.
Scratch = tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.int64], NDArray[np.float64], NDArray[np.int64]]
#: A pixel's centre as :func:`pixel_centre` returns it: (latitude, longitude from the cells' origin, x, y, z,
#: 1 / cos latitude).
Centre = tuple[float, float, float, float, float, float]


class Centres(NamedTuple):
    """Pixel centres as per-row and per-column tables (:func:`fill_centres`; read by :func:`pixel_centre`).

    Attributes
    ----------
    phi, c, z, icp : per row: latitude (radians), rs cos(phi), rs sin(phi), 1 / cos(phi)
    u, cl, sl : per column: longitude from the cells' origin in [0, 2 pi), cos and sin of the longitude
    paired : True: pixel p is row p with column p (scattered pixels); False: a grid, row by row
    """

    phi: NDArray[np.float64]
    c: NDArray[np.float64]
    z: NDArray[np.float64]
    icp: NDArray[np.float64]
    u: NDArray[np.float64]
    cl: NDArray[np.float64]
    sl: NDArray[np.float64]
    paired: bool


@numba.njit(cache=True, inline="always")
def _band_run(lo: float, hi: float, iw: float, last: int, lon_span: float, f: int, cell_start: NDArray[np.int64], out: NDArray[np.int64],
              n: int) -> int:  # pragma: no cover
    """Append to ``out`` the run of sorted points in the cells of the band starting at cell f
    (cells 0..last, iw cells per radian) that meet the longitudes [lo, hi]; return the count.
    """
    j0 = 0 if lo <= 0.0 else min(int(math.floor(lo * iw)), last)
    j1 = last if hi >= lon_span else min(int(math.floor(hi * iw)), last)
    out[n, 0] = cell_start[f + j0]
    out[n, 1] = cell_start[f + j1 + 1]
    return n + 1


@numba.njit(cache=True, inline="always")
def cap_ranges(t: SearchTables, phi: float, icp: float, u: float, a: float, out: NDArray[np.int64]) -> int:  # pragma: no cover
    """Contiguous runs of sorted points of the index ``t`` that hold every point within angle a of (phi, u).

    ``u`` is the query's east longitude from the cells' origin, in [0, 2 pi) (per column:
    ``(lam - lon0) mod 2 pi``), ``icp`` is ``1 / cos(phi)`` (per row), ``inv_bh`` is 1 / the
    band height and ``band_invw[b]`` the cells per radian of band b (its cells / lon_span):
    reciprocals so the search multiplies instead of dividing. Bands and cells found with
    them are those of the division, or one further out: the cap is widened by 1e-9 of itself
    plus 1e-12 rad, far more than the few ulps the reciprocal can shift a boundary by, so
    the runs still hold the whole cap (a wider run only costs time, never changes a result).
    Writes ``[start, end)`` pairs into ``out`` (at least 2 x bands rows); returns their number.
    """
    lat0, inv_bh, lon_span, band_invw, band_first, cell_start = (t.lat0, t.inv_bh, t.lon_span, t.band_invw,
                                                                 t.band_first, t.cell_start)
    nb = band_invw.size
    ae = a * (1.0 + 1e-9) + 1e-12
    b0 = int(math.floor((phi - ae - lat0) * inv_bh))
    b1 = int(math.floor((phi + ae - lat0) * inv_bh))
    if b0 < 0:
        b0 = 0
    if b1 > nb - 1:
        b1 = nb - 1
    full = ae >= math.pi or phi + ae >= 0.5 * math.pi or phi - ae <= -0.5 * math.pi
    dl = math.pi
    if not full:
        # sin(ae) <= ae: for small caps ae itself (a conservative bound, one sine fewer per cap)
        sa = ae if ae < SMALL_ANGLE else math.sin(ae)
        x = sa * icp
        if x >= 1.0:
            full = True
        else:
            # asin(x) = x + x^3/6 + 3 x^5/40 + ... <= x (1 + x^2 / 5) for small x (no arcsine per cap)
            dl = (x * (1.0 + 0.2 * x * x) if x < SMALL_ANGLE else math.asin(x)) * (1.0 + 1e-9) + 1e-12
            full = dl >= math.pi
    n = 0
    if full:
        for b in range(b0, b1 + 1):
            out[n, 0] = cell_start[band_first[b]]
            out[n, 1] = cell_start[band_first[b + 1]]
            n += 1
        return n
    # the interval [u - dl, u + dl] and its copies one turn away, cut to the cells [0, lon_span):
    # shorter than a turn, it meets [0, 2 pi) in at most two pieces, the same for every band
    # (u is in [0, 2 pi): the copy one turn up or down is the only other one that can meet it)
    ua = u - dl
    ub = u + dl
    one = ua < lon_span
    va = vb = 0.0
    two = False
    if ua < 0.0:  # the piece below 0 wraps to the top: [ua + 2 pi, 2 pi)
        va = ua + 2.0 * math.pi
        vb = 2.0 * math.pi
        two = va < lon_span
    elif ub >= 2.0 * math.pi:  # the piece above 2 pi wraps to the bottom: [0, ub - 2 pi]
        vb = ub - 2.0 * math.pi
        two = True
    for b in range(b0, b1 + 1):
        f = band_first[b]
        last = band_first[b + 1] - f - 1
        iw = band_invw[b]
        if one:
            n = _band_run(ua, ub, iw, last, lon_span, f, cell_start, out, n)
        if two:
            n = _band_run(va, vb, iw, last, lon_span, f, cell_start, out, n)
    return n


@numba.njit(cache=True, inline="always")
def _insert(dk2: NDArray[np.float64], ik: NDArray[np.int64], m: int, k: int, d2: float, i: int) -> int:  # pragma: no cover
    """Insert (d2, i) into the ascending top-k list (ties broken by point index); return its new length."""
    if m < k:
        j = m - 1
        m += 1
    elif d2 < dk2[k - 1] or (d2 == dk2[k - 1] and i < ik[k - 1]):
        j = k - 2
    else:
        return m
    while j >= 0 and (dk2[j] > d2 or (dk2[j] == d2 and ik[j] > i)):
        dk2[j + 1] = dk2[j]
        ik[j + 1] = ik[j]
        j -= 1
    dk2[j + 1] = d2
    ik[j + 1] = i
    return m


@numba.njit(cache=True, inline="always")
def top_k(bd2: NDArray[np.float64], bi: NDArray[np.int64], m: Count, k: int, dk2: NDArray[np.float64],
          ik: NDArray[np.int64]) -> Count:  # pragma: no cover
    """The min(k, m) smallest (bd2[j], bi[j]) of j < m, ascending, into (dk2, ik); returns how many.

    Same result as inserting them one by one with :func:`_insert`. Up to ``RANK_MAX``
    candidates, each one's rank is counted (an O(m^2) loop without data-dependent
    branches, several times faster than insertion's unpredictable shifts at m ~ 10-30).
    """
    if m > RANK_MAX:
        mk = 0
        for j in range(m):
            mk = _insert(dk2, ik, mk, k, bd2[j], bi[j])
        return mk
    for a in range(m):
        da = bd2[a]
        ia = bi[a]
        r = 0
        for b in range(m):
            db = bd2[b]
            r += (db < da) | ((db == da) & (bi[b] < ia))
        if r < k:
            dk2[r] = da
            ik[r] = ia
    return min(m, k)


@numba.njit(cache=True)
def scan_ranges(xyz: NDArray[np.float64], ranges: NDArray[np.int64], nr: int, qx: float, qy: float, qz: float, k: int, d2max: float,
                r2count: float, dk2: NDArray[np.float64], ik: NDArray[np.int64]) -> tuple[int, int]:  # pragma: no cover
    """Keep the k smallest squared distances <= d2max (sorted, with indices); count those <= r2count.

    Returns (number kept, number within the count radius).
    """
    m = 0
    cnt = 0
    for t in range(nr):
        for i in range(ranges[t, 0], ranges[t, 1]):
            dx = xyz[i, 0] - qx
            dy = xyz[i, 1] - qy
            dz = xyz[i, 2] - qz
            d2 = dx * dx + dy * dy + dz * dz
            if d2 <= r2count:
                cnt += 1
            if d2 <= d2max:
                m = _insert(dk2, ik, m, k, d2, i)
    return m, cnt


@numba.njit(cache=True, inline="always")
def collect_within(xyz: NDArray[np.float64], ranges: NDArray[np.int64], nr: int, qx: float, qy: float, qz: float, cap2: float, r2count: float,
                   bd2: NDArray[np.float64], bi: NDArray[np.int64]) -> tuple[Count, int]:  # pragma: no cover
    """Squared distances <= cap2 into (bd2, bi); returns (how many there were, count <= r2count).

    More than ``bd2.size`` means the buffer overflowed (only its first entries are stored).
    When every point of the ranges fits in the buffer, each one is stored and the
    position advanced by the test's 0/1 (no data-dependent branch: about half the
    tests go either way, so a branch is mispredicted about half the time).
    """
    m = 0
    cnt = 0
    nbuf = bd2.size
    tot = 0
    for t in range(nr):
        tot += ranges[t, 1] - ranges[t, 0]
    if tot <= nbuf:
        # Unsigned indices: numba then drops its negative-index wraparound test from every
        # access (measured: the median11 kernel 8 % faster).
        um = numba.uint64(0)
        for t in range(nr):
            for i in range(numba.uint64(ranges[t, 0]), numba.uint64(ranges[t, 1])):
                dx = xyz[i, 0] - qx
                dy = xyz[i, 1] - qy
                dz = xyz[i, 2] - qz
                d2 = dx * dx + dy * dy + dz * dz
                cnt += d2 <= r2count
                bd2[um] = d2
                bi[um] = i
                um += numba.uint64(d2 <= cap2)
        return numba.int64(um), cnt
    for t in range(nr):
        for i in range(ranges[t, 0], ranges[t, 1]):
            dx = xyz[i, 0] - qx
            dy = xyz[i, 1] - qy
            dz = xyz[i, 2] - qz
            d2 = dx * dx + dy * dy + dz * dz
            if d2 <= r2count:
                cnt += 1
            if d2 <= cap2:
                if m < nbuf:
                    bd2[m] = d2
                    bi[m] = i
                m += 1
    return m, cnt


@numba.njit(cache=True, nogil=True)
def fill_centres(lat_deg: NDArray[np.float64], lon_deg: NDArray[np.float64], rs: float, lon0: float, cen: Centres) -> None:  # pragma: no cover
    """Pixel centres on the sphere of radius rs (m) from latitudes and longitudes (degrees), into the
    tables of ``cen`` (:class:`Centres`).

    Per latitude: phi (radians), c = rs cos(phi), z = rs sin(phi), icp = 1 / cos(phi); per
    longitude: lam in [0, 2 pi), its cosine and sine, and u = (lam - lon0) mod 2 pi, the
    longitude from the cells' origin lon0 (the search's). A centre is (c cos(lam), c sin(lam), z):
    the same operations whether the centres come as a grid (rows x columns) or as a list.
    """
    phi, c, z, icp, u, cl, sl = cen.phi, cen.c, cen.z, cen.icp, cen.u, cen.cl, cen.sl
    for i in range(lat_deg.size):
        f = math.radians(lat_deg[i])
        phi[i] = f
        cp = math.cos(f)
        icp[i] = 1.0 / cp
        c[i] = rs * cp
        z[i] = rs * math.sin(f)
    for j in range(lon_deg.size):
        t = math.radians(lon_deg[j]) % (2.0 * math.pi)
        if t >= 2.0 * math.pi:
            t = 0.0
        u[j] = (t - lon0) % (2.0 * math.pi)
        cl[j] = math.cos(t)
        sl[j] = math.sin(t)


@numba.njit(cache=True, inline="always")
def pixel_centre(p: int, cen: Centres) -> Centre:  # pragma: no cover
    """Pixel p's centre: (latitude, longitude from the cells' origin, x, y, z, 1 / cos(latitude)) from
    the per-row/column tables ``cen`` (:class:`Centres`);
    ``cen.paired``: row p with column p (scattered pixels), else p = row * ncol + column (a grid).
    """
    if cen.paired:
        i = p
        j = p
    else:
        ncol = cen.u.size
        i = p // ncol
        j = p - i * ncol
    return cen.phi[i], cen.u[j], cen.c[i] * cen.cl[j], cen.c[i] * cen.sl[j], cen.z[i], cen.icp[i]


@numba.njit(cache=True, inline="always")
def _cap_chord2(a: float, rs: float) -> float:  # pragma: no cover
    """Squared chord of a cap of angle ``a`` on the sphere of radius ``rs`` (inf for the whole sphere)."""
    if a >= math.pi:
        return np.inf
    ch = 2.0 * rs * math.sin(0.5 * a)
    return ch * ch


@numba.njit(cache=True, inline="always")
def _within_to_front(bd2: NDArray[np.float64], bi: NDArray[np.int64], m: Count, t2: float) -> Count:  # pragma: no cover
    """Move the candidates j < m with bd2[j] <= t2 to the front (pairs swapped); return how many."""
    ms = 0
    for j in range(m):
        if bd2[j] <= t2:
            d, i = bd2[j], bi[j]
            bd2[j], bi[j] = bd2[ms], bi[ms]
            bd2[ms], bi[ms] = d, i
            ms += 1
    return ms


@numba.njit(cache=True, inline="always")
def _next_cap(a: float, a_second: float, ang_max: float) -> float:  # pragma: no cover
    """The cap after ``a`` in the k-NN search: ``a_second``, then doubling up to ``ang_max``."""
    if a < a_second:
        return a_second
    return min(2.0 * a, ang_max)


@numba.njit(cache=True, inline="always")
def knn_exact(t: SearchTables, q: Centre, sc: Scratch, k: int, a_first: float, a_second: float, ang_max: float,
              rs: float, r2count: float, t2: float) -> tuple[bool, int]:  # pragma: no cover
    """Exact k nearest of the centre ``q`` (:func:`pixel_centre`) in the index ``t`` (ascending in
    ``sc.dk2``/``sc.ik``): caps a_first, then a_second, then doubling.

    A cap of angle a is scanned whole (every point within a is a candidate), so as soon
    as k candidates lie within it they are the k nearest: any cap sequence gives the
    same result, only the cost differs. ``t2`` is a guess of the k-th squared distance
    (e.g. 1.5 x the previous pixel's): when at least k candidates lie within it, only
    those are ranked. Returns (done, count within r2count).
    """
    phi, u, qx, qy, qz, icp = q
    xyz = t.xyz
    ranges, dk2, ik, bd2, bi = sc
    a = a_first
    while True:
        nr = cap_ranges(t, phi, icp, u, a, ranges)
        cap2 = _cap_chord2(a, rs)
        m, cnt = collect_within(xyz, ranges, nr, qx, qy, qz, cap2, r2count, bd2, bi)
        mk: Count
        if m > bd2.size:
            mk, _ = scan_ranges(xyz, ranges, nr, qx, qy, qz, k, cap2, r2count, dk2, ik)
        else:
            mk = 0
            if t2 < cap2:
                ms = _within_to_front(bd2, bi, m, t2)
                if ms >= k:
                    mk = top_k(bd2, bi, ms, k, dk2, ik)
            if mk < k:
                mk = top_k(bd2, bi, m, k, dk2, ik)
        if mk >= k:
            return True, cnt
        if a >= ang_max:
            return False, cnt
        a = _next_cap(a, a_second, ang_max)


@numba.njit(cache=True, inline="always")
def _smallest_set(bd2: NDArray[np.float64], bi: NDArray[np.int64], m: Count, k: int, dk2: NDArray[np.float64],
                  ik: NDArray[np.int64]) -> tuple[float, float]:  # pragma: no cover
    """The k smallest (bd2[j], bi[j]) of j < m (k <= m) into (dk2[:k], ik[:k]) in any order.

    Returns (smallest, k-th smallest) squared distance. The set is the one :func:`top_k`
    gives (ties by point index). When only a few are in excess, the largest are dropped
    one at a time (m - k passes over m values, without insertion's unpredictable
    shifts); otherwise ranked with :func:`top_k`.
    """
    if m - k > 8:
        top_k(bd2, bi, m, k, dk2, ik)
        return dk2[0], dk2[k - 1]
    m0 = m
    for j in range(m):
        dk2[j] = bd2[j]
        ik[j] = bi[j]
    # Distances alone first: m - k times, the largest is found (a branch-free max pass, then its
    # first position) and dropped. The set is the tie-aware one unless the last value dropped (the
    # smallest dropped) equals a kept one -- a tie at the k-th place, as with duplicated points:
    # then the drops are redone with ties broken by point index.
    dlast = -1.0
    while m > k:
        dmax = dk2[0]
        for j in range(1, m):
            dmax = max(dmax, dk2[j])
        jmax = 0
        while dk2[jmax] != dmax:
            jmax += 1
        m -= 1
        dk2[jmax] = dk2[m]
        ik[jmax] = ik[m]
        dlast = dmax
    tie = False
    for j in range(k):
        tie |= dk2[j] == dlast
    if tie:
        m = m0
        for j in range(m):
            dk2[j] = bd2[j]
            ik[j] = bi[j]
        while m > k:
            jmax = 0
            dmax = dk2[0]
            imax = ik[0]
            for j in range(1, m):
                d = dk2[j]
                i = ik[j]
                if d > dmax or (d == dmax and i > imax):
                    jmax = j
                    dmax = d
                    imax = i
            m -= 1
            dk2[jmax] = dk2[m]
            ik[jmax] = ik[m]
    lo = dk2[0]
    hi = dk2[0]
    for j in range(1, k):
        lo = min(lo, dk2[j])
        hi = max(hi, dk2[j])
    return lo, hi


@numba.njit(cache=True, inline="always")
def knn_unordered(t: SearchTables, phi: float, icp: float, u: float, qx: float, qy: float, qz: float, ranges: NDArray[np.int64],
                  dk2: NDArray[np.float64], ik: NDArray[np.int64], bd2: NDArray[np.float64], bi: NDArray[np.int64], k: int, a_first: float, cap2_first: float,
                  a_second: float, bound: float, a_min: float, ang_max: float, rs: float, r2count: float,
                  t2: float) -> tuple[bool, int, float, float]:  # pragma: no cover
    """:func:`knn_exact` when the order of the k nearest does not matter (median11 sorts their radii).

    Takes the centre (phi, icp, u, qx, qy, qz), the scratch buffers and the settings as separate
    arguments, not as the tuples :func:`knn_exact` takes: this is the median11 kernel's per-pixel hot
    path, and with tuples here the kernel measured 7-12 % slower (``bench_dem_kernels.py``, session
    12); with scalars it is within 1-2 % of the unpacked original. The first cap's squared chord is
    ``cap2_first`` when > 0 (a chord the caller knows, saving the angle's round trip), else that of
    ``a_first``. ``a_second`` < 0: the second cap is computed only if the first fails, from the chord
    ``bound`` (>= 0) not below ``a_min`` and not above ``a_second``'s absolute value. Any cap scanned
    whole is exact (only the cost differs), so these shortcuts never change the result. ``dk2``/``ik``
    need room for ``BUFFER`` values. Returns (done, count within r2count, smallest squared distance,
    k-th smallest squared distance).
    """
    xyz = t.xyz
    a = a_first
    cap2 = cap2_first if cap2_first > 0.0 else _cap_chord2(a, rs)
    while True:
        nr = cap_ranges(t, phi, icp, u, a, ranges)
        m, cnt = collect_within(xyz, ranges, nr, qx, qy, qz, cap2, r2count, bd2, bi)
        if m > bd2.size:
            mk, _ = scan_ranges(xyz, ranges, nr, qx, qy, qz, k, cap2, r2count, dk2, ik)
            if mk >= k:
                return True, cnt, dk2[0], dk2[k - 1]
        elif m >= k:
            ms = m
            if t2 < cap2:
                ms = _within_to_front(bd2, bi, m, t2)
                if ms < k:
                    ms = m
            lo, hi = _smallest_set(bd2, bi, ms, k, dk2, ik)
            return True, cnt, lo, hi
        if a >= ang_max:
            return False, cnt, 0.0, 0.0
        if a_second < 0.0:
            a_second = -a_second
            if bound >= 0.0:
                a_second = min(a_second, max(_angle(bound, rs), a_min))
        a = _next_cap(a, a_second, ang_max)
        cap2 = _cap_chord2(a, rs)


@numba.njit(cache=True, inline="always")
def angle_upper_bound(chord: float, rs: float) -> float:  # pragma: no cover
    """An upper bound of :func:`_angle` without the arcsine for small caps: with x = chord / 2 rs
    < SMALL_ANGLE, 2 asin(x) = 2 (x + x^3/6 + 3 x^5/40 + ...) <= 2 x (1 + x^2 / 5). A cap at
    least as wide as needed is exact all the same (only its cost differs).
    """
    x = chord / (2.0 * rs)
    if x < SMALL_ANGLE:
        return 2.0 * x * (1.0 + 0.2 * x * x)
    return _angle(chord, rs)


@numba.njit(cache=True, inline="always")
def _angle(chord: float, rs: float) -> float:  # pragma: no cover
    """Angle (radians) of a chord on the sphere of radius rs; pi when longer than the diameter."""
    if chord >= 2.0 * rs:
        return math.pi
    return 2.0 * math.asin(chord / (2.0 * rs))

