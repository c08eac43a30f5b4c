"""The calibrate pipeline: images → network → per-camera refiner → stereo fusion → a StereoCalibration.

One :class:`Calibrator` holds one ONNX Runtime session and is reused for every pair of a run. A pair goes
through named stages (``Calibrator._calibrate_in_order``), each carrying a :class:`_PairWork` forward:
the fields (``_read_fields``), each camera's fit and focal decision (``_fit_cameras``), line segments and
the lens their edges show (``_find_lines``), the fusion (``_fuse_pose``), the vanishing points' focal
lengths (``_combine_edge_focals``), gravity with vertical lines and shared between the cameras
(``_fit_gravity``), the baseline (``_baseline``) and the result (``_assemble``).
"""

from __future__ import annotations

import math
import os
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import NamedTuple

import numpy as np

from stereogeo_cli.errors import CalibrationFailed, StereoGeoError
from stereogeo_cli.fuse import Matches, RelativePose, fuse_relative_pose, share_gravity
from stereogeo_cli.fuse.assemble import CameraEstimate, assemble, focal_sigmas
from stereogeo_cli.fuse.matches import Features, detect_features, match_detected
from stereogeo_cli.fuse.pose import default_conf as fuse_conf
from stereogeo_cli.fuse.scale import DepthField, baseline_from_depth
from stereogeo_cli.fuse.scale import default_conf as scale_conf
from stereogeo_cli.geometry import (
    ImageTurn,
    intrinsic_matrix,
    principal_point,
    rotation_angle,
    undistort_division,
)
from stereogeo_cli.io import StereoCalibration
from stereogeo_cli.io.exif import FocalPrior
from stereogeo_cli.io.images import check_pair
from stereogeo_cli.network.runtime import (
    DEPTH_STRIDE,
    FieldNetwork,
    NetworkOutput,
    ViewFields,
    default_model_path,
)
from stereogeo_cli.refine import CameraFit, combine_focal, parse_sigma_inflation, refine_camera
from stereogeo_cli.refine.lines import default_conf as lines_conf
from stereogeo_cli.refine.lines import detect_segments, detector_pixel, gravity_with_lines
from stereogeo_cli.refine.lm import FieldSamples, field_samples, vfov_sigma_deg
from stereogeo_cli.refine.lm import default_conf as refine_default_conf
from stereogeo_cli.refine.manhattan import ManhattanFocal, stable_manhattan_focal
from stereogeo_cli.refine.manhattan import default_conf as manhattan_conf
from stereogeo_cli.refine.plumb import PlumbLens, plumb_line_distortion
from stereogeo_cli.refine.plumb import default_conf as plumb_conf
from stereogeo_cli.settings import resolve

default_conf = {
    "min_mean_confidence": 0.05,  # below this mean field confidence a view is too ambiguous to calibrate
    # 0: a focal length given by the user is held fixed; > 0: its relative 1-sigma, and it is a prior combined
    # with the fields' as an EXIF focal length is
    "known_focal_sigma": 0.0,
    # an EXIF focal length (a prior, combined with the fields' by their sigmas) whose fields read it this many
    # combined sigmas away gets a warning: the photo may be cropped or digitally zoomed
    "exif_warn_sigmas": 4.0,
    # the relative 1-sigma of the network's bias on a camera it has not seen, added in quadrature to a
    # reported focal length read from the images (the fields, alone or with the vanishing points): the
    # fields' own sigma describes the scatter over one image's cells, not how wrong the network can be on a
    # kind of camera, and that error is common to every photo of it (docs/refine.md, "Uncertainty of the
    # focal length on photographs"); it also weighs the fields' read against the straight edges' (which do
    # not share it: Calibrator._with_manhattan); 0: none
    "camera_bias_sigma": 0.25,
    # where evidence moved a focal length away from the images' read (the straight edges' read combined with
    # it; the matches' focal ratio; two focal lengths held equal), the reported focal sigma takes in, in
    # quadrature, this share of the move in log f (Calibrator._spread; it widens only what is reported)
    "read_spread": 0.5,
    # the fusion refines the two focal lengths' common scale with the pose where both are read from the
    # images, its prior the fields' read with the camera bias above (how far that read can be off): the
    # matches of cameras that turn against each other see it (stereogeo_cli/fuse/pose.py, docs/refine.md)
    "common_focal_from_matches": True,
    # Also run the mirrored pair and average the fields (twice the network time). Off: it lowers the mean
    # errors on renders but raises the median roll error and the real-image vFoV errors (docs/network.md).
    "flip": False,
    # With too few matches to tell the two focal lengths' ratio (the pose from the pose head), two images of
    # one size whose fields read focal lengths this many combined sigmas apart or closer are taken for one
    # camera model, and both get the two reads combined (the fusion holds focal lengths equal likewise where
    # its matches cannot tell the ratio from 1); 0: each camera keeps its own
    "equal_focal_fields_sigmas": 1.0,
    # Each camera's gravity averaged with the other camera's seen through the fused R, the focal lengths left
    # as they are (stereogeo_cli/fuse/gravity.py). The correlation of the two cameras' gravity errors
    # only widens the reported sigmas: the errors' own correlation on the validation renders is 0.67 (pitch)
    # to 0.75 (roll); 0.85 keeps 68 % of those errors within 1 sigma after sharing (docs/refine.md).
    "share_gravity": True,
    "gravity_view_correlation": 0.85,
    # vertical line segments set the gravity together with the fields, after the fusion has measured the
    # lens (stereogeo_cli/refine/lines.py, docs/refine.md)
    "lines": {},  # overrides of stereogeo_cli.refine.lines.default_conf ({"enabled": False}: fields alone)
    # overrides of stereogeo_cli.refine.plumb.default_conf: the lens read from the line segments' straight
    # edges, evidence in the fusion's test of whether to fit a lens (needs the line segments)
    "plumb": {},
    # overrides of stereogeo_cli.refine.manhattan.default_conf: the focal length a Manhattan frame of the
    # image's straight edges gives, combined with the fields' where the two agree and no lens is seen (after
    # the fusion, which then runs again; {"enabled": False}: the fields' alone)
    "manhattan": {},
    "match": {},  # overrides of stereogeo_cli.fuse.matches.default_conf
    "fuse": {},  # overrides of stereogeo_cli.fuse.pose.default_conf
    # overrides of stereogeo_cli.fuse.scale.default_conf: the metric baseline from the matches and the depth
    # head (models that have one), in place of the pose head's learned length ({"enabled": False}: off)
    "scale": {},
    "refine": {},  # overrides of stereogeo_cli.refine.default_conf
}


