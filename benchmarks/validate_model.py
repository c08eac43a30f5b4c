"""Validation metrics of a checkpoint, as training logs them, on a whole validation set.

    python benchmarks/validate_model.py CHECKPOINT VAL_DIR [--count N]

The network alone (no feature matches; with --flip the fields are averaged with the mirrored pair's, as
calibrate's off-by-default ``flip`` option does): per-camera roll, pitch and vFoV errors through the NumPy
refiner (median, mean, AUC@1/5/10 in degrees), and the median and 68th percentile of the pose head's
rotation, direction, translation and length errors. These are the figures models/MODEL_CARD.md reports.
"""

import argparse
import json

import torch

from stereogeo_cli.network.checkpoint import load_checkpoint
from stereogeo_cli.network.data import FolderPairs
from stereogeo_cli.network.train import validate


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("checkpoint")
    parser.add_argument("val")
    parser.add_argument("--count", type=int, default=300)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--flip", action="store_true", help="mirror averaging (calibrate's flip option)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    model, checkpoint = load_checkpoint(args.checkpoint)
    short_side = int(checkpoint.get("input_short_side", 224))
    metrics = validate(model, FolderPairs(args.val), args.count, short_side, flip=args.flip)
    print(
        json.dumps(
            {"step": checkpoint.get("step"), "pairs": args.count, "flip": args.flip, **metrics},
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
