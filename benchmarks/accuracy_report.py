"""The README's accuracy tables: `stereogeo evaluate --baselines` on each dataset, as Markdown.

    python benchmarks/accuracy_report.py DATASET [DATASET ...] [--model FILE] [--json-dir DIR]

Prints one table per dataset (our per-camera and pose errors, how many of them lie within the 1 and 3
sigma stereogeo reports (68 % and 99.7 % for honest sigmas), and the baselines' pose errors with the
ground-truth intrinsics), with the date and the model version.
"""

import argparse
import datetime
import json
from pathlib import Path

from stereogeo_cli.evaluate import evaluate_dataset
from stereogeo_cli.pipeline import Calibrator


def _cell(metrics: dict, key: str, field: str = "median", digits: int = 2) -> str:
    value = metrics.get(key, {}).get(field)
    return "–" if value is None else f"{value:.{digits}f}"


def table(results: dict) -> str:
    m = results["metrics"]
    lines = [
        f"**{results['dataset']}** — {m['pairs']['evaluated']} of {m['pairs']['total']} pairs",
        "",
        "| | roll (°) | pitch (°) | vFoV (°) | focal (rel.) | R (°) | t dir. (°) | baseline (rel.) |",
        "|---|---|---|---|---|---|---|---|",
        f"| stereogeo, median | {_cell(m, 'roll_deg')} | {_cell(m, 'pitch_deg')} | {_cell(m, 'vfov_deg')} | "
        f"{_cell(m, 'focal_rel', digits=3)} | {_cell(m, 'rotation_error_deg', digits=3)} | "
        f"{_cell(m, 'direction_error_deg')} | {_cell(m, 'baseline_error_rel')} |",
        f"| stereogeo, AUC@1/5/10° | {_auc(m, 'roll_deg')} | {_auc(m, 'pitch_deg')} | "
        f"{_auc(m, 'vfov_deg')} | | | | |",
        f"| stereogeo, errors within the reported 1σ / 3σ | {_within(m, 'roll')} | {_within(m, 'pitch')} | "
        f"{_within(m, 'vfov')} | | {_within(m, 'rotation')} | {_within(m, 'direction')} | "
        f"{_within(m, 'baseline')} |",
    ]
    for name, label in (("orb+essential", "ORB + E, **true K**"), ("sift+essential", "SIFT + E, **true K**")):
        lines.append(
            f"| {label}, median | | | | | {_cell(m, f'{name}_rotation_error_deg', digits=3)} | "
            f"{_cell(m, f'{name}_direction_error_deg')} | |"
        )
    for reason in results["skipped"]:
        lines.append(f"\n_skipped: {reason}_")
    return "\n".join(lines)


def _within(metrics: dict, name: str) -> str:
    """The shares of errors within their reported 1 and 3 sigma (68 % and 99.7 % for honest sigmas)."""
    m = metrics.get(f"{name}_sigma")
    return "–" if not m else f"{100 * m['within_1_sigma']:.0f} / {100 * m['within_3_sigma']:.0f} %"


def _auc(metrics: dict, key: str) -> str:
    m = metrics.get(key)
    if not m:
        return "–"
    return "/".join(f"{100 * m[f'auc@{t}']:.0f}" for t in (1, 5, 10))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("datasets", nargs="+", type=Path)
    parser.add_argument("--model", type=Path, default=None)
    parser.add_argument("--json-dir", type=Path, default=None, help="also keep each dataset's full results")
    args = parser.parse_args()
    calibrator = Calibrator(args.model)
    version = calibrator.network.metadata.get("model_version", "?")
    sha = calibrator.network.model_sha256[:12]
    print(f"Measured {datetime.date.today()} with model `{version}` (sha256 {sha}).")
    for dataset in args.datasets:
        results = evaluate_dataset(dataset, calibrator, baselines=True)
        if args.json_dir:
            args.json_dir.mkdir(parents=True, exist_ok=True)
            (args.json_dir / f"{dataset.name}.json").write_text(json.dumps(results, indent=1, default=float))
        print()
        print(table(results))


if __name__ == "__main__":
    main()
