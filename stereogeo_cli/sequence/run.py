"""``calibrate-sequence``: one rig's calibration from a sequence of its frame pairs.

The stages, in order:

1. the frame pairs (up to about 25, evenly spaced) are calibrated as ``calibrate`` does
   (:class:`~stereogeo_cli.pipeline.Calibrator`): their focal lengths, lens, gravity, R, T and learned
   baseline are the per-pair evidence; every image's features and line segments are found;
2. COLMAP reconstructs the frames with the two cameras as one rig, started from that evidence, and its
   last bundle adjustment gives each camera's focal length with a sigma (``colmap.py``);
3. the adjustment's focal lengths are combined with the pairs' by their sigmas (``evidence.py``), each
   frame's gravity is rotated into the reconstruction's world and combined into one world up with the
   one the vertical line segments give, and the metric scale comes from ``--baseline`` or the pairs';
4. the world is turned so that its z axis points up and scaled to metres, and the rig's calibration, the
   report's ``sequence`` block, the left camera's trajectory and the COLMAP model are returned for writing.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from stereogeo_cli.errors import CalibrationFailed, StereoGeoError
from stereogeo_cli.fuse.assemble import (
    CameraEstimate,
    calibration,
    finite,
    focal_sigmas,
    measured_pose_report,
)
from stereogeo_cli.geometry import gravity_angle, rotation_angle
from stereogeo_cli.io import StereoCalibration
from stereogeo_cli.io.text import plural
from stereogeo_cli.pipeline import with_rotation_noted
from stereogeo_cli.refine.lines import detect_segments
from stereogeo_cli.rig.combine import FocalEstimate, FocalWidening, pairs_focals, reported, widenings
from stereogeo_cli.rig.evidence import PairEvidence
from stereogeo_cli.rig.start import rig_baseline, rig_pose
from stereogeo_cli.sequence import colmap
from stereogeo_cli.sequence.evidence import (
    attitude,
    combine_adjusted_focal,
    combine_ups,
    frame_attitudes,
    rig_sigmas_deg,
    up_from_segments,
    world_up,
)
from stereogeo_cli.sequence.evidence import default_conf as evidence_conf
from stereogeo_cli.sequence.keyframes import with_frames_counted
from stereogeo_cli.sequence.options import SequenceOptions
from stereogeo_cli.sequence.sources import FramePair, FrameSource
from stereogeo_cli.settings import resolve

default_conf = {
    # pairs calibrated as ``calibrate`` does, at most about this many (evenly spaced): the evidence of the
    # pairs (focal lengths, lens, gravity, R, T, scale) to start and combine with COLMAP's
    "max_pairs_calibrated": 25,
    # line segments of every image for the world's up (evidence.up_from_segments), found on a copy of this
    # short side, those of at least this share of it
    "segments_short_side": 480,
    "segments_min_length": 0.05,
    "colmap": {},  # overrides of stereogeo_cli.sequence.colmap.default_conf
    "evidence": {},  # overrides of stereogeo_cli.sequence.evidence.default_conf
}


# what each stage is expected to take, for the progress's estimate of the time left (which scales it by the
# pace of the stages already done): seconds per frame pair kept and per pair the network calibrates, as
# measured on 640 x 360 frames with two cores (docs/sequence.md, "Speed and limits")
STAGE_SECONDS = {
    "reading and calibrating frame pairs": (0.07, 0.8),  # (per frame, per pair calibrated)
    "COLMAP: matching the frames": (0.15, 0.0),
    "COLMAP: mapping": (0.29, 0.0),
    "COLMAP: bundle adjustment": (0.26, 0.0),
    "COLMAP: cross-checking the adjustment": (0.46, 0.0),
    "combining the frames' evidence": (0.01, 0.0),
}


def expected_seconds(frames: int, calibrated: int) -> dict[str, float]:
    """What each stage from the frames' reading on is expected to take (:data:`STAGE_SECONDS`)."""
    return {
        stage: frames * per_frame + calibrated * per_pair
        for stage, (per_frame, per_pair) in STAGE_SECONDS.items()
    }


# ``progress(done, total, stage)``: ``done`` of ``total`` items (None: not counted) of the stage in flight;
# a ``stage`` (what it does, e.g. "COLMAP: mapping") starts a new stage
Progress = Callable[[int, "int | None", "str | None"], None]


