"""What a pair's output folder records of how it was made, so that ``--resume`` can take it as it is.

After a pair's calibration files, ``batch-calibrate`` writes :data:`MARKER` (``.stereogeo-pair.json``) into
its folder, atomically and last: the options that change the results (:func:`pair_options`: stereogeo's
version, the model's file name and SHA-256, ``--baseline``, ``--pinhole``, ``--no-lines``, ``--no-exif``),
the formats written, each file's SHA-256, the two input images' names and SHA-256, the pair's JSON report
and its time. With ``--same-rig`` the evidence the joint pass needs (focal lengths, gravity, pose,
matches) is kept beside it in :data:`EVIDENCE` (``.stereogeo-evidence.npz``). A folder is a complete
calibration for a run (:func:`completed_pair`) when its marker is there, records the same options and
input images, covers the run's formats, and every file it lists is there with its SHA-256; otherwise the
pair is calibrated again. docs/batch.md, "Interrupting and resuming".
"""

from __future__ import annotations

import io
import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from stereogeo_cli import __version__
from stereogeo_cli.fuse.assemble import CameraEstimate
from stereogeo_cli.network.runtime import file_sha256
from stereogeo_cli.options import PairOptions
from stereogeo_cli.rig.evidence import PairEvidence

MARKER = ".stereogeo-pair.json"
EVIDENCE = ".stereogeo-evidence.npz"
MARKER_VERSION = 1


def model_identity(model: str | os.PathLike | None) -> dict[str, str | None]:
    """The report's ``model`` block of the model a run uses: its file name and SHA-256 (None if unreadable:
    the run itself reports why)."""
    from stereogeo_cli.network.runtime import default_model_path

    path = Path(model) if model is not None else default_model_path()
    try:
        digest = file_sha256(path)
    except OSError:
        digest = None
    return {"file": path.name, "sha256": digest}


def pair_options(model: dict, pair: PairOptions) -> dict:
    """The options a pair's results depend on, as its marker records them (``model``: the report's block).
    ``rotate`` is recorded where it is not 0, so that the markers of unturned pairs name the options alone
    that they depend on."""
    options = {
        "stereogeo": __version__,
        "model": {"file": model.get("file"), "sha256": model.get("sha256")},
        "baseline_m": None if pair.baseline_m is None else float(pair.baseline_m),
        "pinhole": bool(pair.pinhole),
        "lines": bool(pair.lines),
        "exif": bool(pair.exif),
    }
    return options | ({"rotate_deg": int(pair.rotate)} if pair.rotate else {})


def _inputs(left: Path, right: Path) -> dict[str, dict[str, str]]:
    return {
        side: {"name": path.name, "sha256": file_sha256(path)}
        for side, path in (("left", left), ("right", right))
    }


def marker_files(folder: Path) -> set[str]:
    """The files an existing marker in ``folder`` lists (none if there is no readable one)."""
    try:
        files = json.loads((folder / MARKER).read_text(encoding="utf-8")).get("files") or {}
        return {
            name
            for name in files
            if isinstance(name, str) and "/" not in name and name not in ("", ".", "..")
        }
    except (OSError, ValueError, AttributeError):
        return set()


def write_pair_files(folder: Path, calibration, formats, evidence, inputs: tuple[Path, Path], options: dict,
                     report: dict, started: float, figures=None) -> float:  # fmt: skip
    """Write a pair's calibration files (and ``evidence``, a PairEvidence or None), then its marker; return
    the pair's time in ms (from ``started``, a ``time.perf_counter()``) as the marker records it.
    ``figures``: what its report.html draws (:class:`~stereogeo_cli.report.ReportInputs`).

    An earlier marker goes first (a folder half rewritten is never taken as complete), and the files it
    listed that this run does not write again are removed after the new marker is in place.
    """
    import time

    from stereogeo_cli.io import write_calibration
    from stereogeo_cli.io.atomic import write_files_atomically

    earlier = marker_files(folder)
    try:
        (folder / MARKER).unlink(missing_ok=True)
    except OSError:
        pass  # not a folder, or not writable: write_calibration says so
    written = write_calibration(folder, calibration, formats, figures=figures)
    if evidence is not None:
        written += write_files_atomically(folder, {EVIDENCE: evidence_bytes(evidence)})
    time_ms = (time.perf_counter() - started) * 1e3
    marker = {
        "marker": MARKER_VERSION,
        "options": options,
        "formats": list(dict.fromkeys(formats)),
        "inputs": _inputs(*inputs),
        "files": {path.name: file_sha256(path) for path in written},
        "time_ms": time_ms,
        "report": report,
    }
    write_files_atomically(folder, {MARKER: json.dumps(marker, indent=1, allow_nan=False) + "\n"})
    for name in earlier - set(marker["files"]) - {MARKER}:
        (folder / name).unlink(missing_ok=True)
    return time_ms


def completed_pair(
    folder: Path, inputs: tuple[Path, Path], options: dict, formats, evidence: bool
) -> tuple[dict[str, Any], float, Any] | None:
    """``(report, time_ms, evidence or None)`` of a pair folder that holds a complete calibration made with
    ``options`` from these input images, in (at least) ``formats`` and, if ``evidence``, with the
    ``--same-rig`` evidence; None if it does not (the pair is to be calibrated again)."""
    try:
        marker = json.loads((folder / MARKER).read_text(encoding="utf-8"))
        if marker.get("marker") != MARKER_VERSION or marker.get("options") != options:
            return None
        if not set(formats) <= set(marker["formats"]) or (evidence and EVIDENCE not in marker["files"]):
            return None
        for name, digest in marker["files"].items():
            if "/" in name or file_sha256(folder / name) != digest:
                return None
        if marker["inputs"] != _inputs(*inputs):
            return None
        report, time_ms = marker["report"], float(marker["time_ms"])
        if not isinstance(report, dict):
            return None
        kept = read_evidence((folder / EVIDENCE).read_bytes()) if evidence else None
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    return report, time_ms, kept


