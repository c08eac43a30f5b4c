"""What ``stereogeo make-data`` does, below the argument parsing: validate options, render, report."""

from __future__ import annotations

import sys
from pathlib import Path

from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.io.text import plural
from stereogeo_cli.synth.config import SynthConfig


def parse_aspects(text: str) -> tuple[float, ...]:
    """ "4:3,16:9,1" → (1.333…, 1.777…, 1.0): width / height of landscape images."""
    aspects = []
    for part in text.split(","):
        try:
            num, _, den = part.strip().partition(":")
            value = float(num) / float(den or 1)
        except (ValueError, ZeroDivisionError):
            raise StereoGeoError(
                f"--aspects: cannot read {part.strip()!r}; write e.g. 4:3,16:9,1:1"
            ) from None
        if not 0.2 <= value <= 5:
            raise StereoGeoError(f"--aspects: {part.strip()} is not a plausible aspect ratio")
        aspects.append(max(value, 1.0 / value))  # portrait is chosen by --portrait-share
    return tuple(aspects)


def build_config(
    *,
    size,
    aspects,
    portrait_share,
    vfov,
    baseline,
    max_angle,
    outdoor_share,
    close_share,
    panorama_share,
    panorama_max_upsampling,
    augment,
    depth,
    textures,
    panoramas,
) -> SynthConfig:
    checks = [
        (16 <= size <= 4096, "--size must be between 16 and 4096 pixels"),
        (0 < vfov[0] <= vfov[1] < 170, "--vfov-min/--vfov-max must satisfy 0 < min ≤ max < 170 degrees"),
        (0 < baseline[0] <= baseline[1], "--baseline-min/--baseline-max must satisfy 0 < min ≤ max"),
        (0 <= max_angle <= 89, "--max-angle must be within 0–89 degrees"),
        (
            all(0 <= s <= 1 for s in (portrait_share, outdoor_share, close_share, panorama_share)),
            "shares must be within 0–1",
        ),
        (augment >= 0, "--augment must be ≥ 0"),
        (panorama_max_upsampling >= 1, "--panorama-max-upsampling must be ≥ 1"),
    ]
    for ok, message in checks:
        if not ok:
            raise StereoGeoError(message)
    for name, folder in (("--textures", textures), ("--panoramas", panoramas)):
        if folder is not None and not Path(folder).is_dir():
            raise StereoGeoError(f"{name}: no such folder: {folder}")
    return SynthConfig(
        short_side=size,
        aspects=parse_aspects(aspects),
        portrait_share=portrait_share,
        vfov_deg=tuple(vfov),
        baseline_m=tuple(baseline),
        max_angle_deg=max_angle,
        outdoor_share=outdoor_share,
        close_share=close_share,
        panorama_share=panorama_share,
        panorama_max_upsampling=panorama_max_upsampling,
        augment=augment,
        depth=depth,
        textures=Path(textures).resolve() if textures else None,
        panoramas=Path(panoramas).resolve() if panoramas else None,
    )


# defaults of the options that differ between pair datasets and sequences (None on the command line)
PAIR_DEFAULTS = {
    "count": 1000,
    "size": 240,
    "aspects": "4:3,16:9,1:1,3:2",
    "vfov": (20.0, 105.0),
    "baseline": (0.05, 0.8),
    "max_angle": 45.0,
    "augment": 1.0,
}
SEQUENCE_DEFAULTS = {
    "count": 50,
    "size": 480,
    "aspects": "4:3",
    "vfov": (45.0, 80.0),
    "baseline": (0.1, 0.5),
    "max_angle": 5.0,
    "augment": 0.5,
}
# --sequence drive: a car's rig (sequence.DRIVE_CONFIG): 1240 × 376, vFoV 27–33°, baseline 0.45–0.6 m
DRIVE_DEFAULTS = {
    **SEQUENCE_DEFAULTS,
    "size": 376,
    "aspects": "1240:376",
    "vfov": (27.0, 33.0),
    "baseline": (0.45, 0.6),
    "max_angle": 2.0,
}
# the options of the effects of real recordings (sequences only) and their "off" values
EFFECT_OPTIONS = {
    "principal_offset": ("--principal-offset", None),
    "focal_aspect": ("--focal-aspect", 1.0),
    "h264": ("--h264", None),
    "keep_video": ("--keep-video", False),
    "exposure_changes": ("--exposure-changes", 0.0),
    "motion_blur": ("--motion-blur", 0.0),
    "moving_objects": ("--moving-objects", 0),
}


