"""What the pose head's baseline length is made of, on a dataset with ground truth.

    python benchmarks/pose_scale.py CHECKPOINT DATASET [--count N] [--json FILE]

The head reads |T| as a weighted mean over the left view's stride-8 cells of (log parallax + a learned
log-depth term), the parallax being the cell's soft-match displacement minus the learned displacement of a
point at infinity (the rotation's share). Per pair with a baseline, this compares each part with the truth:

- ``length``: |T̂| / |T| − 1, the head's baseline error (the model card's pose-head figures);
- ``parallax``: the head's vote-weighted parallax against the median true parallax of SIFT matches (kept
  within 1 px of the true epipolar lines; the true rotation's displacement taken off), both in units of
  half the network input's short side; and the slope of one against the other over the pairs (1 is ideal);
- ``infinity``: the learned point-at-infinity displacement against the true rotation's (median over the
  cells);
- ``with true infinity``: the length again with the true rotation's displacement in place of the learned
  one, the votes unchanged (what the matches' rotation could give the head as trained);
- ``votes and SIFT parallax``: the median over the SIFT matches of (the vote of the match's left cell + the
  log of its exact parallax): the head's depth term alone, with the parallax a full-resolution matcher and
  the true rotation give.

Torch only (CPU); the network input is prepared as ``calibrate`` prepares it.
"""

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
import torch

from stereogeo_cli.evaluate import read_dataset
from stereogeo_cli.geometry.camera import apply_resize_crop, resize_crop_for_network
from stereogeo_cli.geometry.epipolar import fundamental_matrix, symmetric_epipolar_distance
from stereogeo_cli.io import load_image
from stereogeo_cli.network.checkpoint import load_checkpoint
from stereogeo_cli.network.data import MATCH_STRIDE, match_targets

EPIPOLAR_PX = 1.0


def true_fundamental(record: dict) -> np.ndarray:
    K = [np.array(record[side]["K"], dtype=float) for side in ("left", "right")]
    return fundamental_matrix(
        K[0], K[1], np.array(record["R"], dtype=float), np.array(record["T"], dtype=float)
    )


def sift_parallax(left: np.ndarray, right: np.ndarray, record: dict, sift) -> tuple[np.ndarray, np.ndarray]:
    """SIFT matches on the true epipolar lines: their left points [N x 2] and true parallax [N] (pixels of the
    left image; the true rotation's displacement taken off). Empty when fewer than 8."""
    none = np.zeros((0, 2)), np.zeros(0)
    grey = [cv2.cvtColor(im, cv2.COLOR_RGB2GRAY) for im in (left, right)]
    (k1, d1), (k2, d2) = (sift.detectAndCompute(g, None) for g in grey)
    if d1 is None or d2 is None or len(k1) < 8 or len(k2) < 8:
        return none
    pairs = cv2.BFMatcher().knnMatch(d1, d2, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < 0.8 * p[1].distance]
    if len(good) < 8:
        return none
    p1 = np.float64([k1[g.queryIdx].pt for g in good])
    p2 = np.float64([k2[g.trainIdx].pt for g in good])
    on_line = symmetric_epipolar_distance(true_fundamental(record), p1, p2) < EPIPOLAR_PX
    if on_line.sum() < 8:
        return none
    K1, K2, R = np.array(record["left"]["K"]), np.array(record["right"]["K"]), np.array(record["R"])
    at_infinity = np.c_[p1, np.ones(len(p1))] @ (K2 @ R @ np.linalg.inv(K1)).T
    at_infinity = at_infinity[:, :2] / at_infinity[:, 2:]
    return p1[on_line], np.linalg.norm(p2 - at_infinity, axis=1)[on_line]