@dataclass
class CalibrationResult:
    """Everything one pair gave: the calibration to write, and the pieces it came from."""

    calibration: StereoCalibration
    # in the pixels of the original left image, with the sigmas the estimation used (calibration.sigma_left
    # holds the ones reported: Calibrator.reported_sigma)
    left: CameraFit
    right: CameraFit
    pose: RelativePose
    warnings: list[str] = field(default_factory=list)
    matches: Matches | None = None  # all feature matches (batch-calibrate --same-rig pools them)
    # per camera, where its focal length came from when not from the fields alone (None: the fields', or
    # held where given)
    focal_sources: tuple[FocalCombination | None, FocalCombination | None] = (None, None)
    # which of ``matches`` the relative pose was fitted to (a mask [N]; None: the pose is the pose head's)
    inliers: np.ndarray | None = None
    # each view's perspective fields as the network read them (left, right); None where the images were
    # turned before they were read (``turned_back``: the fields are of the turned images)
    fields: tuple[ViewFields, ViewFields] | None = None
    # each camera's focal length as its fields alone read it, with the refiner's 1-sigma, in pixels (None:
    # held where given): the first of the focal length's pieces of evidence the HTML report shows
    fields_focal: tuple[tuple[float, float] | None, tuple[float, float] | None] = (None, None)

    def report(self) -> dict:
        """The JSON report (docs/io.md), with the pose's provenance and any warnings."""
        return self.calibration.to_report()

    def with_warning(self, note: str) -> CalibrationResult:
        """This result with one more warning (in ``warnings``, the report's ``warnings`` and its notes)."""
        c = self.calibration
        extra = {**c.extra_report, "warnings": [*c.extra_report.get("warnings", []), note]}
        notes = "; ".join(n for n in (c.notes, note) if n)
        calibration = replace(c, notes=notes, extra_report=extra)
        return replace(self, calibration=calibration, warnings=[*self.warnings, note])

    def mirrored(self) -> CalibrationResult:
        """The same rig with the two cameras' roles swapped: each camera keeps its own intrinsics, gravity
        and sigmas, and ``X_right = R @ X_left + T`` becomes ``X_left = Rᵀ @ X_right - Rᵀ T``."""
        c, pose = self.calibration, self.pose
        R = c.R.T
        per_camera = ("focal_prior", "vertical_segments")
        extra = {
            k: (list(v)[::-1] if k in per_camera and v is not None else v) for k, v in c.extra_report.items()
        }
        if isinstance(extra.get("pose"), dict):
            extra["pose"] = {
                k: (list(v)[::-1] if isinstance(v, list | tuple) and len(v) == 2 else v)
                for k, v in extra["pose"].items()
            }
        calibration = replace(
            c, K_left=c.K_right, K_right=c.K_left, image_size_left=c.image_size_right,
            image_size_right=c.image_size_left, R=R, T=-R @ c.T, D_left=c.D_right, D_right=c.D_left,
            gravity_left=c.gravity_right, gravity_right=c.gravity_left, sigma_left=c.sigma_right,
            sigma_right=c.sigma_left, extra_report=extra,
        )  # fmt: skip
        mirrored_pose = replace(
            pose, R=pose.R.T, t_direction=-pose.R.T @ pose.t_direction, focal_scale=pose.focal_scale[::-1],
            distortion=pose.distortion[::-1], sigma_distortion=pose.sigma_distortion[::-1], start=None,
        )  # fmt: skip
        matches = None
        if self.matches is not None:
            matches = Matches(self.matches.right, self.matches.left, self.matches.features[::-1])
        return replace(
            self, calibration=calibration, left=self.right, right=self.left, pose=mirrored_pose,
            matches=matches, focal_sources=self.focal_sources[::-1],
            fields=None if self.fields is None else self.fields[::-1], fields_focal=self.fields_focal[::-1],
        )  # fmt: skip

    def turned_back(self, turn: ImageTurn) -> CalibrationResult:
        """This result, found in images turned by ``turn``, for the images as they were: each camera frame
        rolled back about its optical axis (gravity, R, T), image sizes, K and the matches turned back; focal
        lengths, the lens, the sigmas of the focal length, roll and pitch and the report's other keys are
        unchanged by a roll."""
        if turn.quarters == 0:
            return self
        back = turn.rotation.T  # X = back @ X_turned
        c = self.calibration

        def camera(K, size, gravity, sigma):
            width, height = turn.size_back(size)
            focal = float(K[0, 0])
            if sigma is not None and sigma.get("focal_px") is not None and turn.quarters % 2:
                sigma = {**sigma, "vfov_deg": vfov_sigma_deg(focal, height, sigma["focal_px"] / focal)}
            g = None if gravity is None else back @ gravity
            return intrinsic_matrix(focal, width, height), (width, height), g, sigma

        K_l, size_l, g_l, s_l = camera(c.K_left, c.image_size_left, c.gravity_left, c.sigma_left)
        K_r, size_r, g_r, s_r = camera(c.K_right, c.image_size_right, c.gravity_right, c.sigma_right)
        calibration = replace(
            c, K_left=K_l, K_right=K_r, image_size_left=size_l, image_size_right=size_r,
            R=back @ c.R @ turn.rotation, T=back @ c.T, gravity_left=g_l, gravity_right=g_r, sigma_left=s_l,
            sigma_right=s_r,
        )  # fmt: skip
        calibration = with_rotation_noted(calibration, turn.degrees)

        def fit(f: CameraFit) -> CameraFit:
            width, height = turn.size_back((f.width, f.height))
            return replace(f, width=width, height=height, gravity_up=back @ f.gravity_up)

        R, t = back @ self.pose.R @ turn.rotation, back @ self.pose.t_direction
        pose = replace(self.pose, R=R, t_direction=t, start=None)
        matches = None
        if self.matches is not None:
            sizes = (self.left.width, self.left.height), (self.right.width, self.right.height)
            matches = Matches(
                turn.points_back(self.matches.left, turn.size_back(sizes[0])),
                turn.points_back(self.matches.right, turn.size_back(sizes[1])),
                self.matches.features,
            )
        left, right = fit(self.left), fit(self.right)
        return replace(
            self, calibration=calibration, left=left, right=right, pose=pose, matches=matches, fields=None
        )


def with_rotation_noted(calibration: StereoCalibration, degrees: int) -> StereoCalibration:
    """The calibration with the report's ``rotate_deg`` where its images were read turned (``--rotate``)."""
    if not degrees:
        return calibration
    return replace(calibration, extra_report={**calibration.extra_report, "rotate_deg": int(degrees)})


def _flat_futures(work) -> list:
    """The futures of ``Calibrator._start_image_work``'s result (a tuple of them and None)."""
    return [future for future in work if future is not None]


def _timed(function, *args):
    """(function(*args), its wall time in milliseconds)."""
    tick = time.perf_counter()
    result = function(*args)
    return result, (time.perf_counter() - tick) * 1e3


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


@dataclass(frozen=True)
class FocalCombination:
    """Where a camera's focal length came from when it is not the fields' alone: their read combined in
    log f with another, an EXIF tag (``source`` "exif"), a focal length given with a sigma ("given"), or
    the vanishing points of the image's straight edges ("lines")."""

    source: str
    focal_px: float  # the other read, and its 1-sigma
    sigma_px: float
    fields_focal_px: float  # what the fields alone read, and its 1-sigma
    fields_sigma_px: float
    combined_focal_px: float  # the two combined, before the feature matches refine it
    tag: str | None = None  # the EXIF tag and its value in millimetres
    tag_mm: float | None = None
    segments: tuple[int, int, int] | None = None  # the edges' segments along the frame's three directions

    def to_report(self) -> dict:
        """The report's ``focal_prior`` entry (docs/io.md)."""
        entry = {
            "source": self.source, "tag": self.tag, "tag_mm": self.tag_mm, "focal_px": self.focal_px,
            "sigma_px": self.sigma_px, "fields_focal_px": self.fields_focal_px,
            "fields_sigma_px": _finite(self.fields_sigma_px), "combined_focal_px": self.combined_focal_px,
        }  # fmt: skip
        if self.segments is not None:
            entry["segments"] = list(self.segments)
        return entry


