"""How the calibration depends on the size the network sees: the same pairs at several input short sides.

    python benchmarks/scale_sensitivity.py DATASET [DATASET ...] [--sizes 160,192,224,256,288] [--model M]
        [--by-scene] [--fields-only] [--blur 0,1,2] [--zoom 1,0.7,0.5] [--aspect 0,2.2,3.3]

Every pair of each dataset (the project's layout with ground truth) is calibrated by the full pipeline
with the network's input short side overridden (the shipped rule is the model's ``input_short_side``).
Prints one row per dataset and size: median vFoV error, its median signed value (the "bias": > 0 reads the
lens too wide), median roll and pitch errors where gravity is known, median rotation error. A model that
reads the focal length from geometry gives the same vFoV at every size; one that reads it from how big
things look in pixels reads narrower lenses on smaller inputs and wider ones on larger inputs.

``--fields-only`` calibrates each camera from the network's fields alone (no matches, which refine the
focal ratio): what the network itself reads.

``--blur`` adds a sharpness axis: every image is blurred (Gaussian, sigma in pixels of the network
input) before calibration. A model that reads the focal length from geometry does not care; one that has
learned "blurry means a long lens" (renders and panorama crops are blurrier the narrower the view) reads
narrower lenses from blurrier images.

``--zoom`` adds a field-of-view axis on the same content: each image is cut to its central ``zoom`` of
width and height (no resampling; the ground truth's principal point moves with the cut, the focal length
and gravity stay), so every real set also gives views of known, narrower fields of view. A model that reads
the focal length from geometry reads the cut views' narrower lenses; one that falls back on a prior reads
every cut much like the whole image.

``--aspect`` cuts each (zoomed) image further to a wide strip of that width / height ratio, the full width
kept and the height cut about the centre (0: no cut): the shape of a driving rig's frames (KITTI's are
1242 x 375, 3.3:1), wider than the ordinary training sizes (4:3 to 5:3, and portrait); the training setting
``wide_data`` adds 2:1 to 3.2:1 (docs/network.md, "Wide frames in training").

``--by-scene`` splits a rendered dataset by its records' ``scene`` (room, street, …, and ``panorama`` for
the crops of real panoramas): the panorama crops are real photographs, the renders are not.
"""

import argparse
import json
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

from stereogeo_cli.evaluate import camera_errors, evaluate_dataset, read_dataset
from stereogeo_cli.io import load_image
from stereogeo_cli.pipeline import Calibrator


class _Blurred:
    """A calibrator that blurs both images first, by ``sigma`` pixels of the network input."""

    def __init__(self, calibrator: Calibrator, sigma: float):
        self.calibrator, self.sigma = calibrator, sigma

    def _blur(self, image: np.ndarray) -> np.ndarray:
        if self.sigma <= 0:
            return image
        in_pixels = min(image.shape[:2]) / self.calibrator.network.short_side  # original px per input px
        return cv2.GaussianBlur(image, (0, 0), self.sigma * in_pixels)

    def calibrate(self, left: np.ndarray, right: np.ndarray, **kwargs):
        return self.calibrator.calibrate(self._blur(left), self._blur(right), **kwargs)

    def fields_only(self, left: np.ndarray, right: np.ndarray):
        return self.calibrator.fields_only(self._blur(left), self._blur(right))


def _zoomed(folder: Path, zoom: float, into: Path, aspect: float = 0.0) -> Path:
    """A copy of a dataset with every image cut to its central ``zoom`` (width and height), and then, with
    ``aspect`` > 0, to at most that width / height ratio (the height cut); the ground truth moved along: the
    principal point shifts by the cut's corner; focal length, gravity and pose stay."""
    if zoom == 1 and aspect == 0:
        return folder
    out = into / f"{folder.name}@zoom{zoom:g}@aspect{aspect:g}"
    records = []
    for record in read_dataset(folder):
        for side in ("left", "right"):
            (out / side).mkdir(parents=True, exist_ok=True)
            image = cv2.imread(str(folder / side / f"{record['id']}.png"), cv2.IMREAD_UNCHANGED)
            height, width = image.shape[:2]
            cut_w, cut_h = round(width * zoom), round(height * zoom)
            if aspect > 0:
                cut_h = min(cut_h, round(cut_w / aspect))
            x0, y0 = (width - cut_w) // 2, (height - cut_h) // 2
            cv2.imwrite(str(out / side / f"{record['id']}.png"), image[y0 : y0 + cut_h, x0 : x0 + cut_w])
            K = np.asarray(record[side]["K"], dtype=float)
            K[0, 2] -= x0
            K[1, 2] -= y0
            record[side] = {**record[side], "K": K.tolist(), "width": cut_w, "height": cut_h}
        records.append(json.dumps(record))
    (out / "calib.jsonl").write_text("\n".join(records) + "\n")
    return out


