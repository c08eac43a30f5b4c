"""Texture and panorama sources: photos, procedural materials and skies, all deterministic for a seed.

Default sources (no extra files): the CC0 / public-domain photos that ship inside scikit-image
(``brick``, ``grass``, ``gravel``, ``coffee``, ``chelsea``, ``camera``, ``astronaut``, ``rocket``) and
procedural materials (planks, tiles, plaster, carpet, bricks, facades with windows, asphalt, grass,
doors, car paint, metal) and procedural skies. ``--textures DIR`` adds the user's photos,
``--panoramas DIR`` replaces the procedural skies with real equirectangular panoramas.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from stereogeo_cli.errors import StereoGeoError

IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp"}

# scikit-image sample photos: name → (licence note, tags it may serve as, colour tint for grey images)
_SKIMAGE_PHOTOS = {
    "brick": ({"wall", "facade"}, (0.75, 0.45, 0.35)),
    "grass": ({"ground"}, (0.45, 0.65, 0.3)),
    "gravel": ({"ground", "pavement"}, (0.85, 0.8, 0.72)),
    "coffee": ({"object", "poster"}, None),
    "chelsea": ({"object", "poster"}, None),
    "camera": ({"poster"}, (0.9, 0.9, 0.9)),
    "astronaut": ({"poster"}, None),
    "rocket": ({"poster", "object"}, None),
}


@dataclass(frozen=True)
class Material:
    """One layer of the texture pool."""

    image: np.ndarray  # [S x S x 3] uint8 RGB
    tags: frozenset[str]  # what surfaces it may cover: wall, floor, ceiling, facade, ground, road, ...
    tile_m: tuple[float, float]  # (width, height) in metres that one copy of the texture covers
    mirror: bool  # photos are mirror-repeated (no visible seams); procedural ones repeat seamlessly


def list_images(folder: Path) -> list[Path]:
    """Image files in a folder (sorted, so the order is the same on every machine)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise StereoGeoError(f"not a folder: {folder}")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise StereoGeoError(f"no images (.jpg, .png, ...) in {folder}")
    return files


def read_rgb(path: Path) -> np.ndarray:
    """An image file as [H x W x 3] uint8 RGB (grey, 16-bit and RGBA are converted)."""
    image = cv2.imread(os.fspath(path), cv2.IMREAD_COLOR)
    if image is None:
        raise StereoGeoError(f"cannot read image {path}")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


# --- procedural building blocks ------------------------------------------------------------------------


def tileable_noise(rng: np.random.Generator, size: int, octaves: int = 5, base: int = 4) -> np.ndarray:
    """Seamlessly tileable fractal noise [size x size] float32 in about [-1, 1]."""
    out = np.zeros((size, size), np.float32)
    amplitude, total = 1.0, 0.0
    for octave in range(octaves):
        n = base * 2**octave
        if n > size:
            break
        grid = rng.standard_normal((n, n)).astype(np.float32)
        padded = np.pad(grid, 2, mode="wrap")  # periodic interpolation across the border
        scale = size / n
        big = cv2.resize(
            padded, (round((n + 4) * scale), round((n + 4) * scale)), interpolation=cv2.INTER_CUBIC
        )
        offset = round(2 * scale)
        out += amplitude * big[offset : offset + size, offset : offset + size]
        total += amplitude
        amplitude *= 0.55
    return out / max(total, 1e-9)


def _colorize(shade: np.ndarray, color: np.ndarray) -> np.ndarray:
    return np.clip(shade[..., None] * np.asarray(color, np.float32)[None, None] * 255.0, 0, 255).astype(
        np.uint8
    )


def _random_color(
    rng: np.random.Generator, base: tuple[float, float, float], spread: float = 0.12
) -> np.ndarray:
    return np.clip(np.asarray(base) * np.exp(rng.normal(0.0, spread, 3)), 0.02, 1.0)


def _muted_color(rng: np.random.Generator, lo: float, hi: float, saturation: float) -> np.ndarray:
    """A colour of brightness in [lo, hi] with at most ``saturation`` of a random hue mixed in."""
    level = rng.uniform(lo, hi)
    hue = rng.uniform(0.3, 1.0, 3)
    hue /= hue.max()
    mix = rng.uniform(0.0, saturation)
    return level * ((1 - mix) + mix * hue)


