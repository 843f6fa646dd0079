"""Laser altimetry as the geodetic frame of a DEM (MLA for Mercury, LOLA for the Moon).

* ``store`` — altimetry shots kept columnar with a mission or a run (Parquet), read per tile;
* ``simulate`` — synthetic MLA-like altimetry from a synthetic mission's truth;
* ``register`` — seed 004's two steps: a 3-D affine per tile, then one offset per profile;
* ``merge`` — altimetry gridded where dense, the registered image DEM elsewhere, blended.

Readers of the PDS shot tables are in :mod:`mercury_dem.reference.lola`. Everything here
except the store is a pure function of arrays.
"""
