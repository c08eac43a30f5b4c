"""The bridge to COLMAP: a sequence's frames become one rig's reconstruction, adjusted by COLMAP.

COLMAP (pycolmap) does all of the multi-view work: SIFT features, matching of each frame with its
neighbours in time (and the two images of a frame with each other), incremental mapping with the two
cameras as one rig (a left→right pose shared by every frame) and each camera's intrinsics shared by its
frames, then one last bundle adjustment whose cost profile tells how well the sequence fixes the focal
lengths. stereogeo's per-pair calibration only starts it: the focal lengths, the lens model and the rig's
R, T are the initial values, nothing more.

Pixel conventions: COLMAP puts (0, 0) at the top-left corner of the top-left pixel, stereogeo (OpenCV) at
its centre; a principal point x in stereogeo's pixels is x + 0.5 in COLMAP's.

COLMAP's own log (glog) never reaches the terminal: while it works for a sequence it is written to the
workspace's ``colmap.log`` (:func:`logging_into`), and elsewhere nowhere; its failures come as errors.
"""

from __future__ import annotations

import contextlib
import glob
import math
import os
import sys
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from stereogeo_cli.errors import CalibrationFailed
from stereogeo_cli.fuse.assemble import CameraEstimate
from stereogeo_cli.geometry import rotation_angle
from stereogeo_cli.sequence import blocks
from stereogeo_cli.sequence.blocks import BlockFit
from stereogeo_cli.settings import resolve

SENSORS = ("left", "right")  # the image folders of the workspace, and COLMAP's image-name prefixes

default_conf = {
    "max_features": 1024,  # SIFT features per image
    "overlap": 3,  # each frame is matched with this many following frames
    "quadratic_overlap": True,  # and with the frames 2, 4, 8, … further on
    # loop detection: every ``period``-th image is also matched with the ``images`` that look most like it,
    # however far apart in time (where the rig comes back), by a vocabulary tree of ``words`` visual words
    # built from ``sample`` of the sequence's own SIFT descriptors (nothing is downloaded); for recordings of
    # at least ``min_frames`` frames: on shorter ones the sequential window reaches across much of them, and
    # the extra wide-baseline pairs moved R and T's direction the wrong way (docs/sequence.md)
    "loop_detection": {
        "enabled": True,
        "min_frames": 100,
        "period": 5,
        "images": 20,
        "words": 1024,
        "sample": 40000,
    },
    "min_model_frames": 3,  # a model of fewer registered frames is no calibration
    "threads": -1,  # COLMAP's threads (-1: all cores)
    # overrides of COLMAP's IncrementalPipelineOptions: the global adjustments while frames are added
    # (the last adjustment, below, is global anyway)
    "mapping": {
        "ba_global_frames_ratio": 1.4,
        "ba_global_points_ratio": 1.4,
        "ba_global_max_num_iterations": 25,
    },
    # overrides of COLMAP's IncrementalMapperOptions: a drive straight ahead has no two frames 16° apart
    # (COLMAP's default for the first pair) and moves forward: the first pair may be narrower and forward
    "mapper": {"init_min_tri_angle": 4.0, "init_max_forward_motion": 0.99},
    "profile_step": 0.02,  # δ of the focal lengths' cost profile (adjust), in log f
    # the principal points are freed where the adjustment fixes the focal lengths better than this
    # (relative 1-sigma at the reprojection noise): the motion turned the rig enough to see them
    "principal_point_below": 0.01,
    # ... and kept where freeing them lowers the cost by more than this share: a real camera's principal
    # point 9 px off (EuRoC) explains 12 % of it, a render's exact centre 0.1-0.2 % (model noise)
    "principal_point_min_fall": 0.01,
    # the principal point's prior where an adjustment frees it under one (centre_reading): a Gaussian at
    # the image centre, its 1-sigma this share of the longer side (real cameras: within a few per cent)
    "principal_point_prior": 0.02,
}


@dataclass(frozen=True)
class CameraStart:
    """One camera as the adjustment starts from it (stereogeo's pixels): focal length, size, and whether a
    radial lens is fitted (COLMAP's RADIAL, k1 and k2, else SIMPLE_PINHOLE)."""

    focal_px: float
    width: int
    height: int
    radial: bool

    @property
    def model(self) -> str:
        return "RADIAL" if self.radial else "SIMPLE_PINHOLE"

    def params(self) -> list[float]:
        return [self.focal_px, *image_centre(self.width, self.height), *([0.0, 0.0] if self.radial else [])]


def image_centre(width: int, height: int) -> tuple[float, float]:
    """The image centre, stereogeo's principal point (w/2, h/2), in COLMAP's pixels (+0.5)."""
    return width / 2 + 0.5, height / 2 + 0.5


@dataclass
class SequenceModel:
    """The largest model COLMAP made of a sequence.

    ``cam_from_world``: per registered frame name its left camera's [4 x 4] world→camera transform (the
    world of the reconstruction, its scale arbitrary); ``R``, ``T`` the right camera from the left one
    (``X_right = R @ X_left + T``, in the reconstruction's scale).
    """

    reconstruction: object  # pycolmap.Reconstruction
    cameras: tuple[CameraEstimate, CameraEstimate]  # as adjusted: sigma focal_px, principal point, radial
    R: np.ndarray
    T: np.ndarray
    cam_from_world: dict[str, np.ndarray]
    models: int  # how many models the mapping made (1: the sequence held together)
    points: int
    reprojection_error_px: float
    notes: list[str] = field(default_factory=list)
    # the stretches left out one at a time (blocks.LeftOut), and the adjustment's cost profile's relative
    # sigma of the focal lengths (the cameras' sigma is the wider of it and the stretches')
    left_out: object = None
    robust: RobustReading | None = None
    centre: CentreReading | None = None
    profile_sigma_rel: float = math.inf


