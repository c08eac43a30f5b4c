"""Accuracy and speed of ``calibrate-sequence`` on sequences with ground truth (a ``calib.json`` beside
``left/`` and ``right/``: rendered ones from ``stereogeo make-data --sequence``, or real ones in that layout).

Per sequence: each camera's relative focal error and its z-score (error / reported sigma), whether the
report calls the focal length observable, the errors of R and of T's direction, the per-frame roll and pitch
errors where the ground truth has the frames' poses and the world's up, the rotation span and the time per
frame pair. ``--same-rig`` also runs ``batch-calibrate --same-rig`` on the same frames for comparison.

    python benchmarks/sequence_accuracy.py SEQUENCE [SEQUENCE ...] [--max-frames 50] [--same-rig] [--json]
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from stereogeo_cli.geometry import roll_pitch_from_gravity, rotation_angle


def _angle_deg(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return math.degrees(math.acos(float(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def _errors(report: dict, truth: dict) -> dict:
    out = {}
    for side in ("left", "right"):
        f_true = float(np.asarray(truth[side]["K"])[0, 0])
        cam = report[side]
        error = cam["focal_px"] / f_true - 1
        sigma = (cam["sigma"] or {}).get("focal_px")
        out[f"{side}_focal_rel"] = error
        out[f"{side}_focal_z"] = abs(error) * f_true / sigma if sigma else None
    R_true, T_true = np.asarray(truth["R"]), np.asarray(truth["T"])
    out["R_deg"] = math.degrees(rotation_angle(np.asarray(report["R"]) @ R_true.T))
    out["T_dir_deg"] = _angle_deg(report["T"], T_true)
    pose = report.get("pose") or {}
    out["R_z"] = out["R_deg"] / pose["sigma_rotation_deg"] if pose.get("sigma_rotation_deg") else None
    out["T_dir_z"] = (
        out["T_dir_deg"] / pose["sigma_direction_deg"] if pose.get("sigma_direction_deg") else None
    )
    return out


def _attitude_errors(report: dict, truth: dict) -> dict:
    """Median |roll| and |pitch| errors of the left camera over the registered frames (degrees)."""
    poses, up = truth.get("gt_poses"), truth.get("gravity_up_world")
    if not poses or up is None:
        return {}
    rolls, pitches = [], []
    for frame in report["sequence"]["frames"]:
        world_from_cam = np.asarray(poses[frame["index"]])
        g = world_from_cam[:3, :3].T @ np.asarray(up, float)
        roll, pitch = (math.degrees(float(v)) for v in roll_pitch_from_gravity(g))
        rolls.append(abs(frame["left"]["roll_deg"] - roll))
        pitches.append(abs(frame["left"]["pitch_deg"] - pitch))
    return {"roll_deg": float(np.median(rolls)), "pitch_deg": float(np.median(pitches))}


def run_sequence(folder: Path, max_frames: int | None, every: int) -> dict:
    command = [
        sys.executable,
        "-m",
        "stereogeo_cli",
        "calibrate-sequence",
        str(folder),
        "--json",
        "--no-progress",
    ]
    if max_frames:
        command += ["--max-frames", str(max_frames)]
    if every > 1:
        command += ["--every", str(every)]
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        return {"error": done.stderr.strip().splitlines()[-1] if done.stderr.strip() else done.returncode}
    report = json.loads(done.stdout)
    seq = report["sequence"]
    return {"report": report, "seconds": seconds, "frames": seq["frames_read"]}


def run_same_rig(folder: Path, truth: dict, max_frames: int | None, every: int) -> dict:
    """``batch-calibrate --same-rig`` on the same frames (linked into a folder of its own)."""
    names = sorted(p.name for p in (folder / "left").iterdir())[::every][: max_frames or None]
    with tempfile.TemporaryDirectory() as tmp:
        pairs = Path(tmp) / "pairs"
        for side in ("left", "right"):
            (pairs / side).mkdir(parents=True)
            for name in names:
                (pairs / side / name).symlink_to((folder / side / name).resolve())
        out = Path(tmp) / "out"
        done = subprocess.run(
            [sys.executable, "-m", "stereogeo_cli", "batch-calibrate", str(pairs), "-o", str(out),
             "--same-rig"], capture_output=True, text=True,
        )  # fmt: skip
        report_path = out / "rig" / "report.json"
        if not report_path.is_file():
            return {"error": done.stderr.strip().splitlines()[-1] if done.stderr.strip() else done.returncode}
        return _errors(json.loads(report_path.read_text()), truth)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequences", nargs="+", type=Path)
    parser.add_argument("--max-frames", type=int, default=None)
    parser.add_argument("--every", type=int, default=1)
    parser.add_argument("--same-rig", action="store_true", help="Also run batch-calibrate --same-rig.")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    rows = []
    for folder in args.sequences:
        truth = json.loads((folder / "calib.json").read_text())
        run = run_sequence(folder, args.max_frames, args.every)
        row = {"sequence": folder.name}
        if "error" in run:
            row["error"] = run["error"]
        else:
            report, seq = run["report"], run["report"]["sequence"]
            row |= _errors(report, truth) | _attitude_errors(report, truth)
            row |= {
                "focal_observable": seq["focal_observable"],
                "rotation_span_deg": seq["rotation_span_deg"],
                "registered": f"{seq['frames_registered']}/{seq['frames_read']}",
                "seconds": run["seconds"],
                "seconds_per_pair": run["seconds"] / run["frames"],
            }
        if args.same_rig:
            row["same_rig"] = run_same_rig(folder, truth, args.max_frames, args.every)
        rows.append(row)
        if not args.json:
            print(json.dumps(row, default=float))
    if args.json:
        print(json.dumps(rows, indent=1, default=float))


if __name__ == "__main__":
    main()