def _focal_from_fields(prior: FocalCombination | None, held: float | None) -> bool:
    """Whether a camera's focal length is the network's read (alone, or combined with its straight edges')
    rather than one the user or EXIF gave: its reported sigma is widened by photo_sigma_scale then."""
    return held is None and (prior is None or prior.source == "lines")


def _no_lens(lens: PlumbLens | None, sigmas: float) -> bool:
    """Whether an image's straight edges are consistent with a pinhole camera (within ``sigmas`` sigma of no
    lens, or too few of them to tell)."""
    return lens is None or abs(lens.kappa) <= sigmas * lens.sigma_kappa


def hold_alike_focals(
    pose: RelativePose, fit_left: CameraFit, fit_right: CameraFit, limit: float
) -> RelativePose:
    """``pose`` (from the pose head: no matches to tell the two focal lengths' ratio) with both focal lengths
    moved to the two fields' reads combined (``focal_scale``; ``equal_focals`` set), where the images are
    one size and the reads are at most ``limit`` combined sigmas apart; otherwise ``pose`` as it is.

    Most rigs pair two identical cameras, and the fusion holds focal lengths equal where its matches cannot
    tell their ratio from 1; without matches only the fields can tell it. Each camera keeps its own relative
    sigma: the two reads see one scene, and their errors are correlated."""
    if limit <= 0 or (fit_left.width, fit_left.height) != (fit_right.width, fit_right.height):
        return pose
    focals = (fit_left.focal_px, fit_right.focal_px)
    sigmas = (fit_left.sigma["focal_px"], fit_right.sigma["focal_px"])
    rel = [s / f for s, f in zip(sigmas, focals, strict=True)]
    if not all(math.isfinite(r) and r > 0 for r in rel):
        return pose
    if abs(math.log(focals[0] / focals[1])) > limit * math.hypot(*rel):
        return pose
    focal, _ = combine_focal(focals[0], sigmas[0], focals[1], sigmas[1])
    return replace(
        pose,
        focal_scale=(focal / focals[0], focal / focals[1]),
        equal_focals=True,
        notes=[
            *pose.notes,
            "focal lengths held equal: no matches to tell them apart, and the fields read them alike",
        ],
    )


@dataclass
class _PairWork:
    """What one pair's calibration carries from stage to stage; lists are per camera (left, right)."""

    net: NetworkOutput
    timing: dict[str, float]  # milliseconds per stage
    fits: list = field(default_factory=lambda: [None, None])  # CameraFit, in original pixels
    held: list = field(default_factory=lambda: [None, None])  # focal lengths held fixed (given, no sigma)
    priors: list = field(default_factory=lambda: [None, None])  # FocalCombination or None
    warnings: list[str] = field(default_factory=list)
    segments: list | None = None  # each image's line segments (original pixels); None: lines off
    edge_lens: list = field(default_factory=lambda: [None, None])  # PlumbLens the edges show, or None
    matches: Matches | None = None
    pose: RelativePose | None = None
    used: list[int] = field(default_factory=lambda: [0, 0])  # vertical segments in each gravity fit
    # each camera's focal length and 1-sigma as its fields alone read it (None: held)
    fields_focal: list = field(default_factory=lambda: [None, None])


class _Baseline(NamedTuple):
    """The length of T and where it came from: ``scale_source`` "baseline" (given) or "learned", and for a
    learned one ``source`` ("depth" or "pose_head") and its relative 1-sigma ``sigma_rel``."""

    metres: float
    scale_source: str
    source: str | None
    sigma_rel: float | None


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity where the system tells it, else all)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def lower_thread_priority(steps: int = 10) -> None:
    """Lower the calling thread's scheduling priority by ``steps`` nice levels (Linux; elsewhere, or where
    the system refuses, nothing changes). Linux schedules each thread on its own nice value: a thread whose
    work is needed later yields the cores to the work that is waited for now. On two cores a warm
    ``calibrate`` took about 0.95× as long with the vanishing points' edges on such a thread, measured side
    by side; the results do not change."""
    if not sys.platform.startswith("linux"):
        return
    try:
        thread = threading.get_native_id()
        now = os.getpriority(os.PRIO_PROCESS, thread)
        os.setpriority(os.PRIO_PROCESS, thread, min(now + steps, 19))
    except OSError:
        pass


def network_threads() -> int:
    """The network's threads by default: one per core this process may use, but one. The feature matching
    and the straight edges' detection run on threads of their own while ONNX Runtime runs; with a thread
    per core ONNX Runtime competes with them for every core (on two cores a warm ``calibrate`` took
    about 0.85× as long with one network thread as with two, measured side by side)."""
    return max(1, usable_cores() - 1)