CANCEL_WAIT_S = 30.0  # at most this long for COLMAP to end its work once cancelled


class Cancelled(Exception):
    """The run was stopped (``stop.requested``) while COLMAP worked: nothing it made is used."""


def _cancellable(call, *args, stop=None, **kwargs):
    """``call(*args, **kwargs, cancellation_token=…)`` on a thread of its own, while the main thread waits
    in short steps: a signal's handler runs there (Python runs them only between its own instructions, never
    inside COLMAP) and once ``stop.requested`` the token cancels COLMAP's work. Raises :class:`Cancelled`."""
    import threading

    token = _pycolmap().CancellationToken()
    outcome: dict = {}
    finished = threading.Event()  # not Thread.join: a join cut by a signal's exception may mark the thread
    # ended while it still runs

    def run():
        try:
            outcome["value"] = call(*args, **kwargs, cancellation_token=token)
        except BaseException as error:  # noqa: BLE001 - handed to the waiting thread
            outcome["error"] = error
        finally:
            finished.set()

    threading.Thread(target=run, name="stereogeo-colmap", daemon=True).start()
    try:
        while not finished.wait(0.1):
            if stop is not None and stop.requested and not token.is_cancelled:
                token.cancel()
    except BaseException:  # a second signal: stop COLMAP too, since a thread still inside it when
        token.cancel()  # Python exits aborts the process; a third signal waits for it as well
        from stereogeo_cli.jobs.interrupt import protected

        with protected():
            finished.wait(CANCEL_WAIT_S)
        raise
    if token.is_cancelled:
        raise Cancelled()
    if "error" in outcome:
        raise outcome["error"]
    return outcome.get("value")


def _pycolmap():
    """The COLMAP bindings (~140 MB of libraries: loaded only for sequences), imported with the process's
    SIGINT and SIGTERM handlers kept: glog, loaded with them, installs its own over SIGTERM's, which
    prints a native stack and kills the process instead of letting the run stop cleanly. The two signals
    are blocked during the import, so one that comes meanwhile reaches the restored handler."""
    import sys

    if "pycolmap" not in sys.modules:
        import signal
        import threading

        from stereogeo_cli.jobs.interrupt import SIGNALS, signals_blocked

        main = threading.current_thread() is threading.main_thread()
        handlers = {s: signal.getsignal(s) for s in SIGNALS} if main else {}
        with signals_blocked():
            import pycolmap

            for s, handler in handlers.items():
                signal.signal(s, handler if handler is not None else signal.SIG_DFL)
    import pycolmap

    global _log_sinks_closed
    if not _log_sinks_closed:
        _close_log_sinks(pycolmap.logging)
        _log_sinks_closed = True
    return pycolmap


LOG_NAME = "colmap.log"  # COLMAP's log of a sequence, in its workspace (:func:`logging_into`)
_GLOG_FLAGS = ("logtostderr", "logtostdout", "alsologtostderr", "stderrthreshold", "minloglevel")
_log_sinks_closed = False  # whether _close_log_sinks ran (once per process)
_logging_into: Path | None = None  # the workspace whose log COLMAP writes now (logging_into)


def _close_log_sinks(log) -> None:
    """COLMAP's log (glog) written nowhere but where :func:`logging_into` sends it: not to the terminal
    (pycolmap's default also copies every line to stderr) and into no file of glog's own choosing (it
    would make one per severity in /tmp). A fatal error still shows on stderr, as the process ends."""
    log.logtostderr = log.logtostdout = log.alsologtostderr = False
    log.stderrthreshold = log.FATAL.value
    for level in (log.INFO, log.WARNING, log.ERROR, log.FATAL):
        log.set_log_destination(level, "")  # "": no file for this severity


@contextlib.contextmanager
def logging_into(workspace: str | os.PathLike):
    """While the block runs, COLMAP's log (every line, INFO up) goes to ``workspace/colmap.log``
    (:data:`LOG_NAME`, appended to) and none of it to the terminal. glog names its files itself (the name
    given, a time stamp and the process id): it writes into one of its own in the workspace, which is
    closed (flushed), appended to the log and removed as the block ends. Within such a block it does
    nothing more (COLMAP's log stays where the outer one sends it). Yields the log's path."""
    global _logging_into
    workspace = Path(workspace)
    if _logging_into is not None:
        yield _logging_into / LOG_NAME
        return
    log = _pycolmap().logging
    part = workspace / f".{LOG_NAME}.{os.getpid()}."  # glog's file: this name, its time stamp and pid
    saved = {name: getattr(log, name) for name in _GLOG_FLAGS}
    _logging_into = workspace
    try:
        log.logtostderr = log.logtostdout = log.alsologtostderr = False
        log.stderrthreshold, log.minloglevel = log.FATAL.value, log.INFO.value
        log.set_log_destination(log.INFO, str(part))  # every severity's lines land in INFO's file
        yield workspace / LOG_NAME
    finally:
        log.set_log_destination(log.INFO, "")  # closes glog's file
        for name, value in saved.items():
            setattr(log, name, value)
        _logging_into = None
        with contextlib.suppress(OSError), open(workspace / LOG_NAME, "ab") as out:  # a log is no result
            for written in sorted(workspace.glob(f"{glob.escape(part.name)}*")):
                out.write(written.read_bytes())
                written.unlink()


