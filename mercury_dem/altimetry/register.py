"""Registration of an image DEM onto laser altimetry, in seed 004's two steps (Barker et al. 2014).

1. **Per tile, a 3-D affine transform** ``T`` (rotation, scale, shear, translation: 12
   parameters) that moves the image DEM onto the altimetry, estimated robustly from the
   height residuals of the tile's shots.
2. **Per altimetry profile, a 3-D offset** that moves the profile's shots onto the registered
   DEM (the orbit and boresight errors of that profile).

Model and frame
---------------
Everything of a tile is written in its local east/north/up frame ``E = [e, n, u]`` at the
tile centre ``c`` (on the datum sphere). A shot at body-fixed ``x`` has local coordinates
``q = Eᵀ(x − c)``. The fit estimates the *inverse* map ``G = T⁻¹`` that carries the shots
into the DEM's frame,

    G(x) = c + E [(I + B) q + b],     B: 3 × 3, b: 3 (metres),

because then each residual needs the DEM only at ``G(x)``: with ``y = G(x)``,

    r(x) = (|y| − R_datum) − DEM(lat(y), lon(y))      (metres, shot above DEM > 0 ... below < 0).

Its gradient in ``y`` is ``g = u − (∂h/∂φ) n / |y| − (∂h/∂λ) e / (|y| cos φ)``: the
(unnormalised) normal of the DEM surface, so Gauss-Newton on ``r`` is point-to-plane ICP
(pc_align's method) with the DEM's local slopes. The elements of ``B`` are estimated as
the displacements they cause at the tile's half-width ``L`` (``θ = L·B``, metres), so every
parameter is a length and one threshold judges them all.

Robust weights: Huber (``huber_k`` × the NMAD of the residuals), shots beyond
``reject_k`` × NMAD from the median rejected (counted), Gauss-Newton steps halved until the
robust cost decreases. ``scipy.optimize.least_squares`` would do the same fit
(``loss="huber"``) and is the benchmark's reference; this solver is written out because it
reuses one DEM sample per iteration for residuals *and* Jacobian (least_squares asks for
them separately), reports the parameters' standard deviations for the model fall-back, and
ran 16× faster on the benchmark's tile (docs/benchmarks/altimetry.md).

Profile errors in step 1
------------------------
With ``profile_nuisance`` (default) the tile fit also carries one offset per profile as a
nuisance with a prior of the profiles' expected error, eliminated from the normal equations
by a Schur complement of the 3 × 3 profile blocks each iteration: a constant error per
profile then cannot masquerade as a rotation (measured: a 0.02° rotation under 30 m profile
errors came back 3–13 % off without, within 5 % with; docs/design/altimetry.md).
The offsets are kept out of the transform directions they can mimic (the translation, and with
few near-parallel profiles the rotation about their direction): for each direction ``v`` whose
information the nuisance removes almost entirely, ``Σ_p vᵀ N_tp,p d_p = 0`` (Lagrange multipliers,
eliminated with the profile blocks), so there the transform is fitted as without the nuisance;
without this the offsets and the transform traded off and the transform alone fitted the shots
worse (docs/benchmarks/altimetry.md, session 11).

Fall-back when shear is not determined
--------------------------------------
The models are tried in order ``affine`` (12) → ``similarity`` (rotation + scale +
translation, 7) → ``translation`` (3) → ``vertical`` (1). A model is used when the normal
matrix is not singular and every parameter's standard deviation (σ₀² (JᵀWJ)⁻¹, in metres of
displacement at the tile edge) is below ``max_param_sigma_m`` (judged at convergence; a model
still over twice that after 3 iterations is abandoned then); shots along a single line, or
a tile of few shots on flat ground, thus fall back to a model the shots can carry, and the
result says which model was used. A tile with fewer than ``min_shots`` usable shots, or on
which no model is determined, is not registered: ``ok = False`` with the reason.

The reported transform is ``T = G⁻¹`` (image DEM → altimetry): in the tile's ENU frame
``T(q) = M q + t`` with ``M = (I + B)⁻¹``, ``t = −M b``; ``translation_enu_m`` is ``t``
(where ``T`` moves the tile centre), ``rotation_deg`` the rotation of ``M``'s polar
decomposition ``M = R S`` about the east, north and up axes, ``scale`` = det(S)^⅓ and
``strain`` = S/scale − I.

Per-profile offsets
-------------------
A profile is one altimetry ground track (``profile_id``) within one tile: a ground track crossing several
tiles gets one offset per tile, as seed 004 fits its ~3°-long profile segments. The offset
``d`` (metres, in the ENU frame at the segment's mean position) is the correction *added*
to the shots: ``x + d`` lies on the registered DEM. It is estimated by the same robust
Gauss-Newton, with a weak prior (``profile_sigma_horizontal_m``, ``profile_sigma_vertical_m``)
so a profile on flat ground, whose horizontal offset the heights cannot see, gets a
near-zero horizontal offset and a large reported sigma instead of noise. Profiles with
fewer than ``min_profile_shots`` usable shots (e.g. 2) are counted and left uncorrected.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import polar

from mercury_dem.config.registration import MODEL_NAMES, RegistrationConfig
from mercury_dem.geometry.body import latlon_to_unit, wrap_longitude, xyz_to_latlon
from mercury_dem.stats import NMAD_FACTOR

__all__ = [
    "MODELS",
    "DemWindow",
    "ProfileOffsets",
    "RegisterOptions",
    "TileRegistration",
    "TileTransform",
    "enu_frame",
    "register_tile",
    "tile_window",
]

#: The transform models, most general first, with their number of parameters.
MODELS: dict[str, int] = dict(zip(MODEL_NAMES, (12, 7, 3, 1), strict=True))

_CONFIG = RegistrationConfig()  # the defaults of RegisterOptions: the configuration's, defined once there

#: After this many Gauss-Newton steps a model whose worst parameter σ is over twice
#: ``max_param_sigma_m`` is abandoned (it would be rejected at convergence anyway).
_EARLY_JUDGEMENT_ITERATION = 3


@dataclass(frozen=True)
class RegisterOptions:
    """Settings of the registration (units in the names): the ``registration`` configuration section's keys of
    the same names (:meth:`from_config`; the defaults are that section's).

    Attributes
    ----------
    models : tuple of str
        Models tried in order (see :data:`MODELS`); the first one the shots determine is used.
    max_param_sigma_m : float
        Largest standard deviation of any parameter of a used model, metres of displacement at
        the tile edge (translation: metres).
    huber_k : float
        Huber threshold in units of the residuals' NMAD.
    reject_k : float
        Shots farther than this many NMAD from the median residual are rejected.
    max_iterations : int
        Gauss-Newton iterations per model.
    tolerance_m : float
        Converged when no parameter changes by more than this (metres).
    min_shots : int
        Fewest usable shots for a tile to be registered.
    min_profile_shots : int
        Fewest usable shots for a profile offset to be fitted.
    profile_sigma_horizontal_m, profile_sigma_vertical_m : float
        Prior standard deviations of a profile offset (east/north and up), metres.
    max_abs_height_m : float
        Shots farther than this from the datum sphere are invalid (counted), metres.
    profile_nuisance : bool
        Estimate the tile transform jointly with one offset per profile as a nuisance (random
        effect with the two σ below), so constant profile errors do not bias it; step 2 then fits
        the profile offsets against the registered DEM as without it.
    nuisance_sigma_horizontal_m, nuisance_sigma_vertical_m : float
        The expected size of the profiles' errors (their prior in the joint fit), metres.
    nuisance_min_within_share : float
        Transform directions that keep less than this share of their information once the profile
        offsets are free (generalised eigenvalues of the two normal matrices; the translation ≈ 0, with
        near-parallel profiles also the rotation about their direction) are kept out of the nuisance:
        the offsets may exert no force on them, so there the transform is fitted as without the nuisance.
        0 gives the unconstrained joint fit (before session 11); measured gap between the mimicked
        directions (≤ 0.008) and the others (≥ 0.10) on 42 tiles, docs/design/altimetry.md.
    """

    models: tuple[str, ...] = _CONFIG.models
    max_param_sigma_m: float = _CONFIG.max_param_sigma_m
    huber_k: float = _CONFIG.huber_k
    reject_k: float = _CONFIG.reject_k
    max_iterations: int = _CONFIG.max_iterations
    tolerance_m: float = _CONFIG.tolerance_m
    min_shots: int = _CONFIG.min_shots
    min_profile_shots: int = _CONFIG.min_profile_shots
    profile_sigma_horizontal_m: float = _CONFIG.profile_sigma_horizontal_m
    profile_sigma_vertical_m: float = _CONFIG.profile_sigma_vertical_m
    max_abs_height_m: float = _CONFIG.max_abs_height_m
    profile_nuisance: bool = _CONFIG.profile_nuisance
    nuisance_sigma_horizontal_m: float = _CONFIG.nuisance_sigma_horizontal_m
    nuisance_sigma_vertical_m: float = _CONFIG.nuisance_sigma_vertical_m
    nuisance_min_within_share: float = _CONFIG.nuisance_min_within_share

    @classmethod
    def from_config(cls, cfg: RegistrationConfig) -> RegisterOptions:
        """The fit settings of the ``registration`` configuration section (its keys of the same names)."""
        return cls(**{f.name: getattr(cfg, f.name) for f in fields(cls)})

    def __post_init__(self) -> None:
        unknown = [m for m in self.models if m not in MODELS]
        if unknown or not self.models:
            raise ValueError(f"models must be a non-empty subset of {list(MODELS)}, got {self.models}")
        for name in ("max_param_sigma_m", "huber_k", "reject_k", "tolerance_m", "profile_sigma_horizontal_m",
                     "profile_sigma_vertical_m", "max_abs_height_m", "nuisance_sigma_horizontal_m",
                     "nuisance_sigma_vertical_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v}")
        if not (0.0 <= self.nuisance_min_within_share <= 1.0):
            raise ValueError(f"nuisance_min_within_share must be in [0, 1], got {self.nuisance_min_within_share}")
        if self.max_iterations < 1 or self.min_shots < 1 or self.min_profile_shots < 3:
            raise ValueError("max_iterations >= 1, min_shots >= 1 and min_profile_shots >= 3 are required")


@dataclass(frozen=True, eq=False)
class DemWindow:
    """The part of a DEM one tile needs (its bounds plus a margin), on an even lat/lon grid.

    Attributes
    ----------
    height : ndarray of shape (H, W)
        Heights above ``datum_radius_m``, metres; NaN where the DEM has none.
    lat : ndarray of shape (H,)
        Pixel-centre latitudes, degrees, evenly spaced (either direction).
    lon : ndarray of shape (W,)
        Pixel-centre east longitudes, degrees, evenly spaced and increasing; may run past 360
        (a window across the 0/360 seam).
    datum_radius_m : float
    """

    height: NDArray[np.float64]
    lat: NDArray[np.float64]
    lon: NDArray[np.float64]
    datum_radius_m: float

    def __post_init__(self) -> None:
        h = np.asarray(self.height)
        if h.ndim != 2 or h.shape != (self.lat.size, self.lon.size) or min(h.shape) < 2:
            raise ValueError(f"DEM window of shape {h.shape} does not match {self.lat.size} x {self.lon.size} "
                             f"coordinates (at least 2 x 2 needed)")
        if not np.all(np.diff(self.lon) > 0):
            raise ValueError("DEM window longitudes must increase")


def tile_window(
    height: NDArray[np.floating], lat: ArrayLike, lon: ArrayLike, bounds: tuple[float, float, float, float],
    datum_radius_m: float, margin_deg: float = 1.0,
) -> DemWindow | None:
    """Cut the window of a tile (bounds plus ``margin_deg``) out of a DEM.

    Parameters
    ----------
    height : ndarray of shape (H, W)
        The DEM, metres above ``datum_radius_m``.
    lat, lon : array_like of shape (H,), (W,)
        Its pixel centres (evenly spaced; a global DEM's columns wrap around the seam).
    bounds : (lat_min, lat_max, lon_min, lon_max), degrees
    datum_radius_m : float
    margin_deg : float

    Returns
    -------
    DemWindow or None
        None when the DEM has fewer than 2 × 2 pixels there.
    """
    lat = np.asarray(lat, dtype=np.float64)
    lon = np.asarray(lon, dtype=np.float64)
    lat0, lat1, lon0, lon1 = bounds
    rows = np.flatnonzero((lat >= lat0 - margin_deg) & (lat <= lat1 + margin_deg))
    if lon.size < 2:
        return None
    step = float(np.median(np.diff(lon)))
    periodic = abs(abs(step) * lon.size - 360.0) < 1e-6 * 360.0
    if periodic and lat1 - lat0 < 180.0:
        # Columns from lon0 − margin to lon1 + margin, wrapping: unwrapped coordinates, modular indices.
        first = int(np.floor(wrap_longitude(lon0 - margin_deg - lon[0]) / step))
        n = min(int(np.ceil((lon1 - lon0 + 2 * margin_deg) / step)) + 2, lon.size)
        cols = (first + np.arange(n)) % lon.size
        lon_w = lon[0] + (first + np.arange(n)) * step
        if lat0 - margin_deg <= -90.0 or lat1 + margin_deg >= 90.0:  # a polar tile: every longitude
            cols = np.r_[np.arange(lon.size), 0]  # the first column again: shots in the seam's cell
            lon_w = np.r_[lon, lon[-1] + step]
    else:
        off = wrap_longitude(lon - (lon0 - margin_deg))
        cols = np.flatnonzero(off <= (lon1 - lon0) + 2 * margin_deg)
        lon_w = lon[cols]
        if cols.size and np.any(np.diff(lon_w) <= 0):
            lon_w = lon[cols[0]] + np.cumsum(np.r_[0.0, wrap_longitude(np.diff(lon_w))])
    if rows.size < 2 or cols.size < 2:
        return None
    h = np.asarray(height, dtype=np.float64)[np.ix_(rows, cols)]
    return DemWindow(h, lat[rows], lon_w, float(datum_radius_m))


def enu_frame(lat_deg: ArrayLike, lon_deg: ArrayLike) -> NDArray[np.float64]:
    """East, north, up unit vectors as the columns of ``(..., 3, 3)`` matrices (body-fixed frame)."""
    lat = np.radians(np.asarray(lat_deg, dtype=np.float64))
    lon = np.radians(np.asarray(lon_deg, dtype=np.float64))
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    e = np.stack([-so, co, np.zeros_like(so)], axis=-1)
    n = np.stack([-sl * co, -sl * so, cl], axis=-1)
    u = np.stack([cl * co, cl * so, sl], axis=-1)
    return np.stack([e, n, u], axis=-1)


class _Sampler:
    """Bilinear samples of a window's height and its two gradients at points, in one pass.

    Written here rather than calling :func:`mercury_dem.reference.sampling.sample_grid` three
    times: the cell indices and weights are computed once for the stacked (height, ∂h/∂φ,
    ∂h/∂λ) layers, on the window's even grid; this is the inner loop of every iteration.
    """

    def __init__(self, win: DemWindow):
        h = np.asarray(win.height, dtype=np.float64)
        dlat = math.radians(float(win.lat[1] - win.lat[0]))
        dlon = math.radians(float(win.lon[1] - win.lon[0]))
        g_lat, g_lon = np.gradient(h, dlat, dlon)  # metres per radian of latitude / longitude
        self.layers = np.stack([h, g_lat, g_lon])
        self.lat0, self.dlat = float(win.lat[0]), float(win.lat[1] - win.lat[0])
        self.lon0, self.dlon = float(win.lon[0]), float(win.lon[1] - win.lon[0])
        self.shape = h.shape

    def __call__(self, lat: NDArray[np.float64], lon: NDArray[np.float64]) -> NDArray[np.float64]:
        """(3, N): height, ∂h/∂φ, ∂h/∂λ (per radian); NaN outside the window or on its gaps."""
        nr, nc = self.shape
        fr = (lat - self.lat0) / self.dlat
        fc = wrap_longitude(lon - self.lon0) / self.dlon
        inside = (fr >= 0) & (fr <= nr - 1) & (fc >= 0) & (fc <= nc - 1)
        r0 = np.clip(np.floor(fr), 0, nr - 2).astype(np.intp)
        c0 = np.clip(np.floor(fc), 0, nc - 2).astype(np.intp)
        wr = np.clip(fr - r0, 0.0, 1.0)
        wc = np.clip(fc - c0, 0.0, 1.0)
        L = self.layers
        out = (L[:, r0, c0] * ((1 - wr) * (1 - wc)) + L[:, r0, c0 + 1] * ((1 - wr) * wc)
               + L[:, r0 + 1, c0] * (wr * (1 - wc)) + L[:, r0 + 1, c0 + 1] * (wr * wc))
        out[:, ~inside] = np.nan
        return out


def _residuals(y: NDArray[np.float64], sampler: _Sampler, datum: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Residual (shot height − DEM) at body-fixed points ``y`` (N, 3) and its gradient in y (N, 3)."""
    lat, lon, h = xyz_to_latlon(y, datum)
    s = sampler(lat, lon)
    rad = np.linalg.norm(y, axis=1)
    frame = enu_frame(lat, lon)
    coslat = np.maximum(np.cos(np.radians(lat)), 1e-3)
    g = frame[:, :, 2] - (s[1] / rad)[:, None] * frame[:, :, 1] - (s[2] / (rad * coslat))[:, None] * frame[:, :, 0]
    r = h - s[0]
    r[~np.all(np.isfinite(s), axis=0)] = np.nan  # beside a gap the height may be finite, its slope not
    return r, g


def _model_basis(model: str, L: NDArray[np.float64]) -> NDArray[np.float64]:
    """(12, k) map from a model's parameters to the full vector [B_ij·L_j (row-major 9), b (3)].

    The similarity's scale and rotations are displacements at the horizontal lever ``L[0]``.
    """
    P = np.zeros((12, MODELS[model]))
    if model == "affine":
        P[:] = np.eye(12)
    elif model == "similarity":
        P[[0, 4, 8], 0] = L / L[0]  # scale
        # rotation about e, n, u: the antisymmetric generators [ω]×
        for k, (i, j) in enumerate(((2, 1), (0, 2), (1, 0)), start=1):
            P[3 * i + j, k] = L[j] / L[0]
            P[3 * j + i, k] = -L[i] / L[0]
        P[9:, 4:] = np.eye(3)
    elif model == "translation":
        P[9:, :] = np.eye(3)
    else:
        P[11, 0] = 1.0
    return P


def _nmad(r: NDArray[np.float64]) -> float:
    if r.size == 0:
        return float("nan")
    return float(NMAD_FACTOR * np.median(np.abs(r - np.median(r))))


def _huber_weights(r: NDArray[np.float64], scale: float, k: float) -> NDArray[np.float64]:
    a = np.abs(r)
    thr = k * scale
    return np.where(a <= thr, 1.0, thr / np.maximum(a, 1e-300))


def _huber_cost(r: NDArray[np.float64], scale: float, k: float) -> float:
    a = np.abs(r) / scale
    return float(np.sum(np.where(a <= k, 0.5 * a * a, k * a - 0.5 * k * k)))


@dataclass(frozen=True)
class TileTransform:
    """The transform ``T`` (image DEM → altimetry) of one tile, in its ENU frame at the centre.

    Attributes
    ----------
    tile_id : int
    centre_lat, centre_lon : float
        Tile centre, degrees (the origin of the ENU frame, on the datum sphere).
    datum_radius_m : float
    model : str
        The model used (:data:`MODELS`), "" when the tile was not registered.
    matrix : tuple of 9 floats
        ``M`` row-major (ENU), identity when not registered.
    translation_enu_m : tuple of 3 floats
        ``t``: where T moves the tile centre, metres east, north, up.
    rotation_deg : tuple of 3 floats
        Rotation of ``M`` about the east, north and up axes, degrees.
    scale : float
    strain : tuple of 6 floats
        ``S/scale − I`` of the polar decomposition: ee, nn, uu, en, eu, nu.
    sigma_m : tuple of float
        Standard deviation of each parameter of the model, metres at the tile edge.
    ok : bool
    reason : str
        Why the tile was not registered, or which models were not determined.
    """

    tile_id: int
    centre_lat: float
    centre_lon: float
    datum_radius_m: float
    model: str = ""
    matrix: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    translation_enu_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    scale: float = 1.0
    strain: tuple[float, ...] = (0.0,) * 6
    sigma_m: tuple[float, ...] = ()
    ok: bool = False
    reason: str = ""

    def world(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(A, a)`` with ``T(p) = A p + a`` for body-fixed points (metres)."""
        E = enu_frame(self.centre_lat, self.centre_lon)
        c = self.datum_radius_m * E[:, 2]
        A = E @ np.asarray(self.matrix).reshape(3, 3) @ E.T
        a = c - A @ c + E @ np.asarray(self.translation_enu_m)
        return A, a

    def apply(self, xyz: ArrayLike) -> NDArray[np.float64]:
        """``T`` applied to body-fixed points of shape (..., 3)."""
        A, a = self.world()
        return np.asarray(xyz, dtype=np.float64) @ A.T + a


@dataclass(frozen=True, eq=False)
class ProfileOffsets:
    """One 3-D offset per profile (a ground track within a tile), columnar (arrays of shape (P,)).

    Attributes
    ----------
    profile_id, tile_id : int arrays
    offset_enu_m : ndarray of shape (P, 3)
        Correction added to the profile's shots (ENU at the profile's mean position), metres;
        zero for profiles not fitted.
    sigma_enu_m : ndarray of shape (P, 3)
        Standard deviation of the offset, metres (NaN when not fitted).
    centre_lat, centre_lon : float arrays
        Mean position of the profile's shots (the origin of its ENU frame), degrees.
    n_shots, n_used : int arrays
        Shots of the profile on the DEM; shots used (not rejected).
    rms_before_m, rms_after_m : float arrays
        RMS of the used shots' residuals against the registered DEM, before and after the offset.
    fitted : bool array
        False for profiles with fewer than ``min_profile_shots`` usable shots.
    """

    profile_id: NDArray[np.int64]
    tile_id: NDArray[np.int64]
    offset_enu_m: NDArray[np.float64]
    sigma_enu_m: NDArray[np.float64]
    centre_lat: NDArray[np.float64]
    centre_lon: NDArray[np.float64]
    n_shots: NDArray[np.int64]
    n_used: NDArray[np.int64]
    rms_before_m: NDArray[np.float64]
    rms_after_m: NDArray[np.float64]
    fitted: NDArray[np.bool_]

    @staticmethod
    def empty() -> ProfileOffsets:
        z = np.zeros(0)
        zi = np.zeros(0, dtype=np.int64)
        return ProfileOffsets(zi, zi, np.zeros((0, 3)), np.zeros((0, 3)), z, z, zi, zi, z, z, np.zeros(0, bool))

    def to_frame(self) -> pd.DataFrame:
        """One row per profile: the fields above, the ENU vectors as ``_e``/``_n``/``_u`` columns."""
        d: dict[str, Any] = {"profile_id": self.profile_id, "tile_id": self.tile_id}
        for k, ax in enumerate("enu"):
            d[f"offset_{ax}_m"] = self.offset_enu_m[:, k]
        for k, ax in enumerate("enu"):
            d[f"sigma_{ax}_m"] = self.sigma_enu_m[:, k]
        d.update(centre_lat=self.centre_lat, centre_lon=self.centre_lon, n_shots=self.n_shots, n_used=self.n_used,
                 rms_before_m=self.rms_before_m, rms_after_m=self.rms_after_m, fitted=self.fitted)
        return pd.DataFrame(d)

    @staticmethod
    def concat(parts: list[ProfileOffsets]) -> ProfileOffsets:
        parts = [p for p in parts if p.profile_id.size]
        if not parts:
            return ProfileOffsets.empty()
        return ProfileOffsets(*(np.concatenate([getattr(p, f) for p in parts]) for f in (
            "profile_id", "tile_id", "offset_enu_m", "sigma_enu_m", "centre_lat", "centre_lon", "n_shots",
            "n_used", "rms_before_m", "rms_after_m", "fitted")))


@dataclass(frozen=True)
class TileRegistration:
    """What :func:`register_tile` found on one tile.

    Attributes
    ----------
    transform : TileTransform
    profiles : ProfileOffsets
    counts : dict of str to int
        ``shots`` given, ``invalid`` (non-finite coordinates or radius beyond ``max_abs_height_m``), ``off_dem`` (outside the DEM or
        on its gaps), ``used``, ``rejected`` (robust rejection), ``not_registered`` (usable shots of
        a tile that was not registered; these five add up to ``shots``), ``profiles``,
        ``profiles_fitted``, ``profiles_too_few_shots``.
    rms_before_m : float
        RMS of the used shots' residuals against the image DEM as given.
    rms_registered_m : float
        Same shots against the registered DEM (after ``T``).
    rms_after_m : float
        Same shots, after ``T`` and each profile's offset.
    iterations : int
    """

    transform: TileTransform
    profiles: ProfileOffsets
    counts: dict[str, int] = field(default_factory=dict)
    rms_before_m: float = float("nan")
    rms_registered_m: float = float("nan")
    rms_after_m: float = float("nan")
    iterations: int = 0

    def summary(self) -> dict[str, Any]:
        """A JSON-able row of the per-tile table."""
        t = self.transform
        out: dict[str, Any] = {
            "tile_id": t.tile_id, "centre_lat": t.centre_lat, "centre_lon": t.centre_lon, "ok": t.ok,
            "model": t.model, "reason": t.reason,
            "translation_e_m": t.translation_enu_m[0], "translation_n_m": t.translation_enu_m[1],
            "translation_u_m": t.translation_enu_m[2],
            "rotation_e_deg": t.rotation_deg[0], "rotation_n_deg": t.rotation_deg[1],
            "rotation_u_deg": t.rotation_deg[2], "scale": t.scale,
            "max_strain": float(np.max(np.abs(t.strain))),
            "rms_before_m": self.rms_before_m, "rms_registered_m": self.rms_registered_m,
            "rms_after_m": self.rms_after_m, "iterations": self.iterations,
        }
        out.update({f"n_{k}": int(v) for k, v in self.counts.items()})
        return out


def _rms(r: NDArray[np.float64]) -> float:
    r = r[np.isfinite(r)]
    return float(np.sqrt(np.mean(r * r))) if r.size else float("nan")


def _solve(N: NDArray[np.float64], rhs: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """Solve N x = rhs for a symmetric normal matrix; None when (numerically) singular. Also the inverse."""
    d = np.sqrt(np.maximum(np.diag(N), 0.0))
    if np.any(d <= 0):
        return None
    Ns = N / np.outer(d, d)
    w, V = np.linalg.eigh(Ns)
    if w[0] <= 1e-10 * w[-1]:
        return None
    inv = (V / w) @ V.T / np.outer(d, d)
    return inv @ rhs, inv


@dataclass(frozen=True, eq=False)
class _TransformFit:
    """One model fitted to a tile's shots by :func:`_fit_transform`.

    Attributes
    ----------
    theta : (12,) the transform's parameters (9 linear ones, as displacements a lever ``lever`` away, then the
        translation), tile ENU frame, metres
    keep : (N,) the shots used at the end (finite, within ``reject_k`` robust sigmas)
    r : (N,) the shots' height residuals at ``theta`` (m; NaN off the DEM)
    sigma, sigma_geom : (k,) posterior sigmas of the model's parameters (m): with the profile nuisance, and as the
        shots alone determine them (the sigma the model is judged by)
    iterations : Gauss-Newton iterations run
    nuisance_constrained : parameter directions kept out of the profile nuisance
    centre, enu, lever : the tile's frame (body-fixed centre (3,), ENU axes (3, 3)) and the levers (3,)
    """

    theta: NDArray[np.float64]
    keep: NDArray[np.bool_]
    r: NDArray[np.float64]
    sigma: NDArray[np.float64]
    sigma_geom: NDArray[np.float64]
    iterations: int
    nuisance_constrained: int
    centre: NDArray[np.float64]
    enu: NDArray[np.float64]
    lever: NDArray[np.float64]

    def apply(self, pts: NDArray[np.float64]) -> NDArray[np.float64]:
        """Body-fixed points (N, 3) moved by the fitted transform (the arithmetic of the fit's own model)."""
        c, E, th = self.centre, self.enu, self.theta
        B = th[:9].reshape(3, 3) / self.lever[None, :]
        return c + (((pts - c) @ E) @ (np.eye(3) + B).T + th[9:]) @ E.T


@dataclass(frozen=True)
class _FitFailure:
    """Why a model was not fitted (:func:`_fit_transform`)."""

    reason: str


def _fit_transform(
    x: NDArray[np.float64], q: NDArray[np.float64], E: NDArray[np.float64], c: NDArray[np.float64],
    sampler: _Sampler, datum: float, model: str, L: NDArray[np.float64], opt: RegisterOptions,
    profile_index: NDArray[np.intp] | None = None,
) -> _TransformFit | _FitFailure:
    """Robust Gauss-Newton of one model: the fit (theta (12), weights, sigmas, residuals), or why it failed.

    With ``profile_index`` (each shot's profile, 0..P-1) and ``opt.profile_nuisance``, one offset per
    profile (tile ENU frame) is estimated with it, its 3 × 3 blocks eliminated by a Schur
    complement each iteration, so the transform's covariance includes their uncertainty.
    """
    P = _model_basis(model, L)
    theta = np.zeros(12)
    nuis = bool(opt.profile_nuisance) and profile_index is not None
    n_prof = int(profile_index.max()) + 1 if nuis and profile_index is not None and profile_index.size else 0
    d = np.zeros((n_prof, 3))
    lam = np.array([opt.nuisance_sigma_horizontal_m ** -2] * 2 + [opt.nuisance_sigma_vertical_m ** -2])

    def apply(th: NDArray[np.float64], qq: NDArray[np.float64] = q) -> NDArray[np.float64]:
        B = th[:9].reshape(3, 3) / L[None, :]
        return c + (qq @ (np.eye(3) + B).T + th[9:]) @ E.T

    def shots(th: NDArray[np.float64], dd: NDArray[np.float64]) -> NDArray[np.float64]:
        return apply(th, q + dd[profile_index]) if nuis else apply(th)

    r, g = _residuals(apply(theta), sampler, datum)
    ok = np.isfinite(r)
    # start from the robust vertical offset: the misregistration is mostly up/down
    theta[11] = -float(np.median(r[ok])) if ok.any() else 0.0
    r, g = _residuals(apply(theta), sampler, datum)
    it = 0
    inv = None
    n_constrained = 0
    V = np.zeros((P.shape[1], 0))
    Npp_inv = np.zeros((0, 3, 3))
    w = np.zeros_like(r)
    for it in range(1, opt.max_iterations + 1):
        ok = np.isfinite(r)
        scale = max(_nmad(r[ok]), 1e-3)
        med = float(np.median(r[ok]))
        keep = ok & (np.abs(r - med) <= opt.reject_k * scale) if it > 1 else ok
        w = np.where(keep, _huber_weights(np.where(ok, r, 0.0), scale, opt.huber_k), 0.0)
        Eg = g @ E  # (N, 3): the gradient in ENU components
        Jfull = np.concatenate([(Eg[:, :, None] * (q / L)[:, None, :]).reshape(-1, 9), Eg], axis=1)
        J = np.where(keep[:, None], Jfull @ P, 0.0)
        rz = np.where(keep, r, 0.0)
        N = J.T @ (J * w[:, None])
        bt = J.T @ (w * rz)
        inv_geom = _solve(N, bt) if nuis else None  # the shots' own determination, for the fall-back
        if nuis:
            # profile blocks: N_pp (n_prof,3,3) + prior, N_tp (n_prof,k,3), b_p; eliminate them
            Jp = np.where(keep[:, None], Eg, 0.0)
            k = J.shape[1]
            Npp = np.empty((n_prof, 3, 3))
            Ntp = np.empty((n_prof, k, 3))
            bp = np.empty((n_prof, 3))
            for a_ in range(3):
                bp[:, a_] = np.bincount(profile_index, w * Jp[:, a_] * rz, n_prof) + scale ** 2 * lam[a_] * d[:, a_]
                for b_ in range(3):
                    Npp[:, a_, b_] = np.bincount(profile_index, w * Jp[:, a_] * Jp[:, b_], n_prof)
                for t_ in range(k):
                    Ntp[:, t_, a_] = np.bincount(profile_index, w * J[:, t_] * Jp[:, a_], n_prof)
            Npp += np.eye(3) * (scale ** 2 * lam)
            Npp_inv = np.linalg.inv(Npp)
            X = Ntp @ Npp_inv
            N_plain = N
            N = N - np.einsum("pka,pla->kl", X, Ntp)
            bt = bt - np.einsum("pka,pa->k", X, bp)
            V = _between_profile_directions(N_plain, N, opt.nuisance_min_within_share)
            n_constrained = V.shape[1]
        sol = _solve(N, -bt)
        if sol is None:
            return _FitFailure(f"{model}: singular (the shots do not determine it)")
        delta, inv = sol
        inv_judge = inv_geom[1] if inv_geom is not None else inv
        mult = None
        if nuis and V.shape[1]:
            # The nuisance may exert no force on the directions the profiles' mean offsets mimic:
            # sum_p v^T N_tp,p d_p = 0 for each column v of V (C_p = V^T N_tp,p), by Lagrange multipliers,
            # eliminated with the profile blocks: (N_r + A^T S^-1 A) delta = -b_r + A^T S^-1 g.
            C = np.einsum("km,pka->pma", V, Ntp)
            Y = np.einsum("pma,pab->pmb", C, Npp_inv)
            A = np.einsum("pma,pka->mk", Y, Ntp)
            S = np.einsum("pma,pna->mn", Y, C)
            gvec = np.einsum("pma,pa->m", C, d) - np.einsum("pma,pa->m", Y, bp)
            S_inv = np.linalg.pinv(S, rcond=1e-12, hermitian=True)
            solc = _solve(N + A.T @ S_inv @ A, -bt + A.T @ S_inv @ gvec)
            if solc is None:
                return _FitFailure(f"{model}: singular (the shots do not determine it)")
            delta = solc[0]
            mult = S_inv @ (gvec - A @ delta)
        if nuis:
            force = bp + np.einsum("pka,k->pa", Ntp, delta)
            if mult is not None:
                force = force + np.einsum("pma,m->pa", C, mult)
            d_step = -np.einsum("pab,pb->pa", Npp_inv, force)
        else:
            d_step = d

        def cost(res: NDArray[np.float64], sel: NDArray[np.bool_], dd: NDArray[np.float64]) -> float:
            prior = 0.5 * float(np.sum(dd * dd * lam)) if nuis else 0.0
            return _huber_cost(res[sel], scale, opt.huber_k) + prior  # noqa: B023 (called in this iteration only)

        cost0 = cost(rz, keep, d)
        step = 1.0
        for _ in range(6):
            trial = theta + P @ (step * delta)
            d_trial = d + step * d_step if nuis else d
            r_new, g_new = _residuals(shots(trial, d_trial), sampler, datum)
            k2 = keep & np.isfinite(r_new)
            if k2.sum() >= 0.9 * keep.sum() and cost(r_new, k2, d_trial) <= cost0 * (1 + 1e-9):
                break
            step *= 0.5
        else:
            break  # no decrease: converged (or stuck at the noise floor)
        theta, r, g, d = trial, r_new, g_new, d_trial
        if np.max(np.abs(step * delta)) < opt.tolerance_m:
            break
        if it == _EARLY_JUDGEMENT_ITERATION:
            # Most of the misregistration is gone after a few steps: a model whose parameters are
            # still far from determined (2x the threshold) will not be used, so stop fitting it.
            ok = np.isfinite(r) & keep
            s_now = math.sqrt(float(np.sum(w[ok] * r[ok] ** 2)) / max(int(ok.sum()) - P.shape[1], 1))
            worst = float(np.max(_judged_sigma(inv, inv_judge))) * s_now
            if worst > 2.0 * opt.max_param_sigma_m:
                return _FitFailure(f"{model}: a parameter's sigma {worst:.3g} m > max_param_sigma_m "
                                   f"(judged at iteration {it})")
    ok = np.isfinite(r)
    scale = max(_nmad(r[ok]), 1e-3)
    keep = ok & (np.abs(r - np.median(r[ok])) <= opt.reject_k * scale)
    # posterior sigmas: sigma0^2 (J^T W J)^-1, sigma0 from the weighted residuals
    n_used = int(keep.sum())
    k = P.shape[1]
    wk = w[keep] if w.shape == r.shape else np.ones(n_used)
    s0 = math.sqrt(float(np.sum(wk * r[keep] ** 2)) / max(n_used - k, 1))
    sig = np.sqrt(np.maximum(np.diag(inv), 0.0)) * s0 if inv is not None else np.full(k, np.inf)
    sig_geom = _judged_sigma(inv, inv_judge) * s0 if inv is not None else np.full(k, np.inf)
    return _TransformFit(theta=theta.copy(), keep=keep, r=r, sigma=sig, sigma_geom=sig_geom, iterations=it,
                         nuisance_constrained=int(n_constrained), centre=c, enu=E, lever=L)


def _between_profile_directions(N_plain: NDArray[np.float64], N_within: NDArray[np.float64],
                                min_share: float) -> NDArray[np.float64]:
    """Parameter directions the shots determine mostly *between* profiles, as columns (k, m).

    ``N_plain`` is the transform's normal matrix with the shots independent, ``N_within`` the same after
    the profile nuisance is eliminated (what the pattern within each profile still tells). The
    generalised eigenvalues ``μ`` of ``N_within v = μ N_plain v`` lie in [0, 1]: the share of a direction's
    information that survives the nuisance. A direction with ``μ < min_share`` (the translation, ``μ ≈ 0``;
    with near-parallel profiles also the rotation about their direction and the scale across them) is
    one a set of per-profile offsets can mimic; those are returned, to be kept out of the nuisance.
    Written out (a 12 × 12 eigenproblem; scipy.linalg.eigh(a, b) would do the same) so a singular
    ``N_plain`` is handled by the caller's own test.
    """
    k = N_plain.shape[0]
    dg = np.sqrt(np.maximum(np.diag(N_plain), 0.0))
    if k == 0 or np.any(dg <= 0) or min_share <= 0:
        return np.zeros((k, 0))
    Ns = N_plain / np.outer(dg, dg)
    try:
        Lc = np.linalg.cholesky(Ns)
    except np.linalg.LinAlgError:
        return np.zeros((k, 0))
    Li = np.linalg.inv(Lc)
    M = Li @ (N_within / np.outer(dg, dg)) @ Li.T
    mu, U = np.linalg.eigh((M + M.T) / 2)
    sel = mu < min_share
    return (Li.T @ U[:, sel]) / dg[:, None]


def _judged_sigma(inv_joint: NDArray[np.float64], inv_geom: NDArray[np.float64]) -> NDArray[np.float64]:
    """σ per parameter (unit σ₀) for the fall-back: the joint fit's for the linear parameters, the shots' own
    (without the profile nuisance) for the translation (the model's last min(3, k) parameters).

    The profiles' unknown mean error limits how well the tile's translation is *known* (σ_h/√profiles:
    reported), not whether the shots determine it; the linear parameters must be determined in the joint fit.
    """
    k = inv_joint.shape[0]
    sj = np.sqrt(np.maximum(np.diag(inv_joint), 0.0))
    sg = np.sqrt(np.maximum(np.diag(inv_geom), 0.0))
    return np.where(np.arange(k) >= k - min(3, k), sg, sj)


def _decompose(theta: NDArray[np.float64], L: NDArray[np.float64]) -> dict[str, Any]:
    """T's matrix, translation, rotation, scale and strain from G's parameters."""
    B = theta[:9].reshape(3, 3) / L[None, :]
    M = np.linalg.inv(np.eye(3) + B)
    t = -M @ theta[9:]
    R, S = polar(M)  # M = R S
    scale = float(np.cbrt(np.linalg.det(S)))
    strain = S / scale - np.eye(3)
    rot = np.degrees([(R[2, 1] - R[1, 2]) / 2, (R[0, 2] - R[2, 0]) / 2, (R[1, 0] - R[0, 1]) / 2])
    return {"matrix": tuple(float(v) for v in M.ravel()), "translation_enu_m": tuple(float(v) for v in t),
            "rotation_deg": tuple(float(v) for v in rot), "scale": scale,
            "strain": tuple(float(strain[i, j]) for i, j in ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)))}


