"""Rendering speed of make-data: pairs per second (both views) at a given image size.

    python benchmarks/bench_synth.py                 # 320x240 and 640x480, 2 workers
    python benchmarks/bench_synth.py --pairs 60 --workers 2 --sizes 240

Reports (1) the steady-state throughput of make-data's worker pool (render, augment, PNG-encode and
write both views; process start-up and texture-pool build excluded, measured separately), (2) the CPU
time per pair of one single-threaded worker doing the same, and the throughput that gives on 2 free
cores (independent of other load on the machine), and (3) the median wall time of one ``sample_pair``
call in a single process.
"""

from __future__ import annotations

import argparse
import multiprocessing
import statistics
import tempfile
import time
from pathlib import Path

from stereogeo_cli.synth.config import SynthConfig


def _config(short_side: int, panoramas: Path | None) -> SynthConfig:
    return SynthConfig(short_side=short_side, aspects=(4 / 3,), portrait_share=0.0, panoramas=panoramas)


def _pool_throughput(
    short_side: int, pairs: int, workers: int, panoramas: Path | None
) -> tuple[float, float]:
    from stereogeo_cli.synth import dataset

    config = _config(short_side, panoramas)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "left").mkdir()
        (folder / "right").mkdir()
        ctx = multiprocessing.get_context("spawn")
        start = time.perf_counter()
        with ctx.Pool(workers, dataset._init_worker, (folder, 0, config, workers > 1)) as pool:
            list(pool.imap(dataset._render_and_write, range(8 * workers), chunksize=1))  # warm-up
            ready = time.perf_counter()
            list(pool.imap(dataset._render_and_write, range(1000, 1000 + pairs), chunksize=1))
            done = time.perf_counter()
    return pairs / (done - ready), ready - start


def _cpu_per_pair(short_side: int, pairs: int, panoramas: Path | None) -> float:
    """CPU milliseconds (all threads of the process) per pair of a single-threaded worker, PNGs written."""
    ctx = multiprocessing.get_context("spawn")
    with ctx.Pool(1) as pool:
        return pool.apply(_cpu_worker, (short_side, pairs, panoramas))


def _cpu_worker(short_side: int, pairs: int, panoramas: Path | None) -> float:
    from stereogeo_cli.synth import dataset

    config = _config(short_side, panoramas)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "left").mkdir()
        (folder / "right").mkdir()
        dataset._init_worker(folder, 0, config, single_thread=True)
        for i in range(8):  # warm-up (skies, shaders)
            dataset._render_and_write(i)
        times = []
        for i in range(pairs):
            t = time.process_time()
            dataset._render_and_write(3000 + i)
            times.append(time.process_time() - t)
    return statistics.mean(times) * 1000


def _single_process(short_side: int, pairs: int, panoramas: Path | None) -> float:
    from stereogeo_cli.synth.sample import get_renderer, sample_pair

    config = _config(short_side, panoramas)
    renderer = get_renderer(0, config)
    sample_pair(0, 0, config, renderer)
    times = []
    for i in range(1, pairs + 1):
        t = time.perf_counter()
        sample_pair(0, 2000 + i, config, renderer)
        times.append(time.perf_counter() - t)
    return statistics.median(times) * 1000


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--sizes", type=int, nargs="+", default=[240, 480], help="short sides (4:3 images)")
    parser.add_argument("--pairs", type=int, default=100, help="timed pairs per size for the worker pool")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument(
        "--panoramas", type=Path, default=None, help="panorama folder (default: procedural skies)"
    )
    args = parser.parse_args()
    for short in args.sizes:
        size = f"{round(short * 4 / 3)}x{short}"
        rate, startup = _pool_throughput(short, args.pairs, args.workers, args.panoramas)
        print(
            f"{size}: {rate:.1f} pairs/s with {args.workers} workers (steady state, {args.pairs} pairs, "
            f"PNG written; start-up {startup:.1f} s)",
            flush=True,
        )
    for short in args.sizes:
        size = f"{round(short * 4 / 3)}x{short}"
        cpu = _cpu_per_pair(short, min(args.pairs, 60), args.panoramas)
        print(
            f"{size}: {cpu:.1f} CPU-ms per pair in a single-threaded worker (PNG written) "
            f"= {2000 / cpu:.1f} pairs/s on 2 free cores",
            flush=True,
        )
    for short in args.sizes:
        size = f"{round(short * 4 / 3)}x{short}"
        ms = _single_process(short, min(args.pairs, 40), args.panoramas)
        print(f"{size}: median {ms:.1f} ms per sample_pair in one process (both views, no PNG)", flush=True)


if __name__ == "__main__":
    main()