@contextlib.contextmanager
def _stderr_into(path: Path):
    """While the block runs, what the process writes to its stderr file descriptor (C++ libraries' own
    prints) is appended to ``path`` instead."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(path, "ab") as log:
            os.dup2(log.fileno(), 2)
            try:
                yield
            finally:
                os.dup2(saved, 2)
    finally:
        os.close(saved)


def image_features(image: np.ndarray, max_features: int) -> tuple[np.ndarray, np.ndarray]:
    """One image's SIFT keypoints as COLMAP stores them: positions [N x 2] float32 in COLMAP's pixels and
    descriptors [N x 128] uint8. OpenCV's SIFT (the pipeline's detector) is several times faster than
    COLMAP's on a CPU; its descriptors are L2-normalised and scaled by 512 as COLMAP's L2 ones are, so
    COLMAP's matcher takes them as they are."""
    from stereogeo_cli.fuse.matches import detect_features

    found = detect_features(image, {"max_features": max_features, "max_side": max(image.shape[:2])})
    if found.descriptors is None:
        return np.zeros((0, 2), np.float32), np.zeros((0, 128), np.uint8)
    descriptors = np.clip(np.rint(found.descriptors), 0, 255).astype(np.uint8)
    return (found.xy + 0.5).astype(np.float32), descriptors


def _matrix(rigid) -> np.ndarray:
    """A pycolmap Rigid3d as a [4 x 4] matrix."""
    M = np.eye(4)
    M[:3, :4] = rigid.matrix()
    return M


def _frame_name(image_name: str) -> str:
    return image_name.split("/", 1)[1]


def _write_cameras(db, starts: tuple[CameraStart, CameraStart]) -> None:
    """Give each folder's camera (one per sensor, made by the feature extraction) its start values, in the
    open database ``db``."""
    by_prefix = {}
    for image in db.read_all_images():
        by_prefix.setdefault(image.name.split("/", 1)[0], image.camera_id)
    for sensor, start in zip(SENSORS, starts, strict=True):
        camera = db.read_camera(by_prefix[sensor])
        camera.model = start.model
        camera.width, camera.height = start.width, start.height
        camera.params = start.params()
        camera.has_prior_focal_length = True
        db.update_camera(camera)


def _rig_config(pycolmap, R: np.ndarray, T: np.ndarray):
    """The rig: the left camera is the reference sensor, the right one sits at (R, T) from it."""
    right = pycolmap.Rigid3d(pycolmap.Rotation3d(np.asarray(R, float)), np.asarray(T, float))
    return pycolmap.RigConfig(
        cameras=[
            pycolmap.RigConfigCamera(ref_sensor=True, image_prefix=f"{SENSORS[0]}/"),
            pycolmap.RigConfigCamera(image_prefix=f"{SENSORS[1]}/", cam_from_rig=right),
        ]
    )


def match_frames(
    workspace: Path, starts: tuple[CameraStart, CameraStart], R: np.ndarray, T: np.ndarray, conf: dict,
    stop=None, features: dict | None = None,
) -> Path:  # fmt: skip
    """Features and verified matches of the workspace's ``images/left`` and ``images/right`` frames in a
    COLMAP database (returned): each frame with its ``overlap`` successors in time, and the two images of
    each frame with each other. ``features``: per image name (``left/000000.png``) its
    :func:`image_features` (else COLMAP extracts its own)."""
    pycolmap = _pycolmap()
    conf = resolve(default_conf, conf)
    database = workspace / "database.db"
    database.unlink(missing_ok=True)
    with pycolmap.Database.open(database):  # a new, empty database
        pass
    reader = pycolmap.ImageReaderOptions(camera_model=starts[0].model, camera_params=",".join(
        str(p) for p in starts[0].params()
    ))  # fmt: skip
    if features is None:
        sift = pycolmap.SiftExtractionOptions(max_num_features=conf["max_features"])
        extraction = pycolmap.FeatureExtractionOptions(num_threads=conf["threads"], sift=sift)
        _cancellable(
            pycolmap.extract_features, database, workspace / "images",
            camera_mode=pycolmap.CameraMode.PER_FOLDER, reader_options=reader,
            extraction_options=extraction, device=pycolmap.Device.cpu, stop=stop,
        )  # fmt: skip
    else:
        pycolmap.import_images(
            database, workspace / "images", camera_mode=pycolmap.CameraMode.PER_FOLDER, options=reader
        )
        with pycolmap.Database.open(database) as db:
            for image in db.read_all_images():
                keypoints, descriptors = features[image.name]
                db.write_keypoints(image.image_id, keypoints)
                db.write_descriptors(
                    image.image_id,
                    pycolmap.FeatureDescriptors(pycolmap.FeatureExtractorType.SIFT, descriptors),
                )
    with pycolmap.Database.open(database) as db:
        _write_cameras(db, starts)
        pycolmap.apply_rig_config([_rig_config(pycolmap, R, T)], db)
    matching = pycolmap.FeatureMatchingOptions(num_threads=conf["threads"])
    loops = conf["loop_detection"]
    detect = loops["enabled"] and _frame_count(workspace) >= loops["min_frames"]
    pairing = pycolmap.SequentialPairingOptions(
        overlap=conf["overlap"], quadratic_overlap=conf["quadratic_overlap"], loop_detection=detect,
        **(_loop_options(database, workspace, loops, conf["threads"]) if detect else {}),
    )  # fmt: skip
    _cancellable(
        pycolmap.match_sequential, database, matching_options=matching, pairing_options=pairing,
        device=pycolmap.Device.cpu, stop=stop,
    )  # fmt: skip
    return database


def _frame_count(workspace: Path) -> int:
    """How many frames the workspace holds (its left camera's images)."""
    return len(os.listdir(workspace / "images" / SENSORS[0]))


