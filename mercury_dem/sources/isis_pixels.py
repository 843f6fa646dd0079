"""Pixels of an ISIS3 cube: one band as float32 with ISIS's special pixels masked.

Layout facts used (ISIS3 ``Cube/CubeTileHandler.cpp``, ``Cube/CubeIoHandler.cpp``,
``SpecialPixel/SpecialPixel.h``; the label side is in :mod:`mercury_dem.sources.isis_cube`):

* ``Tile``: the band is cut into TileSamples x TileLines tiles stored whole, sample-tile
  fastest, then line-tile, then band; tiles at the right and bottom edges are padded to
  full size (so a band occupies ceil(S/ts) * ceil(L/tl) * ts * tl pixels).
  ``BandSequential`` is the same with one tile per band (ts = S, tl = L).
* Physical value = Base + Multiplier * stored value for the integer types; ``Real`` pixels
  are used as stored (ISIS ignores Base/Multiplier for them).
* Special pixels (ISIS Null, Lrs, Lis, His, Hrs): Real bit patterns 0xFF7FFFFB..0xFF7FFFFF
  and anything below VALID_MIN4 = 0xFF7FFFFA (ISIS calls the unknown ones, NaN and -inf
  Lrs); SignedWord -32768..-32764 (below -32752 is special); UnsignedWord 0, 1, 2,
  65534, 65535 (3..65522 valid, the rest Lrs); UnsignedByte 0 (Null) and 255 (Hrs).

Arrays are (lines, samples); our pixel (0, 0) is ISIS pixel (1, 1). Checked against GDAL's
ISIS3 driver on real and synthetic cubes of every type, byte order and format (tests/sources).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.exceptions import CubeError
from mercury_dem.sources.isis_cube import IsisCube, read_cube_bytes

#: The ISIS special-pixel kinds in the order of their codes.
SPECIAL_KINDS = ("Null", "Lrs", "Lis", "His", "Hrs")
_DTYPE_CHAR = {"Real": "f4", "SignedWord": "i2", "UnsignedWord": "u2", "UnsignedByte": "u1"}


def _stored_band(cube: IsisCube, band: int) -> NDArray[Any]:
    """The stored values of one band, (lines, samples), in the file's type and byte order."""
    if isinstance(band, bool) or not isinstance(band, (int, np.integer)) or not 1 <= band <= cube.bands:
        raise CubeError(f"ISIS cube {cube.path}: band {band!r} does not exist (it has bands 1..{cube.bands}); "
                        "ask for one of those")
    offset = cube.core_start_byte - 1 + (int(band) - 1) * cube.band_bytes
    data = read_cube_bytes(cube, offset, cube.band_bytes)
    dtype = np.dtype(("<" if cube.byte_order == "Lsb" else ">") + _DTYPE_CHAR[cube.pixel_type])
    ts, tl = cube.tile_samples, cube.tile_lines
    nts, ntl = -(-cube.samples // ts), -(-cube.lines // tl)
    tiles = np.frombuffer(data, dtype=dtype).reshape(ntl, nts, tl, ts)
    return tiles.transpose(0, 2, 1, 3).reshape(ntl * tl, nts * ts)[: cube.lines, : cube.samples]


def _special_codes(cube: IsisCube, stored: NDArray[Any]) -> NDArray[np.int8]:
    """0 for a valid pixel, 1..5 for Null, Lrs, Lis, His, Hrs (ISIS's classification)."""
    code = np.zeros(stored.shape, np.int8)
    t = cube.pixel_type
    if t == "Real":
        bits = stored.astype(stored.dtype.newbyteorder("="), copy=False).view(np.uint32)
        valid = stored >= np.float32(np.frombuffer(np.uint32(0xFF7FFFFA).tobytes(), np.float32)[0])
        code[~valid] = 2  # ISIS: any other value below VALID_MIN4 (NaN, -inf) is Lrs
        for k, pattern in enumerate((0xFF7FFFFB, 0xFF7FFFFC, 0xFF7FFFFD, 0xFF7FFFFE, 0xFF7FFFFF), start=1):
            code[bits == pattern] = k
        code[np.isposinf(stored)] = 5  # a float32 image cannot carry +inf as a value
    elif t == "SignedWord":
        v = stored.astype(np.int32)
        code[v < -32752] = 2
        for k in range(1, 6):
            code[v == -32769 + k] = k
    elif t == "UnsignedWord":
        v = stored.astype(np.int32)
        code[(v < 3) | (v > 65522)] = 2
        code[v == 0], code[v == 2], code[v == 65534], code[v == 65535] = 1, 3, 4, 5
    else:
        code[stored == 0], code[stored == 255] = 1, 5
    return code


def read_pixels(cube: IsisCube, band: int = 1) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """One band's pixel values, special pixels masked.

    Parameters
    ----------
    cube : from :func:`open_cube`
    band : 1-based band number (ISIS's numbering, as in the label)

    Returns
    -------
    image : ndarray of shape (lines, samples), float32; Base + Multiplier * stored for
        integer types, NaN at special pixels. ``image[0, 0]`` is ISIS pixel (1, 1).
    valid : ndarray of shape (lines, samples), bool; False at ISIS special pixels
        (Null, Lrs, Lis, His, Hrs; see :func:`special_pixel_counts`)
    """
    stored = _stored_band(cube, band)
    valid = _special_codes(cube, stored) == 0
    if cube.pixel_type == "Real":
        image = stored.astype(np.float32)
    else:
        image = (cube.base + cube.multiplier * stored.astype(np.float64)).astype(np.float32)
    image[~valid] = np.nan
    return image, valid


def special_pixel_counts(cube: IsisCube, band: int = 1) -> dict[str, int]:
    """How many pixels of a band are of each ISIS special kind (``Null``, ``Lrs``, ``Lis``, ``His``, ``Hrs``)."""
    counts = np.bincount(_special_codes(cube, _stored_band(cube, band)).ravel(), minlength=6)
    return {kind: int(counts[k]) for k, kind in enumerate(SPECIAL_KINDS, start=1)}
