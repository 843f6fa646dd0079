"""Ingest: a mission from real images — ISIS cubes with SPICE attached, or images beside CSM ISDs.

:func:`ingest_mission` is the stage runner behind ``mercury-dem ingest``. For each input:

* ``*.cub`` — an ISIS3 level-1 cube after ``spiceinit attach=true``: label, pixels (special
  pixels -> NaN), the exterior orientation at the exposure centre from its SPICE tables
  (:mod:`mercury_dem.sources`) and the camera from its ``NaifKeywords``
  (:func:`mercury_dem.geometry.naif_camera.camera_from_naif`: focal plane map, distortion,
  AlphaCube crop/reduce, the look direction);
* a CSM frame ISD (ALE or usgscsm layout, :func:`mercury_dem.geometry.isd.read_isd`), recognised
  by its content (a JSON object: ``.json``, ``.isd`` or any name; :func:`~mercury_dem.geometry.isd.is_isd_file`)
  with its image beside it (or in ``--isd-dir``'s counterpart): any GDAL-readable raster (PDS3
  ``.IMG``, GeoTIFF, PNG) or an ISIS cube, matched by file stem (``X.json`` <-> ``X.png``, or
  ``X_anything.png`` when exactly one such image exists); an image given alone finds its ISD
  as ``X.json``, ``X.isd`` or ``X`` (:data:`ISD_NAMES`).

Every input that cannot be used is rejected with a reason naming the file and what to do
(no SPICE: "run spiceinit attach=true"; image size != camera size; unknown distortion model;
another body than the rest) and the others go on; the selection of seed 000 (pixel scale
range, instruments) is applied after geometry is known. The mission directory is written
under a temporary name and renamed when complete (nothing half-written is left).
"""

from __future__ import annotations

import glob
import hashlib
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.exceptions import IsdError, MercuryDemError, StoreError
from mercury_dem.geometry.body import Body, body_by_name
from mercury_dem.geometry.camera import FramingCamera
from mercury_dem.geometry.isd import is_isd_file
from mercury_dem.io.atomic import atomic_directory
from mercury_dem.io.names import name_fault
from mercury_dem.mission.cameras import camera_to_dict
from mercury_dem.mission.catalog import build_catalog
from mercury_dem.mission.radiometry import Radiometry, float_radiometry, radiometry_of_dtype, robust_range
from mercury_dem.mission.store import MissionWriter

IMAGE_SUFFIXES = (".cub", ".img", ".tif", ".tiff", ".png", ".jp2", ".jpg")


@dataclass
class SourceImage:
    """One image read from its files: pixels, camera, a-priori pose, sun, and where it came from."""

    image_id: str
    instrument: str
    camera: FramingCamera
    position: NDArray[np.float64]
    rotation: NDArray[np.float64]
    sun: NDArray[np.float64]
    time: float
    body: Body
    pixels: NDArray[Any]
    files: list[str]
    serial_number: str | None = None
    bits: int | None = None
    notes: list[str] = field(default_factory=list)


class IngestError(MercuryDemError):
    """One input cannot become an image of the mission (the message names the file and why)."""


def expand_inputs(patterns: Sequence[str]) -> list[Path]:
    """Files named by paths or globs, in a stable order; a pattern matching nothing is an error."""
    out: list[Path] = []
    for pat in patterns:
        hits = sorted(glob.glob(pat)) if any(ch in pat for ch in "*?[") else [pat]
        if not hits:
            raise StoreError(f"ingest: {pat!r} matches no file")
        for h in hits:
            p = Path(h)
            if p not in out:
                out.append(p)
    return out


def _body_of(name: str | None, source: str) -> Body:
    if not name:
        raise IngestError(f"{source}: the target body is not named (TargetName / target_name)")
    try:
        return body_by_name(name)
    except ValueError as exc:
        raise IngestError(f"{source}: {exc}") from None


#: Instrument names as the labels and ISDs spell them -> the names the missions use.
_INSTRUMENT_ALIASES = {
    "MSGR_MDIS_NAC": "MDIS-NAC", "MSGR_MDIS_WAC": "MDIS-WAC",
    "MERCURY DUAL IMAGING SYSTEM NARROW ANGLE CAMERA": "MDIS-NAC",
    "MERCURY DUAL IMAGING SYSTEM WIDE ANGLE CAMERA": "MDIS-WAC",
}


