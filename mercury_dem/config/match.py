"""Configuration of feature matching."""

from __future__ import annotations

from dataclasses import dataclass

from mercury_dem.config.base import ConfigSection, param


@dataclass(frozen=True)
class MatchConfig(ConfigSection):
    detector: str = param("FAST", "OpenCV feature detector", choices=("FAST", "SIFT", "ORB", "AKAZE", "BRISK"))
    descriptor: str = param("SIFT", "OpenCV descriptor extractor", choices=("SIFT", "ORB", "AKAZE", "BRISK"))
    fast_threshold: int = param(20, "FAST intensity threshold (8-bit scale)", lo=1, hi=255)
    ratio: float = param(0.8, "Lowe ratio test threshold, both directions", lo=0.1, hi=1.0)
    max_matches: int = param(400, "Most matches kept per image pair", lo=1, hi=100000)
