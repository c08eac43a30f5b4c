"""How honest a model's reported sigmas are on real photographs, and the photo_sigma_scale that makes them so.

    python benchmarks/photo_sigma.py MODEL DATASET [DATASET ...] [--threads N]

Users feed photographs. The model's ``sigma_inflation`` is measured on renders and crops of real panoramas
together, and on the crops alone the network errs more than its sigmas say. The crops of real panoramas in
rendered sets (``kind`` "panorama" in calib.jsonl, from ``make-data --panoramas``) are real photographs
with exact gravity and focal length: through ``calibrate``, this prints the share of their roll, pitch and
vFoV errors within the reported 1 sigma and the 68th percentile of error / sigma. Multiplied by the model's
current ``photo_sigma_scale``, that is the factor to export with ``--photo-sigma-scale`` (the estimates do
not change with it, only the sigmas reported). The renders' figures are printed beside, for reference.
"""

import argparse
from pathlib import Path

import numpy as np

from stereogeo_cli.errors import CalibrationFailed
from stereogeo_cli.evaluate import pair_errors, read_dataset
from stereogeo_cli.io import load_image
from stereogeo_cli.pipeline import Calibrator

QUANTITIES = ("roll", "pitch", "vfov")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("model")
    parser.add_argument("datasets", nargs="+")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--renders", action="store_true", help="also calibrate the renders (slower)")
    args = parser.parse_args()
    calibrator = Calibrator(args.model, threads=args.threads)
    z = {kind: {q: [] for q in QUANTITIES} for kind in ("photographs", "renders")}
    for folder in map(Path, args.datasets):
        for record in read_dataset(folder):
            kind = "photographs" if record.get("kind") == "panorama" else "renders"
            if kind == "renders" and not args.renders:
                continue
            name = record["id"]
            try:
                result = calibrator.calibrate(
                    load_image(folder / "left" / f"{name}.png"), load_image(folder / "right" / f"{name}.png")
                )
            except CalibrationFailed:
                continue
            row = pair_errors(result, record)
            for q in QUANTITIES:
                z[kind][q] += [
                    row[f"{v}_{q}_z"] for v in ("left", "right") if row.get(f"{v}_{q}_z") is not None
                ]
    current = calibrator.photo_sigma_scale
    print(f"model {args.model}: photo_sigma_scale now {','.join(f'{c:g}' for c in current)}")
    for kind, found in z.items():
        if not found["vfov"]:
            continue
        cells = []
        for q in QUANTITIES:
            values = np.abs(np.array(found[q]))
            cells.append(
                f"{q} {100 * np.mean(values <= 1):.0f} % within 1 sigma, x{np.percentile(values, 68.27):.3f}"
            )
        print(f"{kind} ({len(found['vfov'])} views): " + "; ".join(cells))
    if z["photographs"]["vfov"]:
        photos = z["photographs"]
        scale = [
            c * np.percentile(np.abs(photos[q]), 68.27) for c, q in zip(current, QUANTITIES, strict=True)
        ]
        print("--photo-sigma-scale " + ",".join(f"{s:.2f}" for s in scale))


if __name__ == "__main__":
    main()