def _instrument_name(spacecraft: str | None, instrument: str | None) -> str:
    sc = (spacecraft or "").strip().upper().replace(" ", "")
    inst = (instrument or "").strip().upper()
    inst = _INSTRUMENT_ALIASES.get(inst, inst)
    if inst.startswith("MDIS"):
        return inst  # MDIS-NAC / MDIS-WAC, the synthetic missions' names
    return f"{sc}/{inst}" if sc else inst or "UNKNOWN"


def _isd_names(raw: dict[str, Any]) -> tuple[str, str]:
    """(spacecraft, instrument) of an ISD: the specific keys first (knoten ISDs name a generic platform)."""
    generic = {"", "GENERIC PLATFORM", "GENERIC SENSOR"}
    sc = next((str(raw[k]) for k in ("spacecraft_name", "name_platform") if str(raw.get(k) or "").upper() not in generic), "")
    inst = next((str(raw[k]) for k in ("instrument_id", "name_sensor") if str(raw.get(k) or "").upper() not in generic), "")
    return sc, inst


def read_cube_image(path: Path, *, pixels: bool = True) -> SourceImage:
    """A cube with SPICE attached -> one image (IngestError naming the cube otherwise).

    ``pixels=False`` reads the geometry only (label, SPICE tables, NaifKeywords): the
    returned image's ``pixels`` is an empty (0, 0) array and no pixel is read.
    """
    from mercury_dem.geometry.naif_camera import camera_from_naif
    from mercury_dem.sources import alpha_cube, cube_spice, naif_keywords, open_cube, read_pixels

    cube = open_cube(path)
    spice = cube_spice(cube)  # CubeError "... run spiceinit attach=true" when there is no SPICE
    body = _body_of(cube.target_name, str(path))
    keywords = naif_keywords(cube)
    name = _instrument_name(cube.spacecraft_name, cube.instrument_id)
    alpha = alpha_cube(cube)  # checked against the cube; None when never cropped or reduced
    camera, inst_to_cam = camera_from_naif(
        keywords, spice.ik_code, cube.samples, cube.lines, name=name, summing=cube.summing or 1,
        alpha=alpha,
    )
    bits: int | None = None
    if not pixels:
        image: NDArray[Any] = np.zeros((0, 0), np.float32)
    else:
        values, valid = read_pixels(cube)
        if cube.pixel_type == "Real":
            image = np.where(valid, values, np.nan).astype(np.float32)
        else:
            image, bits = _integer_image(values, valid, cube.pixel_type)
    return SourceImage(
        image_id=path.name.split(".")[0], instrument=name, camera=camera, position=spice.position,
        rotation=inst_to_cam @ spice.body_to_instrument, sun=spice.sun_position, time=spice.et, body=body,
        pixels=image, files=[str(path)], serial_number=spice.serial_number, bits=bits,
    )


def _integer_image(pixels: NDArray[np.float32], valid: NDArray[np.bool_], pixel_type: str) -> tuple[NDArray[Any], int | None]:
    """Integer DN of a cube as the smallest type the mission stores; invalid pixels become NaN floats."""
    if not valid.all():
        return np.where(valid, pixels, np.nan).astype(np.float32), None
    top = float(np.nanmax(pixels)) if pixels.size else 0.0
    if pixel_type == "UnsignedByte":
        return pixels.astype(np.uint8), 8
    if float(np.nanmin(pixels)) >= 0 and top <= 65535 and np.all(pixels == np.round(pixels)):
        return pixels.astype(np.uint16), None
    return pixels.astype(np.float32), None


