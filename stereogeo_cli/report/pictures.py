"""The report's pictures drawn on the images (OpenCV: fast, and a picture needs no axes): the horizon and
gravity, the network's fields, the rectified pair, the matches' coverage and the lens as a grid.

Every function takes RGB images [H x W x 3] uint8 and pixels of the images as given, and returns an RGB
picture at most ``width`` pixels wide.
"""

from __future__ import annotations

import cv2
import numpy as np

from stereogeo_cli.geometry import up_at
from stereogeo_cli.io.calibration import StereoCalibration
from stereogeo_cli.io.preview import render_preview
from stereogeo_cli.report.inputs import FieldMaps

HORIZON = (255, 0, 255)  # RGB, as in the preview image
GRAVITY = (255, 214, 0)
NETWORK = (30, 90, 200)  # the network's up-vectors
MATCH = (40, 230, 90)
EMPTY_CELL = (230, 60, 60)
LENS_GRID = (0, 200, 255)
COVERAGE_CELLS = (8, 6)  # columns, rows of the coverage grid
LATITUDE_STEP_DEG = 10  # the latitude's contour lines


def fit_width(image: np.ndarray, width: int) -> tuple[np.ndarray, float]:
    """``image`` shrunk to at most ``width`` pixels wide (never enlarged), and the scale applied."""
    scale = min(1.0, width / image.shape[1])
    if scale >= 1.0:
        return image.copy(), 1.0
    size = (max(1, round(image.shape[1] * scale)), max(1, round(image.shape[0] * scale)))
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA), scale


def _rgb(image: np.ndarray) -> np.ndarray:
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)
    return np.ascontiguousarray(image[..., :3])


def _dimmed(image: np.ndarray, keep: float = 0.55) -> np.ndarray:
    """The image in grey, faded towards white: what is drawn on it stands out."""
    grey = cv2.cvtColor(_rgb(image), cv2.COLOR_RGB2GRAY).astype(np.float32)
    faded = 255.0 - keep * (255.0 - grey)
    return cv2.cvtColor(faded.astype(np.uint8), cv2.COLOR_GRAY2RGB)