class Calibrator:
    """Calibrates stereo pairs with one network session.

    Args:
        model_path: the ONNX model (default: the shipped one).
        threads: ONNX Runtime intra-op threads (0: one per core this process may use but one, which the
            feature matching takes while the network runs: :func:`network_threads`).
        conf: overrides of :data:`default_conf`.
        first_pair: the images (left, right) the first :meth:`calibrate` will be given, where they are
            loaded already: their image work (features, line segments, edges; no network needed) starts
            on the pool while the network's session opens, on the core that opening leaves idle, and that
            :meth:`calibrate` of those same arrays takes it up. The results are the same as without it.
    """

    def __init__(
        self,
        model_path: str | Path | None = None,
        threads: int = 0,
        conf: dict | None = None,
        *,
        first_pair: tuple[np.ndarray, np.ndarray] | None = None,
    ):
        self.conf = resolve(default_conf, conf)
        self.conf["lines"] = resolve(lines_conf, self.conf["lines"])
        self.conf["plumb"] = resolve(plumb_conf, self.conf["plumb"])
        self.conf["manhattan"] = resolve(manhattan_conf, self.conf["manhattan"])
        # the features and the straight edges' detection need no network output: they run on the pool's
        # threads while ONNX Runtime runs (all three release the GIL)
        self._pool = ThreadPoolExecutor(max_workers=2, thread_name_prefix="stereogeo-pool")
        # the edges for the vanishing points are needed only after the fusion: on a thread of their own that
        # yields the cores to the features, which the fusion waits for (``lower_thread_priority``)
        self._background = ThreadPoolExecutor(
            max_workers=1, thread_name_prefix="stereogeo-background", initializer=lower_thread_priority
        )
        # SIFT builds a scale space of about 70 MB for a 640 x 480 image: one image at a time (this pair's,
        # or the next pair's started ahead) keeps the peak memory to one of them
        self._features_lock = threading.Lock()
        self._view_samples: dict[int, tuple[ViewFields, FieldSamples]] = {}
        self._ahead: tuple | None = None  # (left, right, image work) of the pair to be calibrated next
        self._turned_memo: tuple | None = None  # (left, right, turn, both turned): Calibrator._turned
        if first_pair is not None:
            check_pair(*first_pair)
            self._ahead = (*first_pair, self._start_image_work(*first_pair))
        self.model_path = Path(model_path) if model_path is not None else default_model_path()
        try:
            self.network = FieldNetwork(self.model_path, threads=threads or network_threads())
        except BaseException:
            self._drop_ahead()
            raise
        # The refiner's sigmas treat field cells as independent; a network's errors are correlated, and the
        # model records how much to widen them (measured on validation data when it was exported).
        # It also records how much wider the reported sigmas must be on real photographs, where the network
        # errs more than on the renders those factors were measured on (photo_sigma_scale: reported_sigma).
        try:
            inflation = parse_sigma_inflation(self.network.metadata.get("sigma_inflation", "1"))
            photo = parse_sigma_inflation(
                self.network.metadata.get("photo_sigma_scale", "1"), "photo sigma scale"
            )
        except ValueError as error:
            raise StereoGeoError(f"model file {self.model_path} has invalid metadata: {error}") from None
        self.conf["refine"] = {"sigma_inflation": inflation, **self.conf["refine"]}
        self.photo_sigma_scale = photo if isinstance(photo, tuple) else (photo, photo, photo)
        # The pose head's own 1-sigma (68th percentiles of its validation errors), when the model records it:
        # how strongly the fusion leans on it, and its sigma when it is all there is.
        measured = {
            "prior_rotation_sigma_deg": self.network.metadata.get("pose_sigma_rotation_deg"),
            "prior_direction_sigma_deg": self.network.metadata.get("pose_sigma_direction_deg"),
        }
        self.conf["fuse"] = {
            **{k: float(v) for k, v in measured.items() if v is not None},
            **self.conf["fuse"],
        }
        scale_sigma = self.network.metadata.get("pose_sigma_scale_rel")
        self._learned_scale_sigma = float(scale_sigma) if scale_sigma is not None else None
        depth_sigma = self.network.metadata.get("depth_sigma_scale_rel")
        self._depth_scale_sigma = float(depth_sigma) if depth_sigma is not None else None
        self.conf["scale"] = resolve(scale_conf, self.conf["scale"])

    def reported_sigma(
        self,
        fit: CameraFit,
        focal_from_fields: bool = True,
        spread_rel: float = 0.0,
        rotation_rel: float | None = None,
    ) -> dict[str, float]:
        """The sigmas to report for a fit: every sigma of the estimation weighs one piece of evidence against
        another; the ones reported are widened by the model's photo_sigma_scale, measured end to end on crops
        of real panoramas, so that they hold 68 % of the errors on photographs. The estimates do not change.
        A focal length that was given or had an EXIF prior keeps its sigma: that scale was not measured with
        one. ``spread_rel``: a relative spread added in quadrature to the focal length's (two reads that
        disagree: ``_spread``), as is the conf's ``camera_bias_sigma`` for a focal length read from the
        images. ``rotation_rel``: the relative sigma of the focal length a rotation from one centre reads
        (``fuse/one_centre.py``), which the estimate combines with the images' or the given read: the sigma
        reported is the two combined (their information adds)."""
        roll, pitch, vfov = self.photo_sigma_scale
        sigma = fit.sigma
        relative = sigma["focal_px"] / fit.focal_px * (vfov if focal_from_fields else 1.0)
        if focal_from_fields:
            spread_rel = math.hypot(spread_rel, self.conf["camera_bias_sigma"])
        if rotation_rel is not None:
            read = math.hypot(relative, spread_rel)
            relative, spread_rel = 1.0 / math.sqrt(read**-2 + rotation_rel**-2), 0.0
        return {
            **focal_sigmas(fit.focal_px, fit.height, relative, spread_rel),
            "roll_deg": sigma["roll_deg"] * roll,
            "pitch_deg": sigma["pitch_deg"] * pitch,
        }

    def _spread(self, prior: FocalCombination | None, scale: float) -> float:
        """The relative spread the reported sigma of a focal length read from the images takes in where
        evidence moved it away from that read: the conf's ``read_spread`` times the move in log f. The moves:
        to the straight edges' read, for a focal length combined with its edges' (their distance from the
        fields'), and the fusion's ``scale`` (the matches' focal ratio, or the two focal lengths held equal,
        and on a turned rig their common scale). Where two reads disagree, the truth is uncertain by about as
        much, whatever their sigmas say (docs/refine.md, "Vanishing points" and "The fusion's allowances").
        A given or EXIF focal length keeps its prior's sigma (the caller passes no spread for it)."""
        lines = 0.0
        if prior is not None and prior.source == "lines":
            lines = math.log(prior.focal_px / prior.fields_focal_px)
        return self.conf["read_spread"] * math.hypot(lines, math.log(scale))

    def _samples(self, view: ViewFields) -> FieldSamples:
        """The samples of ``view``'s fields the refiner fits, taken once per view (a camera is fitted up to
        three times: its fields, a combined focal length held, its vertical segments)."""
        kept = self._view_samples.get(id(view))
        if kept is None or kept[0] is not view:
            conf = resolve(refine_default_conf, self.conf["refine"])
            samples = field_samples(
                view.up, view.latitude, view.up_confidence, view.latitude_confidence, view.pixel_xy, conf
            )
            if len(self._view_samples) >= 4:  # the views of the pair at hand only
                self._view_samples.clear()
            kept = self._view_samples[id(view)] = (view, samples)
        return kept[1]

    def _refine_view(
        self, view: ViewFields, known_focal: float | None, gravity: np.ndarray | None = None
    ) -> CameraFit:
        """One camera's fit to its fields, in the original image's pixels (from ``gravity``, where given)."""
        fit = refine_camera(
            view.up, view.latitude, view.up_confidence, view.latitude_confidence,
            image_size=view.image_size, pixel_xy=view.pixel_xy,
            focal_prior=self._focal_prior(view, known_focal), gravity_init=gravity,
            samples=self._samples(view), conf=self.conf["refine"],
        )  # fmt: skip
        return fit.in_original_pixels(view.resize_crop)

    @staticmethod
    def _focal_prior(view: ViewFields, known_focal: float | None) -> float | None:
        """A known focal length (original pixels) as the refiner holds it (network-output pixels)."""
        return None if known_focal is None else view.resize_crop.focal_to_output(known_focal)

    def _refine_with_prior(
        self, view: ViewFields, name: str, known_focal: float | None, prior: FocalPrior | None
    ) -> tuple[CameraFit, FocalCombination | None, str | None]:
        """One camera's fit, its focal length combined with a ``prior`` (from EXIF, or given with a sigma)
        where there is one and no known focal: (fit, the report's entry for the prior or None, a warning or
        None).

        The fields' focal length and the prior are combined in log f by their 1-sigma figures, the fields'
        as the model's sigma inflation widens them, and the gravity is fitted again for that focal length,
        which keeps the combined sigma. (A soft prior inside the refiner would meet the fields' own
        information, which treats correlated field cells as independent: the refiner's sandwich covariance
        then has no meaning for the focal length.)"""
        fit = self._refine_view(view, known_focal)
        if known_focal is not None or prior is None:
            return fit, None, None
        focal, sigma = combine_focal(fit.focal_px, fit.sigma["focal_px"], prior.focal_px, prior.sigma_px)
        combined = self._held_at(view, fit, focal, sigma)
        apart = abs(math.log(fit.focal_px / prior.focal_px))
        fields_sigma = fit.sigma["focal_px"] / fit.focal_px
        fields_sigma = fields_sigma if math.isfinite(fields_sigma) else 0.0
        sigmas = apart / math.sqrt(prior.sigma_rel**2 + fields_sigma**2)
        warning = None
        if sigmas > self.conf["exif_warn_sigmas"]:
            what = "given focal length" if prior.source == "given" else "photo's EXIF focal length"
            advice = (
                ""
                if prior.source == "given"
                else "; if it was cropped or digitally zoomed, calibrate with --no-exif"
            )
            warning = (
                f"the {name} {what} ({prior.focal_px:.0f} px) and its fields ({fit.focal_px:.0f} px) "
                f"disagree by {100 * (math.exp(apart) - 1):.0f} %{advice}"
            )
        entry = FocalCombination(
            prior.source, prior.focal_px, prior.sigma_px, fit.focal_px, fit.sigma["focal_px"], focal,
            tag=prior.tag, tag_mm=prior.value_mm,
        )  # fmt: skip
        return combined, entry, warning

    def _fuse(
        self,
        matches: Matches,
        fit_left: CameraFit,
        fit_right: CameraFit,
        net,
        held: list[float | None],
        edge_lens: list[PlumbLens | None],
        priors: list[dict | None],
        again=None,
    ) -> RelativePose:
        """The relative pose from the matches, the two fits (K, gravity, their sigmas) and the pose head;
        ``again``: an earlier fusion's ``start`` on the same matches (``fuse_relative_pose``)."""
        K_left = intrinsic_matrix(fit_left.focal_px, fit_left.width, fit_left.height)
        K_right = intrinsic_matrix(fit_right.focal_px, fit_right.width, fit_right.height)
        gravity_sigma = math.radians(
            math.sqrt(
                sum(fit.sigma[k] ** 2 for fit in (fit_left, fit_right) for k in ("roll_deg", "pitch_deg"))
            )
        )
        focal_sigma_rel = tuple(
            None if held[side] is not None else fit.sigma["focal_px"] / fit.focal_px
            for side, fit in enumerate((fit_left, fit_right))
        )
        common = None
        from_fields = [_focal_from_fields(prior, h) for prior, h in zip(priors, held, strict=True)]
        if self.conf["common_focal_from_matches"] and all(from_fields):  # neither focal length is held
            common = math.hypot(
                0.5 * (focal_sigma_rel[0] + focal_sigma_rel[1]), self.conf["camera_bias_sigma"]
            )
        pose = fuse_relative_pose(
            matches, K_left, K_right,
            gravity_left=fit_left.gravity_up, gravity_right=fit_right.gravity_up,
            gravity_sigma_rad=max(gravity_sigma, 1e-4) if math.isfinite(gravity_sigma) else None,
            prior_R=net.rotation, prior_t=net.translation, conf=self.conf["fuse"],
            focal_sigma_rel=focal_sigma_rel, common_focal_sigma_rel=common,
            distortion_evidence=(
                None if edge_lens[0] is None else edge_lens[0].division_k(fit_left.focal_px),
                None if edge_lens[1] is None else edge_lens[1].division_k(fit_right.focal_px),
            ),
            lens_seen=tuple(not _no_lens(lens, self.conf["manhattan"]["lens_sigmas"]) for lens in edge_lens),
            again=again,
        )  # fmt: skip
        if pose.source == "pose_head" and held == [None, None]:
            pose = hold_alike_focals(pose, fit_left, fit_right, self.conf["equal_focal_fields_sigmas"])
        return pose

    def _held_at(self, view: ViewFields, fit: CameraFit, focal: float, sigma: float) -> CameraFit:
        """``fit`` of ``view`` with its focal length held at a combined ``focal`` (original pixels) with that
        1-sigma, the gravity fitted again for it (from ``fit``'s)."""
        return self._refine_view(view, focal, fit.gravity_up).with_focal_sigma(sigma / focal)

    def _edge_focals(
        self, finding_edges, fits: tuple[CameraFit, CameraFit], needed: list[bool]
    ) -> tuple[list[ManhattanFocal | None], float]:
        """Each camera's Manhattan-frame focal length from its straight edges (None where not ``needed`` or
        none), started from its fields' fit, and the milliseconds spent finding and fitting the edges."""
        edges, milliseconds = finding_edges.result()
        tick = time.perf_counter()
        conf = self.conf["manhattan"]
        reads = [
            stable_manhattan_focal(
                fine,
                coarse,
                (fit.width, fit.height),
                fit.gravity_up,
                fit.focal_px,
                detector_px=(fine_px, coarse_px),
                conf=conf,
            )  # fmt: skip
            if need
            else None
            for ((fine, fine_px), (coarse, coarse_px)), fit, need in zip(edges, fits, needed, strict=True)
        ]
        return reads, milliseconds + (time.perf_counter() - tick) * 1e3

    def _with_manhattan(
        self, view: ViewFields, fit: CameraFit, found: ManhattanFocal
    ) -> tuple[CameraFit, FocalCombination | None]:
        """``fit`` with its focal length combined with ``found``, the one a Manhattan frame of the image's
        straight edges gives, where the two agree within the conf's ``gate_sigmas``: (fit, the report's
        entry or None).

        The fields' read is weighed, in the gate and in the combination, with the estimation's sigma and
        the conf's ``camera_bias_sigma`` in quadrature: how far the fields can read a real camera off, which
        the edges do not share (docs/refine.md, "Uncertainty of the focal length on photographs"). The
        combination's sigma is the estimation's (the fields' without that bias, as with an EXIF prior; the
        estimates do not depend on photo_sigma_scale): the reported sigma adds the bias and the
        photo_sigma_scale as for the fields' own read (refine/manhattan.py, docs/refine.md)."""
        conf = self.conf["manhattan"]
        fields_sigma = fit.sigma["focal_px"] / fit.focal_px
        if not (math.isfinite(fields_sigma) and fields_sigma > 0):
            return fit, None
        weighed = math.hypot(fields_sigma, self.conf["camera_bias_sigma"])
        apart = abs(math.log(found.focal_px / fit.focal_px))
        if apart > conf["gate_sigmas"] * math.hypot(weighed, found.sigma_rel):
            return fit, None
        lines = found.sigma_rel * found.focal_px
        focal, _ = combine_focal(fit.focal_px, weighed * fit.focal_px, found.focal_px, lines)
        unbiased, spread = combine_focal(fit.focal_px, fields_sigma * fit.focal_px, found.focal_px, lines)
        sigma = focal * spread / unbiased  # the estimation's relative sigma, at the focal length held
        entry = FocalCombination(
            "lines", found.focal_px, found.sigma_rel * found.focal_px, fit.focal_px,
            fields_sigma * fit.focal_px, focal, segments=tuple(found.families),
        )  # fmt: skip
        return self._held_at(view, fit, focal, sigma), entry

    def _with_lines(
        self,
        view: ViewFields,
        fit: CameraFit,
        segments: np.ndarray,
        k: float,
        focal: float | None,
    ) -> tuple[CameraFit, int]:
        """``fit`` with the gravity of its fields and the image's line ``segments`` (original pixels; the
        vertical ones are chosen in refine/lines.py), the lens distortion ``k`` (division model in the
        normalised coordinates of ``fit``'s K, as the fusion gives it) taken out of them first; the gravity is
        fitted with the focal length held at ``focal`` (original pixels; None: free), which stays."""
        lines = self.conf["lines"]
        K = intrinsic_matrix(fit.focal_px, fit.width, fit.height)
        ends = undistort_division(np.asarray(segments, dtype=float).reshape(-1, 2), K, k)
        segments = view.resize_crop.points_to_output(ends).reshape(-1, 4)
        start = (fit.gravity_up, view.resize_crop.focal_to_output(fit.focal_px))  # the fit at hand
        found = gravity_with_lines(
            view.up, view.latitude, view.up_confidence, view.latitude_confidence, segments,
            image_size=view.image_size, pixel_xy=view.pixel_xy, focal_prior=self._focal_prior(view, focal),
            samples=self._samples(view), start=start, conf=lines, refine_conf=self.conf["refine"],
        )  # fmt: skip
        if found is None:
            return fit, 0
        return fit.with_new_gravity(found.gravity_up, found.covariance), found.segments

    def _edge_lens(self, segments: np.ndarray, image: np.ndarray) -> PlumbLens | None:
        """The lens the image's straight edges show (None: too few of them, or they disagree)."""
        height, width = image.shape[:2]
        scale = detector_pixel(width, height, self.conf["lines"]["max_short_side"])
        centre = principal_point(width, height)
        return plumb_line_distortion(
            segments, (width, height), centre, detector_scale=scale, conf=self.conf["plumb"]
        )

    def fields_only(self, left: np.ndarray, right: np.ndarray) -> tuple[CameraFit, CameraFit]:
        """Each camera's fit from its fields alone (network and refiner; no lines, no matches, no sharing),
        in the original images' pixels: what the network itself reads (benchmarks/scale_sensitivity.py)."""
        net = self.network.predict(left, right, flip=self.conf["flip"])
        return self._refine_view(net.left, None), self._refine_view(net.right, None)

    def calibrate(
        self,
        left: np.ndarray,
        right: np.ndarray,
        *,
        baseline_m: float | None = None,
        focal_left: float | None = None,
        focal_right: float | None = None,
        exif: tuple[tuple[FocalPrior | None, str | None], tuple[FocalPrior | None, str | None]] | None = None,
        upcoming: Callable[[], tuple[np.ndarray, np.ndarray] | None] | None = None,
        rotate: int = 0,
    ) -> CalibrationResult:
        """Calibrate one pair of RGB images [H x W x 3] uint8 (the two sizes may differ).

        Args:
            baseline_m: the known |T| in metres; without it the pose head's learned metric scale is used.
            focal_left, focal_right: known focal lengths in pixels of each image, held fixed (with the
                conf ``known_focal_sigma`` > 0, priors with that relative 1-sigma, combined with the
                fields' as an EXIF focal length is).
            exif: per image what :func:`stereogeo_cli.io.exif.read_exif_focal` found, (focal, reason it
                is not usable): a focal length is a prior, combined with the fields' (a known focal
                length wins); a reason becomes a warning.
            upcoming: for a run of pairs (``batch-calibrate``), the next pair's images if they are loaded
                (else None): once this pair's work is all on the pool, the next pair's image work starts
                there, on the core this pair's last stages leave idle, and the next :meth:`calibrate` of
                those same arrays takes it up. The results are the same as without it.
            rotate: degrees (0, 90, 180 or 270) to turn both images clockwise before they are read, for a
                rig mounted upside down (180) or on its side: the network knows views rolled by at most 45°
                and reads a turned view as upright, so without it such a rig's gravity comes out reversed
                (or a quarter turn off), and no warning can tell. The result is for the images as given
                (:meth:`CalibrationResult.turned_back`).
        Raises:
            CalibrationFailed: the images are blank or the fields too ambiguous to trust.

        A pair whose right camera turns out to sit to the left of the left one in the images as read (T_x >
        0) is calibrated again in the other order and the mirror of that is returned: the pose head learnt
        rigs with the right camera on the right, and its read of a swapped pair is worse, so a pair and its
        swap give the same rig. Where the right camera still sits to the left in the left camera's own
        frame, the files were most likely swapped, and a warning says so.
        """
        exif = exif or ((None, None), (None, None))
        turn = ImageTurn(rotate)
        left, right = self._turned(turn, left, right)
        if upcoming is not None and turn.quarters:
            upcoming = self._turning(upcoming, turn)
        if self._ahead is not None and not (self._ahead[0] is left and self._ahead[1] is right):
            self._drop_ahead()  # started for a pair that is not the one calibrated now
        result = self._calibrate_in_order(
            left, right, baseline_m=baseline_m, focal_left=focal_left, focal_right=focal_right, exif=exif,
            upcoming=upcoming,
        )  # fmt: skip
        if result.calibration.T[0] > 0:
            swapped = self._calibrate_in_order(
                right, left, baseline_m=baseline_m, focal_left=focal_right, focal_right=focal_left,
                exif=(exif[1], exif[0]),
            )  # fmt: skip
            if swapped.calibration.T[0] < 0:
                result = swapped.mirrored()
        result = result.turned_back(turn)
        T = result.calibration.T
        if T[0] > abs(T[1]):
            result = result.with_warning(
                "the right camera sits to the left of the left one (T_x > 0): were the two images swapped?"
                + ("" if turn.quarters else " (A rig mounted upside down needs --rotate 180.)")
            )
        return result

    def _turning(self, upcoming: Callable, turn: ImageTurn) -> Callable:
        """``upcoming`` giving the next pair turned (:meth:`_turned`)."""

        def turned():
            pair = upcoming()
            return None if pair is None else self._turned(turn, *pair)

        return turned

    def _turned(self, turn: ImageTurn, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The pair turned (``ImageTurn.image``), as the same arrays when the same pair comes again: the
        next pair's work started ahead on its turned images is found by their identity."""
        memo = self._turned_memo
        if memo is not None and memo[0] is left and memo[1] is right and memo[2] == turn:
            return memo[3], memo[4]
        pair = turn.image(left), turn.image(right)
        self._turned_memo = (left, right, turn, *pair) if turn.quarters else None
        return pair

    def _calibrate_in_order(
        self,
        left: np.ndarray,
        right: np.ndarray,
        *,
        baseline_m: float | None,
        focal_left: float | None,
        focal_right: float | None,
        exif: tuple[tuple[FocalPrior | None, str | None], tuple[FocalPrior | None, str | None]],
        upcoming=None,
    ) -> CalibrationResult:
        """:meth:`calibrate` with the images in the order given: the stages below, in order."""
        start = time.perf_counter()
        check_pair(left, right)
        features, finding_lines, finding_edges = self._image_work(left, right)
        work = self._fit_cameras(self._read_fields(left, right), (focal_left, focal_right), exif)
        reading_edges = self._start_edge_focals(finding_edges, work)
        self._start_upcoming(upcoming)
        work.matches, work.timing["matching"] = self._matches(features)
        self._find_lines(finding_lines, work)
        self._fuse_pose(work)
        if reading_edges is not None:
            self._combine_edge_focals(reading_edges, work)
        self._fit_gravity(work)
        baseline = self._baseline(work, baseline_m)
        work.timing["total"] = (time.perf_counter() - start) * 1e3
        return self._assemble(work, baseline)

    def _image_work(self, left: np.ndarray, right: np.ndarray):
        """The pair's image work (``_start_image_work``): started by the previous :meth:`calibrate` where
        it was this pair's ``upcoming`` (the very same arrays), else started now."""
        ahead = self._ahead
        if ahead is not None and ahead[0] is left and ahead[1] is right:
            self._ahead = None
            return ahead[2]
        return self._start_image_work(left, right)

    def _start_upcoming(self, upcoming) -> None:
        """The next pair's image work started on the pool, behind this pair's (``calibrate``'s
        ``upcoming``); work started for a pair that was then not calibrated is dropped."""
        images = upcoming() if upcoming is not None else None
        if images is None:
            return
        self._drop_ahead()
        self._ahead = (images[0], images[1], self._start_image_work(*images))

    def _drop_ahead(self) -> None:
        if self._ahead is not None:
            for future in _flat_futures(self._ahead[2]):
                future.cancel()  # those not begun; those running finish unread
            self._ahead = None

    def _start_image_work(self, left: np.ndarray, right: np.ndarray):
        """The two images' features, their line segments and the lens those show, and the edges for the
        vanishing points need no network output: they run on the pool's threads while ONNX Runtime and
        the refiner run (all release the GIL). In the order the fusion needs them: the two images' features
        on one thread, the segments and their lens on the other; the edges on the background thread, which
        yields the cores to the others, as their Manhattan frames are needed only after the fusion. Returns
        the features' future, the segments' and the edges' (None where the line segments or the vanishing
        points are off)."""
        conf = self.conf
        features = self._pool.submit(self._features, left, right)
        finding_lines = None
        if conf["lines"]["enabled"]:
            fits_lens = conf["plumb"]["enabled"] and conf["fuse"].get("distortion", fuse_conf["distortion"])
            finding_lines = self._pool.submit(_timed, self._lines_and_lens, left, right, fits_lens)
        finding_edges = None
        if conf["manhattan"]["enabled"]:
            finding_edges = self._background.submit(
                _timed, lambda: [self._edge_segments(image) for image in (left, right)]
            )
        return features, finding_lines, finding_edges

    def _edge_segments(self, image: np.ndarray) -> tuple[tuple[np.ndarray, float], tuple[np.ndarray, float]]:
        """The image's line segments for its Manhattan frame, found at the conf's ``max_short_side`` and again
        at its ``stability_scale`` of that resolution (refine/manhattan.py): each with the size of its
        detector's pixel in image pixels."""
        conf = self.conf["manhattan"]
        height, width = image.shape[:2]
        short = min(conf["max_short_side"], width, height)
        coarse = max(1, round(short * conf["stability_scale"]))
        return tuple(
            (detect_segments(image, side), detector_pixel(width, height, side)) for side in (short, coarse)
        )

    def _features(self, left: np.ndarray, right: np.ndarray) -> tuple[tuple[Features, float], ...]:
        """Both images' features, one after the other (``_features_lock``), each with its milliseconds."""
        with self._features_lock:
            return tuple(_timed(detect_features, image, self.conf["match"]) for image in (left, right))

    def _matches(self, features) -> tuple[Matches, float]:
        """The matches between the two images' features (``_start_image_work``'s future), and the
        milliseconds spent detecting and matching them."""
        (left, left_ms), (right, right_ms) = features.result()
        matches, match_ms = _timed(match_detected, left, right, self.conf["match"])
        return matches, left_ms + right_ms + match_ms

    def _read_fields(self, left: np.ndarray, right: np.ndarray) -> _PairWork:
        """Stage 1, the network: both views' fields and the pose head's pose; a view too ambiguous to
        calibrate from fails here."""
        tick = time.perf_counter()
        net = self.network.predict(left, right, flip=self.conf["flip"])
        work = _PairWork(net, timing={"network": (time.perf_counter() - tick) * 1e3})
        for name, view in (("left", net.left), ("right", net.right)):
            confidence = 0.5 * (float(np.mean(view.up_confidence)) + float(np.mean(view.latitude_confidence)))
            if confidence < self.conf["min_mean_confidence"]:
                raise CalibrationFailed(
                    f"the {name} image shows too little structure to calibrate from "
                    f"(mean field confidence {confidence:.3f})"
                )
        return work

    def _fit_cameras(self, work: _PairWork, known: tuple, exif) -> _PairWork:
        """Stage 2, per camera: the refiner's fit to the fields, its focal length held where it is known or
        combined with a prior (EXIF, or given with a sigma)."""
        tick = time.perf_counter()
        for side, (name, view) in enumerate((("left", work.net.left), ("right", work.net.right))):
            found, reason = exif[side]
            focal = known[side]
            if focal is not None and self.conf["known_focal_sigma"] > 0:  # a given focal length, softly
                found, reason = (
                    FocalPrior(focal, self.conf["known_focal_sigma"], "given", None, "given"),
                    None,
                )
                focal = None
            fit, work.priors[side], disagreement = self._refine_with_prior(view, name, focal, found)
            work.fits[side] = fit
            work.held[side] = focal
            if focal is None:
                work.warnings.extend(note for note in (reason, disagreement) if note)
                prior = work.priors[side]  # the fields' own read, before a prior was combined with it
                work.fields_focal[side] = (
                    (fit.focal_px, fit.sigma["focal_px"])
                    if prior is None
                    else (prior.fields_focal_px, prior.fields_sigma_px)
                )
        work.timing["refine"] = (time.perf_counter() - tick) * 1e3
        for name, fit in zip(("left", "right"), work.fits, strict=True):
            if not np.isfinite(fit.sigma["focal_px"]) and work.held == [None, None]:
                raise CalibrationFailed(f"the {name} camera's focal length could not be determined")
        return work

    def _start_edge_focals(self, finding_edges, work: _PairWork):
        """For a focal length from neither the user nor EXIF: the edges' Manhattan frames are fitted on the
        background thread while this one fits the vertical segments and the fusion runs (which decides
        whether the edges are used: not through a lens). The future, or None."""
        if finding_edges is None:
            return None
        needed = [work.held[side] is None and work.priors[side] is None for side in (0, 1)]
        return self._background.submit(self._edge_focals, finding_edges, tuple(work.fits), needed)

    def _lines_and_lens(self, left: np.ndarray, right: np.ndarray, fits_lens: bool) -> tuple[list, list]:
        """Each image's line segments, and the lens their straight edges show where ``fits_lens`` (the
        fusion fits one and the edges' lens is on; None where none is fitted or they show none), on the
        pool's thread."""
        short = self.conf["lines"]["max_short_side"]
        segments = [detect_segments(image, short) for image in (left, right)]
        lenses = [None, None]
        if fits_lens:
            lenses = [
                self._edge_lens(found, image) for found, image in zip(segments, (left, right), strict=True)
            ]
        return segments, lenses

    def _find_lines(self, finding_lines, work: _PairWork) -> None:
        """Stage 3: each image's line segments, and the lens their straight edges show (evidence in the
        fusion's choice of a lens), found on the pool's thread (``_lines_and_lens``). The segments'
        distortion is taken out once the fusion has measured it."""
        if finding_lines is None:
            return
        (work.segments, work.edge_lens), work.timing["lines"] = finding_lines.result()

    def _fuse_pose(self, work: _PairWork, again=None) -> None:
        """Stage 4: the relative pose from the matches, the fits and the pose head (``_fuse``); ``again``:
        the first fusion's choices, when it runs again with other focal lengths."""
        tick = time.perf_counter()
        work.pose = self._fuse(
            work.matches, *work.fits, work.net, work.held, work.edge_lens, work.priors, again=again
        )
        work.timing["fusion"] = work.timing.get("fusion", 0.0) + (time.perf_counter() - tick) * 1e3

    def _combine_edge_focals(self, reading_edges, work: _PairWork) -> None:
        """Stage 5: each camera's focal length combined with its straight edges' where they agree, not
        through a lens the matches or the edges themselves show (one radial term leaves the edges bent
        enough to move their vanishing points: EuRoC's vFoV 2.11° → 3.51°, the chessboard set's 5.50° →
        7.24°; docs/refine.md); then the fusion again with the combined focal lengths, from the first
        one's pose and choices (``fuse.pose.FusionStart``)."""
        reads, work.timing["manhattan"] = reading_edges.result()  # time on the background thread
        tick = time.perf_counter()
        lens_sigmas = self.conf["manhattan"]["lens_sigmas"]
        for side, view in enumerate((work.net.left, work.net.right)):
            if (
                reads[side] is not None
                and work.pose.distortion[side] == 0.0
                and _no_lens(work.edge_lens[side], lens_sigmas)
            ):
                work.fits[side], work.priors[side] = self._with_manhattan(view, work.fits[side], reads[side])
        work.timing["manhattan"] += (time.perf_counter() - tick) * 1e3
        if any(prior is not None and prior.source == "lines" for prior in work.priors):
            self._fuse_pose(work, again=work.pose.start)

    def _fit_gravity(self, work: _PairWork) -> None:
        """Stage 6: the matches' focal refinement (their ratio always; more where the cameras rotate), each
        camera's gravity fitted again with its vertical segments, then shared between the two cameras (not
        through the R of a turned rig)."""
        pose = work.pose
        work.warnings.extend(pose.notes)
        scales = pose.focal_scale
        work.fits = [fit.with_focal(fit.focal_px * s) for fit, s in zip(work.fits, scales, strict=True)]
        if work.segments is not None:
            tick = time.perf_counter()
            views = (work.net.left, work.net.right)
            for side, (view, fit, segments) in enumerate(zip(views, work.fits, work.segments, strict=True)):
                # after the matches' focal refinement: the fusion's k is in the refined K's coordinates. A
                # focal length combined with a prior (EXIF, given with a sigma, or the vanishing points') is
                # held at the combined value, as a known one is; one read from the fields alone is free in
                # this fit: the fields' latitude is read at the network's own focal scale, and held at the
                # written one (moved by the matches) it tilts the gravity (EuRoC's roll 2.40° → 3.10°). The
                # vanishing points' focal length freed instead tilts the pitch (docs/refine.md)
                # A focal length a rotation from one centre measured is held likewise.
                measured = (
                    pose.focal_read_sigma_rel is not None and pose.focal_read_sigma_rel[side] is not None
                )
                held = fit.focal_px if work.priors[side] or measured else work.held[side]
                work.fits[side], work.used[side] = self._with_lines(
                    view, fit, segments, pose.distortion[side], held
                )
            work.timing["lines"] += (time.perf_counter() - tick) * 1e3
        # Not through the R of a turned rig: its matches lie in a narrow strip and its R, though better than
        # the pose head's, is still off by more than its sigma says (docs/refine.md, "Turned rigs").
        if self.conf["share_gravity"] and not pose.turned:
            # the fusion's rotation sigma is the total over three axes
            work.fits = list(share_gravity(
                *work.fits, pose.R, math.radians(pose.sigma_rotation_deg) / math.sqrt(3),
                self.conf["gravity_view_correlation"],
            ))  # fmt: skip

    def _baseline(self, work: _PairWork, baseline_m: float | None) -> _Baseline:
        """Stage 7, the length of T: given, or learned (the matches with the depth head's depth where the
        model has one, else the pose head's)."""
        if baseline_m is not None:
            return _Baseline(float(baseline_m), "baseline", None, None)
        net, pose = work.net, work.pose
        baseline, source, sigma = (
            float(np.linalg.norm(net.translation)),
            "pose_head",
            self._learned_scale_sigma,
        )
        found = None
        if net.left.depth is not None and pose.source == "matches" and self.conf["scale"]["enabled"]:
            tick = time.perf_counter()
            K_left, K_right = (intrinsic_matrix(f.focal_px, f.width, f.height) for f in work.fits)
            depth = DepthField(net.left.depth, net.left.depth_spread, DEPTH_STRIDE, net.left.resize_crop)
            found = baseline_from_depth(
                work.matches, depth, K_left, K_right, pose.R, pose.t_direction, pose.distortion,
                self.conf["scale"],
            )  # fmt: skip
            work.timing["scale"] = (time.perf_counter() - tick) * 1e3
        if found is not None:
            baseline, source, sigma = found.baseline_m, "depth", self._depth_scale_sigma
        elif not np.isfinite(baseline) or baseline <= 1e-6:
            baseline = 1.0
            work.warnings.append("the pose head gave no usable metric scale: T has unit length")
        return _Baseline(baseline, "learned", source, sigma)

    def _assemble(self, work: _PairWork, baseline: _Baseline) -> CalibrationResult:
        """Stage 8: the calibration to write and report, from the stages' results (``fuse/assemble.py``)."""
        fits, pose, priors, held = work.fits, work.pose, work.priors, work.held
        from_images = [_focal_from_fields(prior, known) for prior, known in zip(priors, held, strict=True)]
        if pose.turned and any(from_images):
            # R and T of cameras turned far apart move with the focal lengths (fuse.assemble's
            # rotation_sigma_deg): on the car-mounted pairs, R was within 0.9–4.0° on 6 of 9 with the true
            # focal lengths given, against 19.6° in the median with those read from the images
            work.warnings.append(
                f"the cameras turn {math.degrees(rotation_angle(pose.R)):.0f}° apart: R and T rest on focal "
                "lengths read from the images; known focal lengths (--focal-left/--focal-right) make them "
                "accurate"
            )
        measured = pose.focal_read_sigma_rel or (None, None)
        cameras = tuple(
            CameraEstimate(
                fit.focal_px,
                fit.width,
                fit.height,
                fit.gravity_up,
                self.reported_sigma(fit, own, self._spread(prior, scale) if own else 0.0, rotation_rel),
            )  # fmt: skip
            for fit, prior, own, scale, rotation_rel in zip(
                fits, priors, from_images, pose.focal_scale, measured, strict=True
            )
        )
        # the edges' lens in the final K's coordinates, as the fusion's k is reported
        edge_k = [
            None if lens is None else lens.division_k(camera.focal_px)
            for lens, camera in zip(work.edge_lens, cameras, strict=True)
        ]
        more_pose = {
            # the lens each image's straight edges show, in the same units, with its 1-sigma (None: too few
            # long edges, or they disagree); it weighed in the choice of a lens
            "edge_distortion_k": [None if k is None else float(k[0]) for k in edge_k],
            "sigma_edge_distortion_k": [None if k is None else float(k[1]) for k in edge_k],
            # where a learned baseline came from: "depth" (the matches with the depth head's depth,
            # stereogeo_cli/fuse/scale.py) or "pose_head"; None when given
            "baseline_source": baseline.source,
            # the pose head's own learned length of T in metres (a second opinion; the network's)
            "head_baseline_m": _finite(float(np.linalg.norm(work.net.translation))),
            # relative 1-sigma of a learned baseline (the model's validation figure); None when given
            "sigma_baseline_rel": baseline.sigma_rel,
        }
        more = {
            # each camera's EXIF focal length, where one was combined with the fields' (left, right)
            "focal_prior": [None if prior is None else prior.to_report() for prior in priors],
            # vertical line segments each camera's gravity was fitted with (left, right)
            "vertical_segments": work.used,
        }
        model = (self.model_path.name, self.network.model_sha256)
        calibration = assemble(
            cameras, pose, baseline.metres, baseline.scale_source, model, work.warnings, more_pose=more_pose,
            more=more, timing_ms=work.timing,
        )  # fmt: skip
        inliers = None
        if (
            pose.source != "pose_head"
            and pose.start is not None
            and len(pose.start.mask) == len(work.matches)
        ):
            inliers = np.asarray(pose.start.mask, dtype=bool).copy()
        return CalibrationResult(
            calibration, fits[0], fits[1], pose, work.warnings, work.matches, (priors[0], priors[1]),
            inliers=inliers, fields=(work.net.left, work.net.right),
            fields_focal=(work.fields_focal[0], work.fields_focal[1]),
        )  # fmt: skip
