"""Speed of the product: warm ``calibrate`` on a 640x480 pair, cold start to first output, batch throughput.

    python benchmarks/bench_calibrate.py --model models/stereogeo.onnx --runs 10 --cold-runs 3 --pairs 20

- Warm: one Calibrator (one ONNX Runtime session), the pair already loaded; each run is the whole
  ``calibrate`` (network, refiner, matching, fusion) plus writing the default files (opencv, json). Medians
  over ``--runs`` after two warm-up runs, with the pipeline's own ``timing_ms`` breakdown.
- Cold: ``stereogeo calibrate LEFT RIGHT --json -o DIR`` in a fresh process, wall clock until it exits
  (interpreter start, imports, session creation, one calibration, files written); median of ``--cold-runs``.
- Batch: ``stereogeo batch-calibrate`` over the first ``--pairs`` rendered 640x480 pairs (one or more
  counts, e.g. ``20,60``), wall clock of the whole command (start-up included) for each ``--workers``
  value; pairs/s = pairs / wall time. With two or more counts, a straight line through (pairs, wall time)
  splits the time into a fixed start-up (interpreter, workers, network sessions) and a marginal rate.
- ``--runs 0`` or ``--cold-runs 0`` skips that part.
- ``--against OLD_CHECKOUT`` (e.g. a ``git worktree`` of an earlier commit): each measurement is made for
  both checkouts, alternately, ``--rounds`` times (warm: each checkout in a fresh process of its own code),
  and the ratios new / old are printed (time ratios for warm and cold, throughput ratios for the batch): a
  speed claim is a ratio measured side by side on one machine, never an absolute time.

The pairs are rendered with ``stereogeo make-data --size 480 --aspects 4:3 --portrait-share 0`` into a
temporary folder (or ``--data``, reused if it holds enough pairs). The load average is printed with the
numbers: on a shared machine they are only as good as the cores are free.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def stereogeo_command() -> list[str]:
    """``stereogeo`` of the checkout ``run`` puts first (whatever an installed ``stereogeo`` points at)."""
    return [sys.executable, "-m", "stereogeo_cli"]


def run(cmd: list[str], root: Path = ROOT, **kwargs) -> subprocess.CompletedProcess:
    """``cmd`` with the code of the checkout ``root``, run in it (``python -m`` looks in the working folder
    first, before PYTHONPATH)."""
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(filter(None, [str(root), os.environ.get("PYTHONPATH")])),
    }
    return subprocess.run(cmd, env=env, cwd=root, **kwargs)


def load() -> str:
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.2f}, {five:.2f}, {fifteen:.2f} (1, 5, 15 min) on {os.cpu_count()} cores"


def render(folder: Path, pairs: int) -> None:
    if (folder / "calib.jsonl").is_file() and len((folder / "calib.jsonl").read_text().splitlines()) >= pairs:
        return
    cmd = [*stereogeo_command(), "make-data", str(folder), "--count", str(pairs), "--size", "480",
           "--aspects", "4:3", "--portrait-share", "0", "--seed", "11", "--no-progress"]  # fmt: skip
    run(cmd, check=True)


def warm(model: Path, left: Path, right: Path, runs: int, threads: int) -> dict:
    from stereogeo_cli.io import load_image, write_calibration
    from stereogeo_cli.pipeline import Calibrator

    calibrator = Calibrator(model, threads=threads)
    images = load_image(left), load_image(right)
    totals, writes, parts = [], [], {}
    with tempfile.TemporaryDirectory() as out:
        for i in range(runs + 2):
            start = time.perf_counter()
            result = calibrator.calibrate(*images)
            tick = time.perf_counter()
            write_calibration(out, result.calibration, ("opencv", "json"))
            end = time.perf_counter()
            if i < 2:
                continue
            totals.append((end - start) * 1e3)
            writes.append((end - tick) * 1e3)
            for key, value in result.calibration.timing_ms.items():
                parts.setdefault(key, []).append(value)
    breakdown = {k: round(statistics.median(v), 1) for k, v in parts.items()}
    return {"median_ms": round(statistics.median(totals), 1), "min_ms": round(min(totals), 1),
            "writing_ms": round(statistics.median(writes), 1), "timing_ms": breakdown}  # fmt: skip


def warm_in(root: Path, model: Path, left: Path, right: Path, runs: int, threads: int) -> dict:
    """:func:`warm` in a fresh process with the code of the checkout ``root``."""
    cmd = [sys.executable, __file__, "--warm-only", str(left), str(right), "--model", str(model), "--runs",
           str(runs), "--threads", str(threads)]  # fmt: skip
    return json.loads(run(cmd, root, capture_output=True, text=True, check=True).stdout)


def cold(model: Path, left: Path, right: Path, runs: int, root: Path = ROOT) -> dict:
    times = []
    with tempfile.TemporaryDirectory() as out:
        for i in range(runs):
            cmd = [*stereogeo_command(), "calibrate", str(left), str(right), "--model", str(model), "--json",
                   "-o", f"{out}/{i}"]  # fmt: skip
            start = time.perf_counter()
            done = run(cmd, root, capture_output=True, text=True, check=True)
            times.append((time.perf_counter() - start) * 1e3)
            json.loads(done.stdout)
    return {"median_ms": round(statistics.median(times), 1), "runs_ms": [round(t) for t in times]}


def subset(folder: Path, pairs: int, into: Path) -> Path:
    """A folder of links to the first ``pairs`` pairs of ``folder`` (left/, right/)."""
    names = sorted(p.name for p in (folder / "left").glob("*.png"))[:pairs]
    for side in ("left", "right"):
        (into / side).mkdir(parents=True)
        for name in names:
            (into / side / name).symlink_to((folder / side / name).resolve())
    return into


def batch(model: Path, folder: Path, pairs: int, workers: int, threads: int, root: Path = ROOT) -> dict:
    with tempfile.TemporaryDirectory() as out, tempfile.TemporaryDirectory() as links:
        folder = subset(folder, pairs, Path(links) / "pairs")
        cmd = [*stereogeo_command(), "batch-calibrate", str(folder), "-o", out, "--model", str(model),
               "--workers", str(workers), "--threads", str(threads)]  # fmt: skip
        start = time.perf_counter()
        done = run(cmd, root, capture_output=True, text=True)
        wall = time.perf_counter() - start
        if done.returncode not in (0, 4):
            raise SystemExit(done.stderr)
        summary = json.loads((Path(out) / "summary.json").read_text())
    return {"workers": workers, "pairs": summary["counts"]["pairs"], "ok": summary["counts"]["ok"],
            "wall_s": round(wall, 2), "pairs_per_s": round(summary["counts"]["pairs"] / wall, 2),
            "median_pair_ms": summary["medians"]["time_ms"]}  # fmt: skip


def side_by_side(args, folder: Path, left: Path, right: Path, counts: list[int]) -> dict:
    """Each measurement for the other checkout and this one, alternately, ``args.rounds`` times; the ratios
    new / old of the medians over the rounds."""
    roots = {"old": args.against.resolve(), "new": ROOT}
    rounds: dict[str, dict[str, list[float]]] = {"warm_ms": {}, "cold_ms": {}, "batch_pairs_per_s": {}}
    for _ in range(args.rounds):
        for label, root in roots.items():
            if args.runs > 0:
                ms = warm_in(root, args.model, left, right, args.runs, args.threads)["median_ms"]
                rounds["warm_ms"].setdefault(label, []).append(ms)
            if args.cold_runs > 0:
                ms = cold(args.model, left, right, args.cold_runs, root)["median_ms"]
                rounds["cold_ms"].setdefault(label, []).append(ms)
            for w in args.workers.split(","):
                result = batch(args.model, folder, max(counts), int(w), args.threads, root)
                rounds["batch_pairs_per_s"].setdefault(f"{label}, {w} workers", []).append(
                    result["pairs_per_s"]
                )
            print(json.dumps(rounds), file=sys.stderr)
    medians = {kind: {k: statistics.median(v) for k, v in per.items()} for kind, per in rounds.items()}
    ratios = {}
    for kind in ("warm_ms", "cold_ms"):
        if "old" in medians[kind]:
            ratios[f"{kind[:-3]} time, new / old"] = round(medians[kind]["new"] / medians[kind]["old"], 3)
    for w in args.workers.split(","):
        old, new = (
            medians["batch_pairs_per_s"][f"old, {w} workers"],
            medians["batch_pairs_per_s"][f"new, {w} workers"],
        )
        ratios[f"batch throughput with {w} workers, new / old"] = round(new / old, 3)
    return {
        "before": load(),
        "against": str(roots["old"]),
        "rounds": rounds,
        "ratios": ratios,
        "after": load(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "stereogeo.onnx")
    parser.add_argument("--data", type=Path, help="folder of rendered pairs (made if needed; default: temp)")
    parser.add_argument("--runs", type=int, default=10, help="warm runs")
    parser.add_argument("--cold-runs", type=int, default=3)
    parser.add_argument("--pairs", default="20", help="comma-separated pair counts for the batch throughput")
    parser.add_argument("--workers", default="1,2", help="comma-separated --workers values for the batch")
    parser.add_argument("--threads", type=int, default=0, help="ONNX Runtime threads (0: one per core)")
    parser.add_argument("--against", type=Path, help="another checkout, measured alternately with this one")
    parser.add_argument("--rounds", type=int, default=3, help="alternations with --against")
    parser.add_argument(
        "--warm-only", nargs=2, type=Path, help=argparse.SUPPRESS
    )  # LEFT RIGHT: warm, as JSON
    args = parser.parse_args()
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before NumPy loads, as the stereogeo command does
    if args.warm_only:
        print(json.dumps(warm(args.model, *args.warm_only, args.runs, args.threads)))
        return
    if not args.model.is_file():
        raise SystemExit(f"no model at {args.model}: pass --model (e.g. an exported checkpoint)")
    temp = None if args.data else tempfile.TemporaryDirectory()
    folder = args.data or Path(temp.name) / "pairs"
    counts = [int(n) for n in args.pairs.split(",")]
    try:
        print(f"rendering {max(counts)} pairs into {folder} ...", file=sys.stderr)
        render(folder, max(counts))
        left, right = folder / "left" / "000000.png", folder / "right" / "000000.png"
        if args.against is not None:
            results = side_by_side(args, folder, left, right, counts)
            print(json.dumps(results, indent=2))
            return
        results = {"before": load(), "model": str(args.model)}
        if args.runs > 0:
            results["warm"] = warm(args.model, left, right, args.runs, args.threads)
            print(json.dumps({"warm": results["warm"]}), file=sys.stderr)
        if args.cold_runs > 0:
            results["cold"] = cold(args.model, left, right, args.cold_runs)
            print(json.dumps({"cold": results["cold"]}), file=sys.stderr)
        results["batch"] = []
        for w in args.workers.split(","):
            runs = [batch(args.model, folder, n, int(w), args.threads) for n in counts]
            results["batch"].extend(runs)
            if len(counts) > 1:
                slope, start_up = statistics.linear_regression(
                    [r["pairs"] for r in runs], [r["wall_s"] for r in runs]
                )
                results["batch"].append(
                    {
                        "workers": int(w),
                        "start_up_s": round(start_up, 2),
                        "marginal_pairs_per_s": round(1 / slope, 2),
                    }
                )
        results["after"] = load()
    finally:
        if temp is not None:
            temp.cleanup()
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
