"""The tile grid, the 14 regions and the two hemispheres of the merge cascade.

Tiles are squares of ``tile_size_deg`` in latitude and longitude, numbered row
by row from the south pole: ``tile_id = row * n_cols + col`` with row 0 the band
[-90, -90 + size) and col 0 the band [0, size) east longitude. An image belongs to
the tile that holds its centre latitude/longitude (Becker et al. 2016).

The reference text counts 720 tiles of 10 deg x 10 deg; a 10 deg grid over the
sphere has 36 x 18 = 648 tiles. The grid here is built honestly from its size.

Regions (14): in each hemisphere one polar cap (|lat| >= 60 deg) and six
60-deg-of-longitude sectors of the 0-60 deg band. Region ids: 0 north cap,
1-6 north sectors (lon 0-60, 60-120, ...), 7 south cap, 8-13 south sectors.
Hemisphere 0 is north (regions 0-6), 1 is south (regions 7-13). Every region is
a whole number of tiles, which is why the tile size must divide 60.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mercury_dem.exceptions import ConfigError
from mercury_dem.geometry.body import wrap_longitude

#: Tile sizes (degrees) that divide 60, so regions are whole tiles.
ALLOWED_TILE_SIZES: tuple[float, ...] = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 10.0, 12.0, 15.0, 20.0, 30.0, 60.0)
N_REGIONS = 14
POLAR_CAP_LAT = 60.0
SECTOR_WIDTH_DEG = 60.0
HEMISPHERE_NAMES = ("north", "south")


def region_name(region_id: int) -> str:
    """Human name of a region, e.g. ``N-cap``, ``N-060-120``, ``S-cap``."""
    if not 0 <= region_id < N_REGIONS:
        raise ConfigError(f"region id {region_id} out of range 0..{N_REGIONS - 1}")
    hemi = "N" if region_id < 7 else "S"
    k = region_id % 7
    if k == 0:
        return f"{hemi}-cap"
    lon0 = (k - 1) * 60
    return f"{hemi}-{lon0:03d}-{lon0 + 60:03d}"


@dataclass(frozen=True)
class TileGrid:
    """A global lat/lon tile grid of square tiles."""

    tile_size_deg: float = 10.0

    def __post_init__(self) -> None:
        if float(self.tile_size_deg) not in ALLOWED_TILE_SIZES:
            raise ConfigError(
                f"config key 'tiling.tile_size_deg' = {self.tile_size_deg!r}: the tile size must divide 60 "
                f"so that regions are whole tiles; one of {', '.join(str(s) for s in ALLOWED_TILE_SIZES)}"
            )

    @property
    def n_rows(self) -> int:
        return int(round(180.0 / self.tile_size_deg))

    @property
    def n_cols(self) -> int:
        return int(round(360.0 / self.tile_size_deg))

    @property
    def n_tiles(self) -> int:
        return self.n_rows * self.n_cols

    # -- tiles ---------------------------------------------------------------
    def tile_of(self, lat_deg: ArrayLike, lon_deg: ArrayLike) -> NDArray[np.int64]:
        """Tile id of points (image centres), any shape. Latitude +90 goes in the top row."""
        lat = np.asarray(lat_deg, dtype=np.float64)
        lon = wrap_longitude(lon_deg)
        if np.any(~np.isfinite(lat)) or np.any(np.abs(lat) > 90.0):
            raise ConfigError("tile_of: latitudes must be finite and within [-90, 90]")
        row = np.clip(np.floor((lat + 90.0) / self.tile_size_deg).astype(np.int64), 0, self.n_rows - 1)
        col = np.floor(lon / self.tile_size_deg).astype(np.int64) % self.n_cols
        return row * self.n_cols + col

    def _check(self, tile_id: ArrayLike) -> NDArray[np.int64]:
        t = np.asarray(tile_id, dtype=np.int64)
        if np.any((t < 0) | (t >= self.n_tiles)):
            raise ConfigError(f"tile id out of range 0..{self.n_tiles - 1}: {np.asarray(tile_id)}")
        return t

    def bounds(self, tile_id: ArrayLike) -> tuple[NDArray[np.float64], ...]:
        """(lat_min, lat_max, lon_min, lon_max) of tiles, degrees."""
        t = self._check(tile_id)
        row, col = t // self.n_cols, t % self.n_cols
        s = self.tile_size_deg
        lat0: NDArray[np.float64] = -90.0 + row.astype(np.float64) * s
        lon0: NDArray[np.float64] = col.astype(np.float64) * s
        return lat0, lat0 + s, lon0, lon0 + s

    def centre(self, tile_id: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        lat0, lat1, lon0, lon1 = self.bounds(tile_id)
        return (lat0 + lat1) / 2.0, (lon0 + lon1) / 2.0

    # -- regions and hemispheres --------------------------------------------
    def region_of_tile(self, tile_id: ArrayLike) -> NDArray[np.int64]:
        """Region id (0..13) of tiles; see the module docstring for the numbering."""
        lat_c, lon_c = self.centre(tile_id)
        north = lat_c >= 0.0
        cap = np.abs(lat_c) >= POLAR_CAP_LAT
        sector = np.floor(lon_c / SECTOR_WIDTH_DEG).astype(np.int64) + 1
        k = np.where(cap, 0, sector)
        return np.where(north, k, 7 + k).astype(np.int64)

    @staticmethod
    def hemisphere_of_region(region_id: ArrayLike) -> NDArray[np.int64]:
        """0 for the north regions (0-6), 1 for the south (7-13)."""
        r = np.asarray(region_id, dtype=np.int64)
        if np.any((r < 0) | (r >= N_REGIONS)):
            raise ConfigError(f"region id out of range 0..{N_REGIONS - 1}")
        return (r >= 7).astype(np.int64)

    def tiles_of_region(self, region_id: int) -> NDArray[np.int64]:
        all_tiles = np.arange(self.n_tiles)
        out: NDArray[np.int64] = all_tiles[self.region_of_tile(all_tiles) == region_id]
        return out

    @staticmethod
    def regions_of_hemisphere(hemisphere: int) -> NDArray[np.int64]:
        if hemisphere not in (0, 1):
            raise ConfigError(f"hemisphere must be 0 (north) or 1 (south), got {hemisphere}")
        return np.arange(7) + 7 * hemisphere

    def summary(self) -> dict[str, object]:
        """Counts of the grid: tiles, tiles per region and per hemisphere."""
        all_tiles = np.arange(self.n_tiles)
        reg = self.region_of_tile(all_tiles)
        per_region = {region_name(r): int(np.sum(reg == r)) for r in range(N_REGIONS)}
        hem = self.hemisphere_of_region(reg)
        return {
            "tile_size_deg": self.tile_size_deg,
            "rows": self.n_rows,
            "cols": self.n_cols,
            "tiles": self.n_tiles,
            "regions": per_region,
            "hemispheres": {HEMISPHERE_NAMES[h]: int(np.sum(hem == h)) for h in (0, 1)},
        }