def _find_image(isd: Path, image_dirs: Sequence[Path]) -> Path:
    stem = isd.stem
    for d in image_dirs:
        exact = [d / f"{stem}{s}" for s in IMAGE_SUFFIXES if (d / f"{stem}{s}").is_file()]
        exact += [d / f"{stem}{s.upper()}" for s in IMAGE_SUFFIXES if (d / f"{stem}{s.upper()}").is_file()]
        if exact:
            return exact[0]
    cands = []
    for d in image_dirs:
        if d.is_dir():
            cands += [p for p in d.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES
                      and p.stem.startswith(stem) and len(p.stem) > len(stem) and not p.stem[len(stem)].isalnum()]
    if len(cands) == 1:
        return cands[0]
    where = ", ".join(str(d) for d in image_dirs)
    if not cands:
        raise IngestError(f"ISD {isd}: no image named {stem}.* or {stem}_*.* in {where}; put the image beside its "
                          "ISD (same stem) or pass the image files with --isd-dir pointing at the ISDs")
    raise IngestError(f"ISD {isd}: several images could be its image ({', '.join(sorted(str(c) for c in cands))}); "
                      "rename them so one has the ISD's stem")


def _read_raster(path: Path) -> NDArray[Any]:
    """The first band of any raster GDAL reads (nodata -> NaN in a float image)."""
    if path.suffix.lower() == ".cub":
        from mercury_dem.sources import open_cube, read_pixels

        cube = open_cube(path)
        px, valid = read_pixels(cube)
        return np.where(valid, px, np.nan).astype(np.float32) if cube.pixel_type == "Real" or not valid.all() \
            else _integer_image(px, valid, cube.pixel_type)[0]
    import warnings

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioIOError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)  # raw images carry no map georeferencing
            with rasterio.open(path) as src:
                band = src.read(1, masked=True)
    except (RasterioIOError, ValueError, OSError) as exc:
        raise IngestError(f"image {path}: GDAL cannot read it ({exc})") from None
    data = np.asarray(band.data)
    mask = np.ma.getmaskarray(band)
    if data.dtype in (np.uint8, np.uint16, np.int16) and not mask.any():
        return data
    return np.where(mask, np.nan, data.astype(np.float32)).astype(np.float32)


#: Names an image's ISD may have beside it (or in --isd-dir), tried in this order; each is checked by content.
ISD_NAMES = ("{stem}.json", "{stem}.isd", "{stem}.ISD", "{stem}")


def is_cube_file(path: Path) -> bool:
    """An ISIS cube: named ``*.cub`` or starting with its label's ``Object = IsisCube``."""
    if path.suffix.lower() == ".cub":
        return True
    try:
        with open(path, "rb") as fh:
            return fh.read(64).lstrip().startswith(b"Object = IsisCube")
    except OSError:
        return False


def _isd_of_image(image: Path, isd_dirs: Sequence[Path]) -> Path | None:
    """The ISD of an image file: the first of :data:`ISD_NAMES` in ``isd_dirs`` then beside it that holds JSON."""
    for d in [*isd_dirs, image.parent]:
        for pattern in ISD_NAMES:
            cand = d / pattern.format(stem=image.stem)
            if cand != image and cand.is_file() and is_isd_file(cand):
                return cand
    return None


