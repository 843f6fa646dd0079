"""mercury_dem: a global digital elevation model of a planet from orbital images.

Follows the USGS method of the first global DEM of Mercury (Becker et al., 2016):
tile-parallel feature matching, hierarchical bundle adjustment and gridding of
the adjusted control-point cloud, orchestrated on Dask.
"""

__version__ = "0.1.0"
