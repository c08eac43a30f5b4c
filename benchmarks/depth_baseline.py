"""The metric baseline `calibrate` reads without `--baseline`, against the truth, by where it came from.

    python benchmarks/depth_baseline.py DATASET [DATASET ...] [--model FILE] [--count N] [--json FILE]

With a model that has a depth head, `calibrate` takes the baseline from the feature matches and the head's
depth (stereogeo_cli/fuse/scale.py) and falls back to the pose head's learned length where too few matches
have parallax. For each dataset this prints how many pairs took each route, and the relative baseline error
|B̂/B − 1| (median and 68th percentile, the figure `export-onnx --depth-sigma` records) of the depth route,
of the pose head's length on the same pairs, and of what calibrate reports on every pair.
"""

import argparse
import json
from pathlib import Path

import numpy as np

from stereogeo_cli.evaluate import read_dataset
from stereogeo_cli.io import load_image
from stereogeo_cli.pipeline import Calibrator


def _summary(errors: list[float]) -> str:
    if not errors:
        return "–"
    e = np.asarray(errors)
    return f"{np.median(e):.3f} / {np.percentile(e, 68):.3f} (n {len(e)})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("datasets", nargs="+")
    parser.add_argument("--model", help="ONNX model (default: the shipped one)")
    parser.add_argument("--count", type=int, default=0, help="first N pairs of each dataset (0: all)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--json", help="write the per-pair rows here")
    args = parser.parse_args()
    calibrator = Calibrator(args.model, threads=args.threads)
    rows = []
    print(
        "| dataset | pairs by depth / pose head | depth route: median / p68 | pose head, same pairs | "
        "calibrate, all pairs |"
    )
    print("|---|---|---|---|---|")
    for dataset in args.datasets:
        root = Path(dataset)
        depth_errors, head_errors, all_errors = [], [], []
        routes = {"depth": 0, "pose_head": 0}
        for record in read_dataset(root)[: args.count or None]:
            T = np.asarray(record.get("T") or [0, 0, 0], dtype=float)
            if record.get("R") is None or np.linalg.norm(T) == 0:
                continue  # no baseline to compare with
            images = [load_image(root / side / f"{record['id']}.png") for side in ("left", "right")]
            result = calibrator.calibrate(*images)
            report = result.report()
            truth = float(np.linalg.norm(T))
            found = float(np.linalg.norm(result.calibration.T))
            head = report["pose"]["head_baseline_m"]
            source = report["pose"]["baseline_source"]
            routes[source] += 1
            error = abs(found / truth - 1)
            all_errors.append(error)
            if source == "depth":
                depth_errors.append(error)
                head_errors.append(abs(head / truth - 1))
            rows.append(
                {"dataset": dataset, "id": record["id"], "baseline_m": truth, "found_m": found,
                 "head_m": head, "source": source}
            )  # fmt: skip
        print(
            f"| {root.name} | {routes['depth']} / {routes['pose_head']} | {_summary(depth_errors)} | "
            f"{_summary(head_errors)} | {_summary(all_errors)} |",
            flush=True,
        )
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
