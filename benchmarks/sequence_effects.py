"""Which effect of real recordings moves ``calibrate-sequence``'s focal length, one effect at a time.

For each motion (``drive`` and ``turning`` by default) and seed, a base sequence is rendered with
``make-data --sequence`` (in-process, ``make_sequence``), then the same seed with each effect switched on
alone (the same scene, path and rig: only the effect differs). Each is calibrated with
``calibrate-sequence --json`` (``sequence_accuracy.run_sequence``) and scored against its calib.json with
``sequence_accuracy._errors``. The table: motion, seed, effect, each camera's focal error (%) against the
true fx, the left camera's reported focal sigma (% of the true fx) and z-score (|error| / sigma), the error
of R (degrees), and the wall time of the calibration.

    python benchmarks/sequence_effects.py [--frames 30] [--seeds 1] [--motions drive,turning]
        [--effects base,principal,aspect,h264,exposure,blur,movers,all] [--size 240] [--json] [--keep DIR]

Run it at low priority on a shared machine (``nice -n 10 python benchmarks/sequence_effects.py ...``): each
calibration takes about 30 s at 30 frames, the whole default run about 13 minutes on 2 cores.
calibrate-sequence varies by about 0.1 % from run to run on the same frames. The effects (docs/synth.md,
"Sequences: effects of real recordings"):

- ``base``: no effect. ``all``: every effect below at once.
- ``principal``: the principal point 2 % of the width right and 1.5 % of the height up of the centre
  (``--principal-offset 0.02,-0.015``).
- ``aspect``: fy = 1.01 fx (``--focal-aspect 1.01``); the error is against fx, so a square-pixel estimate
  between the two reads up to +0.5 % from that alone.
- ``h264``: H.264 at 0.15 bits per pixel and frame (a dash cam's 12 Mbit/s at 1080p and 30 Hz;
  ``--h264 KBPS`` with the bitrate that makes at the sequence's size and rate).
- ``exposure``: the gain drifting by ±0.5 stops (``--exposure-changes 0.5``).
- ``blur``: motion blur over 20 ms (``--motion-blur 20``).
- ``movers``: 8 cars and people moving on their own (``--moving-objects 8``).

A drive renders at its defaults (1240 × 376, 10 Hz); the other motions at ``--size`` (short side, default
240: 320 × 240). ``--keep DIR`` keeps the renders (DIR/<motion>-s<seed>-<effect>/) to look at or to run
again; ``--json`` prints the rows as JSON instead of the table.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from sequence_accuracy import _errors, run_sequence  # noqa: E402

from stereogeo_cli.synth.effects import SequenceEffects  # noqa: E402
from stereogeo_cli.synth.sequence import make_sequence, motion_duration, sequence_config  # noqa: E402
from stereogeo_cli.synth.video import bits_per_pixel_kbps  # noqa: E402

H264_BITS_PER_PIXEL = 0.15
EFFECTS = {
    "base": {},
    "principal": {"principal_offset": (0.02, -0.015)},
    "aspect": {"focal_aspect": 1.01},
    "h264": {"h264_kbps": "bits per pixel"},  # the bitrate follows from the size and the frame rate
    "exposure": {"exposure_stops": 0.5},
    "blur": {"motion_blur_ms": 20.0},
    "movers": {"moving_objects": 8},
}
EFFECTS["all"] = {k: v for effect in EFFECTS.values() for k, v in effect.items()}


def _effects(name: str, width: int, height: int, rate_hz: float) -> SequenceEffects:
    settings = dict(EFFECTS[name])
    if "h264_kbps" in settings:
        settings["h264_kbps"] = round(bits_per_pixel_kbps(H264_BITS_PER_PIXEL, width, height, rate_hz), 1)
    return SequenceEffects(**settings)


def render(folder: Path, motion: str, seed: int, frames: int, size: int, effect: str) -> tuple[dict, float]:
    """Render one sequence; returns its calib.json and the seconds it took."""
    config = sequence_config(motion) if motion == "drive" else sequence_config(motion, short_side=size)
    width, height = int(2 * round(config.short_side * config.aspects[0] / 2)), config.short_side
    rate = (frames - 1) / motion_duration(motion, frames) if frames > 1 else 10.0
    start = time.perf_counter()
    make_sequence(folder, motion, frames, seed, config, progress=False,
                  effects=_effects(effect, width, height, rate))  # fmt: skip
    return json.loads((folder / "calib.json").read_text()), time.perf_counter() - start


def score(folder: Path, truth: dict) -> dict:
    """calibrate-sequence on the folder, scored against its ground truth."""
    run = run_sequence(folder, None, 1)
    if "error" in run:
        return {"error": str(run["error"])}
    report, errors = run["report"], _errors(run["report"], truth)
    f_true = float(truth["left"]["K"][0][0])
    sigma = (report["left"]["sigma"] or {}).get("focal_px")
    seq = report["sequence"]
    return {
        "focal_left_pct": 100 * errors["left_focal_rel"],
        "focal_right_pct": 100 * errors["right_focal_rel"],
        "sigma_left_pct": 100 * sigma / f_true if sigma else None,
        "z_left": errors["left_focal_z"],
        "R_deg": errors["R_deg"],
        "registered": f"{seq['frames_registered']}/{seq['frames_read']}",
        "seconds": run["seconds"],
    }


def _cell(value, digits: int) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def print_table(rows: list[dict]) -> None:
    header = (f"{'motion':8} {'seed':>4} {'effect':10} {'focal L %':>9} {'focal R %':>9} {'sigma %':>8} "
              f"{'z':>6} {'R err °':>8} {'frames':>7} {'time s':>7}")  # fmt: skip
    print(header)
    print("-" * len(header))
    for row in rows:
        start = f"{row['motion']:8} {row['seed']:>4} {row['effect']:10}"
        if "error" in row:
            print(f"{start} failed: {row['error']}")
            continue
        print(f"{start} {row['focal_left_pct']:>+9.2f} {row['focal_right_pct']:>+9.2f} "
              f"{_cell(row['sigma_left_pct'], 3):>8} {_cell(row['z_left'], 1):>6} {row['R_deg']:>8.3f} "
              f"{row['registered']:>7} {row['seconds']:>7.0f}")  # fmt: skip


def print_summary(rows: list[dict]) -> None:
    """Medians over the seeds, per motion and effect (where more than one seed ran)."""
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        if "error" not in row:
            groups.setdefault((row["motion"], row["effect"]), []).append(row)
    print(f"\nmedians over seeds\n{'motion':8} {'effect':10} {'|focal L| %':>11} {'|z|':>6} {'R err °':>8} "
          f"{'within 1σ / 3σ':>15}")  # fmt: skip
    for (motion, effect), group in [*groups.items(), (("all", ""), [r for g in groups.values() for r in g])]:
        focal = statistics.median(abs(r["focal_left_pct"]) for r in group)
        z = [abs(r["z_left"]) for r in group if r["z_left"] is not None]
        shares = f"{_share(z, 1.0)} / {_share(z, 3.0)}"
        z = _cell(statistics.median(z) if z else None, 1)
        R = statistics.median(r["R_deg"] for r in group)
        print(f"{motion:8} {effect:10} {focal:>11.2f} {z:>6} {R:>8.3f} {shares:>15}")


def _share(z: list[float], k: float) -> str:
    """The share of |z| within k, as a percentage of the readings with a sigma."""
    return f"{100 * sum(v <= k for v in z) / len(z):.0f} %" if z else "–"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=30, help="Frame pairs per sequence.")
    parser.add_argument("--seeds", type=int, default=1, help="Seeds 0 … N-1.")
    parser.add_argument("--motions", default="drive,turning", help="Comma-separated motions.")
    parser.add_argument("--effects", default=",".join(EFFECTS), help="Comma-separated effects (see above).")
    parser.add_argument("--size", type=int, default=240, help="Short side of the motions other than drive.")
    parser.add_argument("--json", action="store_true", help="Print the rows as JSON.")
    parser.add_argument("--keep", type=Path, default=None, help="Keep the renders in this folder.")
    args = parser.parse_args()
    effects = [e.strip() for e in args.effects.split(",") if e.strip()]
    unknown = [e for e in effects if e not in EFFECTS]
    if unknown:
        parser.error(f"unknown effects {', '.join(unknown)}; choose from {', '.join(EFFECTS)}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        for motion in (m.strip() for m in args.motions.split(",")):
            for seed in range(args.seeds):
                for effect in effects:
                    folder = root / f"{motion}-s{seed}-{effect}"
                    truth, render_s = render(folder, motion, seed, args.frames, args.size, effect)
                    row = {"motion": motion, "seed": seed, "effect": effect, "render_seconds": render_s}
                    rows.append(row | score(folder, truth))
                    if not args.json:
                        print(json.dumps(rows[-1], default=float), file=sys.stderr, flush=True)
    if args.json:
        print(json.dumps(rows, indent=1, default=float))
        return
    print_table(rows)
    if args.seeds > 1:
        print_summary(rows)


if __name__ == "__main__":
    main()
