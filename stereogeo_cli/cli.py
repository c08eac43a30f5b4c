"""The command line: parse arguments, render with Rich, map errors to exit codes — nothing else."""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
import typer.core

from stereogeo_cli import __version__
from stereogeo_cli.errors import EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_PARTIAL_BATCH, StereoGeoError

# Exits and usage errors that Typer turns into exit codes itself (its click may be vendored or the package)
_PASS_THROUGH = (
    KeyboardInterrupt,
    typer.Exit,
    typer.Abort,
    *{cls for cls in typer.BadParameter.__mro__ if cls.__name__ == "ClickException"},
)


class _Command(typer.core.TyperCommand):
    """Every command's errors mapped in one place: a :class:`StereoGeoError` (bad input, a failed
    calibration) becomes its one-line message and exit code, anything else one line and exit code 1, never
    a traceback. And help as a user reads it: flags without a type placeholder, arguments as LEFT."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except StereoGeoError as error:
            raise fail(error) from None
        except _PASS_THROUGH:
            raise  # an exit code chosen on purpose, or a usage error Typer reports itself
        except Exception as error:  # noqa: BLE001 - any other failure is ours: one line, exit 1
            raise _internal(error) from None

    def get_params(self, ctx):
        params = super().get_params(ctx)
        for param in params:
            if getattr(param, "is_flag", False) and param.metavar is None:
                param.metavar = ""  # a flag takes no value: no "<bool>"
        return params

    def collect_usage_pieces(self, ctx):
        pieces = super().collect_usage_pieces(ctx)
        # Typer writes a required argument as {name}; the convention of Unix usage lines is NAME
        return [p[1:-1].upper() if p.startswith("{") and p.endswith("}") else p for p in pieces]


class _Typer(typer.Typer):
    def command(self, *args, **kwargs):
        kwargs.setdefault("cls", _Command)
        return super().command(*args, **kwargs)


app = _Typer(
    name="stereogeo",
    help="Calibrate a stereo camera from one image pair, with no calibration pattern.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _version(value: bool) -> None:
    if value:
        from stereogeo_cli.network.runtime import default_model_path, model_version

        path = default_model_path()
        try:
            model = f"model {model_version(path)}"
        except StereoGeoError as error:
            model = f"no usable model ({error})"
        typer.echo(f"stereogeo {__version__}, {model}")
        raise typer.Exit()


# What the training side needs beyond the runtime: the modules of the "train" extra (pyproject.toml)
TRAINING_MODULES = ("torch", "onnx", "moderngl", "skimage", "efficientnet_lite_pytorch")
INSTALL_TRAINING = 'pip install "stereogeo[train]"'


def require_training_extra(command: str) -> None:
    """Raise a one-line error naming the extra to install when a training module is missing."""
    import importlib.util

    missing = [name for name in TRAINING_MODULES if importlib.util.find_spec(name) is None]
    if missing:
        raise StereoGeoError(
            f"stereogeo {command} needs the training extra ({', '.join(missing)} not installed): "
            f"{INSTALL_TRAINING}"
        )


@app.callback()
def _root(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit."),
    ] = False,
) -> None:
    """Calibrate a stereo camera from one image pair, with no calibration pattern."""


def fail(error: StereoGeoError) -> typer.Exit:
    """Print a one-line error on stderr and return the exit to raise."""
    typer.echo(f"error: {error}", err=True)
    return typer.Exit(code=error.exit_code)


# the options of make-data
_MakeDataOut = Annotated[
    Path | None,
    typer.Argument(
        help="Folder for the dataset (left/, right/, calib.jsonl; resumed if it exists), "
        "or for the sequence (left/, right/, calib.json)."
    ),
]
_MakeDataCount = Annotated[
    int | None,
    typer.Option(
        "--count", "-n", help="Number of stereo pairs (default 1000), or frames of a --sequence (50)."
    ),
]
_MakeDataSequence = Annotated[
    str | None,
    typer.Option(
        help="Render one sequence of a stereo rig moving through one scene instead of independent pairs: "
        "straight, turning, handheld, static, or drive (a car's rig on a road at 10 Hz; per-frame ground "
        "truth in calib.json)."
    ),
]
_MakeDataSize = Annotated[
    int | None, typer.Option(help="Short side of the images in pixels (default 240; sequences 480).")
]
_MakeDataAspects = Annotated[
    str | None,
    typer.Option(
        help="Comma-separated aspect ratios (width:height) to draw image sizes from "
        "(default 4:3,16:9,1:1,3:2; sequences 4:3)."
    ),
]
_MakeDataVfovMin = Annotated[
    float | None,
    typer.Option(help="Smallest vertical field of view, in degrees (default 20; sequences 45)."),
]
_MakeDataVfovMax = Annotated[
    float | None,
    typer.Option(help="Largest vertical field of view, in degrees (default 105; sequences 80)."),
]
_MakeDataBaselineMin = Annotated[
    float | None, typer.Option(help="Shortest baseline, in metres (default 0.05; sequences 0.1).")
]
_MakeDataBaselineMax = Annotated[
    float | None, typer.Option(help="Longest baseline, in metres (default 0.8; sequences 0.5).")
]
_MakeDataMaxAngle = Annotated[
    float | None, typer.Option(help="Largest rig roll and pitch, in degrees (default 45; sequences 5).")
]
_MakeDataCloseShare = Annotated[
    float, typer.Option(help="Share of indoor scenes that are close range (a desk seen from 0.35–1.5 m).")
]
_MakeDataPanoramaShare = Annotated[
    float, typer.Option(help="Share of pairs that are two crops of one panorama (needs --panoramas).")
]
_MakeDataPanoramaMaxUpsampling = Annotated[
    float,
    typer.Option(help="Crops of a panorama magnify it at most this much (narrower crops are widened)."),
]
_MakeDataAugment = Annotated[
    float | None,
    typer.Option(help="Strength of noise, blur and exposure changes (default 1; sequences 0.5; 0: none)."),
]
_MakeDataDepth = Annotated[
    bool, typer.Option("--depth", help="Also write z-depth maps in metres (depth/left|right/*.npy).")
]
_MakeDataTextures = Annotated[
    Path | None, typer.Option(help="Folder of photos to use as textures, besides the built-in ones.")
]
_MakeDataPanoramas = Annotated[
    Path | None, typer.Option(help="Folder of equirectangular panoramas for skies, windows and crops.")
]
_MakeDataPreview = Annotated[
    Path | None, typer.Option(help="Write a contact sheet of 16 random pairs to this PNG file.")
]
_MakeDataPhotos = Annotated[
    Path | None,
    typer.Option(
        help="Instead of rendering, write training pairs from single real photographs: a folder with a "
        "labels.jsonl (stereogeo evaluate's photo layout); each photo at three centred zooms, sharp "
        "and softened."
    ),
]
_MakeDataPhotoSplit = Annotated[
    str,
    typer.Option(help="With --photos: the half of benchmarks/real_photos_split.json to use (train, all)."),
]
_MakeDataPrincipalOffset = Annotated[
    str | None,
    typer.Option(
        metavar="DX,DY",
        help="Sequences: move the principal point from the image centre by DX·width, DY·height (each "
        "within ±0.03), the same in both cameras; 'random' draws them from the seed.",
    ),
]
_MakeDataFocalAspect = Annotated[
    float, typer.Option(help="Sequences: render with fy = fx × this (0.95–1.05; 1: square pixels).")
]
_MakeDataH264 = Annotated[
    float | None,
    typer.Option(
        "--h264",
        metavar="KBPS",
        help="Sequences: pass the frames through an H.264 encode and decode at this bitrate in kbit/s "
        "(libx264 through PyAV) before they are written as PNG.",
    ),
]
_MakeDataKeepVideo = Annotated[
    bool,
    typer.Option(
        "--keep-video",
        help="With --h264: also keep the videos, left.mp4 and right.mp4 (calibrate-sequence --video).",
    ),
]
_MakeDataExposureChanges = Annotated[
    float,
    typer.Option(
        metavar="STOPS",
        help="Sequences: the exposure drifts over time by up to ± this many stops, the right camera's by "
        "a tenth of that more on its own.",
    ),
]
_MakeDataMotionBlur = Annotated[
    float,
    typer.Option(
        metavar="MS",
        help="Sequences: motion blur of the rig's and the objects' motion over an exposure of this many "
        "milliseconds.",
    ),
]
_MakeDataMovingObjects = Annotated[
    int, typer.Option(metavar="N", help="Sequences: N cars and people that move on their own.")
]
_MakeDataProgress = Annotated[
    bool | None,
    typer.Option("--progress/--no-progress", help="Show a progress bar (default: if a terminal)."),
]


_MakeDataRate = Annotated[
    float | None,
    typer.Option(metavar="HZ", help="Sequences: the frame rate; the motion spans (n − 1) / HZ seconds."),
]


@app.command("make-data")
def make_data(
    out: _MakeDataOut = None,
    *,
    count: _MakeDataCount = None,
    seed: Annotated[int, typer.Option(help="Seed: the same seed and options give the same bytes.")] = 0,
    sequence: _MakeDataSequence = None,
    workers: Annotated[int, typer.Option(help="Rendering processes to run in parallel.")] = 1,
    size: _MakeDataSize = None,
    aspects: _MakeDataAspects = None,
    portrait_share: Annotated[float, typer.Option(help="Share of pairs with portrait images.")] = 0.2,
    vfov_min: _MakeDataVfovMin = None,
    vfov_max: _MakeDataVfovMax = None,
    baseline_min: _MakeDataBaselineMin = None,
    baseline_max: _MakeDataBaselineMax = None,
    max_angle: _MakeDataMaxAngle = None,
    outdoor_share: Annotated[float, typer.Option(help="Share of rendered scenes that are outdoor.")] = 0.5,
    close_share: _MakeDataCloseShare = 0.25,
    panorama_share: _MakeDataPanoramaShare = 0.2,
    panorama_max_upsampling: _MakeDataPanoramaMaxUpsampling = 1.5,
    augment: _MakeDataAugment = None,
    depth: _MakeDataDepth = False,
    textures: _MakeDataTextures = None,
    panoramas: _MakeDataPanoramas = None,
    preview: _MakeDataPreview = None,
    photos: _MakeDataPhotos = None,
    photo_split: _MakeDataPhotoSplit = "train",
    principal_offset: _MakeDataPrincipalOffset = None,
    focal_aspect: _MakeDataFocalAspect = 1.0,
    h264: _MakeDataH264 = None,
    keep_video: _MakeDataKeepVideo = False,
    exposure_changes: _MakeDataExposureChanges = 0.0,
    motion_blur: _MakeDataMotionBlur = 0.0,
    moving_objects: _MakeDataMovingObjects = 0,
    rate: _MakeDataRate = None,
    progress: _MakeDataProgress = None,
) -> None:
    """Render a synthetic stereo dataset with exact ground truth (K, R, T, gravity per camera), or with
    --sequence one sequence of a moving rig (K, R, T and the pose of every frame)."""
    require_training_extra("make-data")
    if photos is not None:
        return _make_photo_pairs(photos, out, photo_split)
    from stereogeo_cli.synth.cli_support import run_make_data

    run_make_data(
        out, count=count, seed=seed, sequence=sequence, workers=workers, size=size, aspects=aspects,
        portrait_share=portrait_share, vfov=(vfov_min, vfov_max), baseline=(baseline_min, baseline_max),
        max_angle=max_angle, outdoor_share=outdoor_share, close_share=close_share,
        panorama_share=panorama_share, panorama_max_upsampling=panorama_max_upsampling, augment=augment,
        depth=depth, textures=textures, panoramas=panoramas, preview=preview,
        progress=sys.stderr.isatty() if progress is None else progress,
        effects={"principal_offset": principal_offset, "focal_aspect": focal_aspect, "h264": h264,
                 "keep_video": keep_video, "exposure_changes": exposure_changes, "motion_blur": motion_blur,
                 "moving_objects": moving_objects},
        rate=rate,
    )  # fmt: skip


def _make_photo_pairs(photos: Path, out: Path | None, photo_split: str) -> None:
    """``make-data --photos``: pairs cut from real photographs (``synth/photos.py``)."""
    from stereogeo_cli.io.text import plural
    from stereogeo_cli.synth.photos import make_photo_pairs

    if out is None:
        raise StereoGeoError("give the dataset folder to write the photographs' pairs into")
    if photo_split not in ("train", "all"):
        raise StereoGeoError(f"--photo-split must be train or all, not {photo_split!r}")
    written = make_photo_pairs(photos, out, None if photo_split == "all" else photo_split)
    typer.echo(f"wrote {plural(written, 'pair')} to {out}")


def _internal(error: BaseException) -> typer.Exit:
    """An unexpected failure: one line (no traceback), exit code 1."""
    first = str(error).strip().splitlines()[0] if str(error).strip() else ""
    typer.echo(f"error: internal error: {type(error).__name__}{': ' + first if first else ''}", err=True)
    return typer.Exit(code=EXIT_INTERNAL)


def _formats(value: str) -> tuple[str, ...]:
    from stereogeo_cli.io.writers import FORMATS

    names = tuple(dict.fromkeys(v.strip() for v in value.split(",") if v.strip()))
    unknown = [n for n in names if n not in FORMATS]
    if unknown or not names:
        raise StereoGeoError(
            f"unknown output format {unknown[0] if unknown else value!r}; choose from {', '.join(FORMATS)}"
        )
    return names


def _check_output_folder(folder: Path) -> None:
    """Fail before any work if the output folder cannot be made or written."""
    import os

    if folder.exists() and not folder.is_dir():
        raise StereoGeoError(f"output folder {folder} is not a folder")
    probe = folder
    while not probe.exists():
        probe = probe.parent
    if not os.access(probe, os.W_OK | os.X_OK):
        raise StereoGeoError(f"output folder {folder} is not writable")


def _print_summary(result, console) -> None:
    from rich.table import Table

    report = result.report()
    table = Table(title="stereogeo calibration", show_lines=False)
    table.add_column("")
    table.add_column("left", justify="right")
    table.add_column("right", justify="right")

    def cell(cam: dict, key: str, unit: str, digits: int) -> str:
        value, sigma = cam[key], cam["sigma"].get(key)
        if value is None:
            return "—"
        text = f"{value:.{digits}f}{unit}"
        return text + (f" ± {sigma:.{digits}f}" if sigma is not None else "")

    for label, key, unit, digits in (
        ("focal", "focal_px", " px", 1), ("vFoV", "vfov_deg", "°", 2),
        ("roll", "roll_deg", "°", 2), ("pitch", "pitch_deg", "°", 2),
    ):  # fmt: skip
        table.add_row(
            label, cell(report["left"], key, unit, digits), cell(report["right"], key, unit, digits)
        )
    table.add_row("size", f"{report['left']['width']}×{report['left']['height']}",
                  f"{report['right']['width']}×{report['right']['height']}")  # fmt: skip
    if any(report[side]["dist"] and any(report[side]["dist"]) for side in ("left", "right")):
        table.add_row("k1 k2 k3", *(
            " ".join(f"{report[side]['dist'][i]:+.3f}" for i in (0, 1, 4)) for side in ("left", "right")
        ))  # fmt: skip
    console.print(table)
    for side, source in zip(("left", "right"), result.focal_sources, strict=True):
        if source is not None and source.source == "exif":
            unit = "mm (35 mm equiv.)" if source.tag == "FocalLengthIn35mmFilm" else "mm"
            console.print(
                f"{side} focal: EXIF {source.tag_mm:g} {unit} = {source.focal_px:.0f} px, with the "
                f"fields' {source.fields_focal_px:.0f} px"
            )
        elif source is not None and source.source == "lines":
            console.print(
                f"{side} focal: the fields' {source.fields_focal_px:.0f} px with the vanishing points' "
                f"{source.focal_px:.0f} ± {source.sigma_px:.0f} px"
            )
        elif source is not None:
            console.print(
                f"{side} focal: given {source.focal_px:.0f} ± {source.sigma_px:.0f} px, with the fields' "
                f"{source.fields_focal_px:.0f} px"
            )
    if report.get("rotate_deg"):
        turned = report["rotate_deg"]
        console.print(f"images read turned {turned}° clockwise; the result is for them as given")
    pose = result.pose
    if pose.equal_focals:
        console.print("focal lengths held equal: the matches could not tell the two cameras apart")
    from stereogeo_cli.geometry import axis_angle_from_rotation, rotation_angle

    rotvec = np.degrees(axis_angle_from_rotation(result.calibration.R))
    rotation_sigma = report["pose"].get("sigma_rotation_deg")
    sigma_r = f" ± {rotation_sigma:.2f}°" if rotation_sigma is not None else ""
    console.print(
        f"R: {np.degrees(rotation_angle(result.calibration.R)):.2f}°{sigma_r} (rotation vector "
        f"{rotvec[0]:+.2f}°, {rotvec[1]:+.2f}°, {rotvec[2]:+.2f}°), from {pose.source.replace('_', ' ')}"
    )
    T, baseline_sigma = report["T"], report["pose"].get("sigma_baseline_rel")
    console.print(
        f"T: ({T[0]:+.4f}, {T[1]:+.4f}, {T[2]:+.4f}) m, baseline {report['baseline_m']:.4f} m"
        + (f" ± {100 * baseline_sigma:.0f} %" if baseline_sigma else "")
        + f" ({'given' if report['scale_source'] == 'baseline' else 'learned scale'})"
    )
    segments = report.get("vertical_segments") or [0, 0]
    gravity = f"vertical segments {segments[0]} / {segments[1]}" if any(segments) else "no vertical segments"
    console.print(f"matches: {report['matches']['found']} found, {report['matches']['inliers']} inliers; "
                  f"{gravity}; time {report['timing_ms']['total']:.0f} ms")  # fmt: skip
    warnings_console = _stderr_console()  # diagnostics go where a pipe of the summary does not take them
    for warning in report["warnings"]:
        warnings_console.print(f"[yellow]warning:[/yellow] {warning}", highlight=False)


# options that several commands take alike
FormatsOption = Annotated[
    str,
    typer.Option(
        "--format",
        help="Comma-separated output formats to write: opencv, ros, kalibr, colmap, json, html (report.html, "
        "the report with its figures).",
    ),
]
JsonOption = Annotated[
    bool, typer.Option("--json", help="Print the JSON report on stdout, and nothing else there.")
]
BaselineOption = Annotated[
    float | None, typer.Option(help="The rig's baseline in metres, if known; it sets the length of T.")
]
ModelOption = Annotated[
    Path | None, typer.Option(help="The ONNX model to use (default: the model shipped with stereogeo).")
]


PinholeFlag = Annotated[
    bool,
    typer.Option(
        "--pinhole",
        help="The images have no lens distortion (rectified or undistorted): fit none. By default one radial "
        "distortion per camera is fitted where the feature matches clearly show it.",
    ),
]  # calibrate and batch-calibrate

LinesFlag = Annotated[
    bool,
    typer.Option(
        "--lines/--no-lines",
        help="Use the image's straight line segments as well as the network's fields: the vertical ones for "
        "each camera's gravity, and the vanishing points of a Manhattan frame (two horizontal directions and "
        "the vertical) for its focal length where no lens is seen. --no-lines: the fields alone (for scenes "
        "whose straight edges are neither vertical nor square to each other).",
    ),
]  # calibrate and batch-calibrate


RotateOption = Annotated[
    int,
    typer.Option(
        "--rotate",
        help="Degrees to turn both images clockwise before they are read (0, 90, 180 or 270): for a rig "
        "mounted upside down (180) or on its side. The network knows views rolled by at most 45° and reads a "
        "turned view as upright, so without it such a rig's gravity comes out reversed, with no warning. The "
        "calibration is written for the images as they are.",
        metavar="DEG",
    ),
]  # calibrate, batch-calibrate and calibrate-sequence


ExifFlag = Annotated[
    bool,
    typer.Option(
        "--exif/--no-exif",
        help="Take each photo's EXIF focal length (35 mm equivalent, or focal length and sensor resolution) "
        "as a prior, combined with the network's reading. --no-exif: the images alone (for cropped or "
        "digitally zoomed photos whose tags were not updated).",
    ),
]  # calibrate and batch-calibrate


# the options of calibrate
_CalibrateOutput = Annotated[
    Path | None, typer.Option("--output", "-o", help="Folder to write the calibration files into.")
]
_CalibratePreview = Annotated[
    Path | None,
    typer.Option(
        help="Write the rectified pair side by side, with rows every 32 px and the horizons, to this PNG."
    ),
]
_CalibrateFocalLeft = Annotated[
    float | None, typer.Option(help="The left camera's focal length in pixels, if known.")
]
_CalibrateFocalRight = Annotated[
    float | None, typer.Option(help="The right camera's focal length in pixels, if known.")
]
_CalibrateFocalSigma = Annotated[
    float | None,
    typer.Option(
        help="Relative 1-sigma of --focal-left/--focal-right (e.g. 0.05 for a datasheet's lens): they "
        "become priors combined with the network's reading instead of being held fixed."
    ),
]


@app.command()
def calibrate(
    left: Annotated[Path, typer.Argument(help="The left image (any format OpenCV reads).")],
    right: Annotated[Path, typer.Argument(help="The right image.")],
    *,
    output: _CalibrateOutput = None,
    formats: FormatsOption = "opencv,ros,kalibr,colmap,json,html",
    json_out: JsonOption = False,
    preview: _CalibratePreview = None,
    baseline: BaselineOption = None,
    focal_left: _CalibrateFocalLeft = None,
    focal_right: _CalibrateFocalRight = None,
    focal_sigma: _CalibrateFocalSigma = None,
    pinhole: PinholeFlag = False,
    lines: LinesFlag = True,
    exif: ExifFlag = True,
    rotate: RotateOption = 0,
    model: ModelOption = None,
    threads: Annotated[int, typer.Option(help="Threads for the network (0: one per core but one).")] = 0,
) -> None:
    """Calibrate a stereo camera from one image pair: focal lengths, gravity (roll, pitch), R and T."""
    from stereogeo_cli.options import PairOptions

    options = PairOptions(
        baseline, focal_left, focal_right, focal_sigma, pinhole=pinhole, lines=lines, exif=exif, rotate=rotate
    ).checked()
    _check_threads(threads)
    names = _formats(formats)
    if output is not None:
        _check_output_folder(output)
    if preview is not None:
        _check_output_folder(preview.parent)
    from stereogeo_cli.api import calibrate_with
    from stereogeo_cli.io import load_image, write_calibration

    result = calibrate_with(left, right, options, model=model, threads=threads)
    report_wanted = output is not None and "html" in names
    images = (load_image(left), load_image(right)) if preview is not None or report_wanted else None
    written = []
    if output is not None:
        figures = None
        if report_wanted:
            from stereogeo_cli.report.inputs import pair_inputs

            figures = pair_inputs(result, *images)
        written = write_calibration(output, result.calibration, names, figures=figures)
    if preview is not None:
        from stereogeo_cli.io.preview import write_preview

        written.append(write_preview(preview, *images, result.calibration))
    if json_out:
        from stereogeo_cli.io.report import report_json

        sys.stdout.write(report_json(result.calibration))
        return
    from rich.console import Console

    console = Console()
    _print_summary(result, console)
    _print_written(console, written)


def _check_threads(threads: int) -> None:
    if threads < 0:
        raise StereoGeoError("--threads must be 0 or more")


def _print_written(console, written: list[Path]) -> None:
    """The files written, folder by folder (the last lines of a summary)."""
    folders: dict[Path, list[str]] = {}
    for path in written:
        folders.setdefault(path.parent, []).append(path.name)
    for folder, names in folders.items():
        console.print(
            f"wrote {folder}{'/' if str(folder) != '/' else ''}: {', '.join(names)}", soft_wrap=True
        )


# the options of batch-calibrate
_BatchFolder = Annotated[
    Path,
    typer.Argument(
        help="Folder of stereo pairs: left/ + right/, cam0/ + cam1/, or *_left/*_right, *_L/*_R files."
    ),
]
_BatchOutput = Annotated[
    Path,
    typer.Option(
        "--output", "-o", help="Folder for the results: <pair>/ per pair, summary.csv and summary.json."
    ),
]
_BatchThreads = Annotated[
    int, typer.Option(help="Threads for the network in all (0: one per core), shared by the workers.")
]
_BatchSameRig = Annotated[
    bool,
    typer.Option(
        "--same-rig", help="All pairs come from one rig: also write one joint calibration to OUT/rig/."
    ),
]
_BatchShard = Annotated[
    str | None,
    typer.Option(help="Only shard i of n (1-based, e.g. 2/8): every n-th pair, for cluster job arrays."),
]
_BatchJsonOut = Annotated[
    bool, typer.Option("--json", help="Print the summary as JSON on stdout, and nothing else there.")
]
_BatchResume = Annotated[
    bool,
    typer.Option(
        "--resume",
        help="Keep the pairs OUT already holds, calibrated with the same options, model and images (e.g. "
        "by a run that was interrupted), and calibrate the others; the summary lists all.",
    ),
]
_BatchOverwrite = Annotated[
    bool, typer.Option("--overwrite", help="Replace the results OUT already holds (else they are kept).")
]


@app.command("batch-calibrate")
def batch_calibrate(
    folder: _BatchFolder,
    *,
    output: _BatchOutput,
    formats: FormatsOption = "opencv,ros,kalibr,colmap,json,html",
    baseline: BaselineOption = None,
    pinhole: PinholeFlag = False,
    lines: LinesFlag = True,
    exif: ExifFlag = True,
    rotate: RotateOption = 0,
    model: ModelOption = None,
    threads: _BatchThreads = 0,
    workers: Annotated[int, typer.Option(help="Pairs calibrated in parallel, one process each.")] = 1,
    same_rig: _BatchSameRig = False,
    shard: _BatchShard = None,
    json_out: _BatchJsonOut = False,
    resume: _BatchResume = False,
    overwrite: _BatchOverwrite = False,
) -> None:
    """Calibrate every stereo pair of a folder with one network session; exit code 4 if any pair failed.

    Ctrl-C (or SIGTERM) stops after the pairs in flight and writes the summaries (exit code 130, or 143);
    --resume continues."""
    from stereogeo_cli.options import PairOptions

    pair = PairOptions(baseline, pinhole=pinhole, lines=lines, exif=exif, rotate=rotate).checked()
    if threads < 0 or workers < 1:
        raise StereoGeoError("--threads must be 0 or more and --workers 1 or more")
    from stereogeo_cli.batch import BatchOptions, run_batch
    from stereogeo_cli.io.pairs import parse_shard
    from stereogeo_cli.io.text import plural
    from stereogeo_cli.jobs.interrupt import interruptible

    names, shard_spec = _formats(formats), parse_shard(shard) if shard is not None else None
    _check_output_folder(output)
    notice = "{name}: stopping after the pairs in flight (again: at once), then writing the summaries"
    with interruptible(notice=notice) as stop:
        options = BatchOptions(
            formats=names, pair=pair, model=model, threads=threads, workers=workers, same_rig=same_rig,
            shard=shard_spec, progress=sys.stderr.isatty(), resume=resume, overwrite=overwrite,
        )  # fmt: skip
        summary = run_batch(folder, output, options, stop)
    total, left = len(summary.outcomes), summary.not_run
    ok = total - summary.failed - left
    if json_out:
        sys.stdout.write(summary.json_text)
    else:
        typer.echo(
            f"{plural(total, 'pair')}: {ok} ok, {summary.failed} failed{f', {left} not run' if left else ''}"
            f"{f' ({summary.resumed} kept from before)' if summary.resumed else ''}; results in {output}"
        )
        if summary.rig is not None:
            rig = summary.rig.to_report()
            typer.echo(
                f"rig ({output / 'rig'}): focal {rig['left']['focal_px']:.1f} / "
                f"{rig['right']['focal_px']:.1f} px, R {rig['pose']['rotation_deg']:.2f}°, "
                f"baseline {rig['baseline_m']:.4f} m"
            )
    if summary.interrupted is not None:
        other = f"the other {plural(left, 'pair')}"
        rest = f"calibrate {other}" if left else "make the joint calibration (--same-rig)"
        typer.echo(
            f"interrupted by {summary.interrupted}: {total - left} of {plural(total, 'pair')} done; "
            f"summaries written to {output}; to {rest}, run the same command again with --resume",
            err=True,
        )
        raise typer.Exit(code=stop.exit_code or EXIT_INTERRUPTED)
    if summary.rig_error is not None:
        raise summary.rig_error
    if summary.failed:
        raise typer.Exit(code=EXIT_PARTIAL_BATCH)


def _pose_sigmas(text: str) -> dict[str, float]:
    """'ROT,DIR,SCALE' → the model metadata entries; anything else is a one-line error."""
    try:
        rotation, direction, scale = (float(part) for part in text.split(","))
    except ValueError:
        raise StereoGeoError(
            f"--pose-sigmas must be three numbers 'ROT,DIR,SCALE' (degrees, degrees, fraction), got {text!r}"
        ) from None
    if not (0 < rotation < 180 and 0 < direction <= 180 and scale > 0):
        raise StereoGeoError(f"--pose-sigmas must be positive (angles in degrees below 180), got {text!r}")
    return {
        "pose_sigma_rotation_deg": rotation,
        "pose_sigma_direction_deg": direction,
        "pose_sigma_scale_rel": scale,
    }


# the options of calibrate-sequence
_SequenceSource = Annotated[
    Path | None,
    typer.Argument(
        metavar="SOURCE",
        help="A folder of frame pairs in time order (the layouts batch-calibrate reads), or a ROS 1 "
        "bag (.bag) or ROS 2 bag (its folder) with --left-topic and --right-topic.",
    ),
]
_SequenceOutput = Annotated[
    Path | None,
    typer.Option(
        "--output", "-o", help="Folder for the rig's calibration files, trajectory.txt and sparse/."
    ),
]
_SequenceVideo = Annotated[
    tuple[Path, Path] | None,
    typer.Option(help="Two videos, the left camera's and the right camera's (frames paired by number)."),
]
_SequenceSbs = Annotated[
    Path | None, typer.Option(help="One side-by-side video: the left image in the left half.")
]
_SequenceFps = Annotated[
    float | None,
    typer.Option(
        help="Videos and bags: keep frames at most this many per second, in place of keyframes; a folder: "
        "its frame rate (the frames' times; keyframes still choose)."
    ),
]
_SequenceEvery = Annotated[
    int | None, typer.Option(help="Keep every Nth frame pair, in place of keyframes.", show_default=False)
]
_SequenceMaxFrames = Annotated[
    int | None,
    typer.Option(
        help="Use the first N frame pairs (after --every), in place of keyframes.", show_default=False
    ),
]
_SequenceKeyframes = Annotated[
    bool,
    typer.Option(
        "--keyframes/--all-frames",
        help="Keep the frames the motion makes informative (optical flow from the last kept frame: 0.5 % "
        "of the image's larger side, half that where the rig turns) and leave out near-duplicates of a "
        "rig standing still; or keep every frame. --every, --max-frames and a video's or bag's --fps "
        "choose the frames instead.",
    ),
]
_SequenceMaxKeyframes = Annotated[
    int, typer.Option(help="Keep at most this many keyframes, evenly spread over the recording.")
]
_SequenceFormats = Annotated[
    str,
    typer.Option(
        "--format",
        help="Comma-separated calibration formats to write: opencv, ros, kalibr, colmap, json, html "
        "(trajectory.txt and sparse/ are always written).",
    ),
]
_SequenceOverwrite = Annotated[
    bool,
    typer.Option(
        "--overwrite",
        help="Replace an output folder that holds an earlier run's results, in one step (else it is "
        "refused).",
    ),
]
_SequenceBaseline = Annotated[
    float | None, typer.Option(help="The rig's baseline in metres, if known; it sets the metric scale.")
]
_SequenceStampTolerance = Annotated[
    float | None,
    typer.Option(
        help="Bags: the largest difference in seconds between a left and a right image's stamps that "
        "still pairs them (default 0.01; free-running cameras need more)."
    ),
]
_SequenceWorkspace = Annotated[
    Path | None,
    typer.Option(help="Keep COLMAP's images and database in this folder (default: a temporary one)."),
]
_SequenceProgress = Annotated[
    bool,
    typer.Option(
        "--progress/--no-progress",
        help="Show each stage on stderr: a live line on a terminal, else a log line as each ends.",
    ),
]


@app.command("calibrate-sequence")
def calibrate_sequence(
    source: _SequenceSource = None,
    *,
    output: _SequenceOutput = None,
    video: _SequenceVideo = None,
    sbs: _SequenceSbs = None,
    left_topic: Annotated[str | None, typer.Option(help="The bag's left image topic.")] = None,
    right_topic: Annotated[str | None, typer.Option(help="The bag's right image topic.")] = None,
    every: _SequenceEvery = None,
    fps: _SequenceFps = None,
    max_frames: _SequenceMaxFrames = None,
    keyframes: _SequenceKeyframes = True,
    max_keyframes: _SequenceMaxKeyframes = 150,
    formats: _SequenceFormats = "opencv,ros,kalibr,colmap,json,html",
    overwrite: _SequenceOverwrite = False,
    json_out: JsonOption = False,
    baseline: _SequenceBaseline = None,
    pinhole: PinholeFlag = False,
    rotate: RotateOption = 0,
    stamp_tolerance: _SequenceStampTolerance = None,
    workspace: _SequenceWorkspace = None,
    model: ModelOption = None,
    threads: Annotated[int, typer.Option(help="Threads for the network (0: one per core but one).")] = 0,
    progress: _SequenceProgress = True,
) -> None:
    """Calibrate a stereo rig from a sequence of its frame pairs (a drive, a robot's run, a hand-held
    sweep): COLMAP's bundle adjustment over the frames fixes the focal lengths where the rig turns.

    SIGINT or SIGTERM stops the run after the stage in flight: nothing is written (exit code 130, or 143)."""
    from stereogeo_cli.jobs.interrupt import Interrupted, interruptible
    from stereogeo_cli.jobs.progress import StageProgress

    # the handlers are in place from the start, so that a signal at any moment ends the run the same way
    notice = "{name}: stopping after the stage in flight, nothing is written; {name} again to stop at once"
    stage = StageProgress("off" if not progress else "bar" if sys.stderr.isatty() else "log")
    from stereogeo_cli.options import PairOptions
    from stereogeo_cli.sequence.options import SequenceOptions

    _check_threads(threads)
    options = SequenceOptions(
        video=video, sbs=sbs, left_topic=left_topic, right_topic=right_topic,
        stamp_tolerance_s=stamp_tolerance, every=every, fps=fps, max_frames=max_frames, keyframes=keyframes,
        max_keyframes=max_keyframes, pair=PairOptions(baseline, pinhole=pinhole, rotate=rotate),
        workspace=workspace,
    ).checked()  # fmt: skip
    names = _formats(formats)
    with interruptible(notice=notice if sys.stderr.isatty() else None) as stop:
        try:
            with stage:
                written, result = _run_sequence(
                    stop, stage, source, options, output=output, formats=names, overwrite=overwrite,
                    model=model, threads=threads,
                )  # fmt: skip
                if stop.requested:
                    stage.stopped()
        except Interrupted:  # a second signal: the stage in flight was cut, what it made removed
            written, result = [], None
    if stop.requested:
        where = f"the results were written to {output}" if written else "nothing was written"
        typer.echo(f"error: interrupted by {stop.name}: {where}", err=True)
        _ignore_signals_from_now()
        raise typer.Exit(code=stop.exit_code or EXIT_INTERRUPTED)
    if json_out:
        from stereogeo_cli.io.report import report_json

        sys.stdout.write(report_json(result.calibration))
        return
    from rich.console import Console

    _print_sequence_summary(result.report(), Console(), _stderr_console())
    _print_written(Console(), written)


def _ignore_signals_from_now() -> None:
    """A stopped run has said how it ended: further SIGINTs and SIGTERMs are ignored until the process
    exits (Python's shutdown restores the default action of a signal it handled, which would kill the
    process with no word and no exit code)."""
    import signal

    from stereogeo_cli.jobs.interrupt import SIGNALS

    for s in SIGNALS:
        signal.signal(s, signal.SIG_IGN)


def _run_sequence(stop, stage, source, options, *, output, formats, overwrite, model, threads):
    """``calibrate-sequence``'s work: the source opened, the rig calibrated and its files written; ([], None)
    where ``stop`` came first."""
    from stereogeo_cli.sequence.run import check_output_folder, write_sequence

    if output is not None:
        _check_output_folder(output)
        check_output_folder(output, overwrite)
    from stereogeo_cli.pipeline import Calibrator
    from stereogeo_cli.sequence.run import calibrate_sequence as run_sequence

    stage(0, None, "opening the source")
    frames = options.open(source)
    if stop.requested:
        return [], None
    if options.chooses_keyframes(frames):
        frames = _keyframes(frames, options.max_keyframes, stage, stop)
        if stop.requested:
            return [], None
    stage(0, None, "loading the network")
    calibrator = Calibrator(model, threads=threads, conf=options.pair.calibrator_conf())
    result = run_sequence(frames, calibrator, options, progress=stage, stop=stop)
    if result is None or stop.requested:
        return [], None
    if output is None:
        return [], result
    stage(0, None, "writing the results")
    return write_sequence(output, result, formats, overwrite=overwrite, stop=stop), result


def _keyframes(frames, max_kept: int, stage, stop):
    """The keyframes of ``frames`` (sequence/keyframes.py), chosen in a first pass shown as a stage."""
    from stereogeo_cli.sequence.keyframes import KeyframeSource, choose_keyframes

    stage(0, frames.count(), "choosing keyframes by motion")
    choice = choose_keyframes(frames, {"max_kept": max_kept}, progress=stage, stop=stop)
    stage.note(f"{len(choice.kept)} of {choice.read} kept")
    return KeyframeSource(frames, choice)


def _print_sequence_summary(report: dict, console, warnings_console) -> None:
    """The rig's focal lengths with their evidence, R, T and the sequence's figures; the warnings on
    ``warnings_console`` (stderr)."""
    seq = report["sequence"]
    focal = seq["evidence"]["focal"]
    for side in ("left", "right"):
        cam, f = report[side], focal[side]
        console.print(
            f"{side:5}  focal {cam['focal_px']:.1f} ± {cam['sigma']['focal_px']:.1f} px, vFoV "
            f"{cam['vfov_deg']:.2f}°  (adjustment {f['adjustment']['focal_px']:.1f}, pairs "
            f"{f['pairs']['focal_px']:.1f}: the adjustment's weight {100 * f['adjustment_weight']:.0f} %)"
        )
    pose = report["pose"]
    console.print(f"R      {pose['rotation_deg']:.3f}° (± {pose['sigma_rotation_deg'] or 0:.3f}°)")
    console.print(f"T      {np.round(report['T'], 4).tolist()} m ({report['scale_source']} scale)")
    left_out = seq.get("left_out")
    if left_out and left_out["row_error_px"]["median"] is not None:
        rows = left_out["row_error_px"]
        console.print(
            f"check  frames left out of the fit, rectified: rows {rows['median']:.2f} px apart (median), "
            f"{rows['p95']:.2f} px (95 %), {rows['matches']} points; the focal length moves "
            f"{100 * left_out['focal_sigma_rel']:.2f} % between {left_out['blocks']} stretches; reprojection "
            f"{seq['reprojection_error_px']:.2f} px"
        )
    turned = "" if seq["rotation_span_deg"] is None else f", the rig turned {seq['rotation_span_deg']:.1f}°"
    kept = seq.get("frames_kept", seq["frames_read"])
    console.print(
        f"frames {seq['frames_read']} read, {kept} kept, {seq['frames_registered']} registered{turned}: "
        "focal length "
        + ("fixed by the motion" if seq["focal_observable"] else "NOT fixed by the motion (from the pairs)")
    )
    for warning in report.get("warnings") or []:
        warnings_console.print(f"[yellow]warning:[/yellow] {warning}", highlight=False)


# the options of export-onnx
_ExportCheckpoint = Annotated[
    Path, typer.Argument(help="A training checkpoint (.pt) written by stereogeo train.")
]
_ExportModelVersion = Annotated[
    str | None, typer.Option(help="A version name stored in the model (default: the checkpoint's).")
]
_ExportTrainingData = Annotated[
    str | None,
    typer.Option(help="A description of the training data stored in the model (default: the checkpoint's)."),
]
_ExportSigmaInflation = Annotated[
    str,
    typer.Option(
        help="Factor the refiner's 1-sigma figures are widened by with this model, one number or three "
        "'ROLL,PITCH,VFOV' (measured on validation data: `evaluate --json` prints each parameter's "
        "scale_for_68, the factor that puts 68 % of the errors within 1 sigma)."
    ),
]
_ExportPhotoSigmaScale = Annotated[
    str,
    typer.Option(
        help="Factor the sigmas calibrate reports are widened by on top, one number or three "
        "'ROLL,PITCH,VFOV', so that they hold 68 % of the errors on real photographs, where the network "
        "errs more than on renders (benchmarks/photo_sigma.py measures it on the crops of real panoramas "
        "in held-out sets). The estimates do not change."
    ),
]
_ExportPoseSigmas = Annotated[
    str | None,
    typer.Option(
        help="The pose head's 1-sigma errors 'ROT,DIR,SCALE': rotation and translation direction in "
        "degrees, baseline length as a fraction (68th percentiles on validation data, as "
        "benchmarks/validate_model.py prints them). calibrate weighs the head by them and reports the "
        "learned baseline's sigma. Default: the fusion's fixed 5° and 15°, no baseline sigma."
    ),
]
_ExportDepthSigma = Annotated[
    float | None,
    typer.Option(
        help="For a model with a depth head: the relative 1-sigma of the baseline that calibrate reads "
        "from the matches and the depth (68th percentile on validation data, as "
        "benchmarks/depth_baseline.py prints it). calibrate reports it as the baseline's sigma."
    ),
]


@app.command("export-onnx")
def export_onnx_command(
    checkpoint: _ExportCheckpoint,
    *,
    output: Annotated[Path, typer.Option("--output", "-o", help="The ONNX file to write.")] = Path(
        "stereogeo.onnx"
    ),
    model_version: _ExportModelVersion = None,
    training_data: _ExportTrainingData = None,
    sigma_inflation: _ExportSigmaInflation = "1",
    photo_sigma_scale: _ExportPhotoSigmaScale = "1",
    pose_sigmas: _ExportPoseSigmas = None,
    depth_sigma: _ExportDepthSigma = None,
) -> None:
    """Export a checkpoint to one ONNX file (both views, any size), after checking it against torch."""
    require_training_extra("export-onnx")
    from stereogeo_cli.network.export import export_onnx
    from stereogeo_cli.refine import parse_sigma_inflation

    factors = (("--sigma-inflation", sigma_inflation), ("--photo-sigma-scale", photo_sigma_scale))
    for option, text in factors:
        try:
            parse_sigma_inflation(text, option.strip("-").replace("-", " "))
        except ValueError as error:
            raise StereoGeoError(f"{option}: {error}") from None
    extra: dict[str, float | str] = {
        "sigma_inflation": sigma_inflation.replace(" ", ""),
        "photo_sigma_scale": photo_sigma_scale.replace(" ", ""),
    }
    if pose_sigmas is not None:
        extra.update(_pose_sigmas(pose_sigmas))
    if depth_sigma is not None:
        if not (depth_sigma > 0 and math.isfinite(depth_sigma)):
            raise StereoGeoError(f"--depth-sigma must be a positive fraction, got {depth_sigma}")
        extra["depth_sigma_scale_rel"] = depth_sigma
    result = export_onnx(
        checkpoint, output, model_version=model_version, training_data=training_data, extra_metadata=extra
    )
    worst = max(result["max_abs_error"].values())
    typer.echo(f"wrote {result['path']} (largest difference from torch {worst:.2e})")


@app.command("average-checkpoints")
def average_checkpoints_command(
    checkpoints: Annotated[
        list[Path],
        typer.Argument(help="Two or more checkpoints (.pt) of one model, e.g. a model and its fine-tune."),
    ],
    *,
    output: Annotated[Path, typer.Option("--output", "-o", help="The checkpoint to write.")],
    weights: Annotated[
        str | None,
        typer.Option(help="One weight per checkpoint, comma-separated, scaled to sum to 1 (default: equal)."),
    ] = None,
    model_version: Annotated[
        str | None, typer.Option(help="A version name for the average (default: the first checkpoint's).")
    ] = None,
    lineage: Annotated[
        str | None,
        typer.Option(
            help="How the inputs were made, appended to the lineage (the first checkpoint's lineage, then "
            "'weight average ...', then this)."
        ),
    ] = None,
) -> None:
    """Average the weights of checkpoints of one model (a model soup; with a model and its own fine-tune,
    WiSE-FT). Export the result with export-onnx."""
    require_training_extra("average-checkpoints")
    from stereogeo_cli.network.checkpoint import average_checkpoints, write_checkpoint

    if weights is None:
        shares = [1.0] * len(checkpoints)
    else:
        try:
            shares = [float(part) for part in weights.split(",")]
        except ValueError:
            raise StereoGeoError(f"--weights must be numbers separated by commas, got {weights!r}") from None
    if output.is_dir():
        raise StereoGeoError(f"--output {output} is a folder; give the checkpoint file to write")
    average = average_checkpoints(checkpoints, shares)
    if model_version is not None:
        average["model_version"] = model_version
    if lineage:
        average["lineage"] = f"{average['lineage']} ({lineage})"
    write_checkpoint(output, average)
    parts = ", ".join(f"{s['weight']:.3g} × {s['model_version']}" for s in average["averaged_from"])
    typer.echo(f"wrote {output} ({average.get('model_version', 'unnamed')}: {parts})")


@app.command(
    context_settings={"allow_extra_args": True, "ignore_unknown_options": True, "help_option_names": []}
)
def train(ctx: typer.Context) -> None:
    """Train the network (resumable; run under torchrun for several processes). --help lists the settings."""
    try:
        require_training_extra("train")
    except StereoGeoError:
        if {"--help", "-h"} & set(ctx.args):
            typer.echo(
                "Usage: stereogeo train [SETTINGS]\n\nTrain the network on synthetic renders "
                "(resumable; runs under torchrun for several processes).\nThe settings are listed once the "
                f"training extra is installed: {INSTALL_TRAINING}"
            )
            raise typer.Exit() from None
        raise
    from stereogeo_cli.network.train import main as train_main

    train_main(list(ctx.args))


# the options of evaluate
_EvaluateDataset = Annotated[
    Path,
    typer.Argument(
        help="A dataset folder: stereo pairs (left/, right/ and calib.jsonl with ground truth) or single "
        "photographs (images and a labels.jsonl of their intrinsics)."
    ),
]
_EvaluateBaselines = Annotated[
    bool,
    typer.Option("--baselines", help="Also run ORB and SIFT + essential matrix with the true intrinsics."),
]
_EvaluatePlot = Annotated[
    Path | None, typer.Option(help="Draw the cumulative error curves (up to 10°) into this PNG file.")
]
_EvaluateSplit = Annotated[
    str | None,
    typer.Option(
        help="Single photographs: score one half of a split, 'train' or 'measure' (the cameras "
        "--split-file lists under that name), or the images a file lists (their labels' 'file'), "
        "one a line."
    ),
]
_EvaluateSplitFile = Annotated[
    Path | None,
    typer.Option(
        help="The split file for --split train|measure (default: the checkout's "
        "benchmarks/real_photos_split.json)."
    ),
]


@app.command()
def evaluate(
    dataset: _EvaluateDataset,
    *,
    json_out: Annotated[bool, typer.Option("--json", help="Print the results as JSON on stdout.")] = False,
    baselines: _EvaluateBaselines = False,
    plot: _EvaluatePlot = None,
    model: Annotated[Path | None, typer.Option(help="The ONNX model (default: the shipped one).")] = None,
    threads: Annotated[int, typer.Option(help="Threads for the network (0: one per core but one).")] = 0,
    split: _EvaluateSplit = None,
    split_file: _EvaluateSplitFile = None,
) -> None:
    """Calibrate every pair (or photograph) of a dataset with ground truth and report the papers' accuracy
    metrics."""
    import json

    from rich.progress import Progress

    from stereogeo_cli import evaluate_photos as photos
    from stereogeo_cli.evaluate import evaluate_dataset, read_dataset
    from stereogeo_cli.pipeline import Calibrator

    if plot is not None:
        _check_output_folder(plot.parent)
    photo_set = photos.is_photo_set(dataset)
    if photo_set:
        if baselines:
            raise StereoGeoError("--baselines needs stereo pairs; this folder holds single photographs")
        records = photos.select(photos.read_labels(dataset), split, split_file)
        if not records:
            raise StereoGeoError(f"--split {split} selects no image of {dataset}")
        total = len(records)
    else:
        if split is not None or split_file is not None:
            raise StereoGeoError("--split is for single photographs (a folder with a labels.jsonl)")
        total = len(read_dataset(dataset))
    calibrator = Calibrator(model, threads=threads)
    with Progress(transient=True, disable=not sys.stderr.isatty(), console=_stderr_console()) as bar:
        task = bar.add_task("evaluating", total=total)
        if photo_set:
            results = photos.evaluate_photos(dataset, calibrator, records, progress=lambda: bar.advance(task))
            results["split"] = split
        else:
            results = evaluate_dataset(
                dataset, calibrator, baselines=baselines, progress=lambda: bar.advance(task)
            )
    if plot is not None:
        from stereogeo_cli.evaluate import plot_error_cdfs

        plotted = results
        if photo_set:  # the photo's errors under the names of a pair's
            rows = results["photos"]
            plotted = {"pairs": [{k.removeprefix("photo_"): v for k, v in r.items()} for r in rows]}
        plot_error_cdfs(plotted, plot)
    if json_out:
        sys.stdout.write(json.dumps(results, indent=2, allow_nan=False, default=float) + "\n")
        return
    if photo_set:
        _print_photo_evaluation(results)
    else:
        _print_evaluation(results)


def _stderr_console():
    from rich.console import Console

    return Console(stderr=True)


def _print_evaluation(results: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    from stereogeo_cli.io.text import plural

    console = Console()
    metrics = results["metrics"]
    pairs = metrics["pairs"]
    table = Table(title=f"{results['dataset']}: {pairs['evaluated']} of {plural(pairs['total'], 'pair')}")
    for column in ("metric", "median", "mean", "AUC@1°", "AUC@5°", "AUC@10°"):
        table.add_column(column, justify="right" if column != "metric" else "left")
    for key, label in (("roll_deg", "roll (°)"), ("pitch_deg", "pitch (°)"), ("vfov_deg", "vFoV (°)")):
        if key in metrics:
            m = metrics[key]
            table.add_row(label, f"{m['median']:.2f}", f"{m['mean']:.2f}",
                          *(f"{100 * m[f'auc@{t}']:.1f}%" for t in (1, 5, 10)))  # fmt: skip
    rows = (("focal_rel", "focal (relative)"), ("rotation_error_deg", "rotation (°)"),
            ("direction_error_deg", "t direction (°)"), ("translation_error_m", "T (m)"),
            ("baseline_error_rel", "baseline length (relative)"),
            ("orb+essential_rotation_error_deg", "ORB + E, true K: rotation (°)"),
            ("sift+essential_rotation_error_deg", "SIFT + E, true K: rotation (°)"),
            ("orb+essential_direction_error_deg", "ORB + E, true K: t direction (°)"),
            ("sift+essential_direction_error_deg", "SIFT + E, true K: t direction (°)"))  # fmt: skip
    for key, label in rows:
        if key in metrics:
            m = metrics[key]
            table.add_row(label, f"{m['median']:.3f}", f"{m['mean']:.3f}", "", "", "")
    console.print(table)
    names = (("roll", "roll"), ("pitch", "pitch"), ("vfov", "vFoV"), ("rotation", "rotation"),
             ("direction", "t direction"), ("baseline", "baseline length"))  # fmt: skip
    shares = [
        f"{label} {100 * metrics[f'{name}_sigma']['within_1_sigma']:.0f} % / "
        f"{100 * metrics[f'{name}_sigma']['within_3_sigma']:.0f} %"
        for name, label in names
        if f"{name}_sigma" in metrics
    ]
    if shares:
        console.print(
            "errors within the reported 1 / 3 sigma (68 % / 99.7 % for honest sigmas): " + ", ".join(shares),
            soft_wrap=True,
        )
    for reason in results["skipped"]:
        console.print(f"skipped: {reason}")
    for failure in results["failed"]:
        console.print(f"[yellow]failed:[/yellow] {failure['id']}: {failure['error']}")


def _print_photo_evaluation(results: dict) -> None:
    """The single photographs' summaries (all, each set, each source), each with the naive guess's."""
    from rich.console import Console
    from rich.table import Table

    console = Console()
    groups = results["photo_metrics"]
    split = f", split {results['split']}" if results.get("split") else ""
    table = Table(
        title=f"{results['dataset']}{split}: medians, every camera counting once",
        caption="naive: f = 0.7 · max(w, h); 1σ/3σ: the shares of vFoV errors within the reported sigmas (%)",
    )
    for column in ("group", "images", "cameras", "vFoV (°)", "AUC@1/5/10°", "focal (rel.)", "1σ/3σ"):
        table.add_column(column, justify="left" if column == "group" else "right")

    def cell(m: dict, key: str, digits: int) -> str:
        return "–" if m.get(key, {}).get("median") is None else f"{m[key]['median']:.{digits}f}"

    def aucs(m: dict, key: str) -> str:
        return "/".join(f"{100 * m[key][f'auc@{t}']:.0f}" for t in (1, 5, 10)) if key in m else "–"

    def within(sigma: dict | None) -> str:
        if not sigma:
            return "–"
        return f"{100 * sigma['within_1_sigma']:.0f}/{100 * sigma['within_3_sigma']:.0f}"

    named = [("all", groups["all"])]
    named += [(f"set {k}", v) for k, v in groups["sets"].items() if len(groups["sets"]) > 1]
    named += [(k, v) for k, v in groups["sources"].items()]
    for name, m in named:
        table.add_row(
            name, str(m["images"]), str(m["cameras"]), cell(m, "vfov_deg", 2), aucs(m, "vfov_deg"),
            cell(m, "focal_rel", 3), within(m.get("vfov_sigma")),
        )  # fmt: skip
        table.add_row(
            "  naive", "", "", cell(m, "naive_vfov_deg", 2), aucs(m, "naive_vfov_deg"),
            cell(m, "naive_focal_rel", 3), "", end_section=True,
        )  # fmt: skip
    console.print(table)
    m = groups["all"]
    for name, label in (("roll", "roll"), ("pitch", "pitch")):
        if f"{name}_deg" in m:
            console.print(
                f"{label} (°): median {cell(m, f'{name}_deg', 2)} (level camera: "
                f"{cell(m, f'naive_{name}_deg', 2)}), within 1σ/3σ {within(m.get(f'{name}_sigma'))} %"
            )
    for reason in results["skipped"]:
        console.print(f"skipped: {reason}")
    for failure in results["failed"]:
        console.print(f"[yellow]failed:[/yellow] {failure['id']}: {failure['error']}")


def main() -> None:
    """The console script: every error one line on stderr with its exit code, usage errors included
    (``error: Invalid value for '--every': ...``, exit code 2, with the command's ``--help`` named)."""
    click = sys.modules[typer.BadParameter.__module__]  # Typer's click: the package or its vendored copy

    try:
        code = app(standalone_mode=False)
    except click.NoArgsIsHelpError as error:  # a bare command: its help, as Typer shows it
        from typer import rich_utils

        rich_utils.rich_format_error(error)
        sys.exit(error.exit_code)
    except click.ClickException as error:
        context = getattr(error, "ctx", None)
        hint = f" (see {context.command_path} --help)" if context is not None else ""
        typer.echo(f"error: {error.format_message()}{hint}", err=True)
        sys.exit(error.exit_code)
    except typer.Abort:  # the end of standard input at a prompt
        typer.echo("error: aborted", err=True)
        sys.exit(EXIT_INTERNAL)
    except StereoGeoError as error:  # raised outside a command body (e.g. while importing a plugin)
        typer.echo(f"error: {error}", err=True)
        sys.exit(error.exit_code)
    sys.exit(code if isinstance(code, int) else 0)
