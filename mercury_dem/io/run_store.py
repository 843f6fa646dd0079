"""The run store: one place that owns every path and key of a run.

Layout of ``RUN/``::

    run.json                  mission path, configuration, versions, creation time
    plan/                     tile of every image, overlap pairs (written once, atomically)
    tile/<id>/                one unit per tile: network.zarr, pairs.parquet, summary.json, .complete
    region/<id>/              network.zarr (adjusted), solution.parquet, summary.json, .complete
    hemisphere/<id>/          the same
    global/0/                 the same; the run's result
    dem.zarr, coverage.zarr   the gridded DEM (written by the DEM stage; dem_chunks/: its chunks' markers on a bucket)
    registered.zarr, merged.zarr, registration/
                              the DEM registered to the mission's altimetry, merged with it, and the tables
    products/                 GeoTIFF, polar products, browse PNGs, statistics
    report.json               the stable report contract (see docs/design.md)
    performance.html          Dask's performance report (distributed runs)

A *unit* (a tile, region, hemisphere or the globe) is written into a temporary
directory and renamed into place with a completion marker (see
:mod:`mercury_dem.io.atomic`), so a unit directory either is complete or does not
exist; re-running a run skips complete units.

``RUN`` may be an object-store URL (``s3://bucket/run``, ``gs://...``; see
:mod:`mercury_dem.io.location`). Then :attr:`RunStore.root` is a local cache of
the run and the bucket holds the run: units are built in the cache as above and
committed to the bucket with their completion marker last; readers fetch what
they read (:meth:`RunStore.network_path` and the other unit readers fetch the
unit when the cached copy is not the bucket's current commit). The protocol is
in :mod:`mercury_dem.io.remote`. A local ``RUN`` behaves exactly as before.
"""

from __future__ import annotations

import functools
import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mercury_dem.exceptions import CorruptUnitError, StoreError
from mercury_dem.io.atomic import (
    atomic_directory,
    atomic_write_bytes,
    atomic_write_json,
    is_complete,
    tmp_sibling,
    verify_complete,
)
from mercury_dem.io.location import resolve_location
from mercury_dem.io.remote import RemoteDir, cache_dir_for
from mercury_dem.io.tables import read_table
from mercury_dem.plan.tree import LEVELS

if TYPE_CHECKING:  # imported where tables are read or written: 'report' and 'verify' need neither
    from collections.abc import Callable, Mapping

    import numpy as np
    import pandas as pd

#: File names inside a unit directory (``RUN/<level>/<id>/``) and the plan (``RUN/plan/``).
NETWORK_FILE = "network.zarr"
PAIRS_FILE = "pairs.parquet"
SOLUTION_FILE = "solution.parquet"
BUNDLEOUT_FILE = "bundleout.txt"
SUMMARY_FILE = "summary.json"
PLAN_INFO_FILE = "plan.json"
PLAN_IMAGES_FILE = "images.parquet"
PLAN_PAIRS_FILE = "overlaps.parquet"
#: Run-level files and directories of ``RUN/`` (the paths: :class:`RunStore`'s properties).
RUN_FILE = "run.json"
REPORT_FILE = "report.json"
PERFORMANCE_FILE = "performance.html"
PLAN_DIR = "plan"
PRODUCTS_DIR = "products"
#: The DEM stage's stores: the DEM (also the name ``mercury-dem grid`` writes in its output directory), its
#: coverage maps, the per-chunk markers of a DEM gridded into a bucket (with the chunk plan), and the
#: scratch DEM of the a-priori points (validation; removed when done).
DEM_FILE = "dem.zarr"
COVERAGE_FILE = "coverage.zarr"
DEM_CHUNKS_DIR = "dem_chunks"
DEM_CHUNKS_PLAN_FILE = "plan.json"
DEM_APRIORI_FILE = "dem_apriori.zarr"
#: The registration to laser altimetry (``RUN/``, or the directory of ``mercury-dem register``): its maps by
#: key (the key names them in ``report.json`` and is their products' directory, ``products/<key>/``), and the
#: directory of its tables with the files in it; the scratch store of its transformed map (in a temporary
#: directory).
REGISTERED_FILE = "registered.zarr"
MERGED_FILE = "merged.zarr"
REGISTRATION_MAPS = {"registered": REGISTERED_FILE, "merged": MERGED_FILE}
REGISTRATION_DIR = "registration"
REGISTRATION_TILES_TABLE = "tiles.parquet"
REGISTRATION_TILES_JSON = "tiles.json"
REGISTRATION_PROFILES_TABLE = "profiles.parquet"
REGISTRATION_FIGURE = "rms_per_tile.png"
REGISTRATION_SUMMARY_FILE = SUMMARY_FILE
#: The registration's transform as the maps got it (tile table and mean level), for the dense cloud (issue 31).
REGISTRATION_TRANSFORM_FILE = "transform.json"
REGISTRATION_SCRATCH_FILE = "transformed.zarr"
#: What the DEM stage writes into ``RUN/`` (removed by ``--force dem`` or an earlier stage).
DEM_OUTPUTS = (DEM_FILE, DEM_CHUNKS_DIR, COVERAGE_FILE, PRODUCTS_DIR)
#: The dense stage (issue 31): the cloud (one Zarr group per tile), the dense DEM, and its scratch store.
DENSE_FILE = "dense.zarr"
DEM_DENSE_FILE = "dem_dense.zarr"
DEM_DENSE_SCRATCH_FILE = "dem_dense_grid.zarr"
#: The dense DEM's products (GeoTIFF/COG, PDS, ISIS, statistics, browse, orthoimages): RUN/products/dense/.
DENSE_PRODUCTS_DIR = "dense"
DENSE_OUTPUTS = (DENSE_FILE, DEM_DENSE_FILE, DEM_DENSE_SCRATCH_FILE)



