"""Reading and writing a network by file kind: ISIS ``.net`` or our Zarr store (any other path)."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

from mercury_dem.exceptions import NetworkError
from mercury_dem.io.isis_net import read_isis_network, write_isis_network
from mercury_dem.io.network_store import read_network, write_network
from mercury_dem.network.model import ControlNetwork


def is_isis_path(path: str | Path) -> bool:
    """True for ``.net`` files (ISIS binary control networks)."""
    return Path(path).suffix.lower() == ".net"


def load_serial_map(path: str | Path | None) -> dict[str, str] | None:
    """A serial-number -> image-id mapping from a JSON object file, or from a CSV/text
    file with two columns ``serial,image_id`` (a header line starting 'serial' is skipped).
    """
    if path is None:
        return None
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise NetworkError(f"cannot read serial-number map {p}: {exc}") from exc
    if p.suffix.lower() == ".json":
        data = json.loads(text)
        if not isinstance(data, Mapping):
            raise NetworkError(f"serial-number map {p} must be a JSON object {{serial: image_id}}")
        return {str(k): str(v) for k, v in data.items()}
    out = {}
    for n, row in enumerate(text.splitlines(), 1):
        row = row.strip()
        if not row or row.startswith("#") or (n == 1 and row.lower().startswith("serial")):
            continue
        parts = [s.strip() for s in row.split(",")]
        if len(parts) != 2:
            raise NetworkError(f"serial-number map {p}, line {n}: expected 'serial,image_id', got {row!r}")
        out[parts[0]] = parts[1]
    return out


def read_any_network(path: str | Path, serial_to_image: Mapping[str, str] | None = None) -> ControlNetwork:
    """A ``.net`` file or a network store."""
    if is_isis_path(path):
        return read_isis_network(path, serial_to_image=serial_to_image)
    return read_network(path)


def write_any_network(
    network: ControlNetwork,
    path: str | Path,
    version: int = 5,
    image_to_serial: Mapping[str, str] | None = None,
    overwrite: bool = False,
) -> Path:
    """Write a ``.net`` file (ISIS ``version``) or a network store, atomically."""
    p = Path(path)
    if is_isis_path(p):
        if p.exists() and not overwrite:
            raise NetworkError(f"{p} already exists; remove it or pass --overwrite")
        return write_isis_network(network, p, version=version, image_to_serial=image_to_serial)
    return write_network(network, p, overwrite=overwrite)
