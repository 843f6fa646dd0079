"""Spherical-harmonic shape models: the PDS SHADR reader and the evaluation of radii.

A body's shape as spherical harmonics (Mercury's ``GTMES_150V05_SHA.TAB``, fitted by the
MLA team to 26 million laser radii and 557 radio occultations) gives the radius

    r(φ, λ) = Σ_{l=0..L} Σ_{m=0..l} [C_lm cos(mλ) + S_lm sin(mλ)] · P̄_lm(sin φ)

at planetocentric latitude φ and east longitude λ, with P̄_lm the **4π-normalised**
associated Legendre functions of geodesy (∫ P̄_lm² cos²/sin²(mλ) dΩ = 4π, no Condon–Shortley
phase): P̄_lm = sqrt((2 − δ_m0)(2l + 1)(l − m)!/(l + m)!) · P_lm.

Why the evaluation is written here instead of calling pyshtools: pyshtools is a large
optional package (Fortran core, astropy/requests/pooch at import) that the pipeline does not
otherwise need; evaluating a degree-148 model is ~60 lines of numpy. pyshtools 4.14.1 made
the oracle grid the tests compare with, and the tests use it directly when it is installed.

Numerics (Holmes & Featherstone 2002, J. Geodesy 76, 279): the recursion runs on the
*modified* functions P̃_lm = P̄_lm / cos^m φ, so the sectoral seeds
P̃_mm = sqrt(3) · Π_{k=2..m} sqrt((2k + 1)/(2k)) never underflow near the poles, and the
column recursion in l for fixed m

    P̃_lm = a_lm · t · P̃_{l−1,m} − b_lm · P̃_{l−2,m},   t = sin φ,
    a_lm = sqrt((2l − 1)(2l + 1) / ((l − m)(l + m))),
    b_lm = sqrt((2l + 1)(l + m − 1)(l − m − 1) / ((l − m)(l + m)(2l − 3))),

is stable (its coefficients are bounded; it is the standard forward-column scheme). The sums
over l are formed per order m and multiplied by cos^m φ only at the end, where an underflow to
zero is harmless (the true term is below 1e-280 of the radius). The recursion is vectorised
over all orders at each degree, so a degree-L evaluation is L Python steps over arrays of
shape (points, L + 1).
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mercury_dem.exceptions import ReferenceDataError

#: Largest degree the reader accepts (a guard against a corrupt header asking for a huge array).
MAX_DEGREE = 2800

#: Points evaluated together by :func:`evaluate` (memory: ~8 arrays of shape (chunk, lmax + 1)).
_CHUNK = 4096


@dataclass(frozen=True, eq=False)
class ShapeHarmonics:
    """A body's shape as 4π-normalised real spherical harmonics of the radius.

    Attributes
    ----------
    reference_radius_m : float
        The file's reference radius (SHADR header column 1), metres. It is the scale of the
        model, not an offset: the radius is the full sum, C_00 included.
    lmax : int
        Largest degree present in the file.
    c_m, s_m : ndarray of shape (lmax + 1, lmax + 1)
        Coefficients C_lm and S_lm in **metres** (the file's kilometres × 1000), indexed
        ``[l, m]``; zero for m > l.
    c_sigma_m, s_sigma_m : ndarray of shape (lmax + 1, lmax + 1)
        Their uncertainties, metres.
    normalization_state : int
        The header's normalisation indicator (PDS SHADR: 0 unnormalised, 1 normalised,
        2 other; the GTMES file says 2 and its label says "4 pi").
    reference_longitude_deg, reference_latitude_deg : float
        Header columns 7 and 8 (0 for every body-fixed model).
    source : str
        The file it was read from.
    """

    reference_radius_m: float
    lmax: int
    c_m: NDArray[np.float64]
    s_m: NDArray[np.float64]
    c_sigma_m: NDArray[np.float64]
    s_sigma_m: NDArray[np.float64]
    normalization_state: int = 2
    reference_longitude_deg: float = 0.0
    reference_latitude_deg: float = 0.0
    source: str = ""

    @property
    def mean_radius_m(self) -> float:
        """C_00: the mean radius of the shape, metres."""
        return float(self.c_m[0, 0])


# --------------------------------------------------------------------------- reader


def _fail(path: Path | str, fault: str) -> ReferenceDataError:
    return ReferenceDataError(
        f"{path}: {fault}; expected a PDS SHADR spherical-harmonic table (header row: reference "
        f"radius km, constant, its uncertainty, degree, order, normalisation, reference lon, lat; "
        f"then one row 'l, m, C, S, sigma C, sigma S' per coefficient). Fetch a fresh copy."
    )


def _float(path: Path | str, token: str, what: str, line_no: int) -> float:
    try:
        value = float(token)
    except ValueError:
        raise _fail(path, f"line {line_no}: {what} {token.strip()[:40]!r} is not a number") from None
    if not math.isfinite(value):
        raise _fail(path, f"line {line_no}: {what} is {token.strip()[:40]!r}")
    return value


def _int(path: Path | str, token: str, what: str, line_no: int) -> int:
    try:
        return int(token)
    except ValueError:
        raise _fail(path, f"line {line_no}: {what} {token.strip()[:40]!r} is not an integer") from None


def parse_shadr(text: str, source: str = "<text>") -> ShapeHarmonics:
    """Parse the text of a PDS SHADR spherical-harmonic shape table.

    Parameters
    ----------
    text : str
        The whole table: one header row of 8 comma-separated fields, then one row per
        coefficient ``l, m, C, S, sigma_C, sigma_S`` (kilometres for a shape model). Rows
        may carry trailing blank padding (the PDS fixed-length records do).
    source : str
        Name used in error messages (the file path).

    Returns
    -------
    ShapeHarmonics

    Raises
    ------
    ReferenceDataError
        Naming ``source`` and the line at fault: a field that is not a number, a non-finite
        value, a degree or order out of range, a repeated or missing coefficient (a truncated
        file), or an unnormalised model.
    """
    lines = [(i + 1, ln) for i, ln in enumerate(text.splitlines()) if ln.strip()]
    if not lines:
        raise _fail(source, "the file is empty")
    head_no, head = lines[0]
    fields = head.split(",")
    if len(fields) != 8:
        raise _fail(source, f"line {head_no}: header has {len(fields)} fields, not 8")
    ref_radius_km = _float(source, fields[0], "reference radius", head_no)
    if ref_radius_km <= 0.0:
        raise _fail(source, f"line {head_no}: reference radius {ref_radius_km} km is not positive")
    degree = _int(source, fields[3], "degree", head_no)
    order = _int(source, fields[4], "order", head_no)
    norm_state = _int(source, fields[5], "normalisation state", head_no)
    ref_lon = _float(source, fields[6], "reference longitude", head_no)
    ref_lat = _float(source, fields[7], "reference latitude", head_no)
    if not 0 <= degree <= MAX_DEGREE or not 0 <= order <= degree:
        raise _fail(source, f"line {head_no}: degree {degree} / order {order} out of range 0..{MAX_DEGREE}")
    if norm_state == 0:
        raise _fail(source, f"line {head_no}: normalisation state 0 (unnormalised coefficients) is not supported")

    rows = lines[1:]
    n_expected = (degree + 1) * (degree + 2) // 2
    if len(rows) != n_expected:
        raise _fail(
            source,
            f"{len(rows)} coefficient rows for degree {degree} (expected {n_expected}); "
            f"the file is truncated or has extra rows",
        )
    c = np.zeros((degree + 1, degree + 1))
    s = np.zeros_like(c)
    cs = np.zeros_like(c)
    ss = np.zeros_like(c)
    seen = np.zeros(c.shape, dtype=bool)
    for line_no, row in rows:
        f = row.split(",")
        if len(f) != 6:
            raise _fail(source, f"line {line_no}: {len(f)} fields, not 6")
        l_, m_ = _int(source, f[0], "degree", line_no), _int(source, f[1], "order", line_no)
        if not 0 <= m_ <= l_ <= degree:
            raise _fail(source, f"line {line_no}: (l, m) = ({l_}, {m_}) outside 0 <= m <= l <= {degree}")
        if seen[l_, m_]:
            raise _fail(source, f"line {line_no}: coefficient (l, m) = ({l_}, {m_}) repeated")
        seen[l_, m_] = True
        c[l_, m_] = _float(source, f[2], "C", line_no)
        s[l_, m_] = _float(source, f[3], "S", line_no)
        cs[l_, m_] = _float(source, f[4], "sigma C", line_no)
        ss[l_, m_] = _float(source, f[5], "sigma S", line_no)
    # n_expected distinct (l, m) with 0 <= m <= l <= degree were seen: the set is complete.
    return ShapeHarmonics(
        reference_radius_m=ref_radius_km * 1000.0,
        lmax=degree,
        c_m=c * 1000.0,
        s_m=s * 1000.0,
        c_sigma_m=cs * 1000.0,
        s_sigma_m=ss * 1000.0,
        normalization_state=norm_state,
        reference_longitude_deg=ref_lon,
        reference_latitude_deg=ref_lat,
        source=source,
    )


#: The prefix naming a shape table shipped with the package (``mercury_dem/reference/data/``).
PACKAGE_PREFIX = "package:"
#: MLA's GTMES_150V05 shape of Mercury, shipped whole (see ``mercury_dem/reference/data/README.md``).
GTMES_PACKAGED = PACKAGE_PREFIX + "GTMES_150V05_SHA.TAB"


def resolve_shape_path(path: str | Path) -> Path:
    """The file a shape-table name designates: ``package:NAME`` is ``NAME`` in the package's
    ``reference/data`` directory (so a configuration or a mission's ``truth/surface.json`` naming it
    works on any machine the package is installed on); anything else is a path as given.
    """
    text = str(path)
    if text.startswith(PACKAGE_PREFIX):
        name = text[len(PACKAGE_PREFIX):]
        if not name or "/" in name or "\\" in name or name.startswith("."):
            raise ReferenceDataError(f"{text}: not a packaged data file name (expected package:NAME, e.g. "
                                     f"{GTMES_PACKAGED})")
        return Path(__file__).resolve().parent / "data" / name
    return Path(path)


def read_shadr(path: str | Path) -> ShapeHarmonics:
    """Read a PDS SHADR shape table such as MLA's ``GTMES_150V05_SHA.TAB``.

    ``path`` may be ``package:NAME`` for a table shipped with the package (:data:`GTMES_PACKAGED`).

    Layout (from the product's ``.LBL``): record 1 is the header (reference radius km,
    constant 1, its uncertainty 0, degree, order, normalisation state, reference longitude
    and latitude); the coefficient rows start at record 3 (record 2 is the blank tail of the
    header's fixed-length record). The label is not needed to read the table.

    Raises
    ------
    ReferenceDataError
        The file cannot be read or is not a complete SHADR table (see :func:`parse_shadr`).
    """
    path = resolve_shape_path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise _fail(path, f"cannot be read ({exc.strerror or exc})") from None
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError as exc:
        raise _fail(path, f"byte {exc.start} is not ASCII") from None
    return parse_shadr(text, str(path))


def file_sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file (to check a reference file is the published one)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


# --------------------------------------------------------------------------- evaluation


def _check_lmax(shape: ShapeHarmonics, lmax: int | None) -> int:
    lmax = shape.lmax if lmax is None else int(lmax)
    if not 0 <= lmax <= shape.lmax:
        raise ValueError(f"lmax = {lmax} is outside 0..{shape.lmax}, the degrees of {shape.source or 'the model'}")
    return lmax


def _order_sums(
    shape: ShapeHarmonics, lat_deg: NDArray[np.float64], lmax: int
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A_m(φ) = Σ_l C_lm P̄_lm(sin φ) and B_m(φ) likewise with S, shape (n, lmax + 1), metres."""
    phi = np.radians(lat_deg)
    t = np.sin(phi)[:, None]
    u = np.cos(phi)
    m = np.arange(lmax + 1)
    n = lat_deg.shape[0]
    # Sectoral seeds of the modified functions (the cos^m factor is applied at the end).
    seed = np.ones(lmax + 1)
    if lmax >= 1:
        seed[1] = math.sqrt(3.0)
        k = np.arange(2, lmax + 1)
        seed[2:] = math.sqrt(3.0) * np.cumprod(np.sqrt((2.0 * k + 1.0) / (2.0 * k)))
    c = shape.c_m[: lmax + 1, : lmax + 1]
    s = shape.s_m[: lmax + 1, : lmax + 1]
    a_sum = np.zeros((n, lmax + 1))
    b_sum = np.zeros((n, lmax + 1))
    p_prev2 = np.zeros((n, lmax + 1))  # P̃_{l-2, m}
    p_prev1 = np.zeros((n, lmax + 1))  # P̃_{l-1, m}
    for deg in range(lmax + 1):
        p = np.zeros((n, lmax + 1))
        if deg > 0:
            mm = m[:deg]
            lm = (deg - mm) * (deg + mm)
            a = np.sqrt((2.0 * deg - 1.0) * (2.0 * deg + 1.0) / lm)
            b = np.sqrt((2.0 * deg + 1.0) * (deg + mm - 1.0) * np.maximum(deg - mm - 1.0, 0.0)
                        / (lm * max(2.0 * deg - 3.0, 1.0)))
            p[:, :deg] = a * t * p_prev1[:, :deg] - b * p_prev2[:, :deg]
        p[:, deg] = seed[deg]
        a_sum[:, : deg + 1] += p[:, : deg + 1] * c[deg, : deg + 1]
        b_sum[:, : deg + 1] += p[:, : deg + 1] * s[deg, : deg + 1]
        p_prev2, p_prev1 = p_prev1, p
    with np.errstate(under="ignore"):
        um = np.abs(u)[:, None] ** m
    return a_sum * um, b_sum * um


def evaluate(
    shape: ShapeHarmonics, lat_deg: ArrayLike, lon_deg: ArrayLike, lmax: int | None = 148
) -> NDArray[np.float64]:
    """Radius of the shape model at arbitrary points.

    Parameters
    ----------
    shape : ShapeHarmonics
    lat_deg, lon_deg : array_like, broadcastable to a common shape (...)
        Planetocentric latitude and east longitude, degrees (any longitude range).
    lmax : int or None
        Truncation degree (148 for GTMES_150V05, per its label); None uses every degree.

    Returns
    -------
    ndarray of shape (...)
        Radius from the body's centre of mass, metres (NaN where an input is NaN).
    """
    lmax = _check_lmax(shape, lmax)
    lat, lon = np.broadcast_arrays(np.asarray(lat_deg, dtype=np.float64), np.asarray(lon_deg, dtype=np.float64))
    out_shape = lat.shape
    lat, lon = lat.ravel(), lon.ravel()
    out = np.full(lat.shape, np.nan)
    ok = np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90.0)
    idx = np.flatnonzero(ok)
    m = np.arange(lmax + 1)
    for start in range(0, idx.size, _CHUNK):
        sel = idx[start : start + _CHUNK]
        a_sum, b_sum = _order_sums(shape, lat[sel], lmax)
        ml = np.radians(lon[sel])[:, None] * m
        out[sel] = np.sum(a_sum * np.cos(ml) + b_sum * np.sin(ml), axis=1)
    return out.reshape(out_shape)