def write_registration_tables(table_dir: str | Path, *, tiles_parquet: bytes, tiles: Any, profiles_parquet: bytes,
                              figure_png: bytes, summary: Any, overwrite: bool = False, transform: Any = None) -> Path:
    """Write the registration's table directory (``registration/``) as one unit, atomically.

    The tiles' and profiles' Parquet tables, the tiles' JSON, the before/after RMS figure and the
    summary, under :data:`REGISTRATION_DIR`'s file names, and ``transform`` (JSON-able, when given:
    :data:`REGISTRATION_TRANSFORM_FILE`); the directory appears whole or not at all
    (:func:`~mercury_dem.io.atomic.atomic_directory`). Returns the directory.
    """
    with atomic_directory(table_dir, overwrite=overwrite) as tmp:
        atomic_write_bytes(tmp / REGISTRATION_TILES_TABLE, tiles_parquet)
        atomic_write_json(tmp / REGISTRATION_TILES_JSON, tiles)
        atomic_write_bytes(tmp / REGISTRATION_PROFILES_TABLE, profiles_parquet)
        atomic_write_bytes(tmp / REGISTRATION_FIGURE, figure_png)
        atomic_write_json(tmp / REGISTRATION_SUMMARY_FILE, summary)
        if transform is not None:
            atomic_write_json(tmp / REGISTRATION_TRANSFORM_FILE, transform)
    return Path(table_dir)


def read_registration_transform(table_dir: str | Path) -> dict[str, Any] | None:
    """The registration's stored transform (:data:`REGISTRATION_TRANSFORM_FILE` in ``table_dir``), or None
    when there is none (no altimetry, a failed registration, or a run registered before it was stored).
    """
    path = Path(table_dir) / REGISTRATION_TRANSFORM_FILE
    if not path.is_file():
        return None
    out: dict[str, Any] = json.loads(path.read_text())
    return out