def _fit_profiles(
    x: NDArray[np.float64], profile: NDArray[np.int64], keep: NDArray[np.bool_],
    apply: Callable[[NDArray[np.float64]], NDArray[np.float64]], sampler: _Sampler, datum: float, scale0: float,
    opt: RegisterOptions, tile_id: int,
) -> tuple[ProfileOffsets, NDArray[np.float64], NDArray[np.float64]]:
    """One robust 3-D offset per profile; returns the offsets and the shots' residuals before/after."""
    ids, inv_idx = np.unique(profile, return_inverse=True)
    P = ids.size
    lat_s, lon_s, _ = xyz_to_latlon(x, datum)
    # mean position of each profile (of all its shots on the DEM) -> its ENU frame
    cnt = np.bincount(inv_idx, minlength=P).astype(np.float64)
    mean_xyz = np.stack([np.bincount(inv_idx, weights=x[:, k], minlength=P) for k in range(3)], axis=1) / cnt[:, None]
    plat, plon, _ = xyz_to_latlon(mean_xyz, datum)
    Ep = enu_frame(plat, plon)  # (P, 3, 3)
    n_used = np.bincount(inv_idx, weights=keep.astype(np.float64), minlength=P).astype(np.int64)
    fitted = n_used >= opt.min_profile_shots
    d = np.zeros((P, 3))
    cov = np.full((P, 3, 3), np.nan)
    prior = np.diag([1 / opt.profile_sigma_horizontal_m ** 2] * 2 + [1 / opt.profile_sigma_vertical_m ** 2])
    r_before, _ = _residuals(apply(x), sampler, datum)
    r = r_before
    k_shot = keep & fitted[inv_idx]
    for _ in range(8):
        y_off = x + np.einsum("nij,nj->ni", Ep[inv_idx], d[inv_idx])
        r, g = _residuals(apply(y_off), sampler, datum)
        ok = k_shot & np.isfinite(r)
        w = np.where(ok, _huber_weights(np.where(ok, r, 0.0), scale0, opt.huber_k), 0.0)
        # d(residual)/d(offset): g^T dG/dx Ep  ~  g^T Ep (G's linear part is I + O(1e-4))
        j = np.einsum("ni,nij->nj", np.where(ok[:, None], g, 0.0), Ep[inv_idx])
        rz = np.where(ok, r, 0.0)
        N = np.zeros((P, 3, 3))
        b = np.zeros((P, 3))
        for a in range(3):
            b[:, a] = np.bincount(inv_idx, weights=w * j[:, a] * rz, minlength=P)
            for bb in range(a, 3):
                N[:, a, bb] = N[:, bb, a] = np.bincount(inv_idx, weights=w * j[:, a] * j[:, bb], minlength=P)
        # the prior pulls the *total* offset to zero, in units of the residual scale
        A = N + (scale0 ** 2) * prior
        rhs = -(b + (scale0 ** 2) * (prior @ d.T).T)
        sel = np.flatnonzero(fitted)
        if sel.size == 0:
            break
        step = np.linalg.solve(A[sel], rhs[sel][:, :, None])[:, :, 0]
        d[sel] += step
        cov[sel] = np.linalg.inv(A[sel]) * scale0 ** 2
        if np.max(np.abs(step)) < opt.tolerance_m:
            break
    y_off = x + np.einsum("nij,nj->ni", Ep[inv_idx], d[inv_idx])
    r_after, _ = _residuals(apply(y_off), sampler, datum)

    def seg_rms(res: NDArray[np.float64]) -> NDArray[np.float64]:
        ok = keep & np.isfinite(res)
        s = np.bincount(inv_idx, weights=np.where(ok, res * res, 0.0), minlength=P)
        n = np.bincount(inv_idx, weights=ok.astype(np.float64), minlength=P)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.sqrt(s / n)

    sig = np.sqrt(np.abs(np.diagonal(cov, axis1=1, axis2=2)))
    offsets = ProfileOffsets(
        profile_id=ids.astype(np.int64), tile_id=np.full(P, tile_id, dtype=np.int64), offset_enu_m=d,
        sigma_enu_m=np.where(fitted[:, None], sig, np.nan), centre_lat=plat, centre_lon=plon,
        n_shots=cnt.astype(np.int64), n_used=n_used, rms_before_m=seg_rms(r_before), rms_after_m=seg_rms(r_after),
        fitted=fitted,
    )
    return offsets, r_before, r_after