def planks(rng: np.random.Generator, size: int) -> np.ndarray:
    boards = int(rng.integers(4, 9))
    color = _random_color(rng, (0.62, 0.43, 0.26), 0.25)
    grain = tileable_noise(rng, size, base=8)
    y = np.arange(size)[:, None]
    board = (y * boards // size) % boards
    offsets = rng.uniform(0.85, 1.15, boards).astype(np.float32)
    streak = np.sin(np.arange(size)[None, :] * rng.uniform(0.05, 0.2) + grain * 6) * 0.06
    shade = offsets[board] * (0.9 + 0.12 * grain + streak)
    shade[((y * boards) % size < max(2, size // 256))[:, 0]] *= 0.45  # gaps between boards
    return _colorize(shade, color)


def tiles(rng: np.random.Generator, size: int) -> np.ndarray:
    count = int(rng.choice([2, 4, 8]))
    color = _muted_color(rng, 0.5, 0.95, 0.4)
    noise = tileable_noise(rng, size, base=16)
    cell = size // count
    jitter = rng.uniform(0.88, 1.08, (count, count)).astype(np.float32)
    yy, xx = np.mgrid[0:size, 0:size]
    shade = jitter[yy // cell, xx // cell] * (0.95 + 0.05 * noise)
    grout = (yy % cell < max(2, size // 128)) | (xx % cell < max(2, size // 128))
    shade[grout] = 0.55
    return _colorize(shade, color)


def plaster(rng: np.random.Generator, size: int) -> np.ndarray:
    """Painted plaster or concrete: mottled, with stains and a few cracks (real walls are rarely blank)."""
    color = _muted_color(rng, 0.6, 0.95, 0.3)
    shade = (
        0.9 + 0.08 * tileable_noise(rng, size, base=4) + 0.08 * tileable_noise(rng, size, base=32, octaves=3)
    )
    stains = np.clip(tileable_noise(rng, size, base=8) * 3 - rng.uniform(1.0, 2.0), 0, 1)
    shade -= rng.uniform(0.08, 0.2) * stains
    out = _colorize(shade, color)
    darker = tuple(int(c * 255 * rng.uniform(0.5, 0.75)) for c in color)
    for _ in range(int(rng.integers(2, 8))):  # hairline cracks and scuffs
        p = rng.uniform(size * 0.1, size * 0.9, 2)
        points = [p]
        for _ in range(int(rng.integers(3, 10))):
            p = np.clip(p + rng.normal(0, size / 40, 2), 0, size - 1)
            points.append(p)
        cv2.polylines(out, [np.int32(points).reshape(-1, 1, 2)], False, darker, 1, cv2.LINE_AA)
    return out


def stones(rng: np.random.Generator, size: int) -> np.ndarray:
    """A wall or paving of irregular stones (Voronoi cells), seamless."""
    n = int(rng.integers(20, 60))
    seeds = np.zeros((3 * size, 3 * size), np.uint8) + 255
    points = rng.uniform(0, size, (n, 2)).astype(int)
    for dy in range(3):
        for dx in range(3):
            for x, y in points:
                seeds[y + dy * size, x + dx * size] = 0
    dist, labels = cv2.distanceTransformWithLabels(seeds, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    labels = labels[size : 2 * size, size : 2 * size]
    dist = dist[size : 2 * size, size : 2 * size]
    # the same stone in every tile copy gets the same colour: label → seed point index
    ys, xs = np.nonzero(seeds == 0)
    point_of_label = np.zeros(labels.max() + 1, int)
    point_of_label[1:] = (((ys % size) * size + (xs % size)) % 7919)[: labels.max()]
    jitter = rng.uniform(0.7, 1.15, 7919).astype(np.float32)
    shade = jitter[point_of_label[labels]] * (0.92 + 0.08 * tileable_noise(rng, size, base=32, octaves=3))
    edge = cv2.dilate(
        (cv2.Laplacian(labels.astype(np.float32), cv2.CV_32F) != 0).astype(np.uint8), np.ones((3, 3))
    )
    shade[edge > 0] *= 0.45
    del dist
    tone = _random_color(rng, (0.62, 0.58, 0.52), 0.12)
    return _colorize(shade, tone)


def wallpaper(rng: np.random.Generator, size: int) -> np.ndarray:
    """Patterned wallpaper: stripes or scattered motifs over a muted ground."""
    base = plaster(rng, size)
    ink = tuple(int(v * 255) for v in _muted_color(rng, 0.2, 0.7, 0.8))
    out = base.copy()
    if rng.random() < 0.5:
        stripes = int(rng.choice([4, 8, 16]))
        width = size // stripes
        for k in range(stripes):
            if k % 2 == 0:
                cv2.rectangle(out, (k * width, 0), (k * width + width // 3, size), ink, -1)
    else:
        for _ in range(int(rng.integers(15, 40))):
            c = rng.uniform(0, size, 2).astype(int)
            r = int(rng.uniform(size / 50, size / 14))
            round_motif = rng.random() < 0.5
            for dx in (-size, 0, size):
                for dy in (-size, 0, size):
                    x, y = int(c[0] + dx), int(c[1] + dy)
                    if round_motif:
                        cv2.circle(out, (x, y), r, ink, -1, cv2.LINE_AA)
                    else:
                        cv2.rectangle(out, (x - r, y - r), (x + r, y + r), ink, 3)
    return cv2.addWeighted(out, 0.8, base, 0.2, 0)


def carpet(rng: np.random.Generator, size: int) -> np.ndarray:
    color = _muted_color(rng, 0.2, 0.7, 0.6)
    shade = (
        0.9 + 0.08 * tileable_noise(rng, size, base=8) + 0.1 * tileable_noise(rng, size, base=128, octaves=2)
    )
    return _colorize(shade, color)


def bricks(rng: np.random.Generator, size: int) -> np.ndarray:
    rows, cols = 8, 4  # one tile is about 4 bricks wide, 8 courses high
    color = _random_color(rng, (0.62, 0.3, 0.22), 0.18)
    noise = tileable_noise(rng, size, base=32, octaves=3)
    yy, xx = np.mgrid[0:size, 0:size]
    row = yy * rows // size
    shifted = (xx + (row % 2) * size // (2 * cols)) % size
    col = shifted * cols // size
    jitter = rng.uniform(0.8, 1.15, (rows, cols)).astype(np.float32)
    shade = jitter[row, col] * (0.92 + 0.08 * noise)
    mortar = ((yy * rows) % size < size // 64 * rows // 4 + 2) | (
        (shifted * cols) % size < size // 64 * cols // 4 + 2
    )
    out = _colorize(shade, color)
    out[mortar] = (np.array([0.75, 0.72, 0.68]) * 255 * rng.uniform(0.7, 1.0)).astype(np.uint8)
    return out


def facade(rng: np.random.Generator, size: int) -> np.ndarray:
    """One storey by one bay: a window in a wall (tiles into a grid of windows)."""
    wall = plaster(rng, size) if rng.random() < 0.6 else bricks(rng, size)
    out = wall.copy()
    w0, w1 = (rng.uniform(0.18, 0.3), rng.uniform(0.7, 0.82))
    h0, h1 = (rng.uniform(0.2, 0.35), rng.uniform(0.72, 0.85))
    x0, x1, y0, y1 = (int(v * size) for v in (w0, w1, h0, h1))
    frame = max(3, size // 64)
    out[y0 - frame : y1 + frame, x0 - frame : x1 + frame] = (
        np.array(_random_color(rng, (0.8, 0.8, 0.8), 0.3)) * 255
    ).astype(np.uint8)
    glass_color = _random_color(rng, (0.25, 0.32, 0.4), 0.25)
    gradient = np.linspace(1.2, 0.7, y1 - y0, dtype=np.float32)[:, None] * np.ones((1, x1 - x0), np.float32)
    out[y0:y1, x0:x1] = _colorize(gradient, glass_color)
    mid = (x0 + x1) // 2
    out[y0:y1, mid - frame // 2 : mid + frame // 2 + 1] = out[y0 - 1, x0 - 1]
    return out


def asphalt(rng: np.random.Generator, size: int) -> np.ndarray:
    level = rng.uniform(0.25, 0.45)
    shade = (
        1.0 + 0.08 * tileable_noise(rng, size, base=4) + 0.15 * tileable_noise(rng, size, base=128, octaves=2)
    )
    return _colorize(shade, _random_color(rng, (level, level, level * 1.02), 0.04))


def grass(rng: np.random.Generator, size: int) -> np.ndarray:
    shade = (
        0.85 + 0.2 * tileable_noise(rng, size, base=4) + 0.2 * tileable_noise(rng, size, base=128, octaves=2)
    )
    return _colorize(shade, _random_color(rng, (0.3, 0.5, 0.18), 0.15))


def door(rng: np.random.Generator, size: int) -> np.ndarray:
    out = planks(rng, size) if rng.random() < 0.5 else plaster(rng, size)
    out = np.ascontiguousarray(np.rot90(out)) if rng.random() < 0.5 else out
    margin, frame = size // 8, max(3, size // 40)
    for y0, y1 in ((margin, size // 2 - margin // 2), (size // 2 + margin // 2, size - margin)):
        out[y0 : y0 + frame, margin:-margin] //= 2
        out[y1 - frame : y1, margin:-margin] //= 2
        out[y0:y1, margin : margin + frame] //= 2
        out[y0:y1, -margin - frame : -margin] //= 2
    handle = (int(size * 0.8), size // 2)
    cv2.circle(out, handle, max(4, size // 40), (200, 190, 150), -1)
    return out


def car_paint(rng: np.random.Generator, size: int) -> np.ndarray:
    """A car body side: paint below, dark glass above (the tile spans the car's height)."""
    base = tuple(rng.uniform(0.1, 0.9, 3)) if rng.random() < 0.6 else (rng.uniform(0.1, 0.9),) * 3
    shade = 0.95 + 0.03 * tileable_noise(rng, size, base=4)
    out = _colorize(shade, _random_color(rng, base, 0.05))
    glass = int(size * rng.uniform(0.3, 0.4))
    out[:glass] = _colorize(shade[:glass] * 0.9, (0.12, 0.14, 0.17))
    out[glass : glass + size // 40] = 30
    return out


def metal(rng: np.random.Generator, size: int) -> np.ndarray:
    level = rng.uniform(0.3, 0.8)
    shade = 1.0 + 0.04 * tileable_noise(rng, size, base=4)
    return _colorize(shade, _random_color(rng, (level, level, level), 0.06))


# name → (generator, tags, tile size range in metres (square unless given))
_PROCEDURAL = [
    (planks, {"floor", "object"}, (1.0, 3.0)),
    (tiles, {"floor", "pavement", "wall"}, (0.6, 2.4)),
    (plaster, {"wall", "ceiling", "object"}, (1.0, 3.0)),
    (stones, {"wall", "pavement", "facade", "ground"}, (1.0, 2.5)),
    (wallpaper, {"wall"}, (0.5, 1.5)),
    (carpet, {"floor"}, (1.0, 3.0)),
    (bricks, {"wall", "facade", "object"}, (0.5, 0.9)),
    (facade, {"facade"}, (2.5, 4.0)),
    (facade, {"facade"}, (2.5, 4.0)),
    (asphalt, {"road", "ground"}, (2.0, 5.0)),
    (grass, {"ground"}, (1.5, 4.0)),
    (door, {"door"}, (1.0, 1.0)),
    (car_paint, {"car"}, (1.0, 1.0)),
    (metal, {"pole", "object"}, (1.0, 1.0)),
]


def grime(rng: np.random.Generator, size: int) -> np.ndarray:
    """Dirt and wear in the red channel (0.5 = none), overlaid on every surface at a scale that does not
    divide the material's tile: real surfaces are never exact repeats, and matchers need the detail."""
    g = 0.5 + 0.25 * tileable_noise(rng, size, base=8) + 0.3 * tileable_noise(rng, size, base=64, octaves=3)
    g += 0.25 * np.clip(tileable_noise(rng, size, base=16, octaves=3) * 3 - 1.2, 0, 1)
    return np.repeat(np.clip(g * 255, 0, 255).astype(np.uint8)[..., None], 3, axis=2)


def _square_crop(rng: np.random.Generator, image: np.ndarray, size: int) -> np.ndarray:
    h, w = image.shape[:2]
    side = int(min(h, w) * rng.uniform(0.6, 1.0))
    y = int(rng.integers(0, h - side + 1))
    x = int(rng.integers(0, w - side + 1))
    crop = image[y : y + side, x : x + side]
    interp = cv2.INTER_AREA if side > size else cv2.INTER_CUBIC
    return cv2.resize(crop, (size, size), interpolation=interp)


def skimage_photos() -> list[tuple[str, np.ndarray, set[str]]]:
    """The scikit-image sample photos as RGB, with the surfaces they may cover."""
    import skimage.data

    photos = []
    for name, (tags, tint) in _SKIMAGE_PHOTOS.items():
        image = getattr(skimage.data, name)()
        if name == "brick":  # scikit-image stores it rotated by 90°
            image = np.ascontiguousarray(np.rot90(image, -1))
        if image.ndim == 2:
            grey = image.astype(np.float32) / 255.0
            image = _colorize(grey, tint or (1.0, 1.0, 1.0))
        photos.append((name, image[..., :3], set(tags)))
    return photos


def panorama_patches(rng: np.random.Generator, panorama: np.ndarray, count: int) -> list[np.ndarray]:
    """Patches of a panorama's ground (30–75° below the horizon), as extra ground textures."""
    h, w = panorama.shape[:2]
    patches = []
    for _ in range(count):
        side = int(h * rng.uniform(0.08, 0.15))
        y = int(rng.uniform(0.67, 0.92 - side / h) * h)
        x = int(rng.integers(0, w - side))
        patches.append(panorama[y : y + side, x : x + side])
    return patches


def looks_like_sky(panorama: np.ndarray) -> bool:
    """Whether a panorama shows open sky above (outdoor): its band 27–72° above the horizon is mostly
    blue-dominant and smooth. Indoor panoramas (ceilings) and forest canopies fail the test."""
    small = cv2.resize(panorama, (512, 256), interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0
    band = small[int(256 * 0.1) : int(256 * 0.35)]
    grey = cv2.cvtColor(band, cv2.COLOR_RGB2GRAY)
    gradient = float(
        np.abs(cv2.Sobel(grey, cv2.CV_32F, 1, 0)).mean() + np.abs(cv2.Sobel(grey, cv2.CV_32F, 0, 1)).mean()
    )
    blue = float((band[..., 2] > band[..., 0]).mean())
    return blue >= 0.6 and gradient < 0.25


def build_material_pool(
    seed: int,
    size: int,
    layers: int,
    textures_dir: Path | None = None,
    panorama_files: list[Path] | None = None,
) -> list[Material]:
    """The per-process texture pool: the same list in every process for the same arguments."""
    rng = np.random.default_rng([seed, 0x5EED, 1])
    pool: list[Material] = []
    n_procedural = max(len(_PROCEDURAL), layers // 2)
    for i in range(n_procedural):
        make, tags, (lo, hi) = _PROCEDURAL[i % len(_PROCEDURAL)]
        tile = float(rng.uniform(lo, hi))
        pool.append(Material(make(rng, size), frozenset(tags), (tile, tile), mirror=False))

    photos: list[tuple[np.ndarray, set[str]]] = [(img, tags) for _, img, tags in skimage_photos()]
    if textures_dir is not None:
        generic = {"wall", "floor", "object", "ground", "facade", "pavement", "poster"}
        photos += [(read_rgb(p), generic) for p in list_images(textures_dir)]
    if panorama_files:
        for p in panorama_files[:: max(1, len(panorama_files) // 8)]:
            for patch in panorama_patches(rng, read_rgb(p), 1):
                photos.append((patch, {"ground"}))
    n_photo = max(0, layers - 1 - len(pool))
    order = rng.permutation(len(photos))
    for k in range(n_photo):
        image, tags = photos[order[k % len(photos)]]
        tile = float(rng.uniform(1.0, 3.0))
        pool.append(Material(_square_crop(rng, image, size), frozenset(tags), (tile, tile), mirror=True))
    pool.append(Material(grime(rng, size), frozenset({"grime"}), (1.0, 1.0), mirror=False))  # always last
    return pool


def procedural_sky(rng: np.random.Generator, width: int = 1024) -> np.ndarray:
    """An equirectangular sky [width/2 x width x 3] uint8: gradient, clouds above, plain land below."""
    height = width // 2
    lat = (0.5 - (np.arange(height, dtype=np.float32) + 0.5) / height) * np.float32(np.pi)
    zenith = _random_color(rng, (0.25, 0.45, 0.8), 0.2).astype(np.float32)
    horizon = _random_color(rng, (0.75, 0.82, 0.9), 0.08).astype(np.float32)
    t = np.clip(np.sin(lat), 0, 1)[:, None, None] ** 0.6
    gradient = (1 - t) * horizon + t * zenith  # [height x 1 x 3]

    def noise(base: int) -> np.ndarray:  # generated at half resolution: skies are smooth
        n = tileable_noise(rng, width // 2, base=base)[: height // 2]
        return cv2.resize(n, (width, height), interpolation=cv2.INTER_LINEAR)

    clouds = noise(8) * 1.5 + np.float32(rng.uniform(-0.6, 0.3))
    cover = (np.clip(clouds, 0, 1) * (lat > 0)[:, None])[..., None]
    cloud_color = np.float32(rng.uniform(0.8, 1.0))
    sky = gradient * (1 - cover) + cloud_color * cover
    land = _random_color(rng, (0.35, 0.38, 0.3), 0.06).astype(np.float32)
    ground = land * (0.85 + 0.15 * noise(16)[..., None])
    sky = np.where((lat < 0)[:, None, None], ground, sky)
    return np.clip(sky * 255, 0, 255).astype(np.uint8)
