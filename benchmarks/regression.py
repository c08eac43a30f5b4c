"""Behaviour kept: the reports of two checkouts of stereogeo on the same pairs, estimate by estimate.

    python benchmarks/regression.py OLD_CHECKOUT DATASET [DATASET ...] [--limit N] [--model FILE]

Each checkout (OLD_CHECKOUT, and this one) calibrates every pair of each dataset (the ``make-data``
layout: ``left/``, ``right/``, ``calib.jsonl``) in its own process, with its own code and the same model
(default: this checkout's shipped one). Then, per pair, the two reports are compared: each camera's focal
length (relative difference), roll, pitch and vFoV (degrees), the rotation between the two R (degrees) and
the angle between the two T (degrees). Prints how many pairs agree within 0.1 % and 0.01°, the largest
difference of each kind, and the pairs that do not agree.
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


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("old", type=Path, help="the other checkout (a git worktree of an earlier commit)")
    parser.add_argument("datasets", nargs="+")
    parser.add_argument("--limit", type=int, default=0, help="the first N pairs of each dataset (0: all)")
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "stereogeo.onnx")
    args = parser.parse_args()
    datasets = [str(Path(d).resolve()) for d in args.datasets]
    with tempfile.TemporaryDirectory() as tmp:
        old = run(args.old.resolve(), args.model.resolve(), datasets, args.limit, Path(tmp) / "old.json")
        new = run(ROOT, args.model.resolve(), datasets, args.limit, Path(tmp) / "new.json")
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


if __name__ == "__main__":
    main()