def distort(points: np.ndarray, K: np.ndarray, D: np.ndarray) -> np.ndarray:
    """Pixels [N x 2] of an ideal pinhole camera K → where the lens D (OpenCV) puts them."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if D is None or not np.any(D) or len(points) == 0:
        return points
    rays = np.column_stack([points, np.ones(len(points))]) @ np.linalg.inv(K).T
    found, _ = cv2.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, np.asarray(D, float))
    return found.reshape(-1, 2)


def _polyline(picture: np.ndarray, points: np.ndarray, scale: float, colour, thickness: int) -> None:
    ok = np.isfinite(points).all(axis=1)
    if ok.sum() >= 2:
        pts = np.round((points[ok] + 0.5) * scale - 0.5).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(picture, [pts], False, colour, thickness, cv2.LINE_AA)


def horizon_points(
    K: np.ndarray, gravity: np.ndarray, size: tuple[int, int], samples: int = 64
) -> np.ndarray:
    """Points [N x 2] of the horizon (the rays at right angles to gravity) across an ideal pinhole image of
    ``size`` (width, height) and a margin of a tenth around it; none where it misses that area."""
    w, h = size
    a, b, c = np.linalg.inv(K).T @ np.asarray(gravity, dtype=float)
    if abs(b) >= abs(a):
        x = np.linspace(-0.1 * w, 1.1 * w, samples)
        points = np.column_stack([x, -(a * x + c) / b])
    else:
        y = np.linspace(-0.1 * h, 1.1 * h, samples)
        points = np.column_stack([-(b * y + c) / a, y])
    inside = (points[:, 0] >= -0.1 * w) & (points[:, 0] <= 1.1 * w)
    inside &= (points[:, 1] >= -0.1 * h) & (points[:, 1] <= 1.1 * h)
    return points[inside]


def gravity_picture(image: np.ndarray, K: np.ndarray, D: np.ndarray, gravity: np.ndarray, width: int = 480):
    """The image with the calibrated horizon (magenta, through the lens) and the calibrated up direction as
    arrows on a grid (yellow)."""
    picture, scale = fit_width(_rgb(image), width)
    h, w = image.shape[:2]
    _polyline(picture, distort(horizon_points(K, gravity, (w, h)), K, D), scale, HORIZON, 2)
    xs, ys = np.meshgrid((np.arange(6) + 0.5) * w / 6, (np.arange(4) + 0.5) * h / 4)
    ups = up_at(np.asarray(gravity, float), float(K[0, 0]), xs, ys, float(K[0, 2]), float(K[1, 2]))
    length = 0.09 * min(w, h) * scale
    for x, y, (ux, uy) in zip(xs.ravel(), ys.ravel(), ups.reshape(-1, 2), strict=True):
        start = np.array([x, y]) * scale
        end = start + length * np.array([ux, uy])
        for colour, thickness in (((0, 0, 0), 4), (GRAVITY, 2)):
            cv2.arrowedLine(picture, _pt(start), _pt(end), colour, thickness, cv2.LINE_AA, tipLength=0.3)
    return picture


def _pt(p) -> tuple[int, int]:
    return round(float(p[0])), round(float(p[1]))


def _crop(image: np.ndarray, extent: tuple[float, float, float, float]) -> np.ndarray:
    """The part of ``image`` that the field grid covers."""
    h, w = image.shape[:2]
    x0, y0, x1, y1 = (round(v) for v in extent)
    x0, y0, x1, y1 = max(0, x0), max(0, y0), min(w, x1), min(h, y1)
    return image[y0:y1, x0:x1] if x1 > x0 and y1 > y0 else image


def up_field_picture(image: np.ndarray, maps: FieldMaps, K: np.ndarray, gravity: np.ndarray,
                     width: int = 320) -> np.ndarray:  # fmt: skip
    """The network's up-vectors (blue) on the faded part of the image it read, every few cells, each beside
    the calibrated up direction at that cell (yellow)."""
    crop = _crop(image, maps.extent)
    picture = _dimmed(fit_width(_rgb(crop), width)[0])
    gh, gw = maps.latitude.shape
    step = max(1, round(gw / 8))
    x0, y0, x1, y1 = maps.extent
    sx, sy = picture.shape[1] / (x1 - x0), picture.shape[0] / (y1 - y0)
    length = 0.7 * step * min(picture.shape[1] / gw, picture.shape[0] / gh)
    for i in range(step // 2, gh, step):
        for j in range(step // 2, gw, step):
            x, y = x0 + (j + 0.5) * (x1 - x0) / gw, y0 + (i + 0.5) * (y1 - y0) / gh  # the image's pixels
            centre = np.array([(x - x0) * sx, (y - y0) * sy])
            calibrated = up_at(np.asarray(gravity, float), float(K[0, 0]), x - 0.5, y - 0.5, K[0, 2], K[1, 2])
            network = maps.up[i, j] / max(float(np.linalg.norm(maps.up[i, j])), 1e-9)
            # the calibrated arrow wide and the network's thin on top: where they agree, one yellow arrow
            # with a blue core; where they part, two
            for direction, colour, thickness, halo in ((calibrated, GRAVITY, 5, 7), (network, NETWORK, 2, 0)):
                tip = _pt(centre + length * np.asarray(direction, float).reshape(2))
                if halo:
                    cv2.arrowedLine(picture, _pt(centre), tip, (0, 0, 0), halo, cv2.LINE_AA, tipLength=0.3)
                cv2.arrowedLine(picture, _pt(centre), tip, colour, thickness, cv2.LINE_AA, tipLength=0.3)
    return picture


def colour_table(name: str) -> np.ndarray:
    """A matplotlib colour map as a table [256 x 3] uint8 (RGB)."""
    import matplotlib

    return np.round(matplotlib.colormaps[name](np.linspace(0.0, 1.0, 256))[:, :3] * 255).astype(np.uint8)


def _map_picture(values: np.ndarray, low: float, high: float, cmap: str, size: tuple[int, int]) -> np.ndarray:
    index = np.clip((values - low) / (high - low), 0.0, 1.0) * 255
    big = cv2.resize(index.astype(np.float32), size, interpolation=cv2.INTER_LINEAR)
    return colour_table(cmap)[np.round(big).astype(np.uint8)]


def latitude_range_deg(maps: FieldMaps) -> float:
    """The colour scale's half range in degrees: the field's largest |latitude| up to the next 10°."""
    largest = float(np.degrees(np.nanmax(np.abs(maps.latitude)))) if maps.latitude.size else 0.0
    return float(min(90.0, max(LATITUDE_STEP_DEG, np.ceil(largest / LATITUDE_STEP_DEG) * LATITUDE_STEP_DEG)))


def latitude_picture(maps: FieldMaps, width: int = 320) -> np.ndarray:
    """The network's latitude field in colour (blue below the horizon, red above, the scale of
    :func:`latitude_range_deg`), with a contour every 10° and the horizon (0°) in white."""
    size = _map_size(maps, width)
    degrees = np.degrees(maps.latitude)
    half = latitude_range_deg(maps)
    picture = _map_picture(degrees, -half, half, "coolwarm", size)
    big = cv2.resize(degrees.astype(np.float32), size, interpolation=cv2.INTER_LINEAR)
    # the contours of the field lightly smoothed (over about a cell): the colours show it as read
    cell = size[0] / degrees.shape[1]
    big = cv2.GaussianBlur(big, (0, 0), max(0.8 * cell, 0.5))
    level = np.floor(big / LATITUDE_STEP_DEG)
    edge = np.zeros(level.shape, bool)
    edge[:, 1:] |= level[:, 1:] != level[:, :-1]
    edge[1:, :] |= level[1:, :] != level[:-1, :]
    horizon = edge & (np.abs(big) < 0.5 * LATITUDE_STEP_DEG)
    picture[edge] = (40, 40, 40)
    picture[cv2.dilate(horizon.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0] = (255, 255, 255)
    return picture


def confidence_picture(confidence: np.ndarray, maps: FieldMaps, width: int = 320) -> np.ndarray:
    """A confidence map in (0, 1) in colour (viridis: dark 0, yellow 1)."""
    return _map_picture(np.asarray(confidence, float), 0.0, 1.0, "viridis", _map_size(maps, width))


def _map_size(maps: FieldMaps, width: int) -> tuple[int, int]:
    x0, y0, x1, y1 = maps.extent
    w = min(width, max(16, round(x1 - x0)))
    return w, max(1, round(w * (y1 - y0) / (x1 - x0)))


def colour_bar(cmap: str, width: int = 200, height: int = 10) -> np.ndarray:
    """A colour map's bar, low on the left."""
    return np.repeat(colour_table(cmap)[np.linspace(0, 255, width).astype(int)][None], height, axis=0)


