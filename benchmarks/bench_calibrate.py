"""Speed of the product: warm ``calibrate`` on a 640x480 pair, cold start to first output, batch throughput.

    python benchmarks/bench_calibrate.py --model models/stereogeo.onnx --runs 10 --cold-runs 3 --pairs 20

- Warm: one Calibrator (one ONNX Runtime session), the pair already loaded; each run is the whole
  ``calibrate`` (network, refiner, matching, fusion) plus writing the default files (opencv, json). Medians
  over ``--runs`` after two warm-up runs, with the pipeline's own ``timing_ms`` breakdown.
- Cold: ``stereogeo calibrate LEFT RIGHT --json -o DIR`` in a fresh process, wall clock until it exits
  (interpreter start, imports, session creation, one calibration, files written); median of ``--cold-runs``.
  As for an installed package, the modules are compiled to bytecode first, and the network's optimised
  graph is in its cache after the first run (``STEREOGEO_CACHE_DIR=`` measures every run without it).
- Batch: ``stereogeo batch-calibrate`` over the first ``--pairs`` rendered 640x480 pairs (one or more
  counts, e.g. ``20,60``), wall clock of the whole command (start-up included) for each ``--workers``
  value; pairs/s = pairs / wall time. With two or more counts, a straight line through (pairs, wall time)
  splits the time into a fixed start-up (interpreter, workers, network sessions) and a marginal rate.
- ``--runs 0`` or ``--cold-runs 0`` skips that part.
- ``--against OLD_CHECKOUT`` (e.g. a ``git worktree`` of an earlier commit): the ratios new / old (time
  ratios for warm and cold, throughput ratios for the batch): a speed claim is a ratio measured side by side
  on one machine, never an absolute time. Warm: one process per checkout, each with its own code, one
  Calibrator and the batch's pairs loaded; every pair is calibrated by both, one right after the other in
  a random order, ``--runs`` passes over the pairs, and the ratio is the sum of the new times over the sum
  of the old (with the median of the pairs' own ratios). Interleaving pair by pair keeps the machine's
  load, which drifts by tens of percent over minutes on shared machines, out of the ratio. Cold and batch:
  each checkout alternately, ``--rounds`` times, and the ratio of the medians over the rounds.

The pairs are rendered with ``stereogeo make-data --size 480 --aspects 4:3 --portrait-share 0`` into a
temporary folder (or ``--data``, reused if it holds enough pairs). The load average is printed with the
numbers: on a shared machine they are only as good as the cores are free.
"""

from __future__ import annotations

import argparse
import json
import os
import random
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


def warm_server(model: Path, folder: Path, pairs: int, threads: int) -> None:
    """One Calibrator and the first ``pairs`` pairs of ``folder``, loaded; then, for each pair index read
    from stdin, the milliseconds of that pair's ``calibrate`` on stdout (after two warm-up calibrations)."""
    from stereogeo_cli.io import load_image
    from stereogeo_cli.pipeline import Calibrator

    calibrator = Calibrator(model, threads=threads)
    names = sorted(p.name for p in (folder / "left").glob("*.png"))[:pairs]
    images = [(load_image(folder / "left" / n), load_image(folder / "right" / n)) for n in names]
    for pair in images[:2]:
        calibrator.calibrate(*pair)
    print("ready", flush=True)
    for line in sys.stdin:
        start = time.perf_counter()
        calibrator.calibrate(*images[int(line)])
        print((time.perf_counter() - start) * 1e3, flush=True)