@dataclass
class SequenceResult:
    """A sequence's calibration: the rig's files (``calibration``), the world-aligned COLMAP model and
    the left camera's trajectory (time, [4 x 4] world←camera in metres, z up) per registered frame."""

    calibration: StereoCalibration
    reconstruction: Any  # pycolmap.Reconstruction, metric, z up (None: the pairs alone calibrated the rig)
    trajectory: list[tuple[float, np.ndarray]]

    def report(self) -> dict:
        return self.calibration.to_report()


def _write_frame(
    images: Path, frame: FramePair, file_name: str, found: tuple[dict, dict], conf: dict
) -> None:
    """The frame's two images as PNG files of the workspace (COLMAP reads files), and their features and
    line segments (``found``: the dicts they go into, by image name)."""
    features, segments = found
    max_features = resolve(colmap.default_conf, conf["colmap"])["max_features"]
    for sensor, image in zip(colmap.SENSORS, (frame.left, frame.right), strict=True):
        name = f"{sensor}/{file_name}"
        features[name] = colmap.image_features(image, max_features)
        segments[name] = detect_segments(image, conf["segments_short_side"])
        bgr = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
        ok, data = cv2.imencode(".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, 1])
        if not ok:
            raise StereoGeoError(f"frame {frame.name}: could not be encoded for COLMAP")
        (images / sensor / file_name).write_bytes(data.tobytes())


def _check_size(frame: FramePair, sizes: tuple | None) -> tuple:
    now = (frame.left.shape[:2], frame.right.shape[:2])
    if sizes is not None and now != sizes:
        raise StereoGeoError(
            f"frame {frame.name} is {now[0][1]}x{now[0][0]} / {now[1][1]}x{now[1][0]} px, the first frame "
            f"{sizes[0][1]}x{sizes[0][0]} / {sizes[1][1]}x{sizes[1][0]}: a sequence's frames must keep "
            "their size"
        )
    return now


@dataclass
class FrameReadings:
    """What reading a source gave: the frames (without their pixels), the pairs' readings (for the pairs
    calibrated: every ``stride``-th frame, and not those that failed), the image sizes ((h, w) left, right),
    a warning per pair that failed, and every image's features for COLMAP (:func:`colmap.image_features`,
    by image name)."""

    frames: list[FramePair]
    readings: dict[int, PairEvidence]  # by frame index
    sizes: tuple
    warnings: list[str]
    features: dict
    segments: dict  # per image name its line segments [N x 4] (x1, y1, x2, y2), stereogeo's pixels
    # what each camera's focal length from the pairs reports beyond their combined sigma
    widenings: tuple[FocalWidening, FocalWidening] = (FocalWidening(), FocalWidening())


def read_frames(
    source: FrameSource, calibrator, images: Path, *, baseline_m: float | None,
    progress: Progress | None = None, stop=None, conf: dict | None = None, rotate: int = 0,
) -> FrameReadings:  # fmt: skip
    """Write each frame of ``source`` into ``images/{left,right}/``, detect its features, and calibrate
    its pair as ``calibrate`` does: every pair of a sequence of up to ``max_pairs_calibrated``, else evenly
    spaced pairs up to about that many (they are evidence to combine, and each costs a calibration), each
    turned by ``rotate`` degrees as ``Calibrator.calibrate`` does."""
    conf = resolve(default_conf, conf)
    for sensor in colmap.SENSORS:
        (images / sensor).mkdir(parents=True, exist_ok=True)
    frames: list[FramePair] = []
    readings: dict[int, PairEvidence] = {}
    warnings: list[str] = []
    features: dict = {}
    segments: dict = {}
    sizes = None
    total = source.count()
    stride = max(1, math.ceil(total / conf["max_pairs_calibrated"])) if total else 1
    if total and hasattr(progress, "expect"):  # the time left from here on, shown by the progress
        progress.expect(expected_seconds(total, math.ceil(total / stride)))
    if progress is not None:
        progress(0, total, "reading and calibrating frame pairs")
    for frame in source:
        if stop is not None and stop.requested:
            raise colmap.Cancelled()
        sizes = _check_size(frame, sizes)
        _write_frame(images, frame, f"{frame.index:06d}.png", (features, segments), conf)
        if len(frames) % stride == 0:
            try:
                result = calibrator.calibrate(frame.left, frame.right, baseline_m=baseline_m, rotate=rotate)
                readings[frame.index] = PairEvidence.from_result(result, matches=False)
            except CalibrationFailed as error:
                warnings.append(f"frame {frame.name}: {error}")
        frames.append(FramePair(frame.index, frame.time, frame.name, np.empty(0), np.empty(0)))
        if progress is not None:
            progress(len(frames), total)
    if len(frames) < 2:
        read = len(frames)
        raise StereoGeoError(f"{source.description}: a sequence needs 2 frame pairs or more ({read} read)")
    if not readings:
        raise CalibrationFailed("no frame pair of the sequence could be calibrated")
    widened = widenings(calibrator, list(readings.values()))
    return FrameReadings(frames, readings, sizes, warnings, features, segments, widened)


def _start(read: FrameReadings, pinhole: bool) -> tuple:
    """The adjustment's start: each camera's focal length from the pairs (as a rig reports it:
    :mod:`stereogeo_cli.rig.combine`), the lens model (a radial term where most pairs fitted one), and the
    rig's R and T (:func:`~stereogeo_cli.rig.start.rig_pose`, at the pairs' median learned length)."""
    evidence = list(read.readings.values())
    radial = not pinhole and sum(e.lens for e in evidence) * 2 > len(evidence)
    focals: list[FocalEstimate] = [
        reported(estimate, widening)
        for estimate, widening in zip(pairs_focals(evidence), read.widenings, strict=True)
    ]
    starts = tuple(
        colmap.CameraStart(f.focal_px, w, h, radial) for f, (h, w) in zip(focals, read.sizes, strict=True)
    )
    R, direction = rig_pose(evidence)
    T = direction * float(np.median([e.baseline_m for e in evidence]))
    return starts, focals, R, T


def calibrate_frames(
    read: FrameReadings,
    workspace: Path,
    *,
    baseline_m: float | None,
    pinhole: bool,
    model_file: tuple[str | None, str | None],
    warnings: list[str],
    conf: dict | None = None,
    stop=None,
    progress: Progress | None = None,
) -> SequenceResult:
    """Stages 2–4 on frames already written into ``workspace/images`` and read as pairs."""
    frames, readings, sizes = read.frames, read.readings, read.sizes
    timing: dict[str, float] = {}
    notes = [*warnings, *read.warnings]
    start = time.perf_counter()
    starts, pair_focals, R0, T0 = _start(read, pinhole)
    conf = resolve(default_conf, conf)
    try:
        model = colmap.reconstruct(
            workspace, starts, R0, T0, conf["colmap"], stop, read.features, progress=progress
        )
    except CalibrationFailed as error:  # a static rig, or views that share nothing: the pairs alone
        notes.append(f"{error}; the calibration is the pairs' combined")
        notes.append(
            "the motion does not fix the focal length (no model to adjust): the pairs' readings are kept"
        )
        return _pairs_only(
            frames, readings, sizes, starts, pair_focals, R0, T0, baseline_m, model_file, notes
        )
    timing["colmap"] = (time.perf_counter() - start) * 1e3
    if progress is not None:
        progress(0, None, "combining the frames' evidence")
    # the frames' own spread, in the reconstruction's own world (before it is aligned)
    measured = model.centre is not None
    rig_sigmas = rig_sigmas_deg(_rig_spread(model), model.cameras, sizes, conf["evidence"], measured)
    by_index = {f"{f.index:06d}.png": f for f in frames}
    registered = {int(name[:6]): pose for name, pose in model.cam_from_world.items()}
    partial = resolve(evidence_conf, conf["evidence"])["partial_registration_share"]
    if len(registered) < partial * len(frames):
        rig_sigmas = _covering_the_pairs(rig_sigmas, model, R0, T0)
    up, up_sigma_deg, used = world_up(readings, registered, model.R, conf["evidence"])
    if up is None:  # no frame's gravity could be read: the first frame's image up stands in, unweighed
        first = registered[min(registered)]
        up = -first[:3, :3].T[:, 1]
        notes.append("no frame's gravity could be read: the world's z axis is the first frame's image up")
    readings_up = (up, up_sigma_deg, used)
    up, up_sigma_deg, segments_up = _with_vertical_segments(model, read, readings_up, conf, notes)
    baseline, scale_source, baseline_sigma = rig_baseline(list(readings.values()), baseline_m)
    to_output = colmap.align_world(model, up, baseline / float(np.linalg.norm(model.T)))
    cam_from_world = {i: colmap.cam_from_new_world(pose, to_output) for i, pose in registered.items()}
    attitudes = frame_attitudes(cam_from_world, np.array([0.0, 0.0, 1.0]), model.R)
    span = _rotation_span(cam_from_world)
    travel = _travel(cam_from_world) / baseline
    motion = span, travel, len(registered) / len(frames)
    focals = _focals(model, pair_focals, motion, conf["evidence"], notes)
    trajectory = [
        (by_index[f"{i:06d}.png"].time, np.linalg.inv(cam_from_world[i])) for i in sorted(cam_from_world)
    ]
    notes.extend(_model_notes(model, len(frames), len(registered), focals))
    calibration = _assemble(
        frames, model, focals, attitudes, (up, up_sigma_deg, used, readings_up[1], segments_up), span,
        baseline, (scale_source, baseline_sigma), model_file, notes, timing,
        sizes, rig_sigmas,
    )  # fmt: skip
    return SequenceResult(calibration, model.reconstruction, trajectory)


def _focals(model, pair_focals, motion: tuple, conf: dict, notes: list[str]) -> list:
    """Each camera's focal length, the adjustment's combined with the pairs'
    (:func:`~stereogeo_cli.sequence.evidence.combine_adjusted_focal`); ``motion``: the rig's rotation span
    (degrees), its travel (rig baselines) and the share of the frames registered. What the combination
    decided is noted in ``notes``."""
    span, travel, share = motion
    focals = [
        combine_adjusted_focal(
            adjusted,
            FocalEstimate(pf.focal_px, pf.sigma_px),
            span,
            conf,
            travel_baselines=travel,
            registered_share=share,
        )  # fmt: skip
        for adjusted, pf in zip(model.cameras, pair_focals, strict=True)
    ]
    if any(f.pairs_left_out for f in focals):
        notes.append("the pairs' reading of the focal length disagrees with the adjustment's: left out")
    if any(f.partial for f in focals):
        notes.append(
            f"the adjustment registered {share:.0%} of the frames: its focal length is theirs alone, and its "
            "sigma takes in how far the pairs' reading lies from it"
        )
    return focals


def _covering_the_pairs(rig_sigmas: tuple[float, float], model, R0: np.ndarray, T0: np.ndarray) -> tuple:
    """R's and T's direction's sigmas (degrees) at least as wide as the adjustment's R and T lie from the
    pairs' (``R0``, ``T0``): the adjustment of part of the frames only can be sharp and wrong there, as
    its focal length can (``partial_registration_share``)."""
    turn = math.degrees(rotation_angle(model.R @ R0.T))
    direction = math.degrees(float(gravity_angle(model.T, T0)))  # the angle between two directions
    return max(rig_sigmas[0], turn), max(rig_sigmas[1], direction)


def _model_notes(model, frames: int, registered: int, focals) -> list[str]:
    """What the report says of the model: a mapping broken into several models, frames left unregistered,
    and a motion that does not fix the focal lengths (and what is reported instead)."""
    notes = []
    if model.models > 1:
        notes.append(f"the mapping broke the sequence into {model.models} models: the largest is used")
    if frames > registered:
        notes.append(f"{frames - registered} of {plural(frames, 'frame')} could not be registered")
    if not all(f.observable for f in focals):
        kept = (
            "the pairs' readings are kept"
            if all(f.adjustment_weight == 0.0 for f in focals)
            else "the adjustment's and the pairs' readings are combined by their sigmas"
        )
        notes.append(f"the motion does not fix the focal length (too little rotation): {kept}")
    return notes


def _rig_spread(model) -> tuple[float, float]:
    """R's and T's direction's 1-sigma from the frames (degrees): the widest of the right camera's poses
    located alone (:func:`colmap.rig_sigmas`), the left-out stretches' jackknife, the robust
    adjustment's parting (:class:`colmap.RobustReading`) and the other principal points' parting
    (:class:`colmap.CentreReading`: where they trade with R, R's sigma says so)."""
    readings = [colmap.rig_sigmas(model)]
    if model.left_out is not None:
        readings.append((model.left_out.rotation_sigma_deg, model.left_out.direction_sigma_deg))
    if model.robust is not None:
        readings.append((model.robust.rotation_deg, model.robust.direction_deg))
    if model.centre is not None:
        readings.append((model.centre.rotation_deg, model.centre.direction_deg))
    return max(r[0] for r in readings), max(r[1] for r in readings)


def _with_vertical_segments(model, read: FrameReadings, readings_up: tuple, conf: dict, notes: list[str]):
    """The world's up from the readings combined with the one the images' vertical line segments give
    (:func:`evidence.up_from_segments`), by their sigmas, where the two agree within 3 combined sigmas.
    Returns (up, its sigma in degrees, segments used)."""
    up, sigma, _ = readings_up
    if sigma is None:
        return up, sigma, 0
    (h, w), _ = read.sizes
    normals, owners = colmap.segment_normals(
        model.reconstruction, read.segments, conf["segments_min_length"] * min(h, w)
    )
    found, information, count = up_from_segments(normals, owners, up, conf["evidence"])
    if found is None:
        return up, sigma, 0
    combined, combined_sigma, apart = combine_ups(up, sigma, found, information)
    if apart > 3:
        notes.append(
            f"the vertical line segments' up is {apart:.1f} sigmas from the frames' gravity: left out"
        )
        return up, sigma, 0
    return combined, combined_sigma, count


def _pairs_only(frames, readings, sizes, starts, pair_focals, R, T, baseline_m, model_file, notes):
    """The calibration where COLMAP could make nothing of the frames: each camera's focal length, R and T
    combined over the pairs (as the adjustment's start), each frame's attitude its own reading, and no
    trajectory or model. R's and T's sigmas are a typical pair's (the frames of one scene share their
    error)."""
    cameras = tuple(
        CameraEstimate(s.focal_px, w, h, None, {"focal_px": math.inf})
        for s, (h, w) in zip(starts, sizes, strict=True)
    )
    focals = [
        combine_adjusted_focal(camera, FocalEstimate(pf.focal_px, pf.sigma_px), None)
        for camera, pf in zip(cameras, pair_focals, strict=True)
    ]
    model = colmap.SequenceModel(None, cameras, R, T, {}, 0, 0, math.nan)
    attitudes = {
        index: {side: attitude(g) for side, g in zip(("left", "right"), e.gravity, strict=True)}
        for index, e in readings.items()
    }
    evidence = list(readings.values())
    baseline, scale_source, baseline_sigma = rig_baseline(evidence, baseline_m)
    rig_sigmas = (
        float(np.median([e.sigma_rotation_deg for e in evidence])),
        float(np.median([e.sigma_direction_deg for e in evidence])),
    )
    calibration = _assemble(
        frames, model, focals, attitudes, (None, None, 0, None, 0), None, baseline,
        (scale_source, baseline_sigma), model_file, notes, {}, sizes, rig_sigmas,
    )  # fmt: skip
    return SequenceResult(calibration, None, [])


def _rotation_span(cam_from_world: dict[int, np.ndarray]) -> float:
    """The largest rotation (degrees) between any registered frame's camera and the first's."""
    poses = [cam_from_world[i][:3, :3] for i in sorted(cam_from_world)]
    return max(math.degrees(rotation_angle(p @ poses[0].T)) for p in poses)


def _travel(cam_from_world: dict[int, np.ndarray]) -> float:
    """The largest distance between any registered frame's camera centre and the first's (the world's
    units)."""
    centres = [-pose[:3, :3].T @ pose[:3, 3] for _, pose in sorted(cam_from_world.items())]
    return max(float(np.linalg.norm(c - centres[0])) for c in centres)


def _assemble(frames, model, focals, attitudes, up, span, baseline, scale, model_file, notes, timing,
              sizes, rig_sigmas) -> StereoCalibration:  # fmt: skip
    """The rig's :class:`StereoCalibration` (:func:`stereogeo_cli.fuse.assemble.calibration`) with the
    report's ``pose`` and ``sequence`` blocks."""
    cameras = tuple(
        CameraEstimate(
            f.focal_px,
            w,
            h,
            None,
            focal_sigmas(f.focal_px, h, f.sigma_px / f.focal_px),
            camera.principal_point if camera.principal_point_refined else None,
        )  # fmt: skip
        for f, (h, w), camera in zip(focals, sizes, model.cameras, strict=True)
    )
    D = tuple(np.array([*c.radial, 0.0, 0.0, 0.0]) if any(c.radial) else np.zeros(0) for c in model.cameras)
    scale_source, baseline_sigma = scale
    T = model.T / np.linalg.norm(model.T) * baseline
    pose = {
        **measured_pose_report("sequence", model.R, *rig_sigmas),
        "sigma_baseline_rel": baseline_sigma,
    }
    sequence = _sequence_block(frames, model, focals, attitudes, up, span, scale)
    return calibration(
        cameras, (model.R, T, D, pose), scale_source, model_file, notes, matches=(model.points, model.points),
        more={"sequence": sequence}, timing_ms=timing,
    )  # fmt: skip


def _sequence_block(frames, model, focals, attitudes, up, span, scale) -> dict:
    """The report's ``sequence`` block (docs/sequence.md, "Outputs")."""
    scale_source, baseline_sigma = scale
    up_world, up_sigma_deg, up_used, readings_sigma_deg, segments_used = up
    by_index = {f.index: f for f in frames}
    return {
        "frames_read": len(frames),
        "frames_registered": len(model.cam_from_world),
        "models": model.models,
        "points": model.points,
        "reprojection_error_px": finite(model.reprojection_error_px),
        "rotation_span_deg": span,
        "focal_observable": all(f.observable for f in focals),
        # the stretches of frames left out one at a time: their jackknife sigmas and the row check
        "left_out": None if model.left_out is None else model.left_out.to_report(),
        # the last adjustment with a robust loss: how far it parts from the least-squares one
        "robust": None if model.robust is None else model.robust.to_report(),
        # the last adjustment with the principal points treated the other way: how far it parts
        "principal_point_reading": None if model.centre is None else model.centre.to_report(),
        "adjustment_profile_sigma_rel": finite(model.profile_sigma_rel),
        "evidence": {
            "focal": {side: f.to_report() for side, f in zip(("left", "right"), focals, strict=True)},
            "gravity": {
                "readings_used": up_used,
                "readings_sigma_deg": readings_sigma_deg,
                "vertical_segments_used": segments_used,
                "sigma_deg": up_sigma_deg,
            },
            "scale": {"source": scale_source, "sigma_rel": baseline_sigma},
            "lens": {
                side: {
                    "k1": c.radial[0],
                    "k2": c.radial[1],
                    "principal_point": list(c.principal_point or ()),
                    "principal_point_refined": c.principal_point_refined,
                }
                for side, c in zip(("left", "right"), model.cameras, strict=True)
            },
        },
        # the output world: z up (gravity), the first registered frame's left camera at the origin looking
        # along +y, metres
        "world": {"up": [0.0, 0.0, 1.0], "sigma_up_deg": up_sigma_deg},
        "frames": [
            {"index": i, "name": by_index[i].name, "time": by_index[i].time, **attitudes[i]}
            for i in sorted(attitudes)
        ],
    }


def calibrate_sequence(
    source: FrameSource,
    calibrator,
    options: SequenceOptions | None = None,
    *,
    progress: Progress | None = None,
    stop=None,
) -> SequenceResult | None:
    """Calibrate the rig of ``source``'s frames (see the module's docstring for the stages).

    ``calibrator``: a :class:`~stereogeo_cli.pipeline.Calibrator` (one network session for every pair);
    ``options``: the baseline, ``--pinhole``, ``--rotate`` (degrees to turn each pair clockwise before the
    network reads it: a rig upside down, 180), the workspace (a folder for COLMAP's images and database;
    None: a temporary one, removed after) and the stages' settings;
    ``stop``: a :class:`~stereogeo_cli.jobs.interrupt.Stop`: once it is requested the run ends after the
    frame or COLMAP stage in flight and returns None (nothing half done is returned).
    """
    options = options or SequenceOptions()
    pair, conf = options.pair, options.conf
    temporary = options.workspace is None
    folder = (
        Path(tempfile.mkdtemp(prefix="stereogeo-sequence-")) if temporary else _workspace(options.workspace)
    )
    try:
        read = read_frames(
            source, calibrator, folder / "images", baseline_m=pair.baseline_m, progress=progress, stop=stop,
            conf=conf, rotate=pair.rotate,
        )  # fmt: skip
        model_file = (calibrator.model_path.name, calibrator.network.model_sha256)
        result = calibrate_frames(
            read, folder, baseline_m=pair.baseline_m, pinhole=pair.pinhole, model_file=model_file,
            warnings=list(source.warnings), conf=conf, stop=stop, progress=progress,
        )  # fmt: skip
        if result is not None:
            result.calibration = with_rotation_noted(result.calibration, pair.rotate)
            # the frames read, kept (by keyframes, where the source chose them) and registered
            result.calibration = with_frames_counted(result.calibration, source, len(read.frames))
        return result
    except colmap.Cancelled:
        return None
    finally:
        if temporary:
            shutil.rmtree(folder, ignore_errors=True)


def _workspace(workspace: str | Path) -> Path:
    """The folder the user gave for COLMAP's work, made if needed; one that cannot be is an input error."""
    folder = Path(workspace)
    if folder.exists() and not folder.is_dir():
        raise StereoGeoError(f"--workspace {folder} is a file, not a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise StereoGeoError(f"cannot create the workspace {folder}: {exc.strerror or exc}") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise StereoGeoError(f"the workspace {folder} is not writable")
    return folder


def trajectory_tum(trajectory: list[tuple[float, np.ndarray]]) -> str:
    """The left camera's trajectory in the TUM format: per frame ``time tx ty tz qx qy qz qw`` (seconds,
    metres; the camera's position and orientation in the world, z up)."""
    from stereogeo_cli.geometry import quaternion_from_rotation

    lines = ["# time tx ty tz qx qy qz qw (left camera in the world: z up, metres)"]
    for stamp, world_from_cam in trajectory:
        w, x, y, z = quaternion_from_rotation(world_from_cam[:3, :3])
        t = world_from_cam[:3, 3]
        lines.append(" ".join(f"{v:.9f}" for v in (stamp, *t, x, y, z, w)))
    return "\n".join(lines) + "\n"


SEQUENCE_FILES = ("trajectory.txt", "sparse")  # written beside the calibration's files


def check_output_folder(out_dir: str | Path, overwrite: bool = False) -> None:
    """Refuse an output folder that holds anything (a rerun would mix two runs' files), unless
    ``overwrite``; and even then one that holds files a sequence does not write (``--overwrite`` replaces
    the whole folder, so it replaces only a folder of results). Called before the run and again before
    writing. Raises :class:`StereoGeoError` (exit code 2)."""
    from stereogeo_cli.io.writers import FORMAT_FILES

    folder = Path(out_dir)
    if folder.exists() and not folder.is_dir():
        raise StereoGeoError(f"output folder {folder} is not a folder")
    held = sorted(p.name + ("/" if p.is_dir() else "") for p in folder.iterdir()) if folder.is_dir() else []
    if not held:
        return
    shown = ", ".join(held[:4]) + (", …" if len(held) > 4 else "")
    if not overwrite:
        raise StereoGeoError(
            f"{folder} already holds {shown}: add --overwrite to replace the folder with this run's "
            "results, or give a new folder"
        )
    ours = {name for names in FORMAT_FILES.values() for name in names} | set(SEQUENCE_FILES)
    foreign = [name for name in held if name.rstrip("/") not in ours]
    if foreign:
        raise StereoGeoError(
            f"{folder} holds {', '.join(foreign[:4])}{', …' if len(foreign) > 4 else ''}, which "
            "calibrate-sequence does not write: --overwrite replaces a whole folder of results, so give "
            "that folder or a new one"
        )


def write_sequence(out_dir: str | Path, result: SequenceResult, formats=None, *, overwrite: bool = False,
                   stop=None) -> list[Path]:  # fmt: skip
    """Every file of ``calibrate -o`` for the rig (``formats``: all by default), ``trajectory.txt`` and the
    COLMAP model in ``sparse/0/`` (where COLMAP made one), as the whole content of ``out_dir``: written
    into a new folder that then takes its place in one step (:func:`check_output_folder` decides whether
    an ``out_dir`` that holds files may be replaced). ``stop``: once it is requested before that step,
    nothing is written and ``[]`` is returned."""
    from stereogeo_cli.io.atomic import replace_folder_atomically
    from stereogeo_cli.io.writers import DEFAULT_FORMATS, render_calibration
    from stereogeo_cli.jobs.interrupt import protected
    from stereogeo_cli.sequence.report_inputs import sequence_inputs

    check_output_folder(out_dir, overwrite)
    formats = formats or DEFAULT_FORMATS
    figures = sequence_inputs(result) if "html" in formats else None
    files: dict[str, str | bytes] = dict(render_calibration(result.calibration, formats, figures=figures))
    if result.reconstruction is not None:  # COLMAP made a model (else the pairs alone calibrated the rig)
        files["trajectory.txt"] = trajectory_tum(result.trajectory)
        files.update(colmap.model_files(result.reconstruction))
    with protected():  # a second signal waits until the folder is whole, or untouched
        if stop is not None and stop.requested:
            return []
        return replace_folder_atomically(out_dir, files)
