"""The split of the real photographs into a training and a measurement half, made from the labels alone.

    python benchmarks/real_photos_split.py REAL_PHOTOS_DIR [-o benchmarks/real_photos_split.json]

REAL_PHOTOS_DIR is the developer data's ``real-photos`` folder (``labels.jsonl``). The rule
(:func:`stereogeo_cli.evaluate_photos.make_split`) looks at no model's errors; see
``benchmarks/real_photos_split.md``. ``stereogeo evaluate REAL_PHOTOS_DIR --split measure`` scores one half.
"""

import argparse
import hashlib
import json
from collections import Counter
from pathlib import Path

from stereogeo_cli.evaluate_photos import LABELS, make_split, read_labels


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("folder", type=Path, help="the real-photos folder (labels.jsonl)")
    parser.add_argument("-o", "--output", type=Path, default=Path(__file__).parent / "real_photos_split.json")
    args = parser.parse_args()
    records = read_labels(args.folder)
    split = make_split(records)
    side = {camera: half for half, cameras in split.items() for camera in cameras}
    counts = {}
    for half, cameras in split.items():
        sources = Counter(r["source"] for r in records if side[r["camera_id"]] == half)
        counts[half] = {
            "cameras": len(cameras),
            "images": sum(sources.values()),
            "by_source": dict(sorted(sources.items())),
        }
    labels_sha = hashlib.sha256((args.folder / LABELS).read_bytes()).hexdigest()
    out = {
        "made_by": "python benchmarks/real_photos_split.py REAL_PHOTOS_DIR (evaluate_photos.make_split)",
        "labels_sha256": labels_sha,
        "counts": counts,
        **split,
    }
    args.output.write_text(json.dumps(out, indent=1, ensure_ascii=False) + "\n")
    for half, c in counts.items():
        print(f"{half}: {c['cameras']} cameras, {c['images']} images; {c['by_source']}")


if __name__ == "__main__":
    main()