def build_effects(effects: dict):
    """The SequenceEffects of the command line's effect options (EFFECT_OPTIONS; missing ones off)."""
    from stereogeo_cli.synth.effects import SequenceEffects, parse_principal_offset

    given = {key: effects.get(key, off) for key, (_, off) in EFFECT_OPTIONS.items()}
    return SequenceEffects(
        principal_offset=parse_principal_offset(given["principal_offset"]),
        focal_aspect=float(given["focal_aspect"]),
        h264_kbps=None if given["h264"] is None else float(given["h264"]),
        keep_video=bool(given["keep_video"]),
        exposure_stops=float(given["exposure_changes"]),
        motion_blur_ms=float(given["motion_blur"]),
        moving_objects=int(given["moving_objects"]),
    )


def _resolve(options: dict, defaults: dict) -> dict:
    """Options with None (not given) replaced by the mode's defaults; ranges per end."""
    out = dict(options)
    for key, default in defaults.items():
        if key not in out:
            continue
        if isinstance(default, tuple):
            out[key] = tuple(d if v is None else v for v, d in zip(out[key], default, strict=True))
        elif out[key] is None:
            out[key] = default
    return out


def run_make_data(
    out: Path | None,
    *,
    count: int | None,
    seed: int,
    workers: int,
    preview: Path | None,
    progress: bool,
    sequence: str | None = None,
    effects: dict | None = None,
    rate: float | None = None,
    **options,
) -> None:
    """Write the dataset and/or the contact sheet, or one sequence; a one-line summary goes to stderr.

    Options left None take the defaults of the mode (PAIR_DEFAULTS, SEQUENCE_DEFAULTS or, for a drive,
    DRIVE_DEFAULTS). ``effects``: the effect options of a sequence (EFFECT_OPTIONS), refused for pairs;
    ``rate`` (Hz): a sequence's frame rate (None: the motion's own time), refused for pairs.
    """
    if sequence is not None:
        _run_sequence(
            out, count=count, seed=seed, preview=preview, progress=progress, motion=sequence,
            effects=effects or {}, rate=rate, **options,
        )  # fmt: skip
        return
    if rate is not None:
        raise StereoGeoError("--rate is the frame rate of a sequence: it goes with --sequence MOTION")
    for key, value in (effects or {}).items():
        name, off = EFFECT_OPTIONS[key]
        if value != off:
            raise StereoGeoError(f"{name} is an effect of sequences: it goes with --sequence MOTION")
    resolved = _resolve({"count": count, **options}, PAIR_DEFAULTS)
    count = resolved.pop("count")
    if out is None and preview is None:
        raise StereoGeoError("give an output folder, --preview SHEET.png, or both")
    if workers < 1:
        raise StereoGeoError("--workers must be ≥ 1")
    config = build_config(**resolved)
    if out is not None:
        from stereogeo_cli.synth.dataset import make_dataset

        summary = make_dataset(Path(out), count, seed, config, workers=workers, progress=progress)
        print(
            f"wrote {plural(summary.written, 'pair')} to {summary.folder} ({summary.skipped} already there)",
            file=sys.stderr,
        )
    if preview is not None:
        from stereogeo_cli.synth.preview import write_preview

        write_preview(Path(preview), seed, config, dataset_size=max(count, 16))
        print(f"wrote contact sheet {preview}", file=sys.stderr)


def _run_sequence(
    out: Path | None,
    *,
    count: int | None,
    seed: int,
    preview: Path | None,
    progress: bool,
    motion: str,
    effects: dict,
    rate: float | None = None,
    **options,
) -> None:
    """``make-data OUT --sequence MOTION``: one sequence of ``count`` frame pairs in OUT (docs/synth.md,
    "Sequences"), with the effects of real recordings that ``effects`` switches on. Images are always
    landscape and never panorama crops."""
    from stereogeo_cli.synth.sequence import MOTIONS, make_sequence

    if motion not in MOTIONS:
        raise StereoGeoError(f"--sequence: unknown motion {motion!r}; choose from {', '.join(MOTIONS)}")
    if out is None:
        raise StereoGeoError("--sequence needs an output folder")
    if preview is not None:
        raise StereoGeoError("--preview shows independent pairs; it does not go with --sequence")
    resolved = _resolve(
        {"count": count, **options}, DRIVE_DEFAULTS if motion == "drive" else SEQUENCE_DEFAULTS
    )
    count = resolved.pop("count")
    if count < 1:
        raise StereoGeoError("--count: a sequence needs at least one frame")
    if rate is not None and not rate > 0:  # NaN included
        raise StereoGeoError(f"--rate must be > 0 Hz (frames per second), not {rate:g}")
    config = build_config(**resolved).replace(portrait_share=0.0, panorama_share=0.0)
    summary = make_sequence(
        Path(out), motion, count, seed, config, progress=progress, effects=build_effects(effects),
        rate_hz=rate,
    )  # fmt: skip
    print(
        f"wrote a {summary.motion} sequence of {plural(summary.frames, 'frame pair')} ({summary.scene} "
        f"scene) to {summary.folder}",
        file=sys.stderr,
    )