def warm_interleaved(roots: dict[str, Path], args, folder: Path, pairs: int) -> dict:
    """Warm ``calibrate`` of each checkout in ``roots`` (old, new) in a process of its own, pair by pair,
    one right after the other in a random order, ``args.runs`` passes over the pairs (module docstring)."""
    servers = {}
    for label, root in roots.items():
        cmd = [sys.executable, __file__, "--warm-server", str(folder), "--pairs", str(pairs), "--model",
               str(args.model), "--threads", str(args.threads)]  # fmt: skip
        env = {
            **os.environ,
            "PYTHONPATH": os.pathsep.join(filter(None, [str(root), os.environ.get("PYTHONPATH")])),
        }
        servers[label] = subprocess.Popen(
            cmd, cwd=root, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
        )
    times: dict[str, list[float]] = {label: [] for label in roots}
    try:
        for server in servers.values():
            if server.stdout.readline().strip() != "ready":
                raise SystemExit("a warm-up process failed")
        order = random.Random(0)
        for _ in range(args.runs):
            for index in range(pairs):
                for label in order.sample(list(roots), len(roots)):
                    servers[label].stdin.write(f"{index}\n")
                    servers[label].stdin.flush()
                    times[label].append(float(servers[label].stdout.readline()))
    finally:
        for server in servers.values():
            server.stdin.close()
            server.wait()
    paired = [new / old for old, new in zip(times["old"], times["new"], strict=True)]
    return {
        "median_ms": {label: round(statistics.median(v), 1) for label, v in times.items()},
        "calibrations": len(paired),
        "time, new / old": round(sum(times["new"]) / sum(times["old"]), 3),
        "median of the pairs' ratios": round(statistics.median(paired), 3),
    }


def compile_bytecode(root: Path) -> None:
    """The checkout's modules compiled to bytecode, as ``pip install`` leaves an installed package: a cold
    start then reads them instead of compiling every module again (which PYTHONDONTWRITEBYTECODE, or a
    read-only checkout, would make part of every measurement)."""
    run([sys.executable, "-m", "compileall", "-q", str(root / "stereogeo_cli")], root, check=True)


def cold(model: Path, left: Path, right: Path, runs: int, root: Path = ROOT) -> dict:
    compile_bytecode(root)
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
    compile_bytecode(root)
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
    warm_ratio = warm_interleaved(roots, args, folder, max(counts)) if args.runs > 0 else None
    print(json.dumps({"warm": warm_ratio}), file=sys.stderr)
    rounds: dict[str, dict[str, list[float]]] = {"cold_ms": {}, "batch_pairs_per_s": {}}
    for _ in range(args.rounds):
        for label, root in roots.items():
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
    if warm_ratio is not None:
        ratios["warm time, new / old"] = warm_ratio["time, new / old"]
    if "old" in medians["cold_ms"]:
        ratios["cold time, new / old"] = round(medians["cold_ms"]["new"] / medians["cold_ms"]["old"], 3)
    for w in args.workers.split(","):
        old, new = (
            medians["batch_pairs_per_s"][f"old, {w} workers"],
            medians["batch_pairs_per_s"][f"new, {w} workers"],
        )
        ratios[f"batch throughput with {w} workers, new / old"] = round(new / old, 3)
    return {
        "before": load(),
        "against": str(roots["old"]),
        "warm": warm_ratio,
        "rounds": rounds,
        "ratios": ratios,
        "after": load(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "stereogeo.onnx")
    parser.add_argument("--data", type=Path, help="folder of rendered pairs (made if needed; default: temp)")
    parser.add_argument(
        "--runs", type=int, default=10, help="warm runs (with --against: passes over the pairs)"
    )
    parser.add_argument("--cold-runs", type=int, default=3)
    parser.add_argument("--pairs", default="20", help="comma-separated pair counts for the batch throughput")
    parser.add_argument("--workers", default="1,2", help="comma-separated --workers values for the batch")
    parser.add_argument("--threads", type=int, default=0, help="ONNX Runtime threads (0: one per core)")
    parser.add_argument("--against", type=Path, help="another checkout, measured alternately with this one")
    parser.add_argument("--rounds", type=int, default=3, help="alternations with --against")
    parser.add_argument("--warm-server", type=Path, help=argparse.SUPPRESS)  # FOLDER: warm_server
    args = parser.parse_args()
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before NumPy loads, as the stereogeo command does
    if args.warm_server:
        warm_server(args.model, args.warm_server, int(args.pairs.split(",")[-1]), args.threads)
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