def _fields_only(folder: Path, calibrator: Calibrator | _Blurred) -> list[dict]:
    rows = []
    for record in read_dataset(folder):
        images = [load_image(folder / side / f"{record['id']}.png") for side in ("left", "right")]
        row = {"id": record["id"]}
        for view, fit in zip(("left", "right"), calibrator.fields_only(*images), strict=True):
            row.update(camera_errors(fit, record[view], view))
        rows.append(row)
    return rows


def _median(rows: list[dict], key: str) -> float | None:
    values = [r[f"{v}_{key}"] for r in rows for v in ("left", "right") if r.get(f"{v}_{key}") is not None]
    return float(np.median(values)) if values else None


def _groups(folder: Path, rows: list[dict], by_scene: bool) -> dict[str, list[dict]]:
    scene = {}
    for record in read_dataset(folder) if by_scene else []:
        kind = record.get("kind")
        if kind is not None:  # a rendered dataset (real sets have no kind)
            scene[record["id"]] = "panorama" if kind == "panorama" else record.get("scene") or kind
    if not scene:
        return {folder.name: rows}
    groups: dict[str, list[dict]] = defaultdict(list)
    for row in rows:
        groups[f"{folder.name}/{scene.get(row['id'], '?')}"].append(row)
    return dict(sorted(groups.items()))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("datasets", nargs="+", type=Path)
    parser.add_argument("--sizes", default="160,192,224,256,288", help="input short sides, multiples of 32")
    parser.add_argument("--model", type=Path, default=None)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--by-scene", action="store_true", help="split rendered datasets by scene kind")
    parser.add_argument("--fields-only", action="store_true", help="the network's fields alone, no matches")
    parser.add_argument("--blur", default="0", help="Gaussian blurs, sigma in network-input pixels")
    parser.add_argument("--zoom", default="1", help="central cuts, share of width and height (0 < z <= 1)")
    parser.add_argument("--aspect", default="0", help="wide strips, width / height (0: the image as it is)")
    parser.add_argument("--json", type=Path, help="also write the rows to this JSON file")
    args = parser.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    blurs = [float(b) for b in args.blur.split(",")]
    zooms = [float(z) for z in args.zoom.split(",")]
    aspects = [float(a) for a in args.aspect.split(",")]
    if not all(0 < z <= 1 for z in zooms):
        parser.error("--zoom takes shares of the image in (0, 1]")
    if not all(a == 0 or a >= 1 for a in aspects):
        parser.error("--aspect takes width / height ratios of 1 or more (0: no cut)")
    rows = []
    calibrator = Calibrator(args.model, threads=args.threads)
    shipped = calibrator.network.short_side
    print(f"model {calibrator.model_path.name}, shipped input short side {shipped}", file=sys.stderr)
    print("| dataset | zoom | aspect | short side | blur | vFoV | vFoV bias | roll | pitch | R |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    scratch = tempfile.TemporaryDirectory(prefix="stereogeo-zoom-")
    for folder, zoom, aspect in ((f, z, a) for f in args.datasets for z in zooms for a in aspects):
        cut = _zoomed(folder, zoom, Path(scratch.name), aspect)
        for size, blur in ((size, blur) for size in sizes for blur in blurs):
            calibrator.network.short_side = size
            blurred = _Blurred(calibrator, blur)
            if args.fields_only:
                pairs = _fields_only(cut, blurred)
            else:
                pairs = evaluate_dataset(cut, blurred)["pairs"]
            for name, group in _groups(cut, pairs, args.by_scene).items():
                name = name.replace(cut.name, folder.name, 1)
                row = {"dataset": name, "zoom": zoom, "aspect": aspect, "short_side": size, "blur": blur}
                row["pairs"] = len(group)
                for key in ("vfov", "roll", "pitch"):
                    row[key] = _median(group, f"{key}_error_deg")
                row["vfov_bias"] = _median(group, "vfov_bias_deg")
                rotations = [
                    r["rotation_error_deg"] for r in group if r.get("rotation_error_deg") is not None
                ]
                row["rotation"] = float(np.median(rotations)) if rotations else None
                rows.append(row)
                cells = [
                    "–" if row[k] is None else f"{row[k]:+.2f}°" if k == "vfov_bias" else f"{row[k]:.2f}°"
                    for k in ("vfov", "vfov_bias", "roll", "pitch", "rotation")
                ]
                mark = " (shipped)" if size == shipped else ""
                print(
                    f"| {name} | {zoom:g} | {aspect:g} | {size}{mark} | {blur:g} | "
                    + " | ".join(cells)
                    + " |",
                    flush=True,
                )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
