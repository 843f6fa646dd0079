"""Dense stereo: stereo-pair selection, chip rectification, dense matching and triangulation.

Pure numerical functions (docs/design/dense.md); the dense stage runner that reads the run store and
cuts chips per tile is not wired yet.
"""