def rectified_picture(
    left: np.ndarray, right: np.ndarray, calibration: StereoCalibration, width: int = 1100
) -> np.ndarray:
    """The rectified pair side by side with rows every 32 px and the horizons (the ``--preview`` image)."""
    return fit_width(render_preview(_rgb(left), _rgb(right), calibration), width)[0]


def coverage(
    points: np.ndarray, size: tuple[int, int], cells: tuple[int, int] = COVERAGE_CELLS
) -> np.ndarray:
    """Matches per cell of a ``cells`` (columns, rows) grid over an image of ``size`` (width, height):
    [rows x columns]."""
    w, h = size
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    col = np.clip((points[:, 0] + 0.5) * cells[0] // w, 0, cells[0] - 1).astype(int)
    row = np.clip((points[:, 1] + 0.5) * cells[1] // h, 0, cells[1] - 1).astype(int)
    counts = np.zeros((cells[1], cells[0]), dtype=int)
    np.add.at(counts, (row, col), 1)
    return counts


def coverage_picture(image: np.ndarray, points: np.ndarray, K: np.ndarray, D: np.ndarray, width: int = 480):
    """The matches (green) on the faded image, the cells of the coverage grid with none of them tinted
    red, and where a lens was fitted (D not zero) the image of a square grid through it (cyan)."""
    h, w = image.shape[:2]
    picture, scale = fit_width(_rgb(image), width)
    picture = _dimmed(picture)
    counts = coverage(points, (w, h))
    rows, cols = counts.shape
    tint = picture.copy()
    for r in range(rows):
        for c in range(cols):
            if counts[r, c] == 0:
                top_left = _pt((c * w / cols * scale, r * h / rows * scale))
                bottom_right = _pt(((c + 1) * w / cols * scale, (r + 1) * h / rows * scale))
                cv2.rectangle(tint, top_left, bottom_right, EMPTY_CELL, -1)
    picture = cv2.addWeighted(tint, 0.35, picture, 0.65, 0)
    if D is not None and np.any(D):
        _lens_grid(picture, K, np.asarray(D, float), (w, h), scale)
    for x, y in np.asarray(points, float).reshape(-1, 2):
        cv2.circle(
            picture, _pt(((x + 0.5) * scale - 0.5, (y + 0.5) * scale - 0.5)), 2, MATCH, -1, cv2.LINE_AA
        )
    return picture


def _lens_grid(
    picture: np.ndarray, K: np.ndarray, D: np.ndarray, size: tuple[int, int], scale: float
) -> None:
    """Straight lines of a square grid of an ideal pinhole image, drawn where the lens puts them."""
    w, h = size
    step = min(w, h) / 6
    for x in np.arange(w / 2 % step, w, step):
        _polyline(picture, distort(np.column_stack([np.full(48, x), np.linspace(0, h - 1, 48)]), K, D), scale,
                  LENS_GRID, 1)  # fmt: skip
    for y in np.arange(h / 2 % step, h, step):
        _polyline(picture, distort(np.column_stack([np.linspace(0, w - 1, 48), np.full(48, y)]), K, D), scale,
                  LENS_GRID, 1)  # fmt: skip


def encode(picture: np.ndarray, kind: str = "jpeg") -> bytes:
    """An RGB picture as JPEG (photographs) or PNG (maps, plots) bytes."""
    bgr = cv2.cvtColor(picture, cv2.COLOR_RGB2BGR)
    if kind == "jpeg":
        ok, data = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, 85])
    else:
        ok, data = cv2.imencode(".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, 3])
    if not ok:
        raise RuntimeError(f"{kind} encoding of a report picture failed")
    return data.tobytes()
