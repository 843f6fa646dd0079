"""Control networks: columnar model, building from matches, merging, validation, the ISIS codec (pure).

Public API (pure functions on arrays; the files are :mod:`mercury_dem.io`'s: ``io.network_store``
``write_network``/``read_network``/``open_network`` (Zarr v3 group), ``io.isis_net``
``read_isis_network``/``write_isis_network`` (ISIS3 .net v2/v5), ``io.network_files`` (by file kind))::

    ControlNetwork, PointType, MeasureType            model.py
    PairMatches, build_network, triangulate_points    build.py
    merge_networks                                    merge.py
    validate, NetworkReport                           check.py   (structural checks; truth is validate/)
    decode_isis_network, encode_isis_network          isis.py    (ISIS3 .net v2/v5, bytes in and out)
"""

from mercury_dem.network.build import BuildResult, BuildStats, PairMatches, build_network, triangulate_points
from mercury_dem.network.check import NetworkReport, validate
from mercury_dem.network.isis import decode_isis_network, encode_isis_network
from mercury_dem.network.merge import MergeResult, MergeStats, merge_networks
from mercury_dem.network.model import ControlNetwork, MeasureType, PointType

__all__ = [
    "BuildResult", "BuildStats", "ControlNetwork", "MeasureType", "MergeResult", "MergeStats", "NetworkReport",
    "PairMatches", "PointType", "build_network", "decode_isis_network", "encode_isis_network", "merge_networks",
    "triangulate_points", "validate",
]
