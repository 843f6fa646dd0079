"""Procedural 3-D gradient noise on the sphere, compiled with numba.

The fractal roughness and the albedo mottling of the synthetic Mercury are sums
of octaves of gradient ("Perlin") noise evaluated at the body-fixed position of
a point scaled by the octave's wavelength, so the field is defined everywhere,
at any resolution, without a global array, and is seamless across the 0/360
meridian and at the poles (it lives in 3-D, not in lat/lon).

Written here rather than taken from a library: the noise packages on PyPI
(``noise``, ``opensimplex``) are either unmaintained C extensions or pure-Python
per-point loops, and we need a seeded, vectorised, bit-reproducible kernel that
numba can inline into the terrain loop.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

_M1 = np.uint64(0x9E3779B97F4A7C15)
_M2 = np.uint64(0xBF58476D1CE4E5B9)
_M3 = np.uint64(0x94D049BB133111EB)


@numba.njit(cache=True, inline="always")
def _mix(h: np.uint64) -> np.uint64:
    """SplitMix64 finaliser: a well-mixed 64-bit hash of ``h``."""
    h = (h ^ (h >> np.uint64(30))) * _M2
    h = (h ^ (h >> np.uint64(27))) * _M3
    return h ^ (h >> np.uint64(31))


@numba.njit(cache=True, inline="always")
def _corner_grad(ix: np.int64, iy: np.int64, iz: np.int64, seed: np.uint64, dx: float, dy: float, dz: float) -> float:
    """Dot product of the pseudo-random gradient of a lattice corner with the offset to it."""
    h = _mix(
        seed
        ^ (np.uint64(ix & 0x1FFFFF) * _M1)
        ^ (np.uint64(iy & 0x1FFFFF) * _M2)
        ^ (np.uint64(iz & 0x1FFFFF) * _M3)
    )
    # Signed 64-bit before converting to float: uint64 -> float is slow on x86-64.
    gx = np.int64(h & np.uint64(0xFFFF)) * (1.0 / 32767.5) - 1.0
    gy = np.int64((h >> np.uint64(16)) & np.uint64(0xFFFF)) * (1.0 / 32767.5) - 1.0
    gz = np.int64((h >> np.uint64(32)) & np.uint64(0xFFFF)) * (1.0 / 32767.5) - 1.0
    return gx * dx + gy * dy + gz * dz


@numba.njit(cache=True, inline="always")
def _fade(t: float) -> float:
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


@numba.njit(cache=True)
def gradient_noise3(x: float, y: float, z: float, seed: np.uint64) -> float:
    """Gradient noise at one 3-D point (lattice spacing 1), roughly in [-1, 1], zero mean."""
    fx, fy, fz = np.floor(x), np.floor(y), np.floor(z)
    ix, iy, iz = np.int64(fx), np.int64(fy), np.int64(fz)
    dx, dy, dz = x - fx, y - fy, z - fz
    u, v, w = _fade(dx), _fade(dy), _fade(dz)
    n000 = _corner_grad(ix, iy, iz, seed, dx, dy, dz)
    n100 = _corner_grad(ix + 1, iy, iz, seed, dx - 1.0, dy, dz)
    n010 = _corner_grad(ix, iy + 1, iz, seed, dx, dy - 1.0, dz)
    n110 = _corner_grad(ix + 1, iy + 1, iz, seed, dx - 1.0, dy - 1.0, dz)
    n001 = _corner_grad(ix, iy, iz + 1, seed, dx, dy, dz - 1.0)
    n101 = _corner_grad(ix + 1, iy, iz + 1, seed, dx - 1.0, dy, dz - 1.0)
    n011 = _corner_grad(ix, iy + 1, iz + 1, seed, dx, dy - 1.0, dz - 1.0)
    n111 = _corner_grad(ix + 1, iy + 1, iz + 1, seed, dx - 1.0, dy - 1.0, dz - 1.0)
    x00 = n000 + u * (n100 - n000)
    x10 = n010 + u * (n110 - n010)
    x01 = n001 + u * (n101 - n001)
    x11 = n011 + u * (n111 - n011)
    y0 = x00 + v * (x10 - x00)
    y1 = x01 + v * (x11 - x01)
    return y0 + w * (y1 - y0)


@numba.njit(cache=True)
def fbm_point(
    px: float, py: float, pz: float, wavelengths: NDArray[np.float64], amplitudes: NDArray[np.float64], seed: np.uint64
) -> float:
    """Sum of noise octaves at a body-fixed point (metres): sum_k a_k * noise(p / lambda_k)."""
    total = 0.0
    for k in range(wavelengths.shape[0]):
        inv = 1.0 / wavelengths[k]
        # A different offset per octave keeps lattices of successive octaves from aligning.
        off = 17.31 * (k + 1)
        total += amplitudes[k] * gradient_noise3(px * inv + off, py * inv - off, pz * inv + 0.5 * off, seed + np.uint64(k))
    return total


@numba.njit(cache=True)
def fbm(
    points: NDArray[np.float64], wavelengths: NDArray[np.float64], amplitudes: NDArray[np.float64], seed: np.uint64
) -> NDArray[np.float64]:
    """Fractal noise at many body-fixed points, shape (N, 3) metres -> (N,)."""
    n = points.shape[0]
    out = np.empty(n)
    for i in range(n):
        out[i] = fbm_point(points[i, 0], points[i, 1], points[i, 2], wavelengths, amplitudes, seed)
    return out


def octaves(
    longest_m: float, shortest_m: float, amplitude_longest_m: float, hurst: float, lacunarity: float = 2.0
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Wavelengths and amplitudes of a self-affine (power-law) octave series.

    Amplitude scales as ``(lambda / longest) ** hurst``; wavelengths go from
    ``longest_m`` down to no less than ``shortest_m`` by factors of ``lacunarity``.
    """
    n = max(1, int(np.floor(np.log(longest_m / shortest_m) / np.log(lacunarity))) + 1)
    lam = longest_m / lacunarity ** np.arange(n)
    amp = amplitude_longest_m * (lam / longest_m) ** hurst
    return lam.astype(np.float64), amp.astype(np.float64)
