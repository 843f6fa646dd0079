"""Gridding a point cloud into a DEM (pure, per chunk), smoothing, coverage and accuracy."""
