"""ISIS3 binary control network files (``.net``, versions 2 and 5): read, write, peek at the label.

The files are opened and written here and only here; the codec (bytes in, network out and back) is
:mod:`mercury_dem.network.isis`, where the conventions (1-based pixels, serial numbers, old point types)
are converted.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.exceptions import NetworkError
from mercury_dem.io.atomic import atomic_write_bytes
from mercury_dem.network.isis import HEADER_START_BYTE, decode_isis_network, encode_isis_network, label_fields
from mercury_dem.network.model import ControlNetwork


def read_isis_network(
    path: str | Path,
    serial_to_image: Mapping[str, str] | None = None,
    image_ids: Sequence[str] | NDArray[np.str_] | None = None,
    drop_unknown: bool = False,
    int_point_ids: bool = True,
) -> ControlNetwork:
    """Read an ISIS3 binary control network (version 2 or 5).

    Parameters
    ----------
    path : the ``.net`` file
    serial_to_image, image_ids, drop_unknown, int_point_ids : as
        :func:`mercury_dem.network.isis.decode_isis_network`, which decodes the bytes read here.

    Returns
    -------
    ControlNetwork (see :func:`~mercury_dem.network.isis.decode_isis_network`).

    Raises
    ------
    NetworkError naming the file: unreadable, not a control network, truncated (with
    the byte offset where the data stop or the message that overruns), corrupt
    messages, serial numbers that match no catalog image
    (:func:`~mercury_dem.network.isis.decode_isis_network`).
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise NetworkError(f"cannot read control network {path}: {exc}") from exc
    return decode_isis_network(data, path, serial_to_image=serial_to_image, image_ids=image_ids,
                               drop_unknown=drop_unknown, int_point_ids=int_point_ids)


def write_isis_network(
    network: ControlNetwork,
    path: str | Path,
    version: int = 5,
    image_to_serial: Mapping[str, str] | None = None,
    **header: str,
) -> Path:
    """Write ``network`` as an ISIS3 binary control network, atomically.

    Parameters
    ----------
    network : the network (0-based pixels; written 1-based)
    path : output ``.net`` file
    version : 2 or 5
    image_to_serial : optional mapping our image id -> ISIS serial number
        (image ids not in it are written as they are)
    **header : network_id, target_name, description, user_name, created,
        last_modified (defaults: the network's metadata, then "mercury_dem",
        "Mercury", now). Point ids are written as text (int ids as decimals).

    Returns the path.
    """
    return atomic_write_bytes(path, encode_isis_network(network, version, image_to_serial, **header))


def isis_network_info(path: str | Path) -> dict[str, Any]:
    """The label and header fields of a ``.net`` file, without decoding the points."""
    path = Path(path)
    with open(path, "rb") as fh:
        data = fh.read(HEADER_START_BYTE + (1 << 20))
    return label_fields(path, data)


__all__ = ["isis_network_info", "read_isis_network", "write_isis_network"]
