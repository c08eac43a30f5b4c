"""How close the lens `calibrate` fits comes to a raw camera's true one.

    python benchmarks/lens_accuracy.py DATASET [DATASET ...] [--model FILE] [--no-edges]

For every view of a dataset whose ground truth has OpenCV distortion coefficients, the true lens is taken
as the division model (one k about the image centre, the model `calibrate` fits) closest to it over the
image, and compared as the *stretch at the corner*, k·r² with r the corner's normalised radius: the
undistorted corner lies 1/(1 + stretch) as far from the centre. It does not depend on the focal length, so
the fitted lens (in the calibrated K's coordinates) compares directly. Prints per dataset the views with a
lens fitted, the median error of the fitted lens (none fitted counts as 0) and of the lens the straight
edges show (`pose.edge_distortion_k`, where they give one), in stretch and in pixels at the corner.
`--no-edges` runs the pipeline without the edges' evidence (``plumb.enabled`` off), for a before/after.
"""

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

from stereogeo_cli.evaluate import read_dataset
from stereogeo_cli.io import load_image
from stereogeo_cli.pipeline import Calibrator


def true_stretch(camera: dict) -> float | None:
    """The stretch at the corner of the division model closest to the camera's OpenCV lens (None: none)."""
    dist = np.array(camera.get("dist") or [], dtype=float)
    if not len(dist) or not np.any(dist):
        return None
    K = np.array(camera["K"], dtype=float)
    width, height = camera["width"], camera["height"]
    xs, ys = np.meshgrid(np.linspace(0, width - 1, 48), np.linspace(0, height - 1, 36))
    seen = np.column_stack([xs.ravel(), ys.ravel()])
    truth = cv2.undistortPoints(seen[:, None], K, dist).reshape(-1, 2) * K[0, 0] + K[:2, 2]  # pinhole px
    centre = np.array([width / 2.0, height / 2.0])
    x = (seen - centre) / K[0, 0]
    r2 = np.sum(x * x, axis=1, keepdims=True)
    corner = np.hypot(width, height) / 2.0 / K[0, 0]
    trials = np.linspace(-0.9, 0.3, 1201) / corner**2
    misfit = [np.median(np.linalg.norm(x / (1 + k * r2) * K[0, 0] + centre - truth, axis=1)) for k in trials]
    return float(trials[int(np.argmin(misfit))] * corner**2)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("datasets", nargs="+", type=Path)
    parser.add_argument("--model", type=Path, default=None)
    parser.add_argument("--no-edges", action="store_true", help="without the straight edges' evidence")
    args = parser.parse_args()
    conf = {"plumb": {"enabled": False}} if args.no_edges else None
    calibrator = Calibrator(args.model, conf=conf)
    print(
        "| set | views with a lens | fitted | fitted lens: error (stretch / px at the corner) "
        "| edges' lens: views, error |"
    )
    print("|---|---|---|---|---|")
    for folder in args.datasets:
        fitted, edges, corner_px, chosen, views = [], [], [], 0, 0
        for record in read_dataset(folder):
            truths = [true_stretch(record[side]) for side in ("left", "right")]
            if all(t is None for t in truths):
                continue
            images = [load_image(folder / side / f"{record['id']}.png") for side in ("left", "right")]
            report = calibrator.calibrate(*images).report()
            for side, truth in zip(("left", "right"), truths, strict=True):
                if truth is None:
                    continue
                views += 1
                cam = report[side]
                corner2 = (np.hypot(cam["width"], cam["height"]) / 2.0 / cam["focal_px"]) ** 2
                k = report["pose"]["distortion_k"][side == "right"]
                chosen += k != 0.0
                fitted.append(k * corner2 - truth)
                corner_px.append(np.hypot(cam["width"], cam["height"]) / 2.0)
                k_edges = report["pose"]["edge_distortion_k"][side == "right"]
                if k_edges is not None:
                    edges.append(k_edges * corner2 - truth)
        if not views:
            print(f"| {folder.name} | no views with a lens in the ground truth | | | |")
            continue
        error = np.median(np.abs(fitted))
        px = np.median(np.abs(fitted) * np.array(corner_px))
        edge_text = f"{len(edges)}, {np.median(np.abs(edges)):.3f}" if edges else "0"
        print(f"| {folder.name} | {views} | {chosen} | {error:.3f} / {px:.0f} px | {edge_text} |")
        print(json.dumps({"set": folder.name, "fitted": [round(float(e), 4) for e in fitted]}), flush=True)


if __name__ == "__main__":
    main()