def _loop_options(database: Path, workspace: Path, loops: dict, threads: int) -> dict:
    """The sequential matching's loop detection options, with a vocabulary tree (COLMAP's visual index)
    built from an even sample of the database's own descriptors into ``workspace``: COLMAP's trees are
    downloads, and one recording's own words find its own places again."""
    pycolmap = _pycolmap()
    with pycolmap.Database.open(database) as db:
        descriptors = [np.asarray(db.read_descriptors(image.image_id).data) for image in db.read_all_images()]
    pool = np.concatenate(descriptors).astype(np.float32)
    sample = pool[np.random.default_rng(0).permutation(len(pool))[: loops["sample"]]]
    words = int(min(loops["words"], max(len(sample) // 40, 16)))  # the clustering wants 40 points a word
    index = pycolmap.VisualIndex.create(sample.shape[1], 64)
    build = pycolmap.VisualIndex.BuildOptions(num_visual_words=words, num_iterations=10, num_rounds=1,
                                              num_threads=threads)  # fmt: skip
    with _stderr_into(workspace / LOG_NAME):  # the clustering's own warnings, printed outside COLMAP's log
        index.build(build, pycolmap.FeatureDescriptorsFloat(pycolmap.FeatureExtractorType.SIFT, sample))
    path = workspace / "vocabulary.bin"
    index.write(path)
    return {
        "vocab_tree_path": str(path),
        "loop_detection_period": loops["period"],
        "loop_detection_num_images": loops["images"],
    }


def _mapping_options(pycolmap, radial: bool, conf: dict):
    pipeline = {
        "num_threads": conf["threads"],
        "ba_refine_focal_length": True,
        "ba_refine_principal_point": False,
        "ba_refine_extra_params": radial,
        "ba_refine_sensor_from_rig": True,
        "min_model_size": conf["min_model_frames"],
        "random_seed": 0,
        **conf["mapping"],  # e.g. fewer global adjustments while frames are added
    }
    return pycolmap.IncrementalPipelineOptions(
        **pipeline, mapper=pycolmap.IncrementalMapperOptions(**conf["mapper"])
    )


def map_frames(workspace: Path, database: Path, radial: bool, conf: dict, stop=None) -> list:
    """COLMAP's incremental mapping of the matched frames: its models, largest first."""
    pycolmap = _pycolmap()
    conf = resolve(default_conf, conf)
    out = workspace / "mapping"
    out.mkdir(exist_ok=True)
    models = _cancellable(
        pycolmap.incremental_mapping, database, workspace / "images", out,
        options=_mapping_options(pycolmap, radial, conf), stop=stop,
    )  # fmt: skip
    return sorted(models.values(), key=lambda r: r.num_reg_frames(), reverse=True)


@dataclass(frozen=True)
class CentrePrior:
    """A Gaussian prior on each camera's principal point: at the image centre, its 1-sigma ``share`` of
    the image's longer side; ``noise_px`` is the reprojection noise that weighs it against the residuals
    (the adjustment's cost is then the negative log-posterior times the noise's variance)."""

    noise_px: float
    share: float


def _add_centre_prior(adjuster, reconstruction, prior: CentrePrior) -> list:
    """Each camera's :class:`CentrePrior` as one residual block of the adjuster's Ceres problem (pyceres,
    on COLMAP's own parameter block of the camera's intrinsics). Returns the cost functions, which must
    live as long as the problem is solved."""
    import pyceres

    class PrincipalPointPrior(pyceres.CostFunction):
        def __init__(self, size: int, indices, centre, weight: float):
            super().__init__()
            self.set_num_residuals(2)
            self.set_parameter_block_sizes([size])
            self.indices, self.centre, self.weight = list(indices), np.asarray(centre, float), weight

        def Evaluate(self, parameters, residuals, jacobians):  # noqa: N802 (Ceres' name)
            params = parameters[0]
            residuals[:] = self.weight * (params[self.indices] - self.centre)
            if jacobians is not None and jacobians[0] is not None:
                jacobian = np.zeros((2, len(params)))
                jacobian[[0, 1], self.indices] = self.weight
                jacobians[0][:] = jacobian.ravel()
            return True

    costs = []
    for camera in reconstruction.cameras.values():
        sigma_px = prior.share * max(camera.width, camera.height)
        centre = image_centre(camera.width, camera.height)
        cost = PrincipalPointPrior(
            len(camera.params), camera.principal_point_idxs(), centre, prior.noise_px / sigma_px
        )
        adjuster.problem.add_residual_block(cost, None, [camera.params])
        costs.append(cost)
    return costs


def _bundle_adjust(
    reconstruction, radial: bool, refine_focal: bool, refine_principal_point: bool = False, images=None,
    robust_scale_px: float | None = None, centre_prior: CentrePrior | None = None,
) -> tuple[float, int]:  # fmt: skip
    """COLMAP's bundle adjustment of every registered frame (or only the registered ``images``, by id),
    the rig, the points and the intrinsics (the focal lengths only where ``refine_focal``, the principal
    point only where ``refine_principal_point`` or under ``centre_prior``), in least squares (or with a
    Cauchy loss of scale ``robust_scale_px``). Returns its final cost (½ Σ r², r in pixels, a prior's
    residuals included) and its degrees of freedom (residuals less parameters).

    Raises:
        CalibrationFailed: the solver ended without a usable solution (its cost means nothing then).
    """
    pycolmap = _pycolmap()
    options = pycolmap.BundleAdjustmentOptions(
        refine_focal_length=refine_focal,
        refine_principal_point=refine_principal_point or centre_prior is not None,
        refine_extra_params=radial,
        refine_sensor_from_rig=True,
        print_summary=False,
    )
    if centre_prior is not None:  # the prior is evaluated in Python: Ceres must call it from this thread
        options.ceres.solver_options.num_threads = 1
        options.ceres.min_num_residuals_for_cpu_multi_threading = 2**31 - 1
    if robust_scale_px is not None:
        options.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
        options.ceres.loss_function_scale = float(robust_scale_px)
    config = pycolmap.BundleAdjustmentConfig()
    for image_id in reconstruction.reg_image_ids() if images is None else images:
        config.add_image(image_id)
    config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
    adjuster = pycolmap.create_default_ceres_bundle_adjuster(options, config, reconstruction)
    priors = [] if centre_prior is None else _add_centre_prior(adjuster, reconstruction, centre_prior)
    summary = adjuster.solve()
    del priors  # held until the problem was solved
    if not summary.is_solution_usable():  # e.g. FAILURE (a problem Ceres could not solve, or no residuals)
        solver = getattr(summary, "ceres_summary", None)  # absent where Ceres did not run
        reason = " ".join(str(solver.message).split()) if solver is not None else ""
        raise CalibrationFailed(
            f"COLMAP's bundle adjustment found no usable solution ({summary.termination_type.name}"
            f"{': ' + reason if reason else ''})"
        )
    ceres = summary.ceres_summary
    return float(ceres.final_cost), int(ceres.num_residuals_reduced - ceres.num_effective_parameters_reduced)


def adjust(reconstruction, radial: bool, conf: dict, stop=None):
    """One last bundle adjustment, and how well it fixes the focal lengths.

    COLMAP's covariance estimator does not take a rig's non-reference cameras, so the focal lengths'
    1-sigma comes from the adjustment's cost profile instead: both focal lengths scaled by e^±δ and held
    while everything else (poses, rig, points, lens) is adjusted again; the cost rises by Δ, and with the
    noise σ² = 2·cost / dof the relative 1-sigma of the common scale is δ / √(2Δ / σ²). The common scale is
    what a motion without rotation leaves free (their ratio the rig's own matches fix): where the cost
    barely rises, the sigma is wide.

    Where the motion fixes the focal lengths (relative sigma below ``principal_point_below``: the rig
    turned), it can show the principal points too: an adjustment frees them, and it is kept where the cost
    falls by more than ``principal_point_min_fall`` of itself: an off-centre principal point held at the
    centre biases f and R, and one freed without need adds noise to them (on thousands of points a fall
    is always "significant": the share is the practical test). Elsewhere they stay at the image centre.

    Returns the (left, right) :class:`~stereogeo_cli.fuse.assemble.CameraEstimate` as adjusted (its
    focal length's 1-sigma from the cost profile, the same relative one for both; the principal point in
    stereogeo's pixels; COLMAP RADIAL's k1, k2, which are OpenCV's, 0 for a pinhole) and the adjusted
    reconstruction (``reconstruction`` itself, or its copy with the principal points freed). ``stop``: once
    it is requested, :class:`Cancelled` is raised before the next of its adjustments."""
    pycolmap = _pycolmap()

    def go_on() -> None:
        if stop is not None and stop.requested:
            raise Cancelled()

    cost, dof = _bundle_adjust(reconstruction, radial, refine_focal=True)
    noise = 2.0 * cost / max(dof, 1)
    delta = conf["profile_step"]
    rises = []
    for sign in (1.0, -1.0):
        go_on()
        trial = pycolmap.Reconstruction(reconstruction)
        for camera in trial.cameras.values():
            params = np.array(camera.params)
            params[list(camera.focal_length_idxs())] *= math.exp(sign * delta)
            camera.params = params
        rises.append(_bundle_adjust(trial, radial, refine_focal=False)[0] - cost)
    rise = max(float(np.mean(rises)), 0.0)
    sigma_rel = delta / math.sqrt(2.0 * rise / noise) if rise > 0 and noise > 0 else math.inf
    free_centre = False
    if sigma_rel < conf["principal_point_below"]:
        go_on()
        trial = pycolmap.Reconstruction(reconstruction)
        freed = _bundle_adjust(trial, radial, refine_focal=True, refine_principal_point=True)[0]
        if cost - freed > conf["principal_point_min_fall"] * cost:
            reconstruction, free_centre = trial, True
    cameras = []
    for camera_id in _camera_ids(reconstruction):
        camera = reconstruction.cameras[camera_id]
        params = [float(p) for p in camera.params]
        k = params[3:5] if radial else [0.0, 0.0]
        # COLMAP's principal point in stereogeo's pixels (pixel centres at integers)
        centre = (camera.principal_point_x - 0.5, camera.principal_point_y - 0.5)
        sigma = {"focal_px": params[0] * sigma_rel}
        size = camera.width, camera.height
        cameras.append(CameraEstimate(params[0], *size, None, sigma, centre, free_centre, (k[0], k[1])))
    return (cameras[0], cameras[1]), reconstruction


def _block_fit(reconstruction) -> BlockFit:
    """A reconstruction's cameras (K and OpenCV D in stereogeo's pixels) and rig, as :class:`BlockFit`."""
    K, D, focal = [], [], []
    for camera_id in _camera_ids(reconstruction):
        camera = reconstruction.cameras[camera_id]
        params = [float(p) for p in camera.params]
        f, cx, cy = params[0], camera.principal_point_x - 0.5, camera.principal_point_y - 0.5
        K.append(np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]]))
        D.append(np.array([*(params[3:5] if len(params) >= 5 else [0.0, 0.0]), 0.0, 0.0]))
        focal.append(f)
    right_from_left = _right_from_left(reconstruction)
    return BlockFit((focal[0], focal[1]), (K[0], K[1]), (D[0], D[1]), right_from_left[:3, :3],
                    right_from_left[:3, 3])  # fmt: skip


