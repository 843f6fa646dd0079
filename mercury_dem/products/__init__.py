"""DEM products: GeoTIFF/COG, PDS-style equirectangular and polar tiles, browse PNGs, statistics."""
