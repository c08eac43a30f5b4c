"""How the calibration depends on the size the network sees: the same pairs at several input short sides.

    python benchmarks/scale_sensitivity.py DATASET [DATASET ...] [--sizes 160,192,224,256,288] [--model M]

Every pair of each dataset (the project's layout with ground truth) is calibrated by the full pipeline
with the network's input short side overridden (the shipped rule is the model's ``input_short_side``).
Prints one row per dataset and size: median vFoV error, median roll and pitch errors where gravity is
known, median rotation error. A model that reads the focal length from geometry gives the same vFoV at
every size; one that reads it from how big things look in pixels does not.
"""

import argparse
import json
import sys
from pathlib import Path

from stereogeo_cli.evaluate import evaluate_dataset
from stereogeo_cli.pipeline import Calibrator


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("datasets", nargs="+", type=Path)
    parser.add_argument("--sizes", default="160,192,224,256,288", help="input short sides, multiples of 32")
    parser.add_argument("--model", type=Path, default=None)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--json", type=Path, help="also write the rows to this JSON file")
    args = parser.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    rows = []
    calibrator = Calibrator(args.model, threads=args.threads)
    shipped = calibrator.network.short_side
    print(f"model {calibrator.model_path.name}, shipped input short side {shipped}", file=sys.stderr)
    print("| dataset | short side | vFoV | roll | pitch | R |\n|---|---|---|---|---|---|")
    for folder in args.datasets:
        for size in sizes:
            calibrator.network.short_side = size
            metrics = evaluate_dataset(folder, calibrator)["metrics"]

            medians = {k: v.get("median") for k, v in metrics.items() if isinstance(v, dict)}
            row = {"dataset": folder.name, "short_side": size}
            row.update({k: medians.get(f"{k}_deg") for k in ("vfov", "roll", "pitch")})
            row["rotation"] = medians.get("rotation_error_deg")
            rows.append(row)
            cells = [
                f"{row[k]:.2f}°" if row[k] is not None else "–" for k in ("vfov", "roll", "pitch", "rotation")
            ]
            mark = " (shipped)" if size == shipped else ""
            print(f"| {folder.name} | {size}{mark} | " + " | ".join(cells) + " |", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