def _frames(reconstruction) -> dict[str, dict[str, int]]:
    """Per frame name the registered image ids of its sensors (``{"left": id, "right": id}``)."""
    frames: dict[str, dict[str, int]] = {}
    for image_id in reconstruction.reg_image_ids():
        sensor, name = reconstruction.images[image_id].name.split("/", 1)
        frames.setdefault(name, {})[sensor] = image_id
    return frames


def _correspondences(reconstruction, left_id: int, right_id: int) -> tuple[np.ndarray, np.ndarray]:
    """The points of the model seen by both images of one frame: their pixels (stereogeo's) in each."""
    seen = [{p.point3D_id: p.xy for p in reconstruction.images[i].points2D if p.has_point3D()}
            for i in (left_id, right_id)]  # fmt: skip
    common = sorted(set(seen[0]) & set(seen[1]))
    if not common:
        return np.zeros((0, 2)), np.zeros((0, 2))
    return tuple(np.array([s[k] for k in common], float) - 0.5 for s in seen)


@dataclass(frozen=True)
class Parting:
    """How far another adjustment of the same frames lies from the last one: the focal lengths' common
    scale (relative), R and T's direction (degrees)."""

    focal_rel: float
    rotation_deg: float
    direction_deg: float

    def to_report(self) -> dict:
        return {name: getattr(self, name) for name in ("focal_rel", "rotation_deg", "direction_deg")}


