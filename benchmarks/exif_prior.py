"""What an EXIF focal length does to `calibrate`: each pair tagged as a phone would tag it, with and without.

    python benchmarks/exif_prior.py DATASET [DATASET ...] [--tag-error 0,0.05,-0.1] [--model FILE]

Every image of a dataset with ground truth is copied to a temporary PNG (the same pixels) carrying an EXIF
``FocalLengthIn35mmFilm`` tag: the true focal length, times 1 + each ``--tag-error`` (a maker's convention
or a lens that breathes), in whole millimetres as cameras write it. Each copy is calibrated with the tag read
as `calibrate` reads it (``stereogeo_cli.io.exif``) and, for comparison, without it (``--no-exif``). Prints
per dataset and tag error the medians of the vFoV error, the relative focal error, roll and pitch (where
known), the rotation and the translation direction, and the share of the vFoV errors within their 1-sigma.
"""

import argparse
import math
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

from stereogeo_cli.evaluate import pair_errors, read_dataset
from stereogeo_cli.io import load_image
from stereogeo_cli.io.exif import DIAGONAL_35MM, exif_focals
from stereogeo_cli.pipeline import Calibrator

COLUMNS = (
    ("vFoV (°)", ("left_vfov_error_deg", "right_vfov_error_deg")),
    ("focal (rel.)", ("left_focal_error_rel", "right_focal_error_rel")),
    ("roll (°)", ("left_roll_error_deg", "right_roll_error_deg")),
    ("pitch (°)", ("left_pitch_error_deg", "right_pitch_error_deg")),
    ("R (°)", ("rotation_error_deg",)),
    ("t dir. (°)", ("direction_error_deg",)),
)


def tagged_copy(src: Path, dst: Path, focal_px: float, error: float) -> Path:
    image = Image.open(src)
    width, height = image.size
    exif = Image.Exif()
    f35 = focal_px * (1 + error) * DIAGONAL_35MM / math.hypot(width, height)
    exif.get_ifd(0x8769)[0xA405] = max(1, int(round(f35)))
    image.save(dst, exif=exif.tobytes())
    return dst


def rows_for(calibrator: Calibrator, folder: Path, error: float | None, scratch: Path) -> list[dict]:
    rows = []
    for record in read_dataset(folder):
        paths = []
        for view in ("left", "right"):
            src = folder / view / f"{record['id']}.png"
            focal = 0.5 * (record[view]["K"][0][0] + record[view]["K"][1][1])
            paths.append(src if error is None else tagged_copy(src, scratch / f"{view}.png", focal, error))
        images = [load_image(p) for p in paths]
        exif = exif_focals(paths, images) if error is not None else None
        rows.append(pair_errors(calibrator.calibrate(images[0], images[1], exif=exif), record))
    return rows


def line(label: str, rows: list[dict]) -> str:
    cells = []
    for _, keys in COLUMNS:
        values = [r[k] for r in rows for k in keys if r.get(k) is not None]
        cells.append(f"{np.median(values):.3f}" if values else "–")
    z = [r[k] for r in rows for k in ("left_vfov_z", "right_vfov_z") if r.get(k) is not None]
    within = f"{100 * np.mean(np.asarray(z) <= 1):.0f} %" if z else "–"
    return f"| {label} | " + " | ".join(cells) + f" | {within} |"


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("datasets", nargs="+", type=Path)
    parser.add_argument("--tag-error", default="0,0.05", help="relative errors of the tags, comma-separated")
    parser.add_argument("--model", default=None)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    errors = [float(e) for e in args.tag_error.split(",")]
    calibrator = Calibrator(args.model, threads=args.threads)
    with tempfile.TemporaryDirectory() as scratch:
        for folder in args.datasets:
            print(f"\n**{folder.name}**\n")
            print("| EXIF | " + " | ".join(c for c, _ in COLUMNS) + " | vFoV within 1σ |")
            print("|---" * (len(COLUMNS) + 2) + "|")
            print(line("none (--no-exif)", rows_for(calibrator, folder, None, Path(scratch))), flush=True)
            for error in errors:
                label = f"tag {100 * error:+.0f} %"
                print(line(label, rows_for(calibrator, folder, error, Path(scratch))), flush=True)


if __name__ == "__main__":
    main()