def epipolar_distance(terms: dict, record: dict, rc_left, rc_right) -> np.ndarray:
    """Distance (network-input px) of each left cell's soft match to its true epipolar lines."""

    def pixels(xy, rc):  # cell coordinates → pixels of the uncut image
        width, height = rc.out_size
        return rc.points_to_input(xy * (min(width, height) / 2) + np.array([width / 2, height / 2]))

    left, right = pixels(terms["left_xy"], rc_left), pixels(terms["right_xy"], rc_right)
    return symmetric_epipolar_distance(true_fundamental(record), left, right) * rc_right.scale


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("dataset")
    parser.add_argument("--count", type=int, default=0, help="first N pairs (0: all)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--json", help="write the per-pair rows here")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    model, checkpoint = load_checkpoint(args.checkpoint)
    short_side = int(checkpoint.get("input_short_side", 224))
    gain = float(model.pose_head.vote_parallax_gain.detach())
    sift = cv2.SIFT_create(2000)
    rows = []
    records = read_dataset(args.dataset)
    for record in records[: args.count or None]:
        T = np.array(record["T"] or [0, 0, 0], dtype=float)
        if record["R"] is None or np.linalg.norm(T) == 0:
            continue  # no baseline to read (panorama crops: one centre)
        images = [load_image(Path(args.dataset) / side / f"{record['id']}.png") for side in ("left", "right")]
        rcs = [resize_crop_for_network(im.shape[1], im.shape[0], short_side, 32) for im in images]
        if rcs[0].out_size != rcs[1].out_size:
            continue  # the cell coordinates of the two views differ
        tensors = [
            torch.from_numpy(apply_resize_crop(im, rc).transpose(2, 0, 1)[None].astype(np.float32) / 255.0)
            for im, rc in zip(images, rcs, strict=True)
        ]
        with torch.no_grad():
            terms = {k: v[0].numpy().astype(float) for k, v in model.pose_scale_terms(*tensors).items()}
        weight, vote = terms["weight"][:, 0], terms["vote"][:, 0]
        log_length = float(np.sum(weight * (vote + terms["log_parallax"][:, 0])))
        # the true rotation's displacement of a point at infinity, per cell (the cuts have one size)
        inf_true = match_targets(record, *rcs)["infinity_xy"] - terms["left_xy"]
        displacement = terms["right_xy"] - terms["left_xy"]
        log_par_true_inf = np.log(np.linalg.norm(displacement - inf_true, axis=1) + 1e-3)
        logits = terms["vote_logit"][:, 0] + gain * log_par_true_inf
        w_true = np.exp(logits - logits.max())
        w_true /= w_true.sum()
        sift_left, sift_par_px = sift_parallax(*images, record, sift)
        true_parallax_px = float(np.median(sift_par_px)) if len(sift_par_px) else float("nan")
        votes_with_sift = float("nan")  # the head's depth term with exact parallax: median over the matches
        if len(sift_par_px):
            cell_xy = rcs[0].points_to_output(sift_left) // MATCH_STRIDE
            grid_w, grid_h = rcs[0].out_size[0] // MATCH_STRIDE, rcs[0].out_size[1] // MATCH_STRIDE
            index = np.clip(cell_xy[:, 1], 0, grid_h - 1) * grid_w + np.clip(cell_xy[:, 0], 0, grid_w - 1)
            parallax = sift_par_px * rcs[0].scale / (min(rcs[0].out_size) / 2)
            votes_with_sift = float(np.median(vote[index.astype(int)] + np.log(parallax + 1e-3)))
        baseline = float(np.linalg.norm(T))
        rows.append(
            {
                "id": record["id"],
                "baseline_m": baseline,
                "length_error": float(np.exp(log_length) / baseline - 1),
                "length_error_true_infinity": float(
                    np.exp(np.sum(w_true * (vote + log_par_true_inf))) / baseline - 1
                ),
                "head_parallax": float(np.exp(np.sum(weight * terms["log_parallax"][:, 0]))),
                "true_parallax": true_parallax_px * rcs[0].scale / (min(rcs[0].out_size) / 2),
                "sift_matches": len(sift_par_px),
                "length_error_votes_sift": float(np.exp(votes_with_sift) / baseline - 1),
                "epipolar_px": float(np.median(epipolar_distance(terms, record, *rcs))),
                "infinity_error": float(np.linalg.norm(terms["infinity"] - np.median(inf_true, 0))),
                "true_infinity": float(np.linalg.norm(np.median(inf_true, 0))),
            }
        )
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    report(rows, args.dataset)