@dataclass(frozen=True)
class RobustReading(Parting):
    """How far the last adjustment moves when its residuals are weighed robustly (a Cauchy loss at the
    residuals' own scale) instead of in least squares. Where the model fits the data (one camera model, a
    still scene, Gaussian residuals) the two estimators agree to well within their sigmas; where they part,
    the minimum rests on how the residuals are weighed, not on the data, and the parting is a sigma of its
    own."""

    scale_px: float

    def to_report(self) -> dict:
        return {**super().to_report(), "loss_scale_px": self.scale_px}


def robust_reading(reconstruction, radial: bool, free_centre: bool, stop=None) -> RobustReading:
    """The last adjustment run again with a Cauchy loss at the model's mean reprojection error
    (:class:`RobustReading`)."""
    pycolmap = _pycolmap()
    if stop is not None and stop.requested:
        raise Cancelled()
    scale = max(float(reconstruction.compute_mean_reprojection_error()), 0.1)
    trial = pycolmap.Reconstruction(reconstruction)
    _bundle_adjust(
        trial, radial, refine_focal=True, refine_principal_point=free_centre, robust_scale_px=scale
    )
    return RobustReading(*_parting(_block_fit(reconstruction), _block_fit(trial)), scale)


def _parting(fit: BlockFit, other: BlockFit) -> tuple[float, float, float]:
    """:class:`Parting`'s three numbers: how far ``other`` lies from ``fit``."""
    common = 0.5 * sum(math.log(o / f) for o, f in zip(other.focal_px, fit.focal_px, strict=True))
    cosine = float(other.T @ fit.T / (np.linalg.norm(other.T) * np.linalg.norm(fit.T)))
    return (
        abs(common), math.degrees(rotation_angle(other.R @ fit.R.T)),
        math.degrees(math.acos(max(-1.0, min(1.0, cosine)))),
    )  # fmt: skip


@dataclass(frozen=True)
class CentreReading(Parting):
    """How far the last adjustment moves when its principal points are freed under a prior at the image
    centre (:class:`CentrePrior`) instead of held there (or freed without one). A real camera's principal
    point may lie a few per cent off the centre: where the reading parts from the adjustment, the focal
    lengths, R and T rest on how the principal points are modelled (on a drive straight ahead they trade
    with the focal length, and the two cameras' with R), not on the data, and the parting is a sigma of
    its own. ``principal_points``: the reading's, (left, right) in stereogeo's pixels."""

    principal_points: tuple[tuple[float, float], tuple[float, float]]
    focal_px: tuple[float, float]  # the reading's focal lengths (left, right)
    prior_share: float  # the prior's 1-sigma, a share of the image's longer side

    def to_report(self) -> dict:
        sides = ("left", "right")
        return {
            **super().to_report(),
            "prior_sigma_rel": self.prior_share,
            "focal_px": list(self.focal_px),
            "principal_point_px": {s: list(p) for s, p in zip(sides, self.principal_points, strict=True)},
        }


def centre_reading(reconstruction, radial: bool, free_centre: bool, conf: dict, stop=None) -> CentreReading:
    """The last adjustment run again with the principal points freed under a prior at the image centre
    (:class:`CentreReading`), the prior weighed by the adjustment's own reprojection noise."""
    pycolmap = _pycolmap()
    if stop is not None and stop.requested:
        raise Cancelled()
    trial = pycolmap.Reconstruction(reconstruction)
    cost, dof = _bundle_adjust(trial, radial, refine_focal=True, refine_principal_point=free_centre)
    prior = CentrePrior(math.sqrt(2.0 * cost / max(dof, 1)), conf["principal_point_prior"])
    _bundle_adjust(trial, radial, refine_focal=True, centre_prior=prior)
    points = tuple(
        (trial.cameras[i].principal_point_x - 0.5, trial.cameras[i].principal_point_y - 0.5)
        for i in _camera_ids(trial)
    )
    fit = _block_fit(trial)
    return CentreReading(*_parting(_block_fit(reconstruction), fit), points, tuple(fit.focal_px), prior.share)


def left_out_blocks(reconstruction, radial: bool, free_centre: bool, sizes: tuple, conf: dict, stop=None):
    """The jackknife over stretches of the sequence and the left-out frames' row check
    (:mod:`~stereogeo_cli.sequence.blocks`): the adjustment run again without each stretch (as the last one
    was run: the focal lengths and the lens refined, the principal points where they were freed). None
    where the sequence has too few frames for the conf's ``blocks``. ``sizes``: ((h, w) left, right)."""
    pycolmap = _pycolmap()
    settings = resolve(blocks.default_conf, conf.get("blocks"))
    frames = _frames(reconstruction)
    both = [name for name, ids in frames.items() if len(ids) == 2]
    if len(both) < settings["blocks"] * settings["min_block_frames"]:
        return None
    fits, rows = [], []
    for stretch in blocks.stretches(both, settings["blocks"]):
        if stop is not None and stop.requested:
            raise Cancelled()
        left_out = {i for name in stretch for i in frames[name].values()}
        kept = [i for i in reconstruction.reg_image_ids() if i not in left_out]
        trial = pycolmap.Reconstruction(reconstruction)
        _bundle_adjust(trial, radial, refine_focal=True, refine_principal_point=free_centre, images=kept)
        fit = _block_fit(trial)
        fits.append(fit)
        pairs = [_correspondences(reconstruction, frames[n]["left"], frames[n]["right"]) for n in stretch]
        rows.append(blocks.row_errors(fit, sizes, [p for p in pairs if len(p[0])]))
    return blocks.summarise(fits, np.concatenate(rows))