def read_image_list(path: str | Path) -> dict[str, Path]:
    """An ``ISD,IMAGE`` CSV (one pair a line; '#' comments; relative paths from the CSV's folder) ->
    {ISD stem: image path}. StoreError naming the file and line at fault.
    """
    p = Path(path)
    try:
        lines = p.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise StoreError(f"--image-list {p}: cannot be read ({exc})") from None
    out: dict[str, Path] = {}
    for k, line in enumerate(lines, 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = [x.strip() for x in line.split(",")]
        if len(parts) != 2 or not all(parts):
            raise StoreError(f"--image-list {p}, line {k}: expected 'ISD,IMAGE', got {line!r}")
        isd, image = (Path(x) if Path(x).is_absolute() else p.parent / x for x in parts)
        if isd.stem in out:
            raise StoreError(f"--image-list {p}, line {k}: {isd.name} is listed twice")
        out[isd.stem] = image
    return out


def read_isd_image(isd_path: Path, image_dirs: Sequence[Path], *, pixels: bool = True,
                   body: Body | None = None, image_path: Path | None = None) -> SourceImage:
    """A CSM frame ISD and its image -> one image.

    ``pixels=False`` reads the ISD only (no image is looked for; ``pixels`` is an empty
    (0, 0) array). An unusable sun position becomes NaN with a note instead of an error.
    ``body`` is used when the ISD does not name its target. ``image_path`` names the image
    (from ``--image-list``) instead of looking for it by stem. The serial number is the
    ISD's own (:func:`isd_serial_number`), or None.
    """
    from mercury_dem.geometry.isd import isd_from_dict

    try:
        raw = json.loads(isd_path.read_text(encoding="utf-8-sig"))
    except (OSError, ValueError) as exc:
        raise IngestError(f"ISD {isd_path}: not readable JSON ({exc})") from None
    if not isinstance(raw, dict):
        raise IngestError(f"ISD {isd_path}: the top level is not a JSON object")
    try:
        g = isd_from_dict(raw, source=str(isd_path))
    except IsdError as exc:
        if "sun_position" not in str(exc):
            raise
        # The geometry is usable without the Sun (matching then knows no illumination angles).
        g = isd_from_dict(raw, source=str(isd_path), require_sun=False)  # its warnings say the Sun was not used
    target = raw.get("name_target") or raw.get("target_name")
    if not target and body is not None:
        target = body.name
    the_body = _body_of(str(target) if target else None, str(isd_path))
    name = _instrument_name(*_isd_names(raw))
    cam = g.camera
    files = [str(isd_path)]
    if pixels:
        image_path = image_path if image_path is not None else _find_image(isd_path, image_dirs)
        if not image_path.is_file():
            raise IngestError(f"ISD {isd_path}: its image {image_path} does not exist")
        image = _read_raster(image_path)
        if image.shape != (cam.lines, cam.samples):
            raise IngestError(f"image {image_path}: {image.shape[1]} x {image.shape[0]} pixels, but its ISD "
                              f"{isd_path} describes {cam.samples} x {cam.lines}; give the image the ISD was made for")
        files.append(str(image_path))
    else:
        image = np.zeros((0, 0), np.float32)
    return SourceImage(
        image_id=isd_path.stem, instrument=name, camera=cam, position=g.position, rotation=g.rotation,
        sun=g.sun_position if g.sun_position is not None else np.full(3, np.nan), time=g.ephemeris_time,
        body=the_body, pixels=image, files=files, serial_number=isd_serial_number(raw),
        bits=8 if image.dtype == np.uint8 else None, notes=list(g.warnings),
    )


def isd_serial_number(isd: dict[str, Any]) -> str | None:
    """The ISIS serial number an ISD's keys give, or None.

    An explicit ``isis_serial_number`` (or ``serial_number``) key wins. Otherwise
    MESSENGER MDIS is formed as ISIS forms it, ``MeSSEnGeR/<MDIS-NAC|MDIS-WAC>/<clock>``,
    when the ISD carries the start clock count (``spacecraft_clock_start_count`` or
    ``spacecraft_clock_count``; the stop count, which differs, is not used). Apollo
    Metric ISDs rarely carry ISIS's ``StartTime`` string verbatim: give those serials
    with a ``file,serial`` list instead.
    """
    for key in ("isis_serial_number", "serial_number"):
        value = isd.get(key)
        if isinstance(value, str) and value.strip():
            return value.strip()
    clock = isd.get("spacecraft_clock_start_count") or isd.get("spacecraft_clock_count")
    craft = str(isd.get("spacecraft_name") or isd.get("name_platform") or "").upper().replace(" ", "")
    names = f"{isd.get('instrument_id', '')} {isd.get('name_sensor', '')}".upper()
    if clock and craft.startswith("MESSENGER"):
        if "NARROW ANGLE" in names or "MDIS_NAC" in names or "MDIS-NAC" in names:
            return f"MeSSEnGeR/MDIS-NAC/{clock}"
        if "WIDE ANGLE" in names or "MDIS_WAC" in names or "MDIS-WAC" in names:
            return f"MeSSEnGeR/MDIS-WAC/{clock}"
    return None


def camera_key(camera: FramingCamera) -> str:
    """A camera id: the instrument name and a short hash of every field (equal cameras share one id)."""
    blob = json.dumps(camera_to_dict(camera), sort_keys=True).encode()
    return f"{camera.name}-{hashlib.sha1(blob).hexdigest()[:8]}"


#: Bits of the detectors whose raw DN this reads (the saturation of raw DN stored as floats).
INSTRUMENT_BITS = {"MDIS-NAC": 12, "MDIS-WAC": 12}


def _raw_dn(image: NDArray[Any]) -> bool:
    """A float image whose valid values are all whole non-negative numbers holds raw DN (an EDR cube)."""
    v = image[np.isfinite(image)]
    return bool(v.size) and bool(np.all(v >= 0)) and bool(np.all(v == np.round(v))) and float(v.max()) <= 65535


def _radiometry(images: list[SourceImage]) -> list[Radiometry]:
    """Each image's pixel facts: integer DN by dtype; float raw DN (whole numbers) as DN of the instrument's
    bits; other floats (I/F, radiance) share one scale from the mission's typical robust range.
    """
    dn_floats = [im.pixels.dtype.kind == "f" and _raw_dn(im.pixels) for im in images]
    calibrated = [im for im, dn in zip(images, dn_floats) if im.pixels.dtype.kind == "f" and not dn]
    shared = float_radiometry([robust_range(im.pixels) for im in calibrated]) if calibrated else None
    out = []
    for im, dn in zip(images, dn_floats):
        if im.pixels.dtype.kind != "f":
            out.append(radiometry_of_dtype(im.pixels.dtype, im.bits))
        elif dn:
            bits = INSTRUMENT_BITS.get(im.instrument)
            out.append(Radiometry("dn", float(2 ** bits - 1) if bits else float("nan"), 1.0))
        else:
            out.append(shared)  # type: ignore[arg-type]
    return out


def ingest_mission(
    out: str | Path,
    inputs: Sequence[str],
    *,
    isd_dir: str | Path | None = None,
    min_scale_m: float | None = None,
    max_scale_m: float | None = None,
    instruments: Sequence[str] | None = None,
    tile_size_deg: float = 10.0,
    overwrite: bool = False,
    pointing_sigma_urad: float | None = None,
    image_list: str | Path | None = None,
    altimetry: Sequence[str] | None = None,
    altimetry_sigma_m: float | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, Any]:
    """Build the mission at ``out`` from cubes and/or ISDs; return a summary (images, rejected, seconds).

    ``inputs`` are cube, ISD or image paths (globs allowed). An image file given without an ISD is
    paired with the ISD of its stem in ``isd_dir`` (or beside it); ``image_list`` (an ``ISD,IMAGE`` CSV)
    names an ISD's image when the stems differ. ``pointing_sigma_urad`` records how wrong
    the a-priori pointing may be (1 sigma per axis): matching sizes its guidance window from it and the
    adjustment weights its pointing constraint by it (unless ``apriori.pointing_sigma_urad`` overrides it). Rejected inputs are listed with
    their reason; with no usable image at all, StoreError (nothing is written).

    ``altimetry`` names LOLA/MLA RDR shot tables (CSV, globs allowed) read against the mission's body
    (its datum radius ± 25 km) into the mission's altimetry store (``MISSION/altimetry``, partitioned by
    tile); each shot gets ``altimetry_sigma_m`` (default 1 m) as its height sigma. A table that cannot be
    read is listed among the rejected inputs with the reader's reason. ``progress(done, total)``
    is called after each input file is read (presentation only).
    """
    t0 = time.perf_counter()
    out = Path(out)
    if out.exists() and not overwrite:
        raise StoreError(f"{out} already exists; pass --overwrite to replace it (or choose another MISSION)")
    files = expand_inputs(inputs)
    listed = read_image_list(image_list) if image_list is not None else {}
    isd_dirs = [Path(isd_dir)] if isd_dir is not None else []
    images: list[SourceImage] = []
    rejected: dict[str, str] = {}
    seen_isds: set[Path] = set()
    for i, f in enumerate(files, 1):
        try:
            suffix = f.suffix.lower()
            if not f.is_file():
                raise IngestError(f"{f}: no such file")
            if is_cube_file(f) and not isd_dirs:
                images.append(read_cube_image(f))
            elif is_isd_file(f):
                seen_isds.add(f.resolve())
                images.append(read_isd_image(f, [f.parent, *isd_dirs], image_path=listed.get(f.stem)))
            elif suffix in IMAGE_SUFFIXES or is_cube_file(f):
                isd = _isd_of_image(f, isd_dirs)
                if isd is None:
                    raise IngestError(f"{f}: an image without geometry (no ISD {f.stem}.json, {f.stem}.isd or "
                                      f"{f.stem} beside it or in --isd-dir); give a cube with SPICE attached or the "
                                      "image's CSM ISD")
                if isd.resolve() in seen_isds:
                    continue
                seen_isds.add(isd.resolve())
                images.append(read_isd_image(isd, [f.parent]))
            else:
                raise IngestError(f"{f}: not an ISIS cube, a CSM ISD (a JSON object: .json, .isd or any name) or an "
                                  f"image ({', '.join(IMAGE_SUFFIXES)})")
        except MercuryDemError as exc:
            rejected[str(f)] = str(exc)
        finally:
            if progress is not None:
                progress(i, len(files))
    images = _dedupe(images, rejected)
    if images:
        bodies = sorted({im.body.name for im in images})
        if len(bodies) > 1:
            main = max(bodies, key=lambda b: sum(im.body.name == b for im in images))
            for im in [im for im in images if im.body.name != main]:
                rejected[im.files[0]] = f"{im.files[0]}: target {im.body.name}, but the mission's body is {main}"
            images = [im for im in images if im.body.name == main]
    if not images:
        detail = "; ".join(f"{k}: {v}" for k, v in list(rejected.items())[:5])
        raise StoreError(f"ingest: no usable image among {len(files)} inputs ({detail})")
    body = images[0].body
    cameras = {camera_key(im.camera): im.camera for im in images}
    cam_ids = [camera_key(im.camera) for im in images]
    catalog = build_catalog(
        [im.image_id for im in images], [im.instrument for im in images], cameras, cam_ids,
        np.array([im.time for im in images]), np.array([im.position for im in images]),
        np.array([im.rotation for im in images]), np.array([im.sun for im in images]),
        body, tile_size_deg, _radiometry(images),
        extra={"serial_number": [im.serial_number or "" for im in images]},
    )
    keep = np.ones(len(images), bool)
    scale = catalog["pixel_scale_m"].to_numpy()
    for k, im in enumerate(images):
        why = None
        if not np.isfinite(catalog["center_lat"].iat[k]):
            why = "its centre pixel does not see the body (a-priori pointing off the limb?)"
        elif min_scale_m is not None and not scale[k] >= min_scale_m:
            why = f"pixel scale {scale[k]:.1f} m is below --min-scale-m {min_scale_m:g}"
        elif max_scale_m is not None and not scale[k] <= max_scale_m:
            why = f"pixel scale {scale[k]:.1f} m is above --max-scale-m {max_scale_m:g}"
        elif instruments and im.instrument not in instruments:
            why = f"instrument {im.instrument} is not among --instrument {', '.join(instruments)}"
        if why:
            keep[k] = False
            rejected[im.files[0]] = f"{im.image_id}: {why}"
    if not keep.any():
        detail = "; ".join(f"{k}: {v}" for k, v in list(rejected.items())[:5])
        raise StoreError(f"ingest: every image was rejected ({detail})")
    images = [im for im, k in zip(images, keep) if k]
    catalog = catalog[keep].reset_index(drop=True)
    cameras = {k: c for k, c in cameras.items() if k in set(catalog["camera_id"])}
    meta = {"source": "ingest", "tile_size_deg": tile_size_deg, "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "selection": {"min_scale_m": min_scale_m, "max_scale_m": max_scale_m,
                          "instruments": list(instruments) if instruments else None},
            "rejected": rejected}
    if pointing_sigma_urad is not None:
        if not (math.isfinite(pointing_sigma_urad) and pointing_sigma_urad > 0):
            raise StoreError(f"ingest: --pointing-sigma-urad must be a positive number, got {pointing_sigma_urad}")
        meta["pointing_sigma_urad"] = float(pointing_sigma_urad)
    alt_table, alt_sources = _read_altimetry(altimetry or [], body, altimetry_sigma_m, rejected)
    if alt_sources:
        meta["altimetry"] = {"n_shots": int(len(alt_table)), "files": [s.name for s in alt_sources]}
    with atomic_directory(out, overwrite=overwrite) as tmp:
        writer = MissionWriter(tmp)
        for im in images:
            writer.write_image(tmp, im.image_id, im.pixels)
        if alt_sources:
            writer.write_altimetry(alt_table, sources=alt_sources, body=body, tile_size_deg=tile_size_deg)
        writer.finish(meta, body, cameras, catalog,
                      sources={im.image_id: {"files": im.files, "serial_number": im.serial_number, "notes": im.notes}
                               for im in images})
    return {
        "path": str(out), "body": body.name, "images": len(images), "inputs": len(files),
        "rejected": rejected, "cameras": sorted(cameras), "seconds": time.perf_counter() - t0,
        "catalog": catalog,
        "altimetry": None if not alt_sources else {
            "n_shots": int(len(alt_table)), "n_profiles": int(alt_table["profile_id"].nunique()) if len(alt_table) else 0,
            "sources": [s.to_dict() for s in alt_sources]},
    }


