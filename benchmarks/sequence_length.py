"""Time, memory and accuracy of ``calibrate-sequence`` against the length of the recording.

For each sequence given (a folder with a ``calib.json`` beside ``left/`` and ``right/``: a render of
``stereogeo make-data --sequence``, or a real one of shared/data/real-dev/sequences), ``calibrate-sequence``
runs with its default options (keyframes chosen by optical flow, at most 150) in a subprocess with
``--json``; with ``--video`` it reads the folder's ``left.mp4`` and ``right.mp4`` (``make-data --h264 KBPS
--keep-video``) in place of its frames. Per sequence: the wall time, the child's peak memory (its
``ru_maxrss``, from ``os.wait4``: the largest resident set of the calibrating process), the frames read /
kept / registered (from the report), each camera's focal error (%) against the true fx, the left camera's
reported focal sigma (% of the true fx) and z-score (|error| / sigma), the error of R (degrees) and R's
reported sigma (degrees), and the time of each stage (the stage lines ``calibrate-sequence`` prints on
stderr). Below the table: the shares of the focal z-scores within 1σ and 3σ. The ground truth is read with
``read_sequence_ground_truth`` and scored with ``sequence_accuracy._errors`` (the helpers of
sequence_accuracy.py and sequence_effects.py).

    nice -n 10 python benchmarks/sequence_length.py SEQUENCE [SEQUENCE ...] [--video] [--json]
        [--logs DIR] [-- EXTRA calibrate-sequence OPTIONS]

Long renders to run it on (640 × 360 at 30 fps as a camera's H.264 video, the same turn at every length):

    for n in 50 300 1500 3000; do
        nice -n 10 stereogeo make-data long/turning-$n --sequence turning -n $n --seed 0 --size 360 \\
            --aspects 16:9 --rate 30 --h264 1500 --keep-video
    done
    nice -n 10 python benchmarks/sequence_length.py long/turning-* --video --logs long/logs

Run one calibration at a time at low priority on a shared machine; the wall times depend on what else
the machine runs (say so where you quote them). ``--logs DIR`` keeps each run's stderr (DIR/<name>.log),
``--workspaces DIR`` each run's COLMAP workspace (``calibrate-sequence --workspace``: the keyframes' images
and COLMAP's database, to run COLMAP on again). Options after ``--`` go to every calibrate-sequence run.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from sequence_accuracy import _errors  # noqa: E402
from sequence_effects import _cell, _share  # noqa: E402

from stereogeo_cli.synth.sequence import read_sequence_ground_truth  # noqa: E402

# "what it did[, n of N][ (note)]: 12.3 s[; about 2 min left in all]"
_STAGE_LINE = re.compile(r"^(?P<stage>.+?)(?:, \d+ of \d+)?(?: \(.*\))?: (?P<seconds>[\d.]+) s(?:;.*)?$")


def truth_of(folder: Path) -> dict:
    """The ground truth in the form ``sequence_accuracy._errors`` scores against (K, R, T as lists)."""
    gt = read_sequence_ground_truth(folder)
    return {
        "left": {"K": np.asarray(gt["K_left"]).tolist()},
        "right": {"K": np.asarray(gt["K_right"]).tolist()},
        "R": np.asarray(gt["R"]).tolist(),
        "T": np.asarray(gt["T"]).tolist(),
        "frames": len(gt["left_images"]),
    }


def stages(stderr: str) -> dict[str, float]:
    """Seconds per stage from calibrate-sequence's stage lines ("what it did[, n of N][ (note)]: 12.3 s");
    a stage that ran more than once is summed."""
    out: dict[str, float] = {}
    for line in stderr.splitlines():
        match = _STAGE_LINE.match(line.strip())
        if match:
            out[match["stage"]] = out.get(match["stage"], 0.0) + float(match["seconds"])
    return out


def calibrate(folder: Path, video: bool, extra: list[str], log: Path | None, workspace: Path | None) -> dict:
    """One ``calibrate-sequence --json`` run in a child process: its report, wall time, peak memory."""
    source = ["--video", str(folder / "left.mp4"), str(folder / "right.mp4")] if video else [str(folder)]
    command = [sys.executable, "-m", "stereogeo_cli", "calibrate-sequence", *source, "--json", *extra]
    if workspace is not None:
        command += ["--workspace", str(workspace)]
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        start = time.perf_counter()
        child = subprocess.Popen(command, stdout=out, stderr=err, text=True)
        _, status, usage = os.wait4(child.pid, 0)  # this child's own rusage (RUSAGE_CHILDREN sums them all)
        seconds = time.perf_counter() - start
        child.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read(), err.read()
    if log is not None:
        log.parent.mkdir(parents=True, exist_ok=True)
        log.write_text(stderr)
    peak_mib = usage.ru_maxrss / 1024  # kilobytes on Linux
    if child.returncode != 0:
        last = stderr.strip().splitlines()[-1] if stderr.strip() else f"exit code {child.returncode}"
        return {"error": last, "seconds": seconds, "peak_mib": peak_mib}
    return {"report": json.loads(stdout), "seconds": seconds, "peak_mib": peak_mib, "stages": stages(stderr)}


def score(folder: Path, video: bool, extra: list[str], log: Path | None, workspace: Path | None) -> dict:
    truth = truth_of(folder)
    run = calibrate(folder, video, extra, log, workspace)
    row = {"sequence": folder.name, "source": "video" if video else "frames", "frames_total": truth["frames"],
           "seconds": run["seconds"], "peak_mib": run["peak_mib"]}  # fmt: skip
    if "error" in run:
        return row | {"error": str(run["error"])}
    report = run["report"]
    errors, seq = _errors(report, truth), report["sequence"]
    f_true = float(truth["left"]["K"][0][0])
    sigma = (report["left"]["sigma"] or {}).get("focal_px")
    return row | {
        "frames_read": seq["frames_read"],
        "frames_kept": seq["frames_kept"],
        "frames_registered": seq["frames_registered"],
        "models": seq.get("models"),
        "focal_left_pct": 100 * errors["left_focal_rel"],
        "focal_right_pct": 100 * errors["right_focal_rel"],
        "sigma_left_pct": 100 * sigma / f_true if sigma else None,
        "z_left": errors["left_focal_z"],
        "z_right": errors["right_focal_z"],
        "R_deg": errors["R_deg"],
        "R_sigma_deg": (report.get("pose") or {}).get("sigma_rotation_deg"),
        "focal_observable": seq.get("focal_observable"),
        "stages_s": run["stages"],
    }


def print_table(rows: list[dict]) -> None:
    header = (f"{'sequence':34} {'src':5} {'time s':>7} {'peak MiB':>8} {'read/kept/reg':>14} "
              f"{'focal L %':>9} {'focal R %':>9} {'sigma %':>7} {'z':>5} {'R err °':>8} "
              f"{'R σ °':>7}")  # fmt: skip
    print(header)
    print("-" * len(header))
    for row in rows:
        name, source = row["sequence"][:34], row["source"][:5]
        start = f"{name:34} {source:5} {row['seconds']:>7.0f} {row['peak_mib']:>8.0f}"
        if "error" in row:
            print(f"{start} failed: {row['error']}")
            continue
        frames = f"{row['frames_read']}/{row['frames_kept']}/{row['frames_registered']}"
        print(f"{start} {frames:>14} {row['focal_left_pct']:>+9.3f} {row['focal_right_pct']:>+9.3f} "
              f"{_cell(row['sigma_left_pct'], 3):>7} {_cell(row['z_left'], 1):>5} {row['R_deg']:>8.4f} "
              f"{_cell(row['R_sigma_deg'], 4):>7}")  # fmt: skip
    z = [abs(v) for r in rows if "error" not in r for v in (r["z_left"], r["z_right"]) if v is not None]
    if z:
        print(f"\nfocal z-scores (both cameras) within 1σ / 3σ: {_share(z, 1.0)} / {_share(z, 3.0)}")
    print("\nseconds per stage")
    for row in rows:
        if "error" not in row:
            spent = sorted(row["stages_s"].items(), key=lambda kv: -kv[1])
            print(f"{row['sequence']}: " + "; ".join(f"{name} {s:.1f}" for name, s in spent))


def main() -> None:
    argv = sys.argv[1:]
    extra = argv[argv.index("--") + 1 :] if "--" in argv else []
    argv = argv[: argv.index("--")] if "--" in argv else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequences", nargs="+", type=Path)
    parser.add_argument("--video", action="store_true", help="Read each folder's left.mp4 and right.mp4.")
    parser.add_argument("--logs", type=Path, default=None, help="Keep each run's stderr here.")
    parser.add_argument("--workspaces", type=Path, default=None,
                        help="Keep each run's COLMAP workspace (images, database) in DIR/NAME.")  # fmt: skip
    parser.add_argument("--json", action="store_true", help="Print the rows as JSON instead of the table.")
    args = parser.parse_args(argv)
    rows = []
    for folder in args.sequences:
        name = f"{folder.name}{'-video' if args.video else ''}"
        log = args.logs / f"{name}.log" if args.logs else None
        workspace = args.workspaces / name if args.workspaces else None
        rows.append(score(folder, args.video, extra, log, workspace))
        if not args.json:
            print(json.dumps({k: v for k, v in rows[-1].items() if k != "stages_s"}, default=float),
                  file=sys.stderr, flush=True)  # fmt: skip
    if args.json:
        print(json.dumps(rows, indent=1, default=float))
    else:
        print_table(rows)


if __name__ == "__main__":
    main()