def rig_sigmas(model: SequenceModel) -> tuple[float, float]:
    """R's and T's direction's 1-sigma (degrees) from the frames themselves: each registered frame's right
    camera located alone (PnP against the adjusted points, its own pose, not the rig's) gives one reading
    of the rig's R and T's direction; the sigma is their RMS distance from the rig's over √n (the
    standard error of their mean), as the rig is in effect their mean. Infinite with fewer than 3."""
    pycolmap = _pycolmap()
    reconstruction = model.reconstruction
    left_id, right_id = _camera_ids(reconstruction)
    direction = model.T / np.linalg.norm(model.T)
    angles, turns = [], []
    for image_id in reconstruction.reg_image_ids():
        image = reconstruction.images[image_id]
        name = _frame_name(image.name)
        if image.camera_id != right_id or name not in model.cam_from_world:
            continue
        seen = [p for p in image.points2D if p.has_point3D()]
        if len(seen) < 12:
            continue
        xy = np.array([p.xy for p in seen])
        xyz = np.array([reconstruction.points3D[p.point3D_id].xyz for p in seen])
        found = pycolmap.estimate_and_refine_absolute_pose(xy, xyz, reconstruction.cameras[right_id])
        if not found:
            continue
        right = _matrix(found["cam_from_world"])
        left = model.cam_from_world[name]
        R = right[:3, :3] @ left[:3, :3].T
        T = right[:3, 3] - R @ left[:3, 3]
        turns.append(math.degrees(rotation_angle(R @ model.R.T)))
        cosine = float(np.clip(T @ direction / max(np.linalg.norm(T), 1e-12), -1.0, 1.0))
        angles.append(math.degrees(math.acos(cosine)))
    if len(turns) < 3:
        return math.inf, math.inf
    n = len(turns)
    return (
        math.sqrt(float(np.mean(np.square(turns))) / n),
        math.sqrt(float(np.mean(np.square(angles))) / n),
    )


def segment_normals(reconstruction, segments: dict, min_length_px: float) -> tuple[np.ndarray, np.ndarray]:
    """The planes through each registered image's line segments and its camera centre, in the world.

    ``segments``: per image name ``[N x 4]`` (x1, y1, x2, y2) in stereogeo's pixels. Each segment's ends
    are unprojected through the image's adjusted camera (its lens included) and the plane's unit normal
    r1 × r2 is turned into the world. A vertical segment's normal is perpendicular to the world's up.
    Returns the normals [M x 3] and the index of the image each came from [M]."""
    normals, owners = [], []
    for image_id in reconstruction.reg_image_ids():
        image = reconstruction.images[image_id]
        found = segments.get(image.name)
        if found is None or len(found) == 0:
            continue
        found = found[np.hypot(found[:, 2] - found[:, 0], found[:, 3] - found[:, 1]) >= min_length_px]
        if len(found) == 0:
            continue
        camera = reconstruction.cameras[image.camera_id]
        ends = found.reshape(-1, 2) + 0.5  # COLMAP's pixels
        rays = np.asarray(camera.cam_ray_from_img(ends), float).reshape(-1, 2, 3)
        n = np.cross(rays[:, 0], rays[:, 1])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        world_from_cam = _matrix(image.cam_from_world())[:3, :3].T
        normals.append(n @ world_from_cam.T)
        owners.append(np.full(len(n), image_id))
    if not normals:
        return np.zeros((0, 3)), np.zeros(0, int)
    return np.concatenate(normals), np.concatenate(owners)


def align_world(model: SequenceModel, up: np.ndarray, scale: float) -> np.ndarray:
    """Move the reconstruction into the output's world: z along ``up``, the first registered frame's left
    camera at the origin looking along +y, ``scale`` metres per unit. Returns that similarity [4 x 4]
    (new world ← old world)."""
    pycolmap = _pycolmap()
    z = up / np.linalg.norm(up)
    first = np.linalg.inv(model.cam_from_world[sorted(model.cam_from_world)[0]])  # world ← camera
    x = np.cross(first[:3, 2], z)  # across the first camera's optical axis, level
    x = x / np.linalg.norm(x) if np.linalg.norm(x) > 1e-6 else np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    rotation = np.stack([x, np.cross(z, x), z])
    translation = -scale * rotation @ first[:3, 3]
    model.reconstruction.transform(pycolmap.Sim3d(scale, pycolmap.Rotation3d(rotation), translation))
    S = np.eye(4)
    S[:3, :3], S[:3, 3] = scale * rotation, translation
    return S


def cam_from_new_world(cam_from_world: np.ndarray, new_from_old: np.ndarray) -> np.ndarray:
    """A camera's rigid world→camera transform [4 x 4] in the world a similarity ``new_from_old``
    (:func:`align_world`'s) moved the reconstruction into: a rotation and a translation in the new world's
    units (``cam_from_world @ inv(new_from_old)`` alone is that transform divided by the similarity's
    scale)."""
    scale = float(np.cbrt(np.linalg.det(new_from_old[:3, :3])))
    moved = cam_from_world @ np.linalg.inv(new_from_old)
    moved[:3, :] *= scale
    return moved


