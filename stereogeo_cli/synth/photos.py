"""Training pairs from single real photographs with known intrinsics (``make-data --photos``).

A folder of photographs with a ``labels.jsonl`` (``stereogeo evaluate``'s photo layout: K for the image as
stored, gravity where known) becomes a dataset folder in the project's layout. Each photograph gives one
pair per zoom: its central part (the whole frame, then smaller centred cuts, each with its exact focal
length and principal point at the centre), resized to ``short_side``, as the left view, and the same view
softened as the right one (``evaluate_photos.soften``: resized down by ``softening`` and back up): the same
camera seen sharp and soft, so that sharpness does not tell the lens. A pair has no R or T (no pose losses);
its gravity is the label's or unknown (null), so where it is unknown the fields are supervised through the
focal length alone (``network/losses.py``, ``photo_weight``). Images whose pixels are all one value are left
out.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np

from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.io.atomic import write_files_atomically


def centre_cut(
    image: np.ndarray, K: np.ndarray, zoom: float, short_side: int
) -> tuple[np.ndarray, np.ndarray]:
    """The central ``zoom`` share of the image (each side), resized to ``short_side`` (area filter when
    shrinking): (image, its K with the principal point at the centre and the focal length scaled)."""
    height, width = image.shape[:2]
    cut_w, cut_h = max(8, round(width * zoom)), max(8, round(height * zoom))
    x0, y0 = (width - cut_w) // 2, (height - cut_h) // 2
    cut = image[y0 : y0 + cut_h, x0 : x0 + cut_w]
    scale = short_side / min(cut_w, cut_h)
    size = (max(1, round(cut_w * scale)), max(1, round(cut_h * scale)))
    filter_ = cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR
    out = cv2.resize(cut, size, interpolation=filter_)
    sx, sy = size[0] / cut_w, size[1] / cut_h
    focal = 0.5 * (K[0, 0] * sx + K[1, 1] * sy)
    K_out = np.array([[focal, 0.0, (size[0] - 1) / 2], [0.0, focal, (size[1] - 1) / 2], [0.0, 0.0, 1.0]])
    return out, K_out


def make_photo_pairs(
    folder: str | Path,
    out: str | Path,
    split: str | None = "train",
    zooms: tuple[float, ...] = (1.0, 0.75, 0.55),
    softening: float = 2.0,
    short_side: int = 320,
) -> int:
    """Write the pairs of the photographs of ``folder`` (of one half of the project's split, or all with
    ``split`` None) into ``out``; returns how many. Only ``train_ok`` images are used."""
    from stereogeo_cli.evaluate_photos import read_labels, select, soften

    records = [r for r in select(read_labels(folder), split) if r.get("train_ok", True)]
    if not records:
        raise StereoGeoError(f"{folder} has no photographs to train on in that split")
    out = Path(out)
    for side in ("left", "right"):
        (out / side).mkdir(parents=True, exist_ok=True)
    lines = []
    for index, record in enumerate(records):
        image = cv2.imread(str(Path(folder) / record["file"]), cv2.IMREAD_COLOR)
        if image is None:
            raise StereoGeoError(f"cannot read {Path(folder) / record['file']}")
        if int(image.max()) == int(image.min()):
            continue
        K = np.asarray(record["K"], dtype=float)
        gravity = record.get("gravity_up")
        for zoom in zooms:
            view, K_view = centre_cut(image, K, zoom, short_side)
            name = f"{index:05d}_{round(zoom * 100):03d}"
            cv2.imwrite(str(out / "left" / f"{name}.png"), view)
            cv2.imwrite(str(out / "right" / f"{name}.png"), soften(view, softening))
            height, width = view.shape[:2]
            camera = {
                "K": K_view.tolist(),
                "dist": [],
                "width": width,
                "height": height,
                "gravity_up": gravity,
            }
            lines.append(
                json.dumps(
                    {
                        "id": name, "left": camera, "right": camera, "R": None, "T": None, "kind": "photo",
                        "source": record["file"], "camera": record["camera_id"], "zoom": zoom,
                        "vfov_deg": math.degrees(2 * math.atan(height / (2 * K_view[1, 1]))),
                    }
                )
            )  # fmt: skip
    write_files_atomically(out, {"calib.jsonl": "\n".join(lines) + "\n"})
    return len(lines)