@dataclass(frozen=True)
class RunStore:
    """Paths and small readers/writers of one run directory (local, or cached from a bucket).

    Parameters
    ----------
    root : the run's local directory; given a URL (``s3://bucket/run``) it is checked
        (:func:`~mercury_dem.io.location.resolve_location`), kept as :attr:`url`, and
        ``root`` becomes the run's cache directory.
    url : the object-store URL of the run, or None for a local run
    """

    root: Path
    url: str | None = None

    def __post_init__(self) -> None:
        root: Any = self.root
        if self.url is None and not isinstance(root, Path):
            loc = resolve_location(root, "run store")
            if isinstance(loc, str):
                object.__setattr__(self, "url", loc)
                root = cache_dir_for(loc, "runs")
            else:
                root = loc
        object.__setattr__(self, "root", Path(root))

    @classmethod
    def open(cls, root: str | Path) -> RunStore:
        store = cls(root)
        if not store.has_run():
            r = store.location
            raise StoreError(f"{r} is not a mercury-dem run (no run.json); run 'mercury-dem run MISSION --out {r}'")
        if store.url is not None:
            store.fetch_file(RUN_FILE)
            store.fetch_file(REPORT_FILE)
        return store

    @property
    def location(self) -> str:
        """What the user named: the URL of a bucket run, else the directory (as a task argument)."""
        return self.url if self.url is not None else str(self.root)

    @functools.cached_property
    def remote(self) -> RemoteDir:
        """The run's prefix on the object store (only for a URL run)."""
        if self.url is None:
            raise StoreError(f"{self.root} is a local run; it has no object-store prefix")
        return RemoteDir(self.url)

    def check_writable(self) -> None:
        """Write and delete a probe object under a bucket run's prefix; a clear error when the bucket cannot be used.

        Raises
        ------
        StoreError : no such bucket, no credentials or no permission, endpoint unreachable (the
            fsspec/botocore error is quoted).
        """
        if self.url is None:
            return
        try:
            self.remote.write_bytes(".write-probe", b"")
            self.remote.remove(".write-probe")
        except Exception as exc:  # noqa: BLE001 - botocore/gcsfs raise many types; all mean "cannot use it"
            raise StoreError(
                f"{self.url}: cannot write to the bucket ({type(exc).__name__}: {exc}); check that the bucket "
                "exists, the endpoint (FSSPEC_S3_ENDPOINT_URL for a service that is not AWS) and the credentials "
                "(AWS_ACCESS_KEY_ID/AWS_SECRET_ACCESS_KEY, ~/.aws, or the instance role)") from None

    def has_run(self) -> bool:
        """Whether the run's ``run.json`` exists (on the bucket for a URL run)."""
        if self.url is not None:
            return self.remote.exists(RUN_FILE)
        return self.run_json.is_file()

    def is_empty(self) -> bool:
        """Whether nothing is stored at the run's location yet."""
        if self.url is not None:
            return not self.remote.list("")
        return not self.root.exists() or not any(self.root.iterdir())

    def remove(self, name: str) -> None:
        """Delete ``RUN/name`` (a file or a directory), on the bucket too (``--force``)."""
        p = self.root / name
        if p.is_dir():
            shutil.rmtree(p, ignore_errors=True)
        elif p.exists():
            p.unlink()
        if self.url is not None:
            self.remote.remove(name)

    # -- object-store commits and fetches (no-ops for a local run) -------------------
    def commit_dir(self, name: str) -> None:
        """Commit the cached directory ``RUN/name`` (plan, a unit) to the bucket, marker last."""
        if self.url is not None:
            self.remote.commit_dir(self.root / name, name)

    def commit_zarr(self, name: str) -> None:
        """Commit the cached Zarr store ``RUN/name`` to the bucket, its root ``zarr.json`` last."""
        if self.url is not None:
            self.remote.commit_dir(self.root / name, name, last="zarr.json", token_marker=False)

    def fetch_zarr(self, name: str, force: bool = False) -> bool:
        """Make the cached ``RUN/name`` the bucket's committed Zarr store; False (and no cached copy) when
        the bucket has none. A local run: whether the store exists. The cached copy is reused only while the
        bucket's store has the content it was fetched at (:meth:`~mercury_dem.io.remote.RemoteDir.content_token`:
        any object rewritten, ``zarr.json`` or a chunk, makes it stale), so no reader needs ``force`` (kept: a
        download whatever the token).
        """
        if self.url is None:
            return (self.root / name).exists()
        ok = self.remote.fetch_dir(name, self.root / name, last="zarr.json", token_marker=False,
                                   mark_complete=lambda tmp: None, force=force)
        if not ok:
            shutil.rmtree(self.root / name, ignore_errors=True)
        return ok

    def commit_tree(self, name: str) -> None:
        """Replace ``RUN/name`` on the bucket by the cached directory (products: rewritten by every run)."""
        if self.url is not None:
            self.remote.remove(name)
            files = [p for p in sorted((self.root / name).rglob("*")) if p.is_file()]
            if files:  # one call: uploaded concurrently
                self.remote.fs.put([str(p) for p in files],
                                   [self.remote.key(f"{name}/{p.relative_to(self.root / name).as_posix()}") for p in files])

    def commit_file(self, name: str) -> None:
        """Upload the cached file ``RUN/name`` (one PUT: whole or absent)."""
        if self.url is not None:
            self.remote.write_bytes(name, (self.root / name).read_bytes())

    def fetch_file(self, name: str) -> bool:
        """Copy ``RUN/name`` from the bucket into the cache; False (and no cached copy) when absent there."""
        if self.url is None:
            return (self.root / name).is_file()
        data = self.remote.read_bytes(name)
        if data is None:
            (self.root / name).unlink(missing_ok=True)  # the cache mirrors the bucket: no stale copy
            return False
        from mercury_dem.io.atomic import atomic_write_bytes

        atomic_write_bytes(self.root / name, data)
        return True

    # -- run-level files ---------------------------------------------------------
    @property
    def run_json(self) -> Path:
        return self.root / RUN_FILE

    @property
    def plan_dir(self) -> Path:
        return self.root / PLAN_DIR

    @property
    def report_json(self) -> Path:
        return self.root / REPORT_FILE

    @property
    def dem_path(self) -> Path:
        return self.root / DEM_FILE

    @property
    def coverage_path(self) -> Path:
        return self.root / COVERAGE_FILE

    @property
    def registration_dir(self) -> Path:
        return self.root / REGISTRATION_DIR

    @property
    def products_dir(self) -> Path:
        return self.root / PRODUCTS_DIR

    @property
    def performance_html(self) -> Path:
        return self.root / PERFORMANCE_FILE

    @property
    def plan_json(self) -> Path:
        return self.plan_dir / PLAN_INFO_FILE

    def write_report(self, report: dict[str, Any]) -> None:
        """Write ``report.json`` atomically (and commit it to a bucket run)."""
        atomic_write_json(self.report_json, report)
        self.commit_file(self.report_json.name)

    def commit_performance_report(self) -> None:
        """Upload ``performance.html`` (Dask's, written by the distributed client) to a bucket run, if written."""
        if self.performance_html.is_file():
            self.commit_file(self.performance_html.name)

    def read_run(self) -> dict[str, Any]:
        if self.url is not None:
            data = self.remote.read_bytes(RUN_FILE)
            if data is None:
                raise StoreError(f"{self.url} has no run.json; run 'mercury-dem run MISSION --out {self.url}'")
            return json.loads(data)
        return json.loads(self.run_json.read_text())

    def write_run(self, info: dict[str, Any]) -> None:
        atomic_write_json(self.run_json, info)
        self.commit_file(RUN_FILE)

    # -- units ---------------------------------------------------------------------
    def unit_dir(self, level: str, unit_id: int) -> Path:
        if level not in LEVELS:
            raise StoreError(f"unknown level {level!r}; one of {LEVELS}")
        return self.root / level / str(int(unit_id))

    def unit_complete(self, level: str, unit_id: int) -> bool:
        """Whether the unit is committed: its completion marker exists (on the bucket for a URL run)."""
        if self.url is not None:
            return self.remote.commit_token(self._unit_key(level, unit_id)) is not None
        return is_complete(self.unit_dir(level, unit_id))

    def verify_unit(self, level: str, unit_id: int) -> list[str] | None:
        """Check a committed unit's files against the checksums of its completion marker.

        Returns
        -------
        None when the unit's marker carries no checksums (a run written before they existed:
        trusted as before), else the faults, one line per file (``network.zarr/points/c/0:
        checksum mismatch ...``); [] when every file matches. A bucket run verifies the copy
        fetched into the cache (the marker and its manifest come from the bucket).
        """
        try:
            d = self.local_unit(level, unit_id)
        except StoreError as exc:
            return [str(exc)]
        return verify_complete(d)

    def check_unit(self, level: str, unit_id: int) -> None:
        """Raise :class:`CorruptUnitError` naming the unit and its faulty files when its checksums fail."""
        problems = self.verify_unit(level, unit_id)
        if problems:
            raise CorruptUnitError(corrupt_message(self.unit_dir(level, unit_id), problems))

    def invalidate_unit(self, level: str, unit_id: int) -> None:
        """Withdraw a unit (corrupt): its marker first (on the bucket too), then its files; it is recomputed."""
        d = self.unit_dir(level, unit_id)
        if self.url is not None:
            key = self._unit_key(level, unit_id)
            self.remote.remove(f"{key}/.complete")
            self.remote.remove(key)
            (d.parent / f".{d.name}.remote-token").unlink(missing_ok=True)
        if d.exists():
            aside = tmp_sibling(d)  # renamed first: a reader never sees a half-deleted unit
            d.rename(aside)
            shutil.rmtree(aside, ignore_errors=True)

    def _unit_key(self, level: str, unit_id: int) -> str:
        return self.unit_dir(level, unit_id).relative_to(self.root).as_posix()

    def local_unit(self, level: str, unit_id: int) -> Path:
        """The unit's directory to read from: for a URL run, its committed objects fetched into the cache.

        Raises
        ------
        StoreError : the unit has no completion marker on the bucket (never trusted).
        """
        d = self.unit_dir(level, unit_id)
        if self.url is not None and not self.remote.fetch_dir(self._unit_key(level, unit_id), d):
            raise StoreError(f"{self.remote.url_of(self._unit_key(level, unit_id))} is not complete (no completion "
                             "marker); resume the run to recompute it")
        return d

    def commit_unit(self, level: str, unit_id: int) -> None:
        """Commit a unit written into :meth:`unit_dir` to the bucket (no-op for a local run)."""
        self.commit_dir(self._unit_key(level, unit_id))

    def write_unit(self, level: str, unit_id: int, summary: Mapping[str, Any],
                   files: Mapping[str, Callable[[Path], object]] | None = None) -> None:
        """Write a unit directory atomically: its files, then ``summary.json``, then the completion marker.

        ``files``: file name (:data:`NETWORK_FILE`, ...) -> a function writing that file at the path it is
        given (:meth:`mercury_dem.pipeline.results.UnitFiles.writers`). The marker holds every file's
        SHA-256, so a unit damaged after its commit is detected on resume. On a bucket run the directory
        is built in the cache, then committed with the marker last (:mod:`mercury_dem.io.remote`).
        """
        with atomic_directory(self.unit_dir(level, unit_id), overwrite=True, checksums=True) as tmp:
            for name, write in (files or {}).items():
                write(tmp / name)
            atomic_write_json(tmp / SUMMARY_FILE, dict(summary))
        self.commit_unit(level, unit_id)

    def network_path(self, level: str, unit_id: int) -> Path:
        return self.local_unit(level, unit_id) / NETWORK_FILE

    def solution_path(self, level: str, unit_id: int) -> Path:
        return self.local_unit(level, unit_id) / SOLUTION_FILE

    def unit_file(self, level: str, unit_id: int, name: str) -> Path:
        return self.local_unit(level, unit_id) / name

    def summary_path(self, level: str, unit_id: int) -> Path:
        return self.unit_dir(level, unit_id) / SUMMARY_FILE

    def read_summary(self, level: str, unit_id: int) -> dict[str, Any]:
        if self.url is not None:
            key = f"{self._unit_key(level, unit_id)}/{SUMMARY_FILE}"
            data = self.remote.read_bytes(key)
            if data is None:
                raise StoreError(f"{self.remote.url_of(key)} does not exist; resume the run to recompute the unit")
            return json.loads(data)
        return json.loads(self.summary_path(level, unit_id).read_text())

    def completed_units(self, level: str) -> list[int]:
        if self.url is not None:
            return sorted(int(n) for n in self.remote.list(level) if n.isdigit() and self.unit_complete(level, int(n)))
        d = self.root / level
        if not d.is_dir():
            return []
        return sorted(int(p.name) for p in d.iterdir() if p.name.isdigit() and is_complete(p))

    def remove_level(self, level: str) -> None:
        """Delete every unit of a level (``--force``)."""
        d = self.root / level
        if d.exists():
            shutil.rmtree(d)
        if self.url is not None:
            self.remote.remove(level)

    # -- plan ------------------------------------------------------------------------
    def write_plan(self, images: pd.DataFrame, pairs: pd.DataFrame, info: dict[str, Any]) -> None:
        """Write the plan (images table, overlap pairs, plan info) atomically with checksums, and commit it."""
        with atomic_directory(self.plan_dir, overwrite=True, checksums=True) as tmp:
            images.to_parquet(tmp / PLAN_IMAGES_FILE, index=False)
            pairs.to_parquet(tmp / PLAN_PAIRS_FILE, index=False)
            (tmp / PLAN_INFO_FILE).write_text(json.dumps(info, indent=2))
        self.commit_dir(PLAN_DIR)

    def read_plan_info(self) -> dict[str, Any]:
        """The plan's ``plan.json`` (tile size, non-empty tiles, exclusions, counts) of a complete plan."""
        return json.loads(self.plan_json.read_text())

    def read_plan(self) -> tuple[pd.DataFrame, pd.DataFrame, dict[str, Any]]:
        """(images table, overlap pairs table, plan info)."""
        if self.url is not None:
            self.remote.fetch_dir(PLAN_DIR, self.plan_dir)
        if not is_complete(self.plan_dir):
            raise StoreError(f"{self.plan_dir} is missing or incomplete; re-run 'mercury-dem run'")
        images = read_table(self.plan_dir / PLAN_IMAGES_FILE, f"run plan {self.plan_dir}")
        pairs = read_table(self.plan_dir / PLAN_PAIRS_FILE, f"run plan {self.plan_dir}")
        return images, pairs, self.read_plan_info()

    def plan_complete(self) -> bool:
        """Whether the plan is committed (fetched into the cache for a URL run)."""
        if self.url is not None:
            return self.remote.fetch_dir(PLAN_DIR, self.plan_dir)
        return is_complete(self.plan_dir)


