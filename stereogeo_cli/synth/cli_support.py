"""What ``stereogeo make-data`` does, below the argument parsing: validate options, render, report."""

from __future__ import annotations

import sys
from pathlib import Path

from stereogeo_cli.errors import StereoGeoError
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


def run_make_data(
    out: Path | None, *, count: int, seed: int, workers: int, preview: Path | None, progress: bool, **options
) -> None:
    """Write the dataset and/or the contact sheet; a one-line summary goes to stderr."""
    if out is None and preview is None:
        raise StereoGeoError("give an output folder, --preview SHEET.png, or both")
    if workers < 1:
        raise StereoGeoError("--workers must be ≥ 1")
    config = build_config(**options)
    if out is not None:
        from stereogeo_cli.synth.dataset import make_dataset

        summary = make_dataset(Path(out), count, seed, config, workers=workers, progress=progress)
        print(
            f"wrote {summary.written} pairs to {summary.folder} ({summary.skipped} already there)",
            file=sys.stderr,
        )
    if preview is not None:
        from stereogeo_cli.synth.preview import write_preview

        write_preview(Path(preview), seed, config, dataset_size=max(count, 16))
        print(f"wrote contact sheet {preview}", file=sys.stderr)