def model_files(reconstruction) -> dict[str, bytes]:
    """The COLMAP model (binary, as COLMAP writes it) as ``{"sparse/0/<file>": bytes}``."""
    with tempfile.TemporaryDirectory(prefix="stereogeo-model-") as folder:
        reconstruction.write_binary(folder)
        return {f"sparse/0/{p.name}": p.read_bytes() for p in sorted(Path(folder).iterdir()) if p.is_file()}


def _camera_ids(reconstruction) -> tuple[int, int]:
    """The camera ids of the left and the right sensor."""
    ids: dict[str, int] = {}
    for image in reconstruction.images.values():
        ids.setdefault(image.name.split("/", 1)[0], image.camera_id)
    return ids[SENSORS[0]], ids[SENSORS[1]]


def _right_from_left(reconstruction) -> np.ndarray:
    """The rig's right camera from its left one [4 x 4], read off the first frame with both images."""
    frames = _frames(reconstruction)
    both = sorted(name for name, ids in frames.items() if len(ids) == 2)
    if not both:
        raise CalibrationFailed("COLMAP registered no frame with both of its images")
    left, right = (_matrix(reconstruction.images[frames[both[0]][s]].cam_from_world()) for s in SENSORS)
    return right @ np.linalg.inv(left)


def read_model(adjusted, models: int) -> SequenceModel:
    """The pieces of an adjusted reconstruction (:func:`adjust`'s result) that the calibration needs."""
    cameras, reconstruction = adjusted
    left_id, right_id = _camera_ids(reconstruction)
    cam_from_world: dict[str, np.ndarray] = {}
    right_from_world: dict[str, np.ndarray] = {}
    for image_id in reconstruction.reg_image_ids():
        image = reconstruction.images[image_id]
        pose = _matrix(image.cam_from_world())
        (cam_from_world if image.camera_id == left_id else right_from_world)[_frame_name(image.name)] = pose
    right_from_left = _right_from_left(reconstruction)
    return SequenceModel(
        reconstruction=reconstruction,
        cameras=cameras,
        R=right_from_left[:3, :3],
        T=right_from_left[:3, 3],
        cam_from_world=cam_from_world,
        models=models,
        points=reconstruction.num_points3D(),
        reprojection_error_px=float(reconstruction.compute_mean_reprojection_error()),
    )


def reconstruct(
    workspace: str | os.PathLike, starts: tuple[CameraStart, CameraStart], R: np.ndarray, T: np.ndarray,
    conf: dict | None = None, stop=None, features: dict | None = None, progress=None,
) -> SequenceModel:  # fmt: skip
    """The whole bridge: match, map and adjust the frames in ``workspace/images/{left,right}/`` (the same
    file names in both, in time order), starting from ``starts`` and the rig (R, T). ``stop``: a
    :class:`~stereogeo_cli.jobs.interrupt.Stop` whose request cancels COLMAP's work (:class:`Cancelled`).
    ``progress``: called as ``progress(0, None, stage)`` when each of the three stages starts. COLMAP's
    log of it all is ``workspace/colmap.log`` (:func:`logging_into`; a log from before is replaced).

    Raises:
        CalibrationFailed: COLMAP made no model of at least ``min_model_frames`` frames.
    """
    conf = resolve(default_conf, conf)
    workspace = Path(workspace)

    def stage(name: str) -> None:
        if progress is not None:
            progress(0, None, name)

    (workspace / LOG_NAME).unlink(missing_ok=True)  # this run's log, as its database is this run's
    with logging_into(workspace):
        stage("COLMAP: matching the frames")
        database = match_frames(workspace, starts, R, T, conf, stop, features)
        radial = starts[0].radial or starts[1].radial
        stage("COLMAP: mapping")
        models = map_frames(workspace, database, radial, conf, stop)
        if models and hasattr(progress, "note"):  # the frames registered, on the stage's line
            progress.note(f"{models[0].num_reg_frames()} of {_frame_count(workspace)} frames registered")
        if not models or models[0].num_reg_frames() < conf["min_model_frames"]:
            raise CalibrationFailed(
                "COLMAP could not reconstruct the sequence (too few frames share enough features): "
                "a sequence needs overlapping views of a textured scene"
            )
        stage("COLMAP: bundle adjustment")
        cameras, adjusted = adjust(models[0], radial, conf, stop)
        stage("COLMAP: cross-checking the adjustment")  # the left-out stretches and the two readings
        sizes = tuple((start.height, start.width) for start in starts)
        free_centre = cameras[0].principal_point_refined
        left_out = left_out_blocks(adjusted, radial, free_centre, sizes, conf, stop)
        robust = robust_reading(adjusted, radial, free_centre, stop)
        centre = centre_reading(adjusted, radial, free_centre, conf, stop)
        return _with_readings(read_model((cameras, adjusted), len(models)), left_out, robust, centre)


def _with_readings(
    model: SequenceModel, left_out, robust: RobustReading, centre: CentreReading
) -> SequenceModel:
    """The model with the other readings of its focal lengths: each one's sigma the widest of the cost
    profile's, the left-out stretches' jackknife, the robust adjustment's parting and the other principal
    points' parting (the profile measures how sharply the adjustment's own model ties the focal lengths;
    the stretches how far the data move them; the robust loss how far the weighing of the residuals does;
    the principal points how far their model does)."""
    others = [robust.focal_rel, centre.focal_rel] + ([] if left_out is None else [left_out.focal_sigma_rel])
    cameras = []
    for camera in model.cameras:
        profile = camera.sigma_focal_rel
        wider = max(profile, *others) if math.isfinite(profile) else profile
        cameras.append(replace(camera, sigma={**camera.sigma, "focal_px": camera.focal_px * wider}))
    profile = model.cameras[0].sigma_focal_rel
    return replace(
        model,
        cameras=tuple(cameras),
        left_out=left_out,
        robust=robust,
        centre=centre,
        profile_sigma_rel=profile,
    )
