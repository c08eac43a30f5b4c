"""A contact sheet of random pairs, with the ground-truth horizon drawn in, to check renders by eye."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from stereogeo_cli.geometry import latitude_field, roll_pitch_from_gravity
from stereogeo_cli.synth.config import SynthConfig
from stereogeo_cli.synth.sample import StereoSample, sample_pair

TILE = 240  # height in pixels of one view on the sheet


def _with_horizon(image: np.ndarray, camera: dict) -> np.ndarray:
    """The view with the ground-truth horizon (latitude 0) in red and a green "up" tick at the centre."""
    h, w = image.shape[:2]
    focal = camera["K"][0][0]
    g = np.array(camera["gravity_up"])
    lat = latitude_field(g, focal, w, h)
    above = lat > 0
    edge = np.zeros_like(above)
    edge[:, 1:] |= above[:, 1:] != above[:, :-1]
    edge[1:, :] |= above[1:, :] != above[:-1, :]
    out = image.copy()
    out[edge] = (255, 0, 0)
    # the up direction at the image centre: (g_x, g_y), as in the up field at the principal point
    c = np.array([w / 2, h / 2])
    up = g[:2] / max(np.linalg.norm(g[:2]), 1e-9)
    cv2.line(out, tuple(int(v) for v in c), tuple(int(v) for v in c + 0.12 * min(w, h) * up), (0, 255, 0), 2)
    return out


def pair_tile(sample: StereoSample) -> np.ndarray:
    """Both views side by side at height TILE, horizons drawn, and a caption."""
    views = []
    for image, cam in ((sample.left, sample.calib["left"]), (sample.right, sample.calib["right"])):
        marked = _with_horizon(image, cam)
        scale = TILE / marked.shape[0]
        views.append(cv2.resize(marked, (round(marked.shape[1] * scale), TILE), interpolation=cv2.INTER_AREA))
    tile = np.hstack([views[0], np.full((TILE, 4, 3), 255, np.uint8), views[1]])
    c = sample.calib
    roll, pitch = np.degrees(roll_pitch_from_gravity(np.array(c["left"]["gravity_up"])))
    text = (
        f"{c['id']} {c['scene']} vfov {c['vfov_deg'][0]:.0f}/{c['vfov_deg'][1]:.0f} "
        f"r {roll:.0f} p {pitch:.0f} b {c['baseline_m']:.2f}m"
    )
    caption = np.full((18, tile.shape[1], 3), 255, np.uint8)
    cv2.putText(caption, text, (3, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([caption, tile])


def contact_sheet(samples: list[StereoSample], columns: int = 2) -> np.ndarray:
    """Pairs in a grid [H x W x 3] uint8 RGB."""
    tiles = [pair_tile(s) for s in samples]
    width = max(t.shape[1] for t in tiles)
    tiles = [np.pad(t, ((0, 6), (0, width - t.shape[1] + 6), (0, 0)), constant_values=255) for t in tiles]
    while len(tiles) % columns:
        tiles.append(np.full_like(tiles[0], 255))
    rows = [np.hstack(tiles[i : i + columns]) for i in range(0, len(tiles), columns)]
    return np.vstack(rows)


def write_preview(
    path: Path, seed: int, config: SynthConfig, count: int = 16, dataset_size: int = 1000
) -> list[int]:
    """Render ``count`` random pairs of dataset ``seed``, write their contact sheet; returns the indices."""
    rng = np.random.default_rng([seed, 0x9E7])
    indices = sorted(int(i) for i in rng.choice(max(dataset_size, count), size=count, replace=False))
    sheet = contact_sheet([sample_pair(seed, i, config) for i in indices])
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".tmp-{os.getpid()}-{path.name}")
    ok, buf = cv2.imencode(".png", cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
    tmp.write_bytes(buf.tobytes())
    os.replace(tmp, path)
    return indices