def unit_name(level: str, unit_id: int) -> str:
    """``tile 17``, ``region N-060-120``, ``hemisphere north``, ``global``."""
    if level == "region":
        from mercury_dem.geometry.tiling import region_name

        return f"region {region_name(unit_id)}"
    if level == "hemisphere":
        return f"hemisphere {'north' if unit_id == 0 else 'south'}"
    if level == "global":
        return "global"
    return f"{level} {unit_id}"


def corrupt_message(unit_dir: Path, problems: list[str]) -> str:
    """``RUN/tile/17: checksum mismatch in network.zarr/...; ...`` and what to do."""
    shown = "; ".join(problems[:5]) + (f"; ... {len(problems) - 5} more" if len(problems) > 5 else "")
    return (f"{unit_dir}: its files differ from the checksums committed with it ({shown}); the unit is not "
            "trusted: resume the run ('mercury-dem run MISSION --out RUN') to recompute it")


def write_solution(path: Path, image_ids: np.ndarray, rotations: np.ndarray, positions: np.ndarray,
                   extra: dict[str, np.ndarray] | None = None) -> None:
    """Per-image adjusted pointing as Parquet: image_id, rotation_00..22, position_x/y/z, extra columns."""
    import numpy as np
    import pandas as pd

    cols: dict[str, Any] = {"image_id": np.asarray(image_ids, dtype=str)}
    r = np.asarray(rotations, dtype=np.float64).reshape(-1, 9)
    for k in range(9):
        cols[f"rotation_{k // 3}{k % 3}"] = r[:, k]
    p = np.asarray(positions, dtype=np.float64)
    for k, ax in enumerate("xyz"):
        cols[f"position_{ax}"] = p[:, k]
    for name, values in (extra or {}).items():
        cols[name] = np.asarray(values)
    pd.DataFrame(cols).to_parquet(path, index=False)


def read_solution(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, pd.DataFrame]:
    """(image_ids, rotations (N,3,3), positions (N,3), the whole table)."""
    df = read_table(path, "solution")
    rot = df[[f"rotation_{i}{j}" for i in range(3) for j in range(3)]].to_numpy().reshape(-1, 3, 3)
    pos = df[["position_x", "position_y", "position_z"]].to_numpy()
    return df["image_id"].to_numpy(dtype=str), rot, pos, df