def report(rows: list[dict], dataset: str) -> None:
    def med(key, subset=None):
        vals = np.array([r[key] for r in (subset if subset is not None else rows)], dtype=float)
        vals = vals[np.isfinite(vals)]
        return float(np.median(vals)) if len(vals) else float("nan")

    abs_rows = [
        {**r, "a": abs(r["length_error"]), "b": abs(r["length_error_true_infinity"]),
         "c": abs(r["length_error_votes_sift"])}
        for r in rows
    ]  # fmt: skip
    print(f"# {dataset}: {len(rows)} pairs with a baseline\n")
    print("| median | value |\n|---|---|")
    print(f"| baseline error \\|T̂\\|/\\|T\\| − 1 (absolute) | {med('a', abs_rows):.1%} |")
    print(f"| ... with the true rotation's point at infinity | {med('b', abs_rows):.1%} |")
    print(f"| ... from the head's votes and the SIFT parallax (true rotation) | {med('c', abs_rows):.1%} |")
    print(f"| signed log ratio | {np.median([np.log1p(r['length_error']) for r in rows]):+.3f} |")
    print(f"| head's matches: distance to the true epipolar line (network px) | {med('epipolar_px'):.2f} |")
    print(f"| learned point-at-infinity error (half-short units) | {med('infinity_error'):.3f} |")
    print(f"| true point-at-infinity displacement | {med('true_infinity'):.3f} |")
    print(f"| true parallax (SIFT, half-short units) | {med('true_parallax'):.3f} |")
    print(f"| head's vote-weighted parallax | {med('head_parallax'):.3f} |")
    print("\n| true baseline | pairs | log(\\|T̂\\|/\\|T\\|), median | error, median (absolute) |")
    print("|---|---|---|---|")
    for lo, hi in ((0.0, 0.1), (0.1, 0.2), (0.2, 0.4), (0.4, np.inf)):
        sub = [r for r in rows if lo <= r["baseline_m"] < hi]
        if sub:
            log_ratio = float(np.median([np.log1p(r["length_error"]) for r in sub]))
            error = float(np.median([abs(r["length_error"]) for r in sub]))
            print(f"| {lo}–{hi} m | {len(sub)} | {log_ratio:+.2f} | {error:.1%} |")
    ok = [r for r in rows if np.isfinite(r["true_parallax"]) and r["true_parallax"] > 0]
    if len(ok) > 2:
        x = np.log([r["true_parallax"] for r in ok])
        y = np.log([r["head_parallax"] for r in ok])
        b = np.log([r["baseline_m"] for r in ok])
        print(
            f"\nSlope of log head parallax on log true parallax: {np.polyfit(x, y, 1)[0]:.2f} "
            f"(correlation {np.corrcoef(x, y)[0, 1]:.2f}; {len(ok)} pairs with ≥ 8 SIFT matches)."
        )
        print(
            f"Slope of log true parallax on log baseline: {np.polyfit(b, x, 1)[0]:.2f} "
            f"(correlation {np.corrcoef(b, x)[0, 1]:.2f}: the depth's share)."
        )
        print("\n| true parallax | pairs | head's parallax (median) | baseline error (median, absolute) |")
        print("|---|---|---|---|")
        for lo, hi in ((0, 0.02), (0.02, 0.05), (0.05, 0.1), (0.1, 0.2), (0.2, np.inf)):
            sub = [r for r in ok if lo <= r["true_parallax"] < hi]
            if sub:
                print(
                    f"| {lo}–{hi} | {len(sub)} | {med('head_parallax', sub):.3f} | "
                    f"{float(np.median([abs(r['length_error']) for r in sub])):.1%} |"
                )


if __name__ == "__main__":
    main()
