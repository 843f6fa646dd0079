"""Dense stereo: stereo-pair selection, chip rectification, dense matching and triangulation.

Pure numerical functions (docs/design/dense.md); the dense stage's runners (``pipeline/dense_*.py``) read
the run store, cut chips per tile and call them. Failed pairs and chips are recorded by kind
(:mod:`mercury_dem.dense.failures`).
"""
