"""Where the relative rotation's error comes from, step by step from the truth to what stereogeo does.

    python benchmarks/rotation_budget.py DATASET [DATASET ...] [--model M]

For each dataset (the project's layout with ground truth), the median rotation error of the same SIFT
matches under less and less given knowledge:

1. ``E, true K and lens``: matches undistorted with the true lens, essential matrix with the true K (the
   evaluation's SIFT baseline).
2. ``E, principal points centred``: the same, with each K's principal point moved to the image centre
   (stereogeo's camera model): a difference between the two cameras' principal points is a rotation the
   pose absorbs. The median of that difference, as an angle (|Δ principal point| / f), is printed too.
3. ``stereogeo, true focal and lens``: the images undistorted with their true lens, then ``calibrate``
   with the true focal lengths given and no lens fitted (``--pinhole``): the fusion on 2.'s knowledge.
4. ``stereogeo, true focal``: the raw images with the true focal lengths given; the lens is fitted.
5. ``stereogeo``: nothing given.

Going down the rows, each step's increase is what that piece of knowledge is worth.
"""

import argparse
import json
import math
from pathlib import Path

import cv2
import numpy as np

from stereogeo_cli.evaluate import read_dataset, undistort_with_lens
from stereogeo_cli.fuse import Matches, essential_pose, match_features
from stereogeo_cli.geometry import intrinsic_matrix, rotation_error
from stereogeo_cli.io import load_image
from stereogeo_cli.pipeline import Calibrator

ROWS = (
    "E, true K and lens",
    "E, principal points centred",
    "stereogeo, true focal and lens",
    "stereogeo, true focal",
    "stereogeo",
)


def _error_deg(R: np.ndarray, record: dict) -> float:
    return math.degrees(rotation_error(R, np.asarray(record["R"], dtype=float)))


def budget(folder: Path, calibrator: Calibrator, pinhole: Calibrator) -> dict:
    errors: dict[str, list[float]] = {row: [] for row in ROWS}
    offsets = []
    for record in read_dataset(folder):
        if record.get("R") is None:
            continue
        left, right = (load_image(folder / side / f"{record['id']}.png") for side in ("left", "right"))
        K = [np.asarray(record[side]["K"], dtype=float) for side in ("left", "right")]
        dist = [np.asarray(record[side]["dist"], dtype=float) for side in ("left", "right")]
        sizes = [(image.shape[1], image.shape[0]) for image in (left, right)]
        centred = [intrinsic_matrix(k[1, 1], *size) for k, size in zip(K, sizes, strict=True)]
        shift = [k[:2, 2] - c[:2, 2] for k, c in zip(K, centred, strict=True)]
        offsets.append(math.degrees(float(np.linalg.norm(shift[1] - shift[0])) / K[0][1, 1]))
        m = match_features(left, right)
        undistorted = Matches(
            undistort_with_lens(m.left, record["left"]), undistort_with_lens(m.right, record["right"])
        )
        for row, (K_left, K_right) in zip(ROWS[:2], (K, centred), strict=True):
            pose = essential_pose(undistorted, K_left, K_right) if len(undistorted) else None
            errors[row].append(_error_deg(pose[0], record) if pose is not None else math.nan)
        focal = {"focal_left": K[0][1, 1], "focal_right": K[1][1, 1]}
        flat = [
            cv2.undistort(image, k, d) if len(d) else image
            for image, k, d in zip((left, right), K, dist, strict=True)
        ]
        errors[ROWS[2]].append(_error_deg(pinhole.calibrate(*flat, **focal).calibration.R, record))
        errors[ROWS[3]].append(_error_deg(calibrator.calibrate(left, right, **focal).calibration.R, record))
        errors[ROWS[4]].append(_error_deg(calibrator.calibrate(left, right).calibration.R, record))
    return {
        "dataset": folder.name,
        "pairs": len(offsets),
        "principal_point_difference_deg": float(np.median(offsets)) if offsets else None,
        **{row: float(np.nanmedian(values)) if values else None for row, values in errors.items()},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+", type=Path)
    parser.add_argument("--model", type=Path, default=None)
    parser.add_argument("--json", type=Path, help="also write the rows to this JSON file")
    args = parser.parse_args()
    calibrator = Calibrator(args.model)
    pinhole = Calibrator(args.model, conf={"fuse": {"distortion": False}})
    print("| dataset | pairs | Δ principal point | " + " | ".join(ROWS) + " |")
    print("|---|---|---|" + "---|" * len(ROWS))
    results = []
    for folder in args.datasets:
        row = budget(folder, calibrator, pinhole)
        results.append(row)
        cells = ["–" if row[k] is None else f"{row[k]:.3f}°" for k in ROWS]
        offset = row["principal_point_difference_deg"]
        print(
            f"| {row['dataset']} | {row['pairs']} | {'–' if offset is None else f'{offset:.2f}°'} | "
            + " | ".join(cells) + " |",
            flush=True,
        )  # fmt: skip
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