def existing_results(out_dir: Path, names, summary_stem: str, rig_folder: str | None) -> list[Path]:
    """What ``out_dir`` already holds that a run would write: the non-empty folders of the pairs ``names``,
    the summary files ``summary_stem``.csv/.json, and the non-empty ``rig_folder``."""
    found = []
    folders = [out_dir / name for name in names] + ([out_dir / rig_folder] if rig_folder else [])
    for folder in folders:
        try:
            if folder.is_dir() and any(folder.iterdir()):
                found.append(folder)
        except OSError:
            found.append(folder)
    found += [p for p in (out_dir / f"{summary_stem}.csv", out_dir / f"{summary_stem}.json") if p.exists()]
    return found


def remove_leftovers(out_dir: Path, names, summary_stem: str, rig_folder: str | None) -> list[Path]:
    """Remove what a run killed mid-write left of its atomic writes (their ``.<name>.XXXXXXXX.tmp`` files,
    :func:`~stereogeo_cli.io.atomic.remove_leftovers`): in the folders of the pairs ``names`` and in
    ``rig_folder``, and in ``out_dir`` those of the summary files ``summary_stem``.csv/.json (another
    shard's may be in the making). Returns the files removed."""
    from stereogeo_cli.io.atomic import remove_leftovers as remove

    removed = remove(out_dir, [f"{summary_stem}.csv", f"{summary_stem}.json"])
    for name in [*names, *([rig_folder] if rig_folder else [])]:
        removed += remove(out_dir / name)
    return removed


# ---------------------------------------------------------------------------------- --same-rig evidence


def evidence_bytes(ev) -> bytes:
    """A PairEvidence as an .npz file's bytes (exact: every number as float64 or int64)."""
    left, right = ev.cameras
    priors = [c.focal_prior for c in ev.cameras]
    arrays = {
        "size_left": np.array((left.width, left.height), dtype=np.int64),
        "size_right": np.array((right.width, right.height), dtype=np.int64),
        "focal": np.array([c.focal_px for c in ev.cameras], dtype=float),
        "focal_sigma": np.array([c.sigma["focal_px"] for c in ev.cameras], dtype=float),
        "gravity_left": np.asarray(left.gravity_up, dtype=float),
        "gravity_right": np.asarray(right.gravity_up, dtype=float),
        "R": np.asarray(ev.R, dtype=float),
        "t_direction": np.asarray(ev.t_direction, dtype=float),
        "pose_source": np.array(ev.pose_source),
        "baseline_m": np.array(ev.baseline_m, dtype=float),
        "matches_left": np.asarray(ev.matches_left, dtype=float),
        "matches_right": np.asarray(ev.matches_right, dtype=float),
        "distortion": np.array([c.division_k for c in ev.cameras], dtype=float),
        "focal_prior": np.array([p if p is not None else (np.nan, np.nan) for p in priors], dtype=float),
        "has_prior": np.array([p is not None for p in priors]),
        "sigma_gravity_deg": np.array([c.sigma.get("gravity_deg", math.inf) for c in ev.cameras]),
        "sigma_rotation_deg": np.array(ev.sigma_rotation_deg, dtype=float),
        "sigma_direction_deg": np.array(ev.sigma_direction_deg, dtype=float),
        "sigma_baseline_rel": np.array(np.nan if ev.sigma_baseline_rel is None else ev.sigma_baseline_rel),
        "lens": np.array(bool(ev.lens)),
    }
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def read_evidence(data: bytes):
    """The PairEvidence of :func:`evidence_bytes` (an older file without the reported sigmas gets the
    defaults: --same-rig does not use them)."""
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        a = {key: z[key] for key in z.files}

    def pair(values, kind=float):
        return tuple(kind(v) for v in values)

    priors = tuple(pair(p) if has else None for p, has in zip(a["focal_prior"], a["has_prior"], strict=True))
    gravity_sigmas = pair(a["sigma_gravity_deg"]) if "lens" in a else (math.inf, math.inf)
    cameras = tuple(
        CameraEstimate(
            float(a["focal"][i]),
            *pair(a[f"size_{side}"], int),
            a[f"gravity_{side}"],
            {"focal_px": float(a["focal_sigma"][i]), "gravity_deg": gravity_sigmas[i]},
            division_k=float(a["distortion"][i]),
            focal_prior=priors[i],
        )  # fmt: skip
        for i, side in enumerate(("left", "right"))
    )
    optional = {}
    if "lens" in a:
        baseline_sigma = float(a["sigma_baseline_rel"])
        optional = {
            "sigma_rotation_deg": float(a["sigma_rotation_deg"]),
            "sigma_direction_deg": float(a["sigma_direction_deg"]),
            "sigma_baseline_rel": None if np.isnan(baseline_sigma) else baseline_sigma,
            "lens": bool(a["lens"]),
        }
    return PairEvidence(
        cameras=cameras,
        R=a["R"],
        t_direction=a["t_direction"],
        pose_source=str(a["pose_source"]),
        baseline_m=float(a["baseline_m"]),
        matches_left=a["matches_left"],
        matches_right=a["matches_right"],
        **optional,
    )