def evaluate_grid(
    shape: ShapeHarmonics, lats_deg: ArrayLike, lons_deg: ArrayLike, lmax: int | None = 148
) -> NDArray[np.float64]:
    """Radius of the shape model on the grid lats × lons.

    The Legendre sums are formed once per latitude; the longitudes are one matrix product
    with cos(mλ) and sin(mλ), so any longitudes (not only an FFT-friendly full circle) work.

    Parameters
    ----------
    shape : ShapeHarmonics
    lats_deg : array_like of shape (H,)
        Planetocentric latitudes, degrees, any order.
    lons_deg : array_like of shape (W,)
        East longitudes, degrees, any order and range.
    lmax : int or None
        Truncation degree; None uses every degree.

    Returns
    -------
    ndarray of shape (H, W)
        Radius, metres.
    """
    lmax = _check_lmax(shape, lmax)
    lats = np.asarray(lats_deg, dtype=np.float64).ravel()
    lons = np.asarray(lons_deg, dtype=np.float64).ravel()
    if not (np.all(np.isfinite(lats)) and np.all(np.abs(lats) <= 90.0) and np.all(np.isfinite(lons))):
        raise ValueError("grid latitudes must be finite within [-90, 90] and longitudes finite")
    m = np.arange(lmax + 1)
    ml = np.radians(lons)[None, :] * m[:, None]  # (M, W)
    out = np.empty((lats.size, lons.size))
    for start in range(0, lats.size, _CHUNK):
        a_sum, b_sum = _order_sums(shape, lats[start : start + _CHUNK], lmax)
        out[start : start + _CHUNK] = a_sum @ np.cos(ml) + b_sum @ np.sin(ml)
    return out
