"""Refiner speed: one camera from 320×240 fields (noisy, with outliers), on one core.

    python benchmarks/bench_refine.py [--repeats 200]

Prints the median and 90th percentile time per camera and the median iteration count.
"""

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[var] = "1"  # the goal is per core (README, "Speed"); must precede the numpy import

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from synthetic_fields import noisy_fields, random_camera  # noqa: E402

from stereogeo_cli.refine import refine_camera  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeats", type=int, default=200)
    parser.add_argument("--max-samples", type=int, default=None, help="override the refiner's sub-sampling")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    conf = {} if args.max_samples is None else {"max_samples": args.max_samples or None}
    cases = []
    for _ in range(args.repeats):
        width, height, f, g, *_ = random_camera(rng, (320, 240))
        cases.append(noisy_fields(rng, width, height, f, g))
    refine_camera(*cases[0][:2], cases[0][2], cases[0][2], conf=conf)  # warm-up
    times, iterations = [], []
    for up, lat, c in cases:
        start = time.perf_counter()
        fit = refine_camera(up, lat, c, c, conf=conf)
        times.append(time.perf_counter() - start)
        iterations.append(fit.iterations)
    ms = np.array(times) * 1e3
    print(
        f"refine_camera 320x240: median {np.median(ms):.1f} ms, p90 {np.percentile(ms, 90):.1f} ms, "
        f"median iterations {np.median(iterations):.0f} ({args.repeats} cameras, 1 thread)"
    )


if __name__ == "__main__":
    main()
