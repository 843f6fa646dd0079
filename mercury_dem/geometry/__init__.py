"""Planetary geometry: body, framing camera, poses, footprints, tiling (pure numpy)."""
