"""Two models through `calibrate`, pair by pair: which errors got better, which worse, and by how much.

    python benchmarks/compare_models.py MODEL_A MODEL_B DATASET [DATASET ...] [--threads N]

Small real sets (1–29 pairs of one scene type each) move their medians with single pairs; pooling every
pair's errors is steadier. For each error (per camera: vFoV, roll and pitch where gravity is known; per
pair: R and the translation direction) it prints how many of the pooled errors B has better and worse
than A, and the geometric mean of the ratios B / A (errors below a floor are raised to it, so that two
tiny errors do not count as a large ratio), then each dataset's medians A → B.

``--conf-a`` / ``--conf-b`` (JSON, ``Calibrator`` settings) compare two pipelines: the same model twice,
one setting changed, e.g. ``--conf-a '{"manhattan": {"enabled": false}}'`` for the vanishing points.

With ``--bootstrap N`` it also prints each error's median over all the datasets' pairs pooled, for A and B,
with 95 % intervals from N resamplings of the pairs (both cameras of a pair stay together), and the paired
difference B − A with its interval: how far a rendered set's median can be trusted (a 300-pair set's vFoV
median spans about ±0.7°).
"""

import argparse
import json
from pathlib import Path

import numpy as np

from stereogeo_cli.evaluate import evaluate_dataset
from stereogeo_cli.pipeline import Calibrator

# error → (row keys, floor): the floors are well below what either model reaches on any set
ERRORS = {
    "vFoV (°)": (("left_vfov_error_deg", "right_vfov_error_deg"), 0.1),
    "roll (°)": (("left_roll_error_deg", "right_roll_error_deg"), 0.1),
    "pitch (°)": (("left_pitch_error_deg", "right_pitch_error_deg"), 0.1),
    "R (°)": (("rotation_error_deg",), 0.01),
    "t direction (°)": (("direction_error_deg",), 0.05),
}


def paired(rows_a: dict, rows_b: dict, keys: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The errors of both models on the pairs (and cameras) both calibrated, in one order."""
    a, b = [], []
    for name, row in rows_a.items():
        other = rows_b.get(name)
        for key in keys:
            if other is not None and row.get(key) is not None and other.get(key) is not None:
                a.append(row[key])
                b.append(other[key])
    return np.asarray(a, dtype=float), np.asarray(b, dtype=float)


def compare(results_a: dict, results_b: dict) -> list[str]:
    """Markdown lines comparing two runs: ``{dataset: {pair id: row}}`` each."""
    lines = [
        "| error | n | B better | B worse | geometric mean B / A | medians A → B |",
        "|---|---|---|---|---|---|",
    ]
    for label, (keys, floor) in ERRORS.items():
        pooled_a, pooled_b, medians = [], [], []
        for dataset, rows_a in results_a.items():
            a, b = paired(rows_a, results_b.get(dataset, {}), keys)
            if len(a):
                pooled_a.append(a)
                pooled_b.append(b)
                medians.append(f"{dataset} {np.median(a):.2f} → {np.median(b):.2f}")
        if not pooled_a:
            continue
        a, b = np.concatenate(pooled_a), np.concatenate(pooled_b)
        ratio = float(np.exp(np.mean(np.log(np.maximum(b, floor) / np.maximum(a, floor)))))
        lines.append(
            f"| {label} | {len(a)} | {int(np.sum(b < a))} | {int(np.sum(b > a))} | {ratio:.3f} | "
            f"{'; '.join(medians)} |"
        )
    return lines


def bootstrap(results_a: dict, results_b: dict, resamples: int, seed: int = 0) -> list[str]:
    """Markdown lines: pooled medians of A and B with 95 % intervals, and B − A paired, resampling pairs."""
    pairs = [
        (row_a, results_b[dataset][name])
        for dataset, rows_a in results_a.items()
        for name, row_a in rows_a.items()
        if name in results_b.get(dataset, {})
    ]
    rng = np.random.default_rng(seed)
    draws = [rng.integers(0, len(pairs), len(pairs)) for _ in range(resamples)]
    lines = [
        f"Pooled over {len(pairs)} pairs, 95 % intervals from {resamples} resamplings of the pairs:",
        "",
        "| error | n | A median | B median | B − A |",
        "|---|---|---|---|---|",
    ]
    for label, (keys, _) in ERRORS.items():
        # per pair, its cameras' errors (or its one pair error) where both models have them
        per_pair = [
            [(a[k], b[k]) for k in keys if a.get(k) is not None and b.get(k) is not None] for a, b in pairs
        ]
        if not any(per_pair):
            continue

        def medians(indices, per_pair=per_pair):
            values = np.array([v for i in indices for v in per_pair[i]], dtype=float).reshape(-1, 2)
            return np.median(values[:, 0]), np.median(values[:, 1])

        a, b = medians(range(len(pairs)))
        samples = np.array([medians(d) for d in draws])
        low_a, high_a = np.percentile(samples[:, 0], [2.5, 97.5])
        low_b, high_b = np.percentile(samples[:, 1], [2.5, 97.5])
        low_d, high_d = np.percentile(samples[:, 1] - samples[:, 0], [2.5, 97.5])
        n = sum(len(p) for p in per_pair)
        lines.append(
            f"| {label} | {n} | {a:.3f} ({low_a:.2f}–{high_a:.2f}) | {b:.3f} ({low_b:.2f}–{high_b:.2f}) | "
            f"{b - a:+.3f} ({low_d:+.2f} to {high_d:+.2f}) |"
        )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("model_a")
    parser.add_argument("model_b")
    parser.add_argument("datasets", nargs="+")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--conf-a", default="{}", help="Calibrator settings (JSON) for A")
    parser.add_argument("--conf-b", default="{}", help="Calibrator settings (JSON) for B")
    parser.add_argument(
        "--bootstrap",
        type=int,
        default=0,
        metavar="N",
        help="pooled medians with 95 %% intervals (N resamplings)",
    )
    args = parser.parse_args()
    try:
        confs = [json.loads(args.conf_a), json.loads(args.conf_b)]
    except json.JSONDecodeError as error:
        parser.error(f"--conf-a / --conf-b: not JSON ({error})")
    results = []
    for model, conf in zip((args.model_a, args.model_b), confs, strict=True):
        calibrator = Calibrator(model, threads=args.threads, conf=conf)
        results.append(
            {
                Path(d).name: {row["id"]: row for row in evaluate_dataset(d, calibrator)["pairs"]}
                for d in args.datasets
            }
        )
    print(f"A = {args.model_a} {args.conf_a}, B = {args.model_b} {args.conf_b}\n")
    print("\n".join(compare(*results)))
    if args.bootstrap:
        print()
        print("\n".join(bootstrap(*results, args.bootstrap)))


if __name__ == "__main__":
    main()
