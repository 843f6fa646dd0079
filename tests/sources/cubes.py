"""Paths of the real test cubes and a writer of tiny synthetic cubes (any type, order, format)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

REAL = Path(__file__).resolve().parents[1] / "data" / "real"
SHARED_DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"

MDIS_SPICE = REAL / "EN1072174528M_raw_dn_with_spice.cub"
MDIS_LEV1 = REAL / "EN0240208184M.lev1.cub"
APOLLO_0297 = REAL / "AS15-M-0297_crop.cub"
APOLLO_0298 = REAL / "AS15-M-0298_crop.cub"

_DTYPE = {"Real": "f4", "SignedWord": "i2", "UnsignedWord": "u2", "UnsignedByte": "u1"}


def shared(relative: str) -> Path:
    """A file of ../shared/data, or skip the test when that folder is absent (a fresh clone)."""
    p = SHARED_DATA / relative
    if not p.exists():
        pytest.skip(f"{p} is absent: it lives in the project's shared data folder, not in the repository")
    return p


def write_cube(path: Path, stored: np.ndarray, pixel_type: str = "Real", byte_order: str = "Lsb",
               fmt: str = "Tile", tile: tuple[int, int] = (3, 2), base: float = 0.0,
               multiplier: float = 1.0, start_byte: int = 2049, extra: str = "") -> Path:
    """Write ``stored`` (bands, lines, samples), already in the file's type, as an ISIS3 cube."""
    bands, lines, samples = stored.shape
    ts, tl = tile if fmt == "Tile" else (samples, lines)
    tiles = f"    TileSamples = {ts}\n    TileLines   = {tl}\n" if fmt == "Tile" else ""
    label = (f"Object = IsisCube\n  Object = Core\n    StartByte   = {start_byte}\n    Format      = {fmt}\n"
             f"{tiles}\n    Group = Dimensions\n      Samples = {samples}\n      Lines   = {lines}\n"
             f"      Bands   = {bands}\n    End_Group\n\n    Group = Pixels\n      Type       = {pixel_type}\n"
             f"      ByteOrder  = {byte_order}\n      Base       = {base}\n      Multiplier = {multiplier}\n"
             f"    End_Group\n  End_Object\n{extra}End_Object\n\nObject = Label\n  Bytes = {start_byte - 1}\n"
             "End_Object\nEnd\n").encode()
    assert len(label) < start_byte - 1
    dtype = np.dtype(("<" if byte_order == "Lsb" else ">") + _DTYPE[pixel_type])
    nts, ntl = -(-samples // ts), -(-lines // tl)
    padded = np.zeros((bands, ntl * tl, nts * ts), dtype)
    padded[:, :lines, :samples] = stored
    core = padded.reshape(bands, ntl, tl, nts, ts).transpose(0, 1, 3, 2, 4).tobytes()
    path.write_bytes(label + b"\0" * (start_byte - 1 - len(label)) + core)
    return path
