"""Behaviour kept: the reports of two checkouts of stereogeo on the same pairs, estimate by estimate.

    python benchmarks/regression.py OLD_CHECKOUT DATASET [DATASET ...] [--limit N] [--model FILE]

Each checkout (OLD_CHECKOUT, and this one) calibrates every pair of each dataset (the ``make-data``
layout: ``left/``, ``right/``, ``calib.jsonl``) in its own process, with its own code and the same model
(default: this checkout's shipped one). Then, per pair, the two reports are compared: each camera's focal
length (relative difference), roll, pitch and vFoV (degrees), the rotation between the two R (degrees) and
the angle between the two T (degrees). Prints how many pairs agree within 0.1 % and 0.01°, the largest
difference of each kind, and the pairs that do not agree. Then, per dataset, the median error of each
checkout against the dataset's ground truth (vFoV, roll and pitch over both cameras, R): whether the pairs
that moved moved towards the truth.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

# Runs in the checkout's own process: its code, one Calibrator, a report per pair.
_RUNNER = """
import json, sys
from pathlib import Path
from stereogeo_cli.io import load_image
from stereogeo_cli.pipeline import Calibrator
model, out, limit, datasets = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4:]
calibrator, reports = Calibrator(model, threads=1), {}
for folder in map(Path, datasets):
    for k, line in enumerate(open(folder / "calib.jsonl")):
        if limit and k >= limit:
            break
        name = json.loads(line)["id"]
        images = [load_image(folder / side / f"{name}.png") for side in ("left", "right")]
        try:
            reports[f"{folder.name}/{name}"] = calibrator.calibrate(*images).report()
        except Exception as error:
            reports[f"{folder.name}/{name}"] = {"error": str(error)}
json.dump(reports, open(out, "w"))
"""


def run(checkout: Path, model: Path, datasets: list[str], limit: int, out: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": str(checkout), "OPENBLAS_NUM_THREADS": "1"}
    command = [sys.executable, "-c", _RUNNER, str(model), str(out), str(limit), *datasets]
    subprocess.run(command, env=env, check=True, cwd=checkout)
    return json.loads(out.read_text())


def differences(a: dict, b: dict) -> dict[str, float]:
    """The largest differences between two reports of one pair."""
    out = {}
    for side in ("left", "right"):
        out[f"{side} focal (rel.)"] = abs(b[side]["focal_px"] / a[side]["focal_px"] - 1)
        for key in ("roll_deg", "pitch_deg", "vfov_deg"):
            out[f"{side} {key[:-4]} (°)"] = abs(b[side][key] - a[side][key])
    Ra, Rb = np.array(a["R"]), np.array(b["R"])
    out["R (°)"] = math.degrees(math.acos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1)))
    Ta, Tb = np.array(a["T"]), np.array(b["T"])
    cos = float(Ta @ Tb / (np.linalg.norm(Ta) * np.linalg.norm(Tb)))
    out["T direction (°)"] = math.degrees(math.acos(np.clip(cos, -1, 1)))
    return out


def errors(report: dict, truth: dict) -> dict[str, list[float]]:
    """A report's errors against a calib.jsonl line: vFoV, roll, pitch (both cameras; gravity where known)
    and R, in degrees."""
    out: dict[str, list[float]] = {"vFoV": [], "roll": [], "pitch": [], "R": []}
    for side in ("left", "right"):
        K, height = np.array(truth[side]["K"]), truth[side]["height"]
        vfov = math.degrees(2 * math.atan(height / (2 * K[1, 1])))
        out["vFoV"].append(abs(report[side]["vfov_deg"] - vfov))
        up = truth[side].get("gravity_up")
        if up is not None:
            roll, pitch = math.degrees(math.atan2(-up[0], -up[1])), math.degrees(math.asin(up[2]))
            out["roll"].append(abs((report[side]["roll_deg"] - roll + 180) % 360 - 180))
            out["pitch"].append(abs(report[side]["pitch_deg"] - pitch))
    if truth.get("R") is not None:
        Ra, Rb = np.array(report["R"]), np.array(truth["R"])
        out["R"].append(math.degrees(math.acos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1))))
    return out


def accuracy(old: dict, new: dict, datasets: list[str]) -> None:
    """Per dataset, the two checkouts' median errors against the ground truth."""
    for folder in map(Path, datasets):
        truth = {
            f"{folder.name}/{json.loads(line)['id']}": json.loads(line)
            for line in open(folder / "calib.jsonl")
        }
        rows = {}
        for label, reports in (("old", old), ("new", new)):
            pooled: dict[str, list[float]] = {}
            for name, report in reports.items():
                if name in truth and "error" not in report:
                    for key, values in errors(report, truth[name]).items():
                        pooled.setdefault(key, []).extend(values)
            rows[label] = {k: float(np.median(v)) for k, v in pooled.items() if v}
        cells = [f"{k} {rows['old'][k]:.2f} → {rows['new'].get(k, math.nan):.2f}" for k in rows["old"]]
        print(f"  {folder.name} (median error, °, old → new): " + ", ".join(cells))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("old", type=Path, help="the other checkout (a git worktree of an earlier commit)")
    parser.add_argument("datasets", nargs="+")
    parser.add_argument("--limit", type=int, default=0, help="the first N pairs of each dataset (0: all)")
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "stereogeo.onnx")
    parser.add_argument("--keep", type=Path, help="a folder to keep the two checkouts' reports in")
    parser.add_argument(
        "--reuse-old", action="store_true", help="take the other checkout's reports from --keep if there"
    )
    args = parser.parse_args()
    datasets = [str(Path(d).resolve()) for d in args.datasets]
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        kept = folder / "old.json"
        if args.reuse_old and kept.exists():
            old = json.loads(kept.read_text())
        else:
            old = run(args.old.resolve(), args.model.resolve(), datasets, args.limit, kept)
        new = run(ROOT, args.model.resolve(), datasets, args.limit, folder / "new.json")
    largest: dict[str, float] = {}
    disagree = []
    for name in old:
        a, b = old[name], new.get(name, {"error": "missing"})
        if "error" in a or "error" in b:
            if a.get("error") != b.get("error"):
                disagree.append((name, {"error": (a.get("error"), b.get("error"))}))
            continue
        diff = differences(a, b)
        for key, value in diff.items():
            largest[key] = max(largest.get(key, 0.0), value)
        off = {k: v for k, v in diff.items() if v > (1e-3 if "rel." in k else 0.01)}
        if off:
            disagree.append((name, off))
    print(f"{len(old) - len(disagree)} of {len(old)} pairs agree within 0.1 % (focal) and 0.01° (angles)")
    for key, value in largest.items():
        print(f"  largest {key}: {value:.3g}")
    for name, off in disagree:
        print(f"  {name}: " + ", ".join(f"{k} {v}" for k, v in off.items()))
    accuracy(old, new, datasets)


if __name__ == "__main__":
    main()