def _read_altimetry(patterns: Sequence[str], body: Body, sigma_m: float | None,
                    rejected: dict[str, str]) -> tuple[Any, list[Any]]:
    """The shot tables named by ``patterns`` as one table (+ their sources); unreadable ones go to ``rejected``."""
    from mercury_dem.altimetry.store import DEFAULT_SIGMA_M, combine_shots, shots_from_files

    if not patterns:
        return None, []
    tables, sources = [], []
    for f in expand_inputs(patterns):
        try:
            t, src = shots_from_files([f], body.datum_radius_m)
        except MercuryDemError as exc:
            rejected[str(f)] = f"altimetry: {exc}"
            continue
        tables.append(t.drop(columns=["sigma_m", "source_id"]))
        sources.extend(src)
    if not sources:
        return None, []
    return combine_shots(tables, sources, DEFAULT_SIGMA_M if sigma_m is None else sigma_m), sources


def _dedupe(images: list[SourceImage], rejected: dict[str, str]) -> list[SourceImage]:
    out: list[SourceImage] = []
    seen: dict[str, str] = {}
    for im in images:
        fault = name_fault(im.image_id)
        if fault is not None:  # the id (from the file name) would name a file in the mission
            rejected[im.files[0]] = (f"{im.files[0]}: its image id {im.image_id!r} (from the file name) {fault}; "
                                     "rename the file")
            continue
        if im.image_id in seen:
            rejected[im.files[0]] = (f"{im.image_id}: the same image id as {seen[im.image_id]}; "
                                     "give each image once")
            continue
        seen[im.image_id] = im.files[0]
        out.append(im)
    return out