def register_tile(
    window: DemWindow,
    lat: ArrayLike,
    lon: ArrayLike,
    radius_m: ArrayLike,
    profile_id: ArrayLike,
    *,
    tile_id: int,
    centre: tuple[float, float],
    half_width_m: float | None = None,
    options: RegisterOptions | None = None,
) -> TileRegistration:
    """Register one tile of an image DEM onto its altimetry shots, then fit per-profile offsets.

    Parameters
    ----------
    window : DemWindow
        The image DEM around the tile (see :func:`tile_window`).
    lat, lon : array_like of shape (N,)
        The tile's shots: planetocentric latitude, east longitude, degrees.
    radius_m : array_like of shape (N,)
        Their radii from the centre of mass, metres.
    profile_id : array_like of shape (N,)
        Profile (ground track) id of each shot.
    tile_id : int
    centre : (lat, lon)
        Tile centre, degrees: the origin of the transform's ENU frame.
    half_width_m : float, optional
        ``L``, the lever arm of the linear parameters (default: half the tile's extent of
        the shots' spread, at least 10 km).
    options : RegisterOptions, optional

    Returns
    -------
    TileRegistration
        Never raises for bad shots: non-finite shots, shots off the DEM and too few shots
        are counted; an undetermined tile is ``ok = False`` with the reason.
    """
    opt = options or RegisterOptions()
    datum = float(window.datum_radius_m)
    lat = np.asarray(lat, dtype=np.float64).ravel()
    lon = np.asarray(lon, dtype=np.float64).ravel()
    rad = np.asarray(radius_m, dtype=np.float64).ravel()
    profile = np.asarray(profile_id).ravel()
    if not (lat.shape == lon.shape == rad.shape == profile.shape):
        raise ValueError(f"shot arrays differ in length: {lat.size}, {lon.size}, {rad.size}, {profile.size}")
    counts = {"shots": int(lat.size)}
    with np.errstate(invalid="ignore"):
        finite = (np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90.0)
                  & (np.abs(rad - datum) <= opt.max_abs_height_m))  # NaN/inf radii fail this too
    counts["invalid"] = int((~finite).sum())
    lat, lon, rad, profile = lat[finite], lon[finite], rad[finite], profile[finite].astype(np.int64)
    sampler = _Sampler(window)
    on = np.isfinite(sampler(lat, lon)[0])
    counts["off_dem"] = int((~on).sum())
    lat, lon, rad, profile = lat[on], lon[on], rad[on], profile[on]
    base = TileTransform(int(tile_id), float(centre[0]), float(centre[1]), datum)
    n = lat.size
    counts.update(used=0, rejected=0, not_registered=0, profiles=int(np.unique(profile).size), profiles_fitted=0,
                  profiles_too_few_shots=0)
    if n < opt.min_shots:
        counts["not_registered"] = n
        tt = TileTransform(**{**base.__dict__, "reason": f"{n} usable shots, fewer than min_shots = {opt.min_shots}"})
        return TileRegistration(tt, ProfileOffsets.empty(), counts)
    x = latlon_to_unit(lat, lon) * rad[:, None]
    E = enu_frame(*centre)
    c = datum * E[:, 2]
    q = (x - c) @ E
    # lever: each linear parameter B_ij is estimated as L·B_ij, the displacement it would cause a
    # lever L away (the farthest shot from the centre). One lever for all columns: B_iu (a shift
    # proportional to height) acts over only the ~km of relief, so on most tiles it is weakly
    # determined and the affine falls back -- as it should, its rotation would be noise.
    lh = float(half_width_m) if half_width_m else max(10_000.0, float(np.max(np.hypot(q[:, 0], q[:, 1]))))
    L = np.array([lh, lh, lh])
    notes = []
    fit = None
    for model in opt.models:
        f = _fit_transform(x, q, E, c, sampler, datum, model, L, opt, np.unique(profile, return_inverse=True)[1])
        if isinstance(f, _FitFailure):
            notes.append(f.reason)
            continue
        worst = float(np.max(f.sigma_geom))
        if worst > opt.max_param_sigma_m:
            notes.append(f"{model}: a parameter's sigma {worst:.3g} m > max_param_sigma_m")
            continue
        fit = (model, f)
        break
    r0, _ = _residuals(x, sampler, datum)
    if fit is None:
        counts["not_registered"] = n
        tt = TileTransform(**{**base.__dict__, "reason": "; ".join(notes)})
        return TileRegistration(tt, ProfileOffsets.empty(), counts, rms_before_m=_rms(r0))
    model, f = fit
    keep = f.keep
    counts["used"] = int(keep.sum())
    counts["rejected"] = int(n - keep.sum())
    dec = _decompose(f.theta, L)
    tt = TileTransform(**{**base.__dict__, **dec, "model": model, "ok": True,
                          "sigma_m": tuple(float(s) for s in f.sigma), "reason": "; ".join(notes)})
    scale0 = max(_nmad(f.r[keep]), 1e-3)
    profiles, r_reg, r_after = _fit_profiles(x, profile, keep, f.apply, sampler, datum, scale0, opt, int(tile_id))
    counts["profiles_fitted"] = int(profiles.fitted.sum())
    counts["profiles_too_few_shots"] = int((~profiles.fitted).sum())
    return TileRegistration(tt, profiles, counts, rms_before_m=_rms(r0[keep]), rms_registered_m=_rms(r_reg[keep]),
                            rms_after_m=_rms(r_after[keep]), iterations=int(f.iterations))
