"""Stage runner of ``mercury-dem adjust-isis``: an ISIS network and its images' cameras in,
the adjusted network, a bundleout-style report and corrected ISDs out.

:func:`run_adjust_isis` reads the network (:mod:`mercury_dem.network.isis`, ISIS 1-based
pixels become ours there), reads the cameras' geometry only (cubes with SPICE attached,
CSM ISDs; no pixel is read), matches serial numbers (:mod:`mercury_dem.network.jigsaw`),
takes a-priori points from the network or triangulates them, runs the project's bundle
adjustment (:func:`~mercury_dem.adjust.unit.adjust_unit_network`, outlier
rejection as configured, datum radius of the cameras' body), and writes atomically:

* ``OUT.net`` — ISIS v5: the input's points and measures, ids, types and a-priori values,
  with adjusted XYZ, measure residuals (pixels) and jigsawRejected flags;
* ``OUT_bundleout.txt`` beside it — the adjustment's jigsaw-like report with a header;
* ``OUT_isds/<image_id>.json`` — the corrected pointing: for an ISD input, a copy of it with
  its orientation replaced in its own layout; for a cube whose camera has transverse
  distortion or none, a usgscsm frame ISD of our camera; for an Apollo Metric cube
  nothing (no usgscsm model of its distortion; the summary says so).

Camera keys: a cube's serial number is ISIS's (:func:`~mercury_dem.sources.cube_spice`);
an ISD's comes from its keys (:func:`~mercury_dem.mission.ingest.isd_serial_number`); a
``file,serial`` CSV overrides both; every camera also answers to its image id (the file
stem), which is what ``mercury-dem export-isis`` writes as serial numbers.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.exceptions import MercuryDemError, NetworkError
from mercury_dem.io.atomic import atomic_write_json, atomic_write_text
from mercury_dem.io.names import name_fault

if TYPE_CHECKING:
    from mercury_dem.network.model import ControlNetwork


class AdjustIsisError(MercuryDemError):
    """An input of adjust-isis cannot be used (the message names the file and what to do)."""


def read_cameras(files: Sequence[str | Path], body_hint: str | None = None) -> list[Any]:
    """SourceImages (geometry only) of cubes and ISDs, in the order given."""
    from mercury_dem.geometry.body import body_by_name
    from mercury_dem.geometry.isd import is_isd_file
    from mercury_dem.mission.ingest import is_cube_file, read_cube_image, read_isd_image

    hint = None
    if body_hint:
        try:
            hint = body_by_name(body_hint)
        except ValueError:
            hint = None
    out = []
    for f in files:
        p = Path(f)
        if not p.is_file():
            raise AdjustIsisError(f"camera file {p}: no such file")
        if is_cube_file(p):
            out.append(read_cube_image(p, pixels=False))
        elif is_isd_file(p):  # by content: .json, .isd or any name
            out.append(read_isd_image(p, [], pixels=False, body=hint))
        else:
            raise AdjustIsisError(f"camera file {p}: neither an ISIS cube with SPICE attached (.cub, or a file "
                                  "starting 'Object = IsisCube') nor a CSM ISD (a JSON object, whatever its "
                                  "extension: .json, .isd, none)")
    return out


def load_serials(path: str | Path, files: Sequence[str | Path]) -> dict[int, str]:
    """The ``file,serial`` CSV as camera index -> serial; files match by path, name or stem."""
    from mercury_dem.network.jigsaw import parse_serials_csv

    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise AdjustIsisError(f"serials file {path}: cannot be read ({exc})") from None
    resolved = [Path(f).resolve() for f in files]
    out: dict[int, str] = {}
    for name, serial, line in parse_serials_csv(text, str(path)):
        p = Path(name)
        hits = [k for k, r in enumerate(resolved)
                if r == (path.parent / p).resolve() or r == p.resolve() or r.name == p.name
                or r.name.split(".")[0] == p.name.split(".")[0]]
        if len(hits) != 1:
            what = "none" if not hits else f"{len(hits)} ({', '.join(str(files[k]) for k in hits)})"
            raise AdjustIsisError(f"serials file {path} line {line}: {name!r} matches {what} of the --cameras files; "
                                  "name each camera file once (path, file name or stem)")
        out[hits[0]] = serial
    return out


def _isd_outputs(images: list[Any], rotations: np.ndarray, positions: np.ndarray, camera_index: np.ndarray,
                 out_dir: Path) -> tuple[dict[str, str], dict[str, str]]:
    """Write the corrected ISDs; return image id -> path written, image id -> why none."""
    from mercury_dem.exceptions import IsdError
    from mercury_dem.geometry.isd import is_isd_file
    from mercury_dem.geometry.isd_update import updated_isd, usgscsm_frame_isd

    written: dict[str, str] = {}
    skipped: dict[str, str] = {}
    for j, c in enumerate(camera_index.tolist()):
        im = images[c]
        src = Path(im.files[0])
        fault = name_fault(im.image_id)
        if fault is not None:  # ids come from file names; one must not write outside out_dir
            skipped[im.image_id] = f"image id {im.image_id!r} {fault}; no ISD written for it"
            continue
        target = out_dir / f"{im.image_id}.json"
        try:
            if is_isd_file(src):
                isd = updated_isd(json.loads(src.read_text(encoding="utf-8-sig")), rotations[j], positions[j],
                                  source=str(src))
            else:
                isd = usgscsm_frame_isd(im.camera, positions[j], rotations[j], sun_position=im.sun,
                                        radius_m=im.body.radius_m, ephemeris_time=im.time,
                                        target_name=im.body.name, platform=im.instrument.split("/")[0],
                                        sensor=im.instrument, serial_number=im.serial_number)
        except IsdError as exc:
            skipped[im.image_id] = str(exc)
            continue
        atomic_write_json(target, isd)
        written[im.image_id] = str(target)
    return written, skipped


def run_adjust_isis(
    net_path: str | Path,
    camera_files: Sequence[str | Path],
    out_path: str | Path,
    config: AdjustConfig,
    *,
    pointing_sigma_urad: float,
    serials_csv: str | Path | None = None,
    require_all: bool = False,
    write_isds: bool = True,
) -> dict[str, Any]:
    """Adjust an ISIS network with the given cameras; write the outputs; return the summary.
    ``pointing_sigma_urad``: how wrong the cameras' pointing may be, per axis (1 sigma, µrad).

    Raises
    ------
    NetworkError / AdjustIsisError / CubeError / IsdError naming the file: an unreadable or
    empty network, a camera file that is not usable (a cube without SPICE: "run spiceinit
    attach=true"), a malformed serials CSV, a serial number without a camera when
    ``require_all``, or no measure left to adjust.
    """
    from mercury_dem.adjust.unit import adjust_unit_network
    from mercury_dem.io.isis_net import write_isis_network
    from mercury_dem.network.jigsaw import merge_adjustment

    t0 = time.perf_counter()
    net_path, out_path = Path(net_path), Path(out_path)
    if out_path.suffix.lower() != ".net":
        raise AdjustIsisError(f"output {out_path}: give a .net file name (the report and ISDs are named after it)")
    network, images, match = _network_and_cameras(net_path, camera_files, serials_csv, require_all)
    job = _adjustable(net_path, network, images, match)
    body = images[0].body
    adj = adjust_unit_network(job.network, job.cameras, job.positions, job.rotations, config,
                              pointing_sigma_urad=pointing_sigma_urad, datum_radius_m=body.datum_radius_m)
    adjusted = adj.network.replace(apriori_xyz=np.where(job.unplaced[:, None], np.nan, adj.network.apriori_xyz))
    result = merge_adjustment(network, job.cut, adjusted, min_point_measures=2)

    out_path.parent.mkdir(parents=True, exist_ok=True)
    report_path = out_path.with_name(out_path.stem + "_bundleout.txt")
    written: dict[str, str] = {}
    skipped: dict[str, str] = {}
    if write_isds:
        written, skipped = _isd_outputs(images, adj.rotations, adj.positions, job.cut.camera_index,
                                        out_path.with_name(out_path.stem + "_isds"))
    summary = _summary(net_path, out_path, report_path, camera_files, network, job, match, adj, result)
    summary.update(isds=written, isds_not_written=skipped)
    summary = {k: summary[k] for k in _SUMMARY_KEYS if k in summary}  # the summary's key order
    write_isis_network(result, out_path, version=5, target_name=body.name.capitalize(),
                       description=f"adjusted by mercury-dem adjust-isis from {net_path.name}")
    summary["seconds"] = time.perf_counter() - t0
    atomic_write_text(report_path, _report_header(summary) + adj.text_report)
    return summary


def _network_and_cameras(net_path: Path, camera_files: Sequence[str | Path], serials_csv: str | Path | None,
                         require_all: bool) -> tuple[Any, list[Any], Any]:
    """The network, the cameras (one body) and the match of its serial numbers to them; each fault named."""
    from mercury_dem.io.isis_net import read_isis_network
    from mercury_dem.network.jigsaw import camera_keys_with_serials, match_serials

    network = read_isis_network(net_path)
    if network.n_points == 0 or network.n_measures == 0:
        raise NetworkError(f"{net_path}: the network is empty ({network.n_points} points, {network.n_measures} "
                           "measures); nothing to adjust")
    if not camera_files:
        raise AdjustIsisError("no camera given: pass the network's cubes (spiceinit'ed) or ISDs with --cameras")
    images = read_cameras(camera_files, network.metadata.get("target_name"))
    bodies = sorted({im.body.name for im in images})
    if len(bodies) > 1:
        raise AdjustIsisError(f"the cameras see different bodies ({', '.join(bodies)}): "
                              + "; ".join(f"{im.files[0]}: {im.body.name}" for im in images))
    given = load_serials(serials_csv, camera_files) if serials_csv is not None else {}
    keys = camera_keys_with_serials([im.image_id for im in images], [im.serial_number for im in images], given)
    match = match_serials(network, keys)
    if match.unmatched and require_all:
        s, n = next(iter(match.unmatched.items()))
        raise AdjustIsisError(
            f"{net_path}: serial number {s!r} ({n} measures) has no camera among --cameras "
            f"({len(match.unmatched)} such serial numbers); give its cube or ISD, or a file,serial line in --serials")
    if np.all(match.camera_of_image[network.measure_image] < 0):
        known = "; ".join(f"{Path(images[c].files[0]).name}: {', '.join(k)}" for c, k in enumerate(keys[:4]))
        raise AdjustIsisError(
            f"{net_path}: none of its {network.n_images} serial numbers (e.g. {str(network.image_ids[0])!r}) matches a "
            f"camera ({known}); give the network's cubes or ISDs, or map files to serials with --serials")
    return network, images, match


@dataclass(frozen=True)
class _Adjustable:
    """The part of the network with cameras, ready to adjust: points placed a priori where they can be."""

    cut: Any  # network.jigsaw cut: the sub-network and the camera of each of its images
    network: ControlNetwork  # the sub-network, image ids those of its cameras
    images: list[Any]  # SourceImage of each of its images
    cameras: list[Any]
    positions: np.ndarray
    rotations: np.ndarray
    triangulated: int  # points without a-priori coordinates, triangulated
    unplaced: np.ndarray  # (P,) bool, points with neither (ignored in the adjustment)
    outside: dict[str, int]  # measures beyond their image's pixels, per image id


def _adjustable(net_path: Path, network: ControlNetwork, images: list[Any], match: Any) -> _Adjustable:
    """Cut the network to the images with cameras; points without a-priori coordinates are triangulated."""
    from mercury_dem.network.build import triangulate_points
    from mercury_dem.network.jigsaw import cut_adjustable

    cut = cut_adjustable(network, match.camera_of_image, min_point_measures=2)
    sub = cut.network
    cams = [images[c] for c in cut.camera_index.tolist()]
    outside = _measures_outside(net_path, sub, cams)
    cameras = [im.camera for im in cams]
    positions = np.array([im.position for im in cams]).reshape(-1, 3)
    rotations = np.array([im.rotation for im in cams]).reshape(-1, 3, 3)
    apriori = np.array(sub.apriori_xyz, copy=True)
    missing = ~np.all(np.isfinite(apriori), axis=1)
    triangulated = 0
    if missing.any():
        xyz, _ = triangulate_points(sub.measure_point, sub.measure_image, sub.pixels(), cameras, positions,
                                    rotations, sub.n_points, datum_radius_m=images[0].body.datum_radius_m)
        apriori[missing] = xyz[missing]
        triangulated = int(np.sum(missing & np.all(np.isfinite(xyz), axis=1)))
    unplaced = ~np.all(np.isfinite(apriori), axis=1)
    sub = sub.replace(apriori_xyz=np.where(unplaced[:, None], 0.0, apriori), point_ignored=unplaced)
    sub = sub.replace(image_ids=np.array([im.image_id for im in cams]))
    return _Adjustable(cut, sub, cams, cameras, positions, rotations, triangulated, unplaced, outside)


_SUMMARY_KEYS = ("network", "out", "body", "images", "points", "measures", "iterations", "converged", "sigma0",
                 "rms_px", "initial_rms_px", "rejected", "rejected_points", "triangulated_points", "unplaced_points",
                 "unmatched_serials", "measures_outside_image", "unused_cameras", "cameras", "image_rms_px",
                 "bundleout", "isds", "isds_not_written", "flagged_images", "islands", "warning")


def _summary(net_path: Path, out_path: Path, report_path: Path, camera_files: Sequence[str | Path], network: ControlNetwork,
             job: _Adjustable, match: Any, adj: Any, result: Any) -> dict[str, Any]:
    """The summary of an adjust-isis run (the ISDs written are added by the caller)."""
    s = adj.summary
    body = job.images[0].body
    summary: dict[str, Any] = {
        "network": str(net_path), "out": str(out_path), "body": body.name,
        **{k: s[k] for k in ("images", "points", "measures", "iterations", "converged", "sigma0", "rms_px",
                             "initial_rms_px", "rejected")},
        "rejected_points": int(result.point_rejected.sum()),
        "triangulated_points": job.triangulated,
        "unplaced_points": int(job.unplaced.sum()),
        "unmatched_serials": match.unmatched,
        "measures_outside_image": job.outside,
        "unused_cameras": [str(camera_files[c]) for c in match.unused_cameras],
        "cameras": {im.image_id: {"file": im.files[0], "serial_number": im.serial_number,
                                  "distortion": im.camera.distortion_model} for im in job.images},
        "image_rms_px": {im.image_id: float(r) for im, r in zip(job.images, adj.image_rms_px)},
        "bundleout": str(report_path),
        "flagged_images": s["flagged_images"],
        "islands": s["islands"],
    }
    target = network.metadata.get("target_name")
    if target and target.strip().upper() != body.name:
        summary["warning"] = (f"the network's TargetName is {target!r} but its cameras see {body.name}; "
                              f"{body.name} (datum radius {body.datum_radius_m:.0f} m) was used")
    return summary


#: Above this fraction of an image's measures outside its pixels, the network was measured on
#: another version of the image (a full frame vs a crop or reduction): an error, not an adjustment.
OUTSIDE_IMAGE_LIMIT = 0.5


def _measures_outside(net_path: Path, sub: Any, cams: list[Any]) -> dict[str, int]:
    """Measures beyond an image's pixels (more than a pixel out), per image id; an error when most are."""
    counts: dict[str, int] = {}
    for k, im in enumerate(cams):
        sel = sub.measure_image == k
        px = sub.pixels()[sel]
        out = int(np.sum(~im.camera.in_image(px, margin=-1.0)))
        if out:
            counts[im.image_id] = out
        if out > OUTSIDE_IMAGE_LIMIT * max(1, int(sel.sum())):
            lo, hi = np.nanmin(px, axis=0), np.nanmax(px, axis=0)
            raise AdjustIsisError(
                f"{net_path}: {out} of the {int(sel.sum())} measures on {im.files[0]} lie outside its "
                f"{im.camera.samples} x {im.camera.lines} pixels (samples {lo[0] + 1:.0f}..{hi[0] + 1:.0f}, lines "
                f"{lo[1] + 1:.0f}..{hi[1] + 1:.0f}, ISIS 1-based): the network was measured on another version of "
                "this image (full frame vs crop or reduced cube?); give the cube the network was measured on")
    return counts


def _report_header(summary: dict[str, Any]) -> str:
    lines = [
        "mercury-dem adjust-isis",
        f"  network          {summary['network']}",
        f"  output           {summary['out']}",
        f"  body             {summary['body']}",
        f"  images           {summary['images']}",
        f"  points           {summary['points']} ({summary['triangulated_points']} triangulated, "
        f"{summary['unplaced_points']} without a-priori and not triangulable)",
        f"  measures         {summary['measures']}",
        f"  rejected         {summary['rejected']} measures, {summary['rejected_points']} points",
        f"  sigma0           {summary['sigma0']:.4f}",
        f"  residual RMS     {summary['rms_px']:.4f} px (a-priori {summary['initial_rms_px']:.4f} px)",
    ]
    for s, n in summary["unmatched_serials"].items():
        lines.append(f"  no camera for    {s} ({n} measures ignored)")
    for i, why in summary["isds_not_written"].items():
        lines.append(f"  no ISD for {i}: {why}")
    if "warning" in summary:
        lines.append(f"  warning: {summary['warning']}")
    return "\n".join(lines) + "\n\n"


def describe(summary: dict[str, Any]) -> str:
    """The printed summary."""
    text = (f"{summary['out']}: {summary['images']} images, {summary['points']} points, {summary['measures']} "
            f"measures; {summary['iterations']} iterations, sigma0 {summary['sigma0']:.3f}, residual RMS "
            f"{summary['rms_px']:.3f} px (a-priori {summary['initial_rms_px']:.3f}), {summary['rejected']} rejected")
    extra = [f"  no camera for {s}: {n} measures ignored" for s, n in summary["unmatched_serials"].items()]
    extra += [f"  no updated ISD for {i}: {why}" for i, why in summary["isds_not_written"].items()]
    extra += [f"  updated ISD {p}" for p in summary["isds"].values()]
    if "warning" in summary:
        extra.append(f"  warning: {summary['warning']}")
    return "\n".join([text, *extra, f"  report {summary['bundleout']}"])


__all__ = ["run_adjust_isis", "read_cameras", "load_serials", "describe", "AdjustIsisError"]