def describe(summary: dict[str, Any]) -> str:
    """The printed summary of an ingest."""
    cat = summary["catalog"]
    lines = [f"mission {summary['path']}: {summary['images']} images of {summary['body']} "
             f"from {summary['inputs']} inputs ({summary['seconds']:.1f} s)"]
    for _, r in cat.iterrows():
        lines.append(f"  {r['image_id']:<28s} {r['instrument']:<18s} {r['samples']}x{r['lines']}  "
                     f"centre {r['center_lat']:8.3f} {r['center_lon']:8.3f}  {r['pixel_scale_m']:8.1f} m/px  "
                     f"inc {r['incidence_deg']:5.1f} emi {r['emission_deg']:5.1f} tile {r['tile_id']}")
    alt = summary.get("altimetry")
    if alt:
        lines.append(f"  altimetry: {alt['n_shots']} shots in {alt['n_profiles']} profiles from {len(alt['sources'])} files")
        for s in alt["sources"]:
            drops = ", ".join(f"{k} {v}" for k, v in s["dropped"].items() if v)
            lines.append(f"    {s['name']}: {s['n_shots']} of {s['n_rows']} rows" + (f" (dropped: {drops})" if drops else ""))
    for f, why in summary["rejected"].items():
        lines.append(f"  rejected {f}: {why}")
    if not math.isfinite(float(cat["incidence_deg"].iloc[0])):
        lines.append("  (no sun position in the geometry: incidence and phase are unknown)")
    return "\n".join(lines)
