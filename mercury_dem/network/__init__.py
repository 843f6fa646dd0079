"""Control networks: columnar model, building from matches, merging, validation, storage, ISIS files.

Public API (pure functions on arrays; only :mod:`.store` and :mod:`.isis` touch files)::

    ControlNetwork, PointType, MeasureType            model.py
    PairMatches, build_network, triangulate_points    build.py
    merge_networks                                    merge.py
    validate, NetworkReport                           check.py   (structural checks; truth is validate/)
    write_network, read_network, open_network         store.py   (Zarr v3 group)
    read_isis_network, write_isis_network             isis.py    (ISIS3 .net v2/v5)
"""

from mercury_dem.network.build import BuildResult, BuildStats, PairMatches, build_network, triangulate_points
from mercury_dem.network.check import NetworkReport, validate
from mercury_dem.network.isis import read_isis_network, write_isis_network
from mercury_dem.network.merge import MergeResult, MergeStats, merge_networks
from mercury_dem.network.model import ControlNetwork, MeasureType, PointType
from mercury_dem.network.store import NetworkStore, open_network, read_network, write_network

__all__ = [
    "BuildResult", "BuildStats", "ControlNetwork", "MeasureType", "MergeResult", "MergeStats", "NetworkReport",
    "NetworkStore", "PairMatches", "PointType", "build_network", "merge_networks", "open_network",
    "read_isis_network", "read_network", "triangulate_points", "validate", "write_isis_network", "write_network",
]
