"""How much the focal length read from a photograph moves when the photograph is softened.

    python benchmarks/sharpness.py REAL_PHOTOS_DIR [--split measure|train|FILE] [--fields-only] [--model M]
        [--upsample linear|cubic] [--at-network-input] [--json FILE]

Every photograph of a single-photograph set (``labels.jsonl``: ``stereogeo evaluate``'s photo layout, e.g.
the developer data's ``real-photos``) is calibrated as ``stereogeo evaluate`` calibrates it (the pair of the
photo and the photo less its 8 leftmost columns, no EXIF), once as it is and once softened 2×: resized
down to half with INTER_AREA and back up to its own size with INTER_LINEAR (``--upsample cubic``:
INTER_CUBIC). The same scene, camera and focal length; only the sharpness differs. A network that reads
the focal length from geometry reads the same vFoV; one that has learned "soft means a long lens" reads a
narrower one. Prints per set (``photo``, ``car``) and for all: the median |vFoV(photo) − vFoV(softened)|
over the images, and over cameras (each camera counting once), the median signed change (< 0: softened
reads narrower), and the median vFoV error of each. The goal is a median change ≤ 2° on each set.

``--fields-only``: each photo's fit from the network's fields alone (network and refiner; no lines, no
matches): what the network itself reads.

``--at-network-input``: soften 2× at the resolution the network reads, not at the photograph's own: down by
2 · (short side / the model's input short side) and back up. The network sees a photograph reduced to its
input size (224 px on the short side), and a photograph of 700–1000 px reduced 3–4.5× loses most of a 2×
softening of its own pixels; softened at the network's input, the network sees it half as sharp.
"""

import argparse
import json
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

from stereogeo_cli.errors import CalibrationFailed, StereoGeoError
from stereogeo_cli.evaluate import weighted_quantile
from stereogeo_cli.evaluate_photos import (
    calibrate_photo,
    camera_weights,
    photo_pair,
    read_labels,
    select,
    soften,
)
from stereogeo_cli.geometry import vfov_from_focal
from stereogeo_cli.io import load_image
from stereogeo_cli.pipeline import Calibrator

GOAL_DEG = 2.0


def read_vfov(calibrator: Calibrator, image: np.ndarray, fields_only: bool) -> float:
    """The photo's vFoV in degrees as the evaluation reads it (or from its fields alone)."""
    if fields_only:
        return calibrator.fields_only(*photo_pair(image))[0].vfov_deg
    return calibrate_photo(calibrator, image).left.vfov_deg


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("folder", type=Path, help="a folder of single photographs with a labels.jsonl")
    parser.add_argument("--split", default=None, help="train, measure, or a file of image paths")
    parser.add_argument("--split-file", type=Path, default=None)
    parser.add_argument("--fields-only", action="store_true", help="the network's fields alone")
    parser.add_argument("--upsample", choices=("linear", "cubic"), default="linear")
    parser.add_argument("--model", type=Path, default=None)
    parser.add_argument("--threads", type=int, default=0)
    parser.add_argument(
        "--at-network-input", action="store_true", help="soften 2x at the resolution the network reads"
    )
    parser.add_argument("--json", type=Path, help="also write the per-image rows to this JSON file")
    args = parser.parse_args()
    upsample = {"linear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC}[args.upsample]
    records = select(read_labels(args.folder), args.split, args.split_file)
    calibrator = Calibrator(args.model, threads=args.threads)
    rows = []
    for record in records:
        K = np.asarray(record["K"], dtype=float)
        truth = float(np.degrees(vfov_from_focal(K[1, 1], record["height"])))
        row = {"id": record["file"], "camera": record["camera_id"], "set": record.get("set") or ""}
        try:
            image = load_image(args.folder / record["file"])
            factor = 2.0
            if args.at_network_input:  # 2x softer as the network sees it (never sharper than the photo)
                factor *= max(1.0, min(image.shape[:2]) / calibrator.network.short_side)
            sharp = read_vfov(calibrator, image, args.fields_only)
            soft = read_vfov(calibrator, soften(image, factor, upsample=upsample), args.fields_only)
        except (StereoGeoError, CalibrationFailed) as error:
            row["error"] = str(error)
        else:
            row.update(vfov_deg=sharp, softened_vfov_deg=soft, change_deg=soft - sharp)
            row.update(vfov_error_deg=abs(sharp - truth), softened_vfov_error_deg=abs(soft - truth))
        rows.append(row)
    groups = defaultdict(list)
    for row in rows:
        if "error" not in row:
            groups[row["set"]].append(row)
            groups["all"].append(row)
    mode = "fields only" if args.fields_only else "calibrate"
    down_up = f"INTER_AREA down, INTER_{args.upsample.upper()} up"
    where = "at the network's input" if args.at_network_input else "at the photograph's resolution"
    print(f"{mode}, softened 2x {where} ({down_up}); goal: median abs. change <= {GOAL_DEG} deg")
    print("| set | images | cameras | median abs. change (°), images / cameras | median change (°) | "
          "vFoV error sharp → softened (°) |")  # fmt: skip
    print("|---|---|---|---|---|---|")
    for name, group in sorted(groups.items(), key=lambda g: g[0] == "all"):
        change = np.array([r["change_deg"] for r in group])
        by_image = float(np.median(np.abs(change)))
        by_camera = weighted_quantile(np.abs(change), camera_weights(group), 0.5)
        verdict = "meets" if by_image <= GOAL_DEG else "misses"
        sharp, soft = (
            float(np.median([r[k] for r in group])) for k in ("vfov_error_deg", "softened_vfov_error_deg")
        )
        cameras = len({r["camera"] for r in group})
        print(
            f"| {name} | {len(group)} | {cameras} | {by_image:.2f} / {by_camera:.2f} ({verdict} the goal) | "
            f"{float(np.median(change)):+.2f} | {sharp:.2f} → {soft:.2f} |"
        )
    for row in rows:
        if "error" in row:
            print(f"failed: {row['id']}: {row['error']}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
